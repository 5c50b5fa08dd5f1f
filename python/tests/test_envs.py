"""The Gymnasium environments: Gymnasium's own checker, transitions equal bit for bit to the
Rust environment driven from Rust, the vectorised form equal to single episodes, and bad input
refused with a Python exception."""

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import lowthrust

IDS = list(lowthrust.ENV_IDS.items())


@pytest.mark.parametrize("scenario,env_id", IDS)
def test_every_environment_passes_gymnasiums_checker(scenario, env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        # The features are unbounded by nature (a Box from -inf to inf): a warning, not a fault.
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped, skip_render_check=True)
    assert env.unwrapped.scenario == scenario


def _fly(env, seed, rng, index=None):
    """One whole episode under uniform random actions: its actions, observations, rewards."""
    obs, info = env.reset(seed=seed, options=None if index is None else {"index": index})
    observations, actions, rewards = [obs], [], []
    while True:
        action = rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert not truncated
        actions.append(action)
        observations.append(obs)
        rewards.append(reward)
        if terminated:
            return np.array(actions), np.array(observations), np.array(rewards), info


@pytest.mark.parametrize("scenario,env_id", IDS)
def test_transitions_equal_the_rust_environments_bit_for_bit(scenario, env_id):
    env = gym.make(env_id)
    rng = np.random.default_rng(5)
    for index in range(3):
        actions, observations, rewards, info = _fly(env, 77, rng, index)
        ref_obs, ref_rewards = lowthrust.reference_rollout(scenario, 77, index, actions)
        assert observations.dtype == np.float32 and ref_obs.dtype == np.float32
        assert np.array_equal(observations, ref_obs)
        assert np.array_equal(rewards, ref_rewards)
        assert len(actions) == lowthrust.draw_scenario(scenario, 77, index)["steps"]
        assert 0.0 < info["mass"] <= 1.0 and info["dr"] >= 0.0


VENUS_INWARD = """
problem = "transfer"
body = "sun"
departure = { a = [0.98, 1.02], e = [0.0, 0.01] }
target = { a = [0.70, 0.74], e = [0.0, 0.01] }
time_of_flight = { lo_days = 250.0, hi_days = 320.0 }
cycle = { days = 7.0 }
"""


def test_a_mission_family_is_an_environment_equal_to_the_rust_one():
    """A family given as a mission table: Gymnasium's checker, 7-day cycles over a drawn time of
    flight, transitions equal to the Rust environment's bit for bit; a bad table is refused."""
    env = gym.make(lowthrust.MISSION_ENV_ID, scenario=VENUS_INWARD)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped, skip_render_check=True)
    rng = np.random.default_rng(8)
    for index in range(2):
        actions, observations, rewards, _ = _fly(env, 12, rng, index)
        ref_obs, ref_rewards = lowthrust.reference_rollout(VENUS_INWARD, 12, index, actions)
        assert np.array_equal(observations, ref_obs) and np.array_equal(rewards, ref_rewards)
        drawn = lowthrust.draw_scenario(VENUS_INWARD, 12, index)["steps"]
        assert len(actions) == drawn and 36 <= drawn <= 46
        # The first observation's time to go (the last transfer feature) is the flight's, in t*.
        days = observations[0][-1] * lowthrust.TIME_UNIT_S / 86400.0
        assert abs(days - 7.0 * drawn) < 1e-3 * days
    # Its vectorised form: each slot the Rust flight of the scenario it drew.
    venv = gym.make_vec(
        lowthrust.MISSION_ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", scenario=VENUS_INWARD
    )
    obs, _ = venv.reset(seed=12)
    assert obs.shape == (3, 10)
    for i in range(3):
        ref_obs, _ = lowthrust.reference_rollout(VENUS_INWARD, 12, i, np.zeros((0, 3), dtype=np.float32))
        assert np.array_equal(obs[i], ref_obs[0])
    with pytest.raises(lowthrust.LowThrustError, match="target.e"):
        lowthrust.LowThrustEnv(VENUS_INWARD.replace("e = [0.0, 0.01] }\ntime", "e = [0.0, 1.5] }\ntime"))
    with pytest.raises(TypeError):
        gym.make(lowthrust.MISSION_ENV_ID)


INCLINED = (Path(__file__).resolve().parents[2] / "configs/missions/transfer-circular-inclined.toml").read_text()


def test_an_inclined_family_is_a_three_dimensional_environment_equal_to_the_rust_one():
    """A family whose target orbit is inclined: 15 features, 4 actions (throttle and an RTN
    direction), Gymnasium's checker, transitions equal to the Rust 3D environment's bit for bit,
    the state in three dimensions; its vectorised form the same; 3-component actions refused."""
    env = gym.make(lowthrust.MISSION_ENV_ID, scenario=INCLINED)
    assert env.observation_space.shape == (15,) and env.action_space.shape == (4,)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped, skip_render_check=True)
    rng = np.random.default_rng(9)
    for index in range(2):
        actions, observations, rewards, info = _fly(env, 13, rng, index)
        ref_obs, ref_rewards = lowthrust.reference_rollout(INCLINED, 13, index, actions)
        assert np.array_equal(observations, ref_obs) and np.array_equal(rewards, ref_rewards)
        assert info["state"].shape == (7,) and info["state"][-1] == info["mass"]
    venv = gym.make_vec(lowthrust.MISSION_ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", scenario=INCLINED)
    obs, _ = venv.reset(seed=13)
    assert obs.shape == (2, 15)
    ref_obs, _ = lowthrust.reference_rollout(INCLINED, 13, 1, np.zeros((0, 4), dtype=np.float32))
    assert np.array_equal(obs[1], ref_obs[0])
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(lowthrust.LowThrustError, match="4 components"):
        lowthrust.Env(INCLINED).step(np.zeros(3, dtype=np.float32))


def test_resets_walk_the_seeds_scenarios_in_order():
    env = gym.make("lowthrust/TransferHard-v0")
    _, first = env.reset(seed=2000003)
    _, second = env.reset()
    _, again = env.reset(seed=2000003)
    assert (first["scenario_index"], second["scenario_index"], again["scenario_index"]) == (0, 1, 0)
    assert second["steps"] == lowthrust.draw_scenario("transfer-hard", 2000003, 1)["steps"]


@pytest.mark.parametrize("scenario", ["transfer-hard", "rendezvous-circular"])
def test_the_vectorised_environment_equals_single_episodes(scenario):
    """Each episode of a vectorised run (next-step autoreset, episodes of different lengths)
    is the Rust environment's flight of the scenario it drew, bit for bit."""
    n = 4
    venv = gym.make_vec(lowthrust.ENV_IDS[scenario], num_envs=n, vectorization_mode="vector_entry_point")
    obs, _ = venv.reset(seed=31)
    rng = np.random.default_rng(3)
    # Per slot: the scenario index it flies, its observations, actions and rewards so far.
    episodes = [{"index": i, "obs": [obs[i]], "actions": [], "rewards": []} for i in range(n)]
    finished, next_index, starting = [], n, np.zeros(n, dtype=bool)
    while len(finished) < 2 * n:
        actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
        obs, rewards, terminations, truncations, _ = venv.step(actions)
        assert not truncations.any()
        for i in range(n):
            if starting[i]:
                # The autoreset step: the next scenario's first observation, reward 0.
                assert rewards[i] == 0.0 and not terminations[i]
                episodes[i] = {"index": next_index, "obs": [obs[i]], "actions": [], "rewards": []}
                next_index += 1
                continue
            episodes[i]["actions"].append(actions[i])
            episodes[i]["obs"].append(obs[i])
            episodes[i]["rewards"].append(rewards[i])
            if terminations[i]:
                finished.append(episodes[i])
        starting = terminations.copy()
    for episode in finished:
        ref_obs, ref_rewards = lowthrust.reference_rollout(
            scenario, 31, episode["index"], np.array(episode["actions"], dtype=np.float32)
        )
        assert np.array_equal(np.array(episode["obs"]), ref_obs)
        assert np.array_equal(np.array(episode["rewards"]), ref_rewards)


def test_bad_input_is_a_python_exception_with_the_reason():
    env = gym.make("lowthrust/TransferCircular-v0").unwrapped
    with pytest.raises(lowthrust.LowThrustError, match="before reset"):
        env.step(np.zeros(3, dtype=np.float32))
    env.reset(seed=1)
    for bad, reason in [
        (np.zeros(4, dtype=np.float32), "shape"),
        (np.zeros((1, 3)), "shape"),
        (np.array([0.0, np.nan, 1.0]), "NaN"),
        (np.array([0.0, np.inf, 1.0]), "infinite"),
        (np.array(["a", "b", "c"]), "dtype"),
    ]:
        with pytest.raises(ValueError, match=reason):
            env.step(bad)
    # A float64 action is taken as the float32 the network would give.
    env.step(np.array([0.5, 0.0, 1.0]))
    with pytest.raises(lowthrust.LowThrustError, match="neither a scenario family preset"):
        lowthrust.Env("warp-drive")
    with pytest.raises(lowthrust.LowThrustError, match="env config"):
        lowthrust.Env("transfer-circular", "[spacecraft]\nmax_thrust = 1.0")
    with pytest.raises(lowthrust.LowThrustError, match="env config"):
        lowthrust.Env("transfer-circular", "this is not toml ===")
    venv = lowthrust.VecEnv("transfer-circular", 2)
    with pytest.raises(lowthrust.LowThrustError, match="indices"):
        venv.reset(1, np.arange(3, dtype=np.uint64))
    venv.reset(1, np.arange(2, dtype=np.uint64))
    with pytest.raises(lowthrust.LowThrustError, match="shape"):
        venv.step(np.zeros((3, 3), dtype=np.float32))
    with pytest.raises(TypeError):
        venv.step(np.zeros((2, 3), dtype=np.float64))
    with pytest.raises(lowthrust.LowThrustError, match="num_envs"):
        lowthrust.VecEnv("transfer-circular", 0)
    # Stepping past the last step is refused, and the environment still answers afterwards.
    env.reset(seed=1)
    for _ in range(env.unwrapped._env.steps):
        env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(lowthrust.LowThrustError, match="terminal step"):
        env.step(np.zeros(3, dtype=np.float32))
    obs, _ = env.reset(seed=1)
    assert np.all(np.isfinite(obs))


def test_an_env_config_changes_the_mdp_as_the_project_config_does():
    """The terminal-accuracy term of a project config's [env]: the reward's parts add up."""
    config = 'terminal = { kind = "terminal-penalty", position = 10.0, velocity = 10.0 }'
    env = lowthrust.Env("transfer-circular", config)
    env.reset(7, 0)
    for _ in range(env.steps):
        _, reward, done, info = env.step(np.zeros(3, dtype=np.float32))
    assert done
    assert info["terminal_term"] == pytest.approx(-10.0 * (info["dr"] + info["dv"]), rel=1e-12)
    assert reward == info["base_reward"] + info["terminal_term"]
