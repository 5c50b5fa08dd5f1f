"""Low-thrust guidance that learns, from Python.

The project's Rust crates through a compiled module (no PyTorch needed):

- Gymnasium environments of the four scenario distributions (``lowthrust.envs``), registered as
  ``lowthrust/TransferCircular-v0``, ``lowthrust/TransferHard-v0``,
  ``lowthrust/RendezvousCircular-v0`` and ``lowthrust/RendezvousHard-v0``, with vectorised
  forms that step every episode in Rust in one call;
- the indirect method: ``solve`` one scenario, ``generate`` a family in parallel (the files of
  ``ground data generate``), ``read_dataset`` as numpy arrays;
- shipped models: ``open_model`` (checked against its card), a blob's ``Policy`` flown by the
  onboard kernels, ``fly_sil`` in the software-in-the-loop against a dispersed plant;
- ``draw_scenario`` and the canonical units (``STEP``, ``TIME_UNIT_S``, ``AU_M``).

Units are canonical: AU, t* = sqrt(AU^3 / mu_sun) (``TIME_UNIT_S`` seconds), masses in m0.
"""

from lowthrust._lowthrust import (
    AU_M,
    SCENARIOS,
    STEP,
    TIME_UNIT_S,
    Env,
    LowThrustError,
    Policy,
    VecEnv,
    draw_scenario,
    fly_sil,
    generate,
    open_model,
    read_dataset,
    reference_rollout,
    solve,
    spacecraft,
)
from lowthrust.envs import ENV_IDS, MISSION_ENV_ID, LowThrustEnv, LowThrustVecEnv, register_envs

__all__ = [
    "AU_M",
    "ENV_IDS",
    "MISSION_ENV_ID",
    "SCENARIOS",
    "STEP",
    "TIME_UNIT_S",
    "Env",
    "LowThrustEnv",
    "LowThrustError",
    "LowThrustVecEnv",
    "Policy",
    "VecEnv",
    "draw_scenario",
    "fly_sil",
    "generate",
    "open_model",
    "read_dataset",
    "reference_rollout",
    "register_envs",
    "solve",
    "spacecraft",
]

register_envs()
