"""Steps per second of the Rust vectorised environment (`lowthrust.VecEnv`) against the plain
numpy reference implementation (`python/tests/numpy_mdp.py`), on transfer-circular episodes
under uniform random actions, for 1, 64 and 1024 episodes stepped together.

    python python/benchmarks/vec_speed.py [--seconds 5] [--num-envs 1,64,1024] [--substeps 64]

Both sides run the same loop: one call steps every episode; the episodes that finished are
started again on the next scenarios of the stream (the Rust side through `reset` with a mask, the
numpy side likewise), and that time counts. An env step is one episode advanced by one 14-day
step. The Rust side steps the episodes in parallel on every core (rayon; RAYON_NUM_THREADS
limits it); numpy runs on one. Output: comment lines (#) with the machine, then CSV.
Takes about 6 x --seconds plus start-up (about 35 s at the default 5 s).
"""

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

import lowthrust

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from numpy_mdp import DEFAULT_SUBSTEPS, NumpyVecEnv  # noqa: E402

KIND = "transfer-circular"
SEED = 1


def _loop(step, reset_done, n, seconds, rng):
    """Calls `step(actions)` until `seconds` have passed (at least 3 calls), resetting the
    finished episodes after each call; returns (env steps, wall seconds)."""
    actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
    step(actions)  # warm-up
    reset_done()
    calls = 0
    start = time.perf_counter()
    while True:
        actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
        step(actions)
        reset_done()
        calls += 1
        elapsed = time.perf_counter() - start
        if calls >= 3 and elapsed >= seconds:
            return calls * n, elapsed


def bench_rust(n, seconds):
    venv = lowthrust.VecEnv(KIND, n)
    indices = np.arange(n, dtype=np.uint64)
    venv.reset(SEED, indices)
    state = {"next": n, "done": np.zeros(n, dtype=bool)}

    def step(actions):
        _, _, state["done"] = venv.step(actions)

    def reset_done():
        done = state["done"]
        if done.any():
            k = int(done.sum())
            indices[done] = np.arange(state["next"], state["next"] + k, dtype=np.uint64)
            state["next"] += k
            venv.reset(SEED, indices, done)
            state["done"] = np.zeros(n, dtype=bool)

    return _loop(step, reset_done, n, seconds, np.random.default_rng(0))


def bench_numpy(n, seconds, substeps, pool):
    sc = lowthrust.spacecraft()
    scenarios = list(pool[:n])
    env = NumpyVecEnv("transfer", scenarios, sc["thrust"], sc["exhaust_speed"], substeps=substeps)
    env.reset()
    state = {"next": n}

    def step(actions):
        env.step(actions)

    def reset_done():
        done = env.done
        if done.any():
            for i in np.flatnonzero(done):
                scenarios[i] = pool[state["next"] % len(pool)]
                state["next"] += 1
            env.reset(mask=done, scenarios=scenarios)

    return _loop(step, reset_done, n, seconds, np.random.default_rng(0))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="timed seconds per measurement")
    parser.add_argument("--num-envs", default="1,64,1024", help="comma-separated episode counts")
    parser.add_argument("--substeps", type=int, default=DEFAULT_SUBSTEPS, help="numpy RK4 substeps per step")
    args = parser.parse_args()
    sizes = [int(s) for s in args.num_envs.split(",")]

    print(f"# machine: processor={platform.processor() or platform.machine()!r}, cpu_count={os.cpu_count()}, "
          f"platform={platform.platform()!r}")
    print(f"# python {platform.python_version()}, numpy {np.__version__}, "
          f"RAYON_NUM_THREADS={os.environ.get('RAYON_NUM_THREADS', 'unset')}")
    print(f"# scenario {KIND}, seed {SEED}, uniform random actions; numpy RK4 substeps {args.substeps} "
          f"(Rust: DOP853 rtol 1e-12); {args.seconds:g} s per measurement")
    # The numpy side's scenarios, drawn before any timing (the Rust side draws its own in reset).
    pool = [lowthrust.draw_scenario(KIND, SEED, i) for i in range(max(sizes) * 4)]
    print("scenario,num_envs,rust_steps_per_s,numpy_steps_per_s,ratio_rust_over_numpy")
    for n in sizes:
        rust_steps, rust_s = bench_rust(n, args.seconds)
        np_steps, np_s = bench_numpy(n, args.seconds, args.substeps, pool)
        rust_rate, np_rate = rust_steps / rust_s, np_steps / np_s
        print(f"{KIND},{n},{rust_rate:.1f},{np_rate:.1f},{rust_rate / np_rate:.2f}", flush=True)


if __name__ == "__main__":
    main()
