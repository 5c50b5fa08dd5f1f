"""The Rust environments against an independent plain-numpy implementation of the same MDPs
(`numpy_mdp.py`: fixed-step RK4 on thrusting steps, Kepler's equation in eccentric anomaly on
coasting steps and for the rendezvous body), whole episodes of 20 scenarios of each of the four
scenario kinds under random actions.

Tolerances, and why:

- positions, velocities and every feature: 1e-8 absolute (canonical units, AU and AU/t*). The
  two sides integrate the thrusting steps differently and each has its own error. The Rust
  side's (adaptive DOP853 at rtol 1e-12, atol 1e-13, per 14-day step) accumulates over an
  episode to at most ~7e-10 on the hard scenarios (periapsis down to ~0.1 AU), measured against
  the same integrator at rtol 1e-14, and ~5e-11 on the circular ones. The numpy side's RK4 at its
  default 64 substeps per step (at a 1 AU time scale; more, by powers of two, for orbits reaching
  closer to the Sun) differs from its own converged answer by at most ~2e-9 (it is 4th order:
  halving the substeps multiplies that by ~16). Over 200 random hard episodes the two sides
  agreed to 1.0e-9, so 1e-8 leaves a margin of ~5 and still catches any modelling difference
  (a frozen inertial thrust direction, for instance, is off by up to 0.06 AU).
- rewards: 1e-8 absolute. The reward's slope in the residuals is at most ~0.4, so feature
  errors of 1e-8 move it by less; measured differences are at most 2e-10.
- mass: 1e-13. The mass is linear in time under a held throttle and both sides get it exactly
  up to rounding (measured ~1e-15).
- throttle flown and done flags: equal. The same float32 action is decoded the same way
  (clamped in float32, u = (a0 + 1)/2, thrust off below |(a1, a2)| = 1e-6) and N is the same.
- observations (float32): the float32 rounding of features that agree to 1e-8 may differ by that
  plus one float32 ulp (a rounding boundary between the two values), so that is the bound.
- the first observation (reset): 1e-13, no integration involved (measured ~4e-15, from the
  rendezvous body's two Kepler solutions).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

import lowthrust

sys.path.insert(0, str(Path(__file__).resolve().parent))  # numpy_mdp, whatever pytest's import mode
from numpy_mdp import (  # noqa: E402
    STEP,
    NumpyVecEnv,
    _rk4_polar_hold,
    default_spacecraft,
    kepler_coast,
    orbit_state_at_time,
)

SEED = 424242
EPISODES = 20
ATOL = 1e-8
MASS_ATOL = 1e-13
RESET_ATOL = 1e-13


def _actions(rng, steps):
    """Random actions that visit every branch of the decoding: components beyond [-1, 1]
    (clamped), throttle exactly 0 (Kepler coast), a direction below the 1e-6 threshold
    (thrust off) or exactly zero, and ordinary thrusting ones."""
    a = rng.uniform(-1.25, 1.25, size=(steps, 3)).astype(np.float32)
    pick = rng.random(steps)
    a[pick < 0.15, 0] = -1.0
    tiny = (pick >= 0.15) & (pick < 0.2)
    a[tiny, 1:] = rng.uniform(-7e-7, 7e-7, size=(int(tiny.sum()), 2)).astype(np.float32)
    a[(pick >= 0.2) & (pick < 0.22), 1:] = 0.0
    return a


def _fly_rust(kind, actions):
    """Every episode with lowthrust.Env: per episode the reset features and, per step, the
    observation, reward, done, features, state and throttle."""
    env = lowthrust.Env(kind)
    out = []
    for i in range(EPISODES):
        obs = env.reset(SEED, i)
        episode = {"reset": np.array(env.features, dtype=np.float64), "reset_obs": np.asarray(obs), "steps": []}
        steps = lowthrust.draw_scenario(kind, SEED, i)["steps"]
        for k in range(steps):
            obs, reward, done, info = env.step(actions[i, k])
            episode["steps"].append(
                {
                    "obs": np.asarray(obs),
                    "reward": reward,
                    "done": done,
                    "features": np.asarray(info["features"]),
                    "state": np.asarray(info["state"]),
                    "mass": info["mass"],
                    "throttle": info["throttle"],
                }
            )
        out.append(episode)
    return out


def test_units_and_spacecraft_match_the_package():
    assert STEP == lowthrust.STEP
    thrust, exhaust_speed = default_spacecraft()
    sc = lowthrust.spacecraft()
    assert thrust == pytest.approx(sc["thrust"], rel=1e-15)
    assert exhaust_speed == pytest.approx(sc["exhaust_speed"], rel=1e-15)


@pytest.mark.parametrize("kind", lowthrust.SCENARIOS)
def test_whole_episodes_agree_with_the_rust_environment(kind):
    scenarios = [lowthrust.draw_scenario(kind, SEED, i) for i in range(EPISODES)]
    longest = max(s["steps"] for s in scenarios)
    rng = np.random.default_rng(list(lowthrust.SCENARIOS).index(kind))
    actions = np.stack([_actions(rng, longest) for _ in scenarios])
    rust = _fly_rust(kind, actions)

    sc = lowthrust.spacecraft()
    env = NumpyVecEnv(scenarios[0]["problem"], scenarios, sc["thrust"], sc["exhaust_speed"])
    obs = env.reset()
    worst = {"reset": 0.0, "features": 0.0, "state": 0.0, "reward": 0.0, "mass": 0.0, "obs": 0.0}
    for i, episode in enumerate(rust):
        d = np.abs(env.features[i] - episode["reset"]).max()
        worst["reset"] = max(worst["reset"], d)
        assert d <= RESET_ATOL, f"episode {i} at reset: {d:.3e}"
        gap = np.abs(obs[i].astype(np.float64) - episode["reset_obs"].astype(np.float64))
        assert np.all(gap <= RESET_ATOL + np.spacing(np.abs(episode["reset_obs"])).astype(np.float64)), i

    for k in range(longest):
        active = ~env.done
        assert active.any()
        obs, reward, done, features = env.step(actions[:, k], active=active)
        for i in np.flatnonzero(active):
            ref = rust[i]["steps"][k]
            where = f"{kind} episode {i} step {k + 1}"
            assert env.throttle[i] == ref["throttle"], where
            assert done[i] == ref["done"], where
            d = {
                "features": np.abs(features[i] - ref["features"]).max(),
                "state": np.abs(env.state[i, :4] - ref["state"][:4]).max(),
                "reward": abs(reward[i] - ref["reward"]),
                "mass": max(abs(env.state[i, 4] - ref["mass"]), abs(ref["state"][4] - ref["mass"])),
            }
            for name, value in d.items():
                worst[name] = max(worst[name], value)
            assert d["features"] <= ATOL, f"{where}: features differ by {d['features']:.3e}"
            assert d["state"] <= ATOL, f"{where}: state differs by {d['state']:.3e}"
            assert d["reward"] <= ATOL, f"{where}: reward differs by {d['reward']:.3e}"
            assert d["mass"] <= MASS_ATOL, f"{where}: mass differs by {d['mass']:.3e}"
            gap = np.abs(obs[i].astype(np.float64) - ref["obs"].astype(np.float64))
            worst["obs"] = max(worst["obs"], gap.max())
            bound = ATOL + np.spacing(np.abs(ref["obs"])).astype(np.float64)
            assert np.all(gap <= bound), f"{where}: observations differ by {gap.max():.3e}"
    assert env.done.all()
    assert all(len(e["steps"]) == s["steps"] for e, s in zip(rust, scenarios))
    print(f"\n{kind}: largest differences " + ", ".join(f"{n} {v:.2e}" for n, v in worst.items()))


def test_edge_actions_decode_like_the_rust_environment():
    kind = "transfer-circular"
    edge = np.array(
        [
            [1.0, 0.0, 1.0],  # full throttle along track
            [0.0, 3.0, -4.0],  # clamped to (1, -1), then normalised
            [1.0, 1e-7, -1e-7],  # direction below 1e-6: thrust off
            [-1.0, 0.6, 0.8],  # throttle 0 with a direction: Kepler coast
            [-7.0, 0.6, 0.8],  # clamped to throttle 0
            [0.3, 0.0, 0.0],  # zero direction: thrust off
            [0.3, -1.0, 0.0],  # inward
            [0.99999994, 1e-6, 0.0],  # direction norm exactly at the threshold (in f64 of the f32)
            [-0.99999994, 2e-6, 0.0],  # smallest throttle above 0
        ],
        dtype=np.float32,
    )
    env = lowthrust.Env(kind)
    env.reset(SEED, 3)
    sc = lowthrust.spacecraft()
    ref = NumpyVecEnv("transfer", [lowthrust.draw_scenario(kind, SEED, 3)], sc["thrust"], sc["exhaust_speed"])
    ref.reset()
    for action in edge:
        _, reward, _, info = env.step(action)
        _, r, _, f = ref.step(action[None, :])
        assert ref.throttle[0] == info["throttle"], action
        assert np.abs(f[0] - info["features"]).max() <= ATOL, action
        assert abs(r[0] - reward) <= ATOL, action


def test_vec_env_agrees_with_the_numpy_reference():
    """The vectorised Rust environment (what the benchmark times) on the same footing."""
    kind, n = "transfer-circular", 16
    venv = lowthrust.VecEnv(kind, n)
    obs_rust = venv.reset(SEED, np.arange(n, dtype=np.uint64))
    scenarios = [lowthrust.draw_scenario(kind, SEED, i) for i in range(n)]
    sc = lowthrust.spacecraft()
    ref = NumpyVecEnv("transfer", scenarios, sc["thrust"], sc["exhaust_speed"])
    obs = ref.reset()
    assert np.all(np.abs(obs - obs_rust) <= RESET_ATOL + np.spacing(np.abs(obs_rust)))
    rng = np.random.default_rng(9)
    for _ in range(min(s["steps"] for s in scenarios)):
        actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
        obs_rust, reward_rust, done_rust = venv.step(actions)
        obs, reward, done, _ = ref.step(actions)
        gap = np.abs(obs.astype(np.float64) - obs_rust.astype(np.float64))
        assert np.all(gap <= ATOL + np.spacing(np.abs(obs_rust)).astype(np.float64))
        assert np.abs(reward - reward_rust).max() <= ATOL
        assert np.array_equal(done, done_rust)


# The numpy reference's own pieces against each other (no Rust): when the comparison above
# fails, these say whether the reference is at fault.


def test_reference_kepler_coast_matches_its_rk4_without_thrust():
    rng = np.random.default_rng(1)
    n = 64
    r = rng.uniform(0.3, 1.6, n)
    th = rng.uniform(0, 2 * np.pi, n)
    # Speeds from well bound to hyperbolic (escape speed sqrt(2/r)).
    speed = np.sqrt(2.0 / r) * rng.uniform(0.5, 1.3, n)
    gamma = rng.uniform(-0.8, 0.8, n)  # flight-path angle
    vr, vt = speed * np.sin(gamma), speed * np.cos(gamma)
    x, y = r * np.cos(th), r * np.sin(th)
    vx, vy = vr * np.cos(th) - vt * np.sin(th), vr * np.sin(th) + vt * np.cos(th)
    coast = np.stack(kepler_coast(x, y, vx, vy, STEP))
    rk4 = _rk4_polar_hold(np.stack([x, y, vx, vy]), np.ones(n), np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n), STEP, 2000)
    assert np.abs(coast - rk4).max() < 1e-10
    # Backwards and multi-revolution coasts return to the start.
    back = np.stack(kepler_coast(*coast, -STEP))
    assert np.abs(back - np.stack([x, y, vx, vy])).max() < 1e-12


def test_reference_body_ephemeris_matches_its_kepler_coast():
    rng = np.random.default_rng(2)
    n = 32
    a, e = rng.uniform(0.39, 1.52, n), rng.uniform(1e-4, 0.75, n)
    omega, nu0 = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2 * np.pi, n)
    start = orbit_state_at_time(a, e, omega, nu0, 0.0)
    for k in (1, 7, 49):
        direct = np.stack(orbit_state_at_time(a, e, omega, nu0, k * STEP))
        coasted = np.stack(kepler_coast(*start, k * STEP))
        assert np.abs(direct - coasted).max() < 1e-12, k
