"""Gymnasium environments of the project's MDPs (docs/spec.md sections 4 to 6).

Each episode is one scenario of a family: ``reset(seed=s)`` starts scenario 0 of the stream ``s``
and each later reset the next one (``options={"index": i}`` picks scenario ``i``), so that
``reset(seed=2000003)`` and the resets after it fly the project's Monte Carlo scenarios in order.
Without a seed the stream is the project's training stream (seed 1). An episode has N guidance
cycles (its ``steps``; 14 days each for the thesis's four presets) and terminates after the last;
it is never truncated. ``lowthrust/Mission-v0`` flies any family: ``gymnasium.make(
"lowthrust/Mission-v0", scenario=...)`` with a mission file's path or a mission table as TOML text
(docs/missions.md).

Observation: the features the onboard network sees (float32; 10 for a transfer, 22 for a
rendezvous; for a family whose orbits are inclined, 15 and 30 in three dimensions). Action: three
float32 in [-1, 1]: throttle (a0 + 1) / 2 and the thrust direction (a1, a2) in the local radial /
transverse frame, thrust off when |(a1, a2)| < 1e-6; in three dimensions four: the throttle and
the direction (a1, a2, a3) in the local radial / transverse / normal frame. Reward: the
project's (docs/spec.md section 5), and ``info`` carries the terminal residuals ``dr`` (AU) and
``dv`` (AU / t*), the mass and the state.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from lowthrust import _lowthrust

#: The Gymnasium ids, by scenario distribution.
ENV_IDS = {
    "transfer-circular": "lowthrust/TransferCircular-v0",
    "transfer-hard": "lowthrust/TransferHard-v0",
    "rendezvous-circular": "lowthrust/RendezvousCircular-v0",
    "rendezvous-hard": "lowthrust/RendezvousHard-v0",
}

#: The Gymnasium id of a family given as a mission (``scenario=`` a file's path or TOML text).
MISSION_ENV_ID = "lowthrust/Mission-v0"

#: The scenario stream of resets without a seed: the project's training seed.
TRAINING_SEED = 1


def _spaces(obs_dim: int, act_dim: int) -> tuple[spaces.Box, spaces.Box]:
    observation = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
    action = spaces.Box(-1.0, 1.0, shape=(act_dim,), dtype=np.float32)
    return observation, action


def _actions(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The actions as float32 of the given shape, refused with the reason otherwise."""
    array = np.asarray(action)
    if array.shape != shape:
        raise ValueError(f"action of shape {array.shape}, expected {shape}")
    if not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
        raise ValueError(f"action of dtype {array.dtype}, expected real numbers")
    array = np.ascontiguousarray(array, dtype=np.float32)
    if not np.all(np.isfinite(array)):
        raise ValueError("the action has a NaN or infinite component")
    return array


class LowThrustEnv(gymnasium.Env):
    """One scenario family's MDP, stepped by the project's Rust environment.

    ``scenario`` is one of ``lowthrust.SCENARIOS``, a mission file's path or a mission table as
    TOML text (docs/missions.md); ``env_config`` the ``[env]`` section of a project config as TOML
    text (spacecraft, reward weights, terminal-accuracy term, integrator).
    """

    metadata = {"render_modes": []}

    def __init__(self, scenario: str = "transfer-circular", env_config: str | None = None):
        self._env = _lowthrust.Env(scenario, env_config)
        self.scenario = scenario
        self.observation_space, self.action_space = _spaces(self._env.obs_dim, self._env.act_dim)
        self._stream = TRAINING_SEED
        self._next_index = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._stream, self._next_index = int(seed), 0
        if options and "index" in options:
            self._next_index = int(options["index"])
        index = self._next_index
        obs = self._env.reset(self._stream, index)
        self._next_index = index + 1
        return obs, {"scenario_seed": self._stream, "scenario_index": index, "steps": self._env.steps}

    def step(self, action):
        obs, reward, done, info = self._env.step(_actions(action, self.action_space.shape))
        return obs, float(reward), bool(done), False, info


class LowThrustVecEnv(VectorEnv):
    """``num_envs`` episodes of one distribution stepped together in Rust (one call, every
    core, the GIL released). Episodes draw the stream's scenarios in order of their resets. A
    finished episode is reset on the next step (Gymnasium's next-step autoreset), which returns
    its first observation with reward 0.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: str = "transfer-circular", env_config: str | None = None):
        self._env = _lowthrust.VecEnv(scenario, num_envs, env_config)
        self.num_envs = num_envs
        self.scenario = scenario
        self.single_observation_space, self.single_action_space = _spaces(self._env.obs_dim, self._env.act_dim)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._stream = TRAINING_SEED
        self._next_index = 0
        self._needs_reset = np.zeros(num_envs, dtype=bool)

    def _indices(self, count: int) -> np.ndarray:
        indices = np.arange(self._next_index, self._next_index + count, dtype=np.uint64)
        self._next_index += count
        return indices

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._stream, self._next_index = int(seed), 0
        obs = self._env.reset(self._stream, self._indices(self.num_envs))
        self._needs_reset[:] = False
        return obs, {}

    def step(self, actions):
        actions = _actions(actions, self.action_space.shape)
        resetting = self._needs_reset
        if resetting.any():
            # Only the finished episodes draw new scenarios; they do not step this call (their
            # first observation, reward 0), the others do.
            indices = np.zeros(self.num_envs, dtype=np.uint64)
            indices[resetting] = self._indices(int(resetting.sum()))
            self._env.reset(self._stream, indices, resetting)
            obs, rewards, done = self._env.step(actions, ~resetting)
        else:
            obs, rewards, done = self._env.step(actions)
        self._needs_reset = done.copy()
        return obs, rewards, done, np.zeros(self.num_envs, dtype=bool), {}


def _mission_env(scenario: str, env_config: str | None = None) -> LowThrustEnv:
    """``lowthrust/Mission-v0``: a family that must be named."""
    return LowThrustEnv(scenario, env_config)


def _mission_vec_env(num_envs: int = 1, scenario: str | None = None, env_config: str | None = None) -> LowThrustVecEnv:
    if scenario is None:
        raise TypeError("lowthrust/Mission-v0 needs scenario=: a mission file's path or TOML text")
    return LowThrustVecEnv(num_envs, scenario, env_config)


def register_envs() -> None:
    """Registers the four presets' environments, ``lowthrust/Mission-v0`` for any family, and
    their vectorised forms with Gymnasium (done on import; registering again is a no-op)."""
    if MISSION_ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=MISSION_ENV_ID,
            entry_point="lowthrust.envs:_mission_env",
            vector_entry_point="lowthrust.envs:_mission_vec_env",
        )
    for scenario, env_id in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="lowthrust.envs:LowThrustEnv",
            vector_entry_point="lowthrust.envs:LowThrustVecEnv",
            kwargs={"scenario": scenario},
        )
