"""Stable-Baselines3 trains on the environments as they are: its own environment checker, then
SAC for a few thousand steps on the vectorised transfer environment (needs PyTorch: skipped
where Stable-Baselines3 is not installed; the project's test command installs it)."""

import numpy as np
import pytest

import lowthrust

sb3 = pytest.importorskip("stable_baselines3")


def test_stable_baselines3_checks_and_trains_sac_on_the_environment():
    import gymnasium as gym
    from stable_baselines3.common.env_checker import check_env

    env = gym.make("lowthrust/TransferCircular-v0")
    check_env(env.unwrapped, warn=False)
    model = sb3.SAC("MlpPolicy", env, learning_starts=500, batch_size=64, seed=1, device="cpu", verbose=0)
    model.learn(total_timesteps=3000)
    assert model.num_timesteps == 3000
    obs, _ = env.reset(seed=2000003)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (3,) and np.all(np.abs(action) <= 1.0)
    # The learned policy flies a whole Monte Carlo episode to its end.
    steps = 0
    while True:
        obs, _, terminated, _, info = env.step(model.predict(obs, deterministic=True)[0])
        steps += 1
        if terminated:
            break
    assert steps == lowthrust.draw_scenario("transfer-circular", 2000003, 0)["steps"]
    assert 0.0 < info["mass"] <= 1.0
