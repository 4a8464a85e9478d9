"""What a real humanoid senses, and the split of the gymnasium observation into sensed and privileged parts.

The 348-dim gymnasium observation holds quantities no robot measures (docs/decisions/deployable-inputs.md).
A dataset stores it in two features that LeRobot's policies read:

    gymnasium observation (348) ──split──> observation.state (48): what the robot senses
                                 └───────> observation.environment_state (311): the rest, privileged
    both, joined by name ──────────────────> the gymnasium observation again, bit for bit

`observation.state` (PROPRIOCEPTION, in this order):
- the 17 hinge joints' positions and velocities (encoders), names `<joint>.pos` / `<joint>.vel`;
- the torso IMU's angular velocity in the torso frame (gyroscope), `root.wx` .. `root.wz`;
- the gravity direction in the torso frame (a unit vector, what an IMU's attitude filter gives
  without the heading, which no IMU observes for long), `imu.gravity_x` .. `imu.gravity_z`;
- foot contact, 1.0 or 0.0 per foot (contact switches), `contact.<foot>`;
- each foot's contact force in the torso frame (N; a force sensor in the ankle, its reading turned
  through the leg's joint angles), `force.<foot>_x` .. `_z`: what lets a state estimator tell how the
  body accelerates (`humanoid.estimator`; docs/decisions/leg-odometry.md).
Entries that copy the gymnasium observation keep its names; the gravity, the contacts and the forces
are computed from it (the root quaternion and the feet's contact wrenches), so any policy that acts
on the gymnasium observation can compute them the same way at run time (`Proprioception`).
The previous action is not repeated: it is the previous frame's `action` / `executed_action`.

`observation.environment_state` is every other entry of the gymnasium observation, in its order:
the torso's height, orientation quaternion and linear velocity, then cinert, cvel, qfrc_actuator
and cfrc_ext. Datasets recorded before this split stored qpos[2:] and qvel (45) as
`observation.state`; `observation_index` joins either layout by the recorded names.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from humanoid.env import nominal_model, observation_names

GRAVITY_NAMES = ("imu.gravity_x", "imu.gravity_y", "imu.gravity_z")
GYRO_NAMES = ("root.wx", "root.wy", "root.wz")  # qvel[3:6]: the free joint's angular velocity, torso frame
QUATERNION_NAMES = ("root.qw", "root.qx", "root.qy", "root.qz")
FEET = ("right_foot", "left_foot")  # the bodies whose contact wrench says whether a foot touches something
FORCE_PART = slice(3, 6)  # a body's cfrc_ext is (torque, force), world-aligned (MuJoCo's spatial vectors)


def contact_names() -> tuple[str, ...]:
    return tuple(f"contact.{foot}" for foot in FEET)


def force_names() -> tuple[str, ...]:
    return tuple(f"force.{foot}_{axis}" for foot in FEET for axis in "xyz")


def _joints(names: list[str], suffix: str) -> list[str]:
    return [name for name in names if name.endswith(suffix) and not name.startswith("root.")]


def proprioception_names(model: mujoco.MjModel) -> list[str]:
    """The names of `observation.state`, one per entry, in order."""
    names = observation_names(model)
    return [
        *_joints(names, ".pos"),
        *_joints(names, ".vel"),
        *GYRO_NAMES,
        *GRAVITY_NAMES,
        *contact_names(),
        *force_names(),
    ]


def privileged_names(model: mujoco.MjModel) -> list[str]:
    """The names of `observation.environment_state`: the gymnasium observation's other entries, in its order."""
    sensed = set(proprioception_names(model))
    return [name for name in observation_names(model) if name not in sensed]


def yaw_rate(quaternion: np.ndarray, angular_velocity: np.ndarray) -> np.ndarray:
    """The yaw rate about the world's vertical (...) of bodies oriented as `quaternion` (..., 4) turning at their local
    `angular_velocity` (..., 3; a free joint's qvel 3:6): that velocity turned into the world, its z component."""
    return (body_axes(quaternion)[..., :, 2] * angular_velocity).sum(-1)


def body_axes(quaternion: np.ndarray) -> np.ndarray:
    """R^T, (..., 3, 3), of body orientations (..., 4) w-x-y-z, R mapping body to world: row i is the body's
    i-th axis in the world (R's i-th column). The state's quaternion drifts from unit length between
    MuJoCo's normalisations: normalised first, as MuJoCo does."""
    w, x, y, z = np.moveaxis(quaternion / np.linalg.norm(quaternion, axis=-1, keepdims=True), -1, 0)
    columns = (
        (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)),
        (2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)),
        (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(column, axis=-1) for column in columns], axis=-2)


def in_body_frame(axes: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """World vectors (..., 3) in the frames whose `body_axes` are `axes`: R^T v, each axis dotted with v."""
    return (
        axes[..., 0] * vector[..., None, 0] + axes[..., 1] * vector[..., None, 1] + axes[..., 2] * vector[..., None, 2]
    )


def gravity_direction(axes: np.ndarray) -> np.ndarray:
    """The world's down direction, (..., 3), in the frames whose `body_axes` are `axes`: R^T (0, 0, -1), minus each
    body axis's vertical component."""
    return -axes[..., 2]


class Proprioception:
    """The sensed features (`observation.state`) computed from gymnasium observations of one model."""

    def __init__(self, model: mujoco.MjModel) -> None:
        names = observation_names(model)
        position = {name: i for i, name in enumerate(names)}
        self.names = proprioception_names(model)
        copied = [name for name in self.names if name in position]
        # Where the inputs sit in the observation.
        self.copied = np.array([position[name] for name in copied])
        self.quaternion = np.array([position[name] for name in QUATERNION_NAMES])
        self.feet = np.array([[position[f"{foot}.cfrc_ext{i}"] for i in range(6)] for foot in FEET])
        self.size = len(self.names)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """(..., 48) float64 features of (..., 348) observations."""
        axes = body_axes(obs[..., self.quaternion])  # once for the gravity and both feet's forces
        contacts = [np.any(obs[..., rows] != 0.0, axis=-1, keepdims=True) for rows in self.feet]
        forces = [in_body_frame(axes, obs[..., rows[FORCE_PART]]) for rows in self.feet]
        sensed = [obs[..., self.copied], gravity_direction(axes), *contacts, *forces]
        return np.concatenate(sensed, axis=-1).astype(np.float64)


class ObservationSplit:
    """(observation.state, observation.environment_state) of gymnasium observations of one model, and back."""

    def __init__(self, model: mujoco.MjModel) -> None:
        sensed = set(proprioception_names(model))
        self.proprioception = Proprioception(model)
        self._privileged = np.array([i for i, name in enumerate(observation_names(model)) if name not in sensed])
        self._joined = observation_index(proprioception_names(model) + privileged_names(model), model)

    def __call__(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.proprioception(obs), obs[..., self._privileged]

    def join(self, state: np.ndarray, environment_state: np.ndarray) -> np.ndarray:
        """The gymnasium observations (..., 348) that `__call__` split, bit for bit."""
        return np.concatenate([state, environment_state], axis=-1)[..., self._joined]


def observation_index(recorded: Sequence[str], model: mujoco.MjModel | None = None) -> np.ndarray | None:
    """Where each gymnasium observation entry sits among the `recorded` names (state's, then environment
    state's, side by side), so that `np.concatenate([state, environment_state], -1)[..., index]` is the
    gymnasium observation of `model` (Humanoid-v5's by default); None if a name is missing (the dataset
    cannot give the observation)."""
    position = {name: i for i, name in enumerate(recorded)}
    try:
        return np.array([position[name] for name in observation_names(model or nominal_model())])
    except KeyError:
        return None
