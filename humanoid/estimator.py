"""The torso's state as a robot estimates it from what it senses (`observation.state`): leg odometry
fused with the feet's force sensors.

The LQR expert reads the torso's height and linear velocity, which no sensor measures
(docs/decisions/deployable-inputs.md). This estimator computes a full MuJoCo state
(qpos, qvel) from the sensed features alone, on the nominal model:

    sensed features (48) ──> orientation: tilt from the gravity direction, heading integrated from the gyro
                         ──> joints, gyro: as measured
    feet's forces ─────────> predicted centre-of-mass velocity: the last one + dt (forces / mass - g)
       a foot down ────────> corrected towards the velocity that holds the touching feet's contact
                             points still (kinematics), by a fixed gain per axis
       landing ────────────> the first steps after a flight: on both feet the kinematic velocity as is,
                             on one the prediction
       both feet down ─────> torso height: the lower foot's sphere resting where the balanced pose has it
                             (1 mm up, inside the contacts' margin; else integrated)
    torso velocity = the centre of mass's velocity - its motion relative to the torso (kinematics)

Why the forces: the kinematic velocity alone errs where a foot slips or rebounds, and the expert's
gain amplifies that; the forces say how the body accelerates, and the feet correct their drift (a
complementary filter; measured in docs/decisions/leg-odometry.md). Its memory is the centre of mass's velocity,
the heading and the height; `reset` starts them at rest, where gymnasium's reset puts the body, facing +x. The heading
(yaw) is what the sensed features do not say and standing does not depend on, but a commanded twist turns
the torso over the pelvis: the estimate integrates it from the gyro (`heading_rate`). Set to zero, it read
a twist as a turn of the whole body and the expert fell on most command schedules
(docs/decisions/estimator-heading.md).
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from humanoid import physics
from humanoid.balance import standing_pose
from humanoid.env import step_seconds
from humanoid.sensors import GRAVITY_NAMES, GYRO_NAMES, Proprioception, contact_names, force_names

GRAVITY = 9.81
"""m/s², Humanoid-v5's (MuJoCo's default)."""
START_HEIGHT = 1.4
"""Torso height of gymnasium's reset (the body drops from there onto the floor)."""
HORIZONTAL_GAIN = 0.3
"""Share of the gap between the feet's kinematic velocity and the force-predicted one closed per step,
horizontally: the one-step prediction errs several times less than the kinematic velocity, and a
lower gain lets it drift (chosen on seeds 5000..5039 under action noise, docs/decisions/leg-odometry.md)."""
VERTICAL_GAIN = 0.1
"""The same, vertically, where the feet's kinematic velocity is the noisier (the contacts' give)."""
SCHEDULED_GAP = 0.1
"""m/s: where a contact schedule holds both feet (`still` all set: a walker standing, or in double support), a
horizontal gap between the feet's kinematic velocity and the force-predicted one wider than this is closed in one step
(gain 1), not by `HORIZONTAL_GAIN`'s share. A kick moves the whole body, feet and all: the forces see only the feet's
friction as they stop, and once they hold, their kinematics see the kick at once, which the 0.3 gain took about 5
steps to take in (0.30 of 0.40 m/s missed at the kick). Without a schedule (the LQR expert) such gaps are more often a
foot slipping under action noise, and closing them halved the sensed expert's survival under `noise`; closing them
while a foot swings too made the walker's students walk less (docs/decisions/leg-odometry.md)."""
LANDING_STEPS = 5
"""Steps on both feet after a flight that take the kinematic velocity as is: a landing's impact is not
in the one force sample per step the sensors give."""


def pitch_roll(gravity: np.ndarray) -> tuple[float, float]:
    """The pitch and roll (rad) of an orientation R = Rz(yaw) Ry(pitch) Rx(roll) whose body frame sees `gravity` (the
    down direction): minus R's third row, (sin pitch, -cos pitch sin roll, -cos pitch cos roll), whatever the yaw."""
    return np.arcsin(np.clip(gravity[0], -1.0, 1.0)), np.arctan2(-gravity[1], -gravity[2])


def heading_rate(gravity: np.ndarray, gyro: np.ndarray) -> float:
    """The rate of change (rad/s) of the heading (yaw) of an orientation R = Rz(yaw) Ry(pitch) Rx(roll) whose body
    frame sees `gravity` (the down direction) and turns at `gyro` (rad/s, body frame): (q sin roll + r cos roll) /
    cos pitch, the z-y-x Euler angles' kinematics."""
    pitch, roll = pitch_roll(gravity)
    return float((gyro[1] * np.sin(roll) + gyro[2] * np.cos(roll)) / np.cos(pitch))


def level_quaternion(gravity: np.ndarray) -> np.ndarray:
    """The orientation (w, x, y, z) with zero heading whose body frame sees `gravity` (the down direction)."""
    pitch, roll = pitch_roll(gravity)
    cy, sy, cx, sx = np.cos(pitch / 2), np.sin(pitch / 2), np.cos(roll / 2), np.sin(roll / 2)
    return np.array([cy * cx, cy * sx, sy * cx, -sy * sx])  # Ry(pitch) ⊗ Rx(roll)


class LegOdometry:
    """(qpos, qvel) of the nominal model estimated from one sensed-feature vector per env step."""

    def __init__(self, model: mujoco.MjModel, seconds: float | None = None) -> None:
        """On a copy of `model` as it is now (the nominal one: later draws of a randomised env do not reach it);
        `seconds`, one step's, default to one Humanoid-v5 env step (`humanoid.env.step_seconds`)."""
        standing = standing_pose(model)
        self.model = model = copy.copy(model)
        self.data = mujoco.MjData(model)
        self.dt = step_seconds(model) if seconds is None else seconds
        self.mass = float(model.body_mass.sum())
        names = Proprioception(model).names
        index = {name: i for i, name in enumerate(names)}
        joints = [model.joint(j).name for j in range(1, model.njnt)]  # after the free joint, in qpos order
        self._pos = np.array([index[f"{joint}.pos"] for joint in joints])
        self._vel = np.array([index[f"{joint}.vel"] for joint in joints])
        self._gyro = np.array([index[name] for name in GYRO_NAMES])
        self._gravity = np.array([index[name] for name in GRAVITY_NAMES])
        self._contact = np.array([index[name] for name in contact_names()])
        self._forces = np.array([index[name] for name in force_names()]).reshape(-1, 3)  # a row per foot
        self._foot_geoms = [model.geom(name).id for name in physics.FOOT_GEOMS]
        self._jac = np.zeros((3, model.nv))
        self._gains = np.array([HORIZONTAL_GAIN, HORIZONTAL_GAIN, VERTICAL_GAIN])
        self._kicked_gains = np.array([1.0, 1.0, VERTICAL_GAIN])
        self._turned = np.zeros(4)
        self.clearance = self._clearance(standing)
        self.reset()

    def reset(self) -> None:
        """At rest at the reset height: where gymnasium's reset puts the body."""
        self.com_velocity = np.zeros(3)
        self.height = START_HEIGHT
        self.heading = 0.0  # where gymnasium's reset faces the torso (+x)
        self.steps_down = 0  # consecutive steps with a foot down
        self._first = True

    def _clearance(self, qpos: np.ndarray) -> float:
        """How high the feet's spheres rest above the floor in `qpos`, the standing pose: inside the contacts'
        margin, where their force carries the body (about 1 mm; taken as 0 the height estimate was that much low and
        the expert leant to make up for it: docs/decisions/estimator-heading.md)."""
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        return float(min(self.data.geom_xpos[g][2] - self.model.geom_size[g][0] for g in self._foot_geoms))

    def _feet(self) -> tuple[np.ndarray, np.ndarray]:
        """Per foot (rows): the torso's velocity that holds its sphere's lowest point still, and the torso's
        height that rests that point on the floor, for `self.data` posed at zero translation."""
        model, data = self.model, self.data
        velocities, heights = [], []
        for geom in self._foot_geoms:
            point = data.geom_xpos[geom].copy()
            point[2] -= model.geom_size[geom][0]  # the sphere's lowest point, where it touches the floor
            mujoco.mj_jac(model, data, self._jac, None, point, model.geom_bodyid[geom])
            velocities.append(-(self._jac @ data.qvel))
            heights.append(-point[2])
        return np.array(velocities), np.array(heights)

    def __call__(self, sensed: np.ndarray, still: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The estimated (qpos with root x = y = 0, qvel) after this step's sensed features. `still` (a bool per foot,
        `physics.FOOT_GEOMS` order), when given, says which feet the controller's contact schedule holds still: a foot
        the sensors say is down corrects the velocity only if it is one of them (a walker's swing foot that grazes the
        floor, or its stance foot as it leaves, slides), and where it holds both a gap wider than `SCHEDULED_GAP` is
        closed at once (a kick); without it every foot down does, by the gains alone, as when the LQR expert stands."""
        model, data = self.model, self.data
        data.qpos[:3] = 0.0
        data.qpos[3:7] = level_quaternion(sensed[self._gravity])
        data.qpos[7:] = sensed[self._pos]
        data.qvel[:3] = 0.0  # so that velocities computed below are relative to the torso's translation
        data.qvel[3:6] = sensed[self._gyro]
        data.qvel[6:] = sensed[self._vel]
        if not self._first:
            self.heading += self.dt * heading_rate(sensed[self._gravity], sensed[self._gyro])
        half = self.heading / 2
        mujoco.mju_mulQuat(self._turned, np.array([np.cos(half), 0.0, 0.0, np.sin(half)]), data.qpos[3:7])
        data.qpos[3:7] = self._turned
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_fwdVelocity(model, data)
        mujoco.mj_subtreeVel(model, data)
        relative = data.subtree_linvel[1].copy()  # the centre of mass's velocity if the torso did not translate
        down = sensed[self._contact] > 0.5
        feet_velocity, feet_height = self._feet()
        self.steps_down = self.steps_down + 1 if down.any() else 0
        if not self._first:  # the first reading is the reset state itself: time runs from the second on
            force = data.xmat[1].reshape(3, 3) @ sensed[self._forces].sum(axis=0)  # torso frame -> level frame
            predicted = self.com_velocity + self.dt * (force / self.mass - np.array([0.0, 0.0, GRAVITY]))
            if down.all() and self.steps_down <= LANDING_STEPS:
                self.com_velocity = feet_velocity.mean(axis=0) + relative
            elif (anchored := down if still is None else down & still).any() and self.steps_down > LANDING_STEPS:
                measured = feet_velocity[anchored].mean(axis=0) + relative
                gap = measured - predicted
                kicked = still is not None and still.all() and float(np.hypot(gap[0], gap[1])) > SCHEDULED_GAP
                self.com_velocity = predicted + (self._kicked_gains if kicked else self._gains) * gap
            else:
                self.com_velocity = predicted
        velocity = self.com_velocity - relative
        if down.all():
            self.height = feet_height.max() + self.clearance
        elif not self._first:
            self.height = self.height + velocity[2] * self.dt
        self._first = False
        qpos, qvel = data.qpos.copy(), data.qvel.copy()
        qpos[2], qvel[:3] = self.height, velocity
        return qpos, qvel


def read_sensed(names: list[str]) -> np.ndarray:
    """Where the sensed features a policy on the leg odometry reads sit among `names` (the sensed features'): all but
    the feet's forces, which reach it through the estimate only.

    Why not the forces: at the end of a step they are what the step's executed action did, so a
    student reading them can copy the previous action instead of acting on the state, and it falls
    (docs/decisions/deployable-inputs.md).
    """
    forces = set(force_names())
    return np.array([i for i, name in enumerate(names) if name not in forces])


def odometry_names(model: mujoco.MjModel) -> list[str]:
    """The names of `OdometryFeatures`' entries: the sensed features' it reads, then the estimate's."""
    sensed = Proprioception(model).names
    bodies = [model.body(b).name for b in range(1, model.nbody)]
    estimate = ["odometry.height", "odometry.vx", "odometry.vy", "odometry.vz"]
    inertias = [f"odometry.{body}.cinert{i}" for body in bodies for i in range(10)]
    return [*(sensed[i] for i in read_sensed(sensed)), *estimate, *inertias]


class OdometryFeatures:
    """A policy's input computed from what a robot senses alone: the sensed features but the forces
    (`read_sensed`), then `LegOdometry`'s torso height and linear velocity, and the body inertias about the
    centre of mass (MuJoCo's `cinert`) of the nominal model in the estimated pose. That pose is turned by the
    estimate's heading (the gyro's integral since reset), so the velocity and the inertias carry the heading too;
    with `heading_frame` they are turned into the heading's frame instead, so that a turned body reads as the same
    body: the walker's students, whose walks turn them to headings their demonstrations never faced
    (docs/decisions/turned-headings.md).

    Why these: a student on the sensed features alone does not stand, one that also reads the
    torso's velocity and the nominal-model inertias does (docs/decisions/deployable-inputs.md). Stateful like
    the estimator: `reset` at every episode's start. The "pending" inputs
    (`students.inputs.PendingInputs`) begin with these.
    """

    def __init__(self, model: mujoco.MjModel, heading_frame: bool = False) -> None:
        self.read = read_sensed(Proprioception(model).names)
        self.odometry = LegOdometry(model)
        self.heading_frame = heading_frame
        self.estimate: tuple[np.ndarray, np.ndarray] = (np.zeros(model.nq), np.zeros(model.nv))
        """The last (qpos, qvel) `from_sensed` estimated."""
        self.still: np.ndarray | None = None
        """The feet held still at the next `from_sensed` (a bool per foot), None: every foot down."""

    def reset(self) -> None:
        self.odometry.reset()
        self.still = None

    def from_sensed(self, sensed: np.ndarray) -> np.ndarray:
        """This step's input from this step's sensed features (float64); the estimated state stays in `estimate`. The
        feet `still` says are held still (a walker's gait: `LegOdometry`), None: every foot down."""
        self.estimate = qpos, qvel = self.odometry(sensed, self.still)
        velocity, inertias = qvel[:3], self.odometry.data.cinert[1:]
        if self.heading_frame:
            velocity, inertias = unturned(self.odometry.heading, velocity, inertias)
        return np.concatenate([sensed[self.read], [qpos[2]], velocity, inertias.ravel()])


def unturned(heading: float, velocity: np.ndarray, inertias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A linear velocity (3) and MuJoCo's `cinert` rows (n, 10: the inertia's xx, yy, zz, xy, xz, yz about the centre
    of mass, then mass times the body's offset from it, then the mass) in the frame turned by `heading` about z: R v,
    R I Rᵀ and R m·c, R the turn by −heading."""
    c, s = np.cos(heading), np.sin(heading)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    inertia = np.ascontiguousarray(inertias[:, [0, 3, 4, 3, 1, 5, 4, 5, 2]]).reshape(-1, 3, 3)  # the symmetric 3 x 3
    inertia = turn @ inertia @ turn.T
    turned = inertias.copy()
    turned[:, :6] = inertia[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    turned[:, 6:9] = inertias[:, 6:9] @ turn.T
    return turn @ velocity, turned
