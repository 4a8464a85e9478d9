"""What a policy reads (`make train-bc INPUTS=...`, recorded in its checkpoint's `MLPSpec.inputs`).

    full      the gymnasium observation (348 floats), as is
    proprio   what a robot senses: `observation.state` (48; humanoid.sensors)
    odometry  the sensed features but the feet's forces, then what `humanoid.estimator` computes from the
              sensed features alone: the torso's height and linear velocity (leg odometry fused with the
              forces) and the nominal model's body inertias (176)
    pending   odometry's, then the command sent but not yet executed under one step of action latency
              (zeros without latency) and that latency in steps (176 + 17 + 1): what a robot knows of
              its own actuation delay (docs/decisions/pending-inputs.md)

Each is built from the dataset columns `INPUT_COLUMNS[kind]`; `odometry` runs the estimator along
each recorded episode in training (`episode_inputs`) and along the live one at run time
(`input_features`, reset at every episode's start). `pending` also reads the previous frame's action
label and the episode's recorded delay (`make record LATENCY=`), and at run time remembers the
policy's last command (`PendingInputs.commanded`) and is told the episode's delay (`set_delay`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import UserError
from common.keys import ACTION, OBS_ENV_STATE, OBS_STATE
from humanoid import estimator, sensors
from humanoid.conditions import LATENCY_PARAMETER, action_delay
from humanoid.env import actuator_names, humanoid_model, observation_names
from humanoid.estimator import OdometryFeatures, OdometryObservation, odometry_names
from humanoid.sensors import Proprioception, proprioception_names

INPUT_COLUMNS: dict[str, tuple[str, ...]] = {
    "full": (OBS_STATE, OBS_ENV_STATE),
    "proprio": (OBS_STATE,),
    "odometry": (OBS_STATE,),
    "pending": (OBS_STATE, ACTION),
}
INPUTS = tuple(INPUT_COLUMNS)


def input_names(inputs: str, model: mujoco.MjModel) -> list[str]:
    """The names of a policy's input entries, in order."""
    if inputs == "full":
        return observation_names(model)
    if inputs == "pending":
        return [*odometry_names(model), *(f"pending.{name}" for name in actuator_names(model)), LATENCY_PARAMETER]
    return proprioception_names(model) if inputs == "proprio" else odometry_names(model)


def recorded_names(inputs: str, model: mujoco.MjModel) -> list[str]:
    """The recorded entries an input is computed from (the gymnasium observation's, or the sensed ones, and for
    "pending" the action label's)."""
    if inputs == "full":
        return observation_names(model)
    return [*proprioception_names(model), *(actuator_names(model) if inputs == "pending" else ())]


def input_features(inputs: str, model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
    """The function from gymnasium observations to a policy's input, for `model`'s environment; a stateful
    one (`odometry`, `pending`) has a `reset` to call at every episode's start, and `pending`'s also takes the
    episode's delay and each command sent (`PendingInputs`)."""
    if inputs == "full":
        return lambda obs: obs
    if inputs == "pending":
        return PendingInputs(model)
    return Proprioception(model) if inputs == "proprio" else OdometryFeatures(model)


def computation_digest(inputs: str) -> str | None:
    """A digest of the code that computes `inputs` from recorded frames (`odometry`: the estimator and the
    sensed features), so that inputs an earlier version computed and cached are not reused; None for
    inputs read as recorded."""
    if inputs not in ("odometry", "pending"):
        return None
    source = b"".join(Path(module.__file__).read_bytes() for module in (estimator, sensors))
    return hashlib.sha256(source).hexdigest()[:16]


def episode_inputs(
    inputs: str,
    recorded: np.ndarray,
    episode_index: np.ndarray,
    model: mujoco.MjModel,
    delays: np.ndarray | None = None,
) -> np.ndarray:
    """A policy's inputs for recorded frames (`recorded_names` entries, rows in frame order); `delays` (per
    frame, the episode's recorded latency in steps; zeros if None) for "pending"."""
    if inputs not in ("odometry", "pending"):
        return recorded
    sensed = recorded[:, : len(proprioception_names(model))]
    odometry = OdometryFeatures(model).episodes(sensed, episode_index).astype(recorded.dtype)
    if inputs == "odometry":
        return odometry
    delays = np.zeros(len(recorded)) if delays is None else np.asarray(delays)
    labels = recorded[:, sensed.shape[1] :]
    pending = np.zeros_like(labels)
    # The previous frame's label, where it is of the same episode and that episode was delayed.
    carried = np.flatnonzero((episode_index[1:] == episode_index[:-1]) & (delays[1:] > 0)) + 1
    pending[carried] = labels[carried - 1]
    return np.concatenate([odometry, pending, delays[:, None].astype(recorded.dtype)], axis=1)


class PendingInputs:
    """The "pending" inputs of one live episode: `OdometryFeatures`, the policy's command still in flight, the delay.

    Why: one step of action latency topples a policy that acts as if its command ran at once; told the
    delay and what it sent, a student learns to act through it (docs/decisions/pending-inputs.md).
    The rollout tells the episode's delay before `reset` (`humanoid.episode.tell_delay`); the policy
    reports each command it sends (`commanded`).
    """

    MAX_DELAY = 1  # the command in flight is one action: one step of latency

    def __init__(self, model: mujoco.MjModel) -> None:
        self.odometry = OdometryFeatures(model)
        self.read = self.odometry.read  # the sensed features read as they are; the rest is computed
        self.delay = 0
        self.pending = np.zeros(model.nu)
        self.size = self.odometry.size + model.nu + 1
        self.estimate_size = self.size - self.read.size

    def set_delay(self, steps: int) -> None:
        if not 0 <= steps <= self.MAX_DELAY:
            raise UserError(
                f"a policy on the 'pending' inputs acts through at most {self.MAX_DELAY} step of action latency; "
                f"this episode delays its actions by {steps}"
            )
        self.delay = steps

    def reset(self) -> None:
        self.odometry.reset()
        self.pending[:] = 0.0  # as ActionLatency does: the first step executes zeros

    def commanded(self, action: np.ndarray) -> None:
        """The command the policy sent this step: in flight until the next one, if the episode is delayed."""
        if self.delay:
            self.pending[:] = action

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.concatenate([self.odometry(obs), self.pending, [float(self.delay)]])


class PendingObservation(OdometryObservation):
    """The env's observation with the "pending" inputs' computed entries appended: the odometry estimate, the
    command in flight (the last action stepped, in a delayed episode) and the episode's delay.

    PPO's actor on the "pending" inputs reads them there (`bc.ppo.features.EstimatedFeatures`), as
    `OdometryObservation` carries the estimate; the delay is the one the inner `ActionLatency` drew at reset.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env, PendingInputs(humanoid_model()))

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.features.set_delay(action_delay(self.env))
        self.features.reset()
        return self._with_estimate(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.features.commanded(action)
        return super().step(action)
