"""What a policy reads (`make train-bc INPUTS=...`, recorded in its checkpoint's `MLPSpec.inputs`).

    full      the gymnasium observation (348 floats), as is
    proprio   what a robot senses: `observation.state` (48; humanoid.sensors)
    odometry  the sensed features but the feet's forces, then what `humanoid.estimator` computes from the
              sensed features alone: the torso's height and linear velocity (leg odometry fused with the
              forces) and the nominal model's body inertias (176)

Each is built from the dataset columns `INPUT_COLUMNS[kind]`; `odometry` runs the estimator along
each recorded episode in training (`episode_inputs`) and along the live one at run time
(`input_features`, reset at every episode's start).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from common.keys import OBS_ENV_STATE, OBS_STATE
from humanoid import estimator, sensors
from humanoid.env import observation_names
from humanoid.estimator import OdometryFeatures, odometry_names
from humanoid.sensors import Proprioception, proprioception_names

INPUT_COLUMNS: dict[str, tuple[str, ...]] = {
    "full": (OBS_STATE, OBS_ENV_STATE),
    "proprio": (OBS_STATE,),
    "odometry": (OBS_STATE,),
}
INPUTS = tuple(INPUT_COLUMNS)


def input_names(inputs: str, model: mujoco.MjModel) -> list[str]:
    """The names of a policy's input entries, in order."""
    if inputs == "full":
        return observation_names(model)
    return proprioception_names(model) if inputs == "proprio" else odometry_names(model)


def recorded_names(inputs: str, model: mujoco.MjModel) -> list[str]:
    """The recorded entries an input is computed from (the gymnasium observation's, or the sensed ones)."""
    return observation_names(model) if inputs == "full" else proprioception_names(model)


def input_features(inputs: str, model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
    """The function from gymnasium observations to a policy's input, for `model`'s environment; a stateful
    one (`odometry`) has a `reset` to call at every episode's start."""
    if inputs == "full":
        return lambda obs: obs
    return Proprioception(model) if inputs == "proprio" else OdometryFeatures(model)


def computation_digest(inputs: str) -> str | None:
    """A digest of the code that computes `inputs` from recorded frames (`odometry`: the estimator and the
    sensed features), so that inputs an earlier version computed and cached are not reused; None for
    inputs read as recorded."""
    if inputs != "odometry":
        return None
    source = b"".join(Path(module.__file__).read_bytes() for module in (estimator, sensors))
    return hashlib.sha256(source).hexdigest()[:16]


def episode_inputs(inputs: str, recorded: np.ndarray, episode_index: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
    """A policy's inputs for recorded frames (`recorded_names` entries, rows in frame order)."""
    if inputs != "odometry":
        return recorded
    return OdometryFeatures(model).episodes(recorded, episode_index).astype(recorded.dtype)
