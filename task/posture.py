"""Commanded postures: what a teleoperator's keys ask the body to hold, and how the command moves toward one.

Balancing 17 motors by hand is impossible, so a key changes *what* the body holds, and a teacher keeps it up. A
``Posture`` names it in a few human terms (lean, crouch, twist, arm pose), one keyword per command field
(`task.command_fields`); ``commanded_pose`` turns it into the statically balanced pose that realises it, which the
tracking measures against (`task.tracking`) and a teacher holds (`teachers.postures`). ``PosturePath`` is the command
filter: where the setpoint is, over time, on its way from one posture to the next, at each field's ``rate``; a
teacher's setpoint follows it and a student reads it (`students.inputs`).

What the fields mean physically. The feet are spheres: each touches the floor at one point, so
the body has no fore-aft support area and at rest the centre of mass must lie in the vertical
plane through the two contact points (``com_over_feet`` x = 0). Sideways the two feet span a base
of about 0.2 m, so the centre of mass can move toward one foot.

- ``lean_forward`` pitches the whole trunk (torso, waist, pelvis) about the hips; the hips and
  knees re-solve so the centre of mass stays over the feet, i.e. the hips go back as the chest
  goes forward. The torso tilts, the centre of mass does not move fore-aft (it cannot, statically).
- ``lean_left`` bends the waist sideways (torso rolls, pelvis stays level, abdomen_x takes the
  angle): the upper body's mass moves toward the left foot, and the feet share the weight
  unequally (solved through a small knee difference, which sets how deep each foot presses).
- ``height`` moves the torso (the root, whose height the env's healthy check reads) up or down:
  the knees take the angle that puts an upright torso ``height`` lower or higher, and the hips
  re-solve. Rising has little room (its row's ``high``, under a centimetre): the neutral knees
  (-0.3 rad) are nearly straight.
- ``twist`` yaws the torso relative to the pelvis (abdomen_z); legs and pelvis keep their yaw.
- ``arms`` selects a preset of shoulder and elbow angles (``ARM_POSES``).

In every pose the unknowns (torso height, hip_y angle, left/right knee difference) are solved so
that inverse dynamics at rest leaves no vertical force and no moment on the root: the contacts
carry the body without help (`humanoid.balance`). A posture the solver cannot balance falls back to the nearest one
on the way to it that it can (`nearest_pose`).
"""

from __future__ import annotations

import dataclasses
import functools
import logging

import mujoco
import numpy as np

from humanoid.balance import BalanceError, balance_legs, crouch_knee, joint_addresses, standing_pose
from humanoid.env import step_seconds
from task.command_fields import ARM_JOINTS, COMMAND_FIELDS, FIELDS, POSTURE_FIELDS, VELOCITY_NAMES

log = logging.getLogger(__name__)


def _clipped(self: Posture) -> Posture:
    """This posture with every field inside its limits (`CommandField.clip`: a preset rounded to one)."""
    return Posture(**{field.name: field.clip(getattr(self, field.name)) for field in COMMAND_FIELDS})


def _posed(self: Posture) -> Posture:
    """This posture without its velocities: the pose the body holds, which the balance solves and the gains are
    designed for (a walk changes neither)."""
    return dataclasses.replace(self, **dict.fromkeys(VELOCITY_NAMES, 0.0))


Posture = dataclasses.make_dataclass(
    "Posture",
    [(field.name, float, dataclasses.field(default=0.0)) for field in COMMAND_FIELDS],
    frozen=True,
    namespace={"clipped": _clipped, "posed": _posed},
    module=__name__,
)
Posture.__doc__ = """A command, one keyword per command field (`task.command_fields`, in the unit its row gives); every
field 0 is the standing pose (`humanoid.balance.standing_pose`). What each posture field does to the body: this module's
docstring; the velocity fields leave the pose alone (`posed`) and a teacher that walks walks them (`teachers`)."""


NEUTRAL = Posture()
"""The never-commanded posture, the zero command: the standing pose."""


def _mirrored(shoulder1: float, shoulder2: float, elbow: float) -> tuple[float, ...]:
    """Right-arm angles (deg) and their mirror image on the left (shoulder axes mirror in sign)."""
    return tuple(np.radians([shoulder1, shoulder2, elbow, -shoulder1, -shoulder2, elbow]))


ARM_POSES: tuple[tuple[float, ...], ...] = (
    _mirrored(0.0, 0.0, 0.0),
    # Found by inverse kinematics of the hand, 5 degrees inside every joint limit:
    _mirrored(0.0, 38.9, -77.9),  # hands straight forward at shoulder height, elbows straight
    _mirrored(-80.0, 22.2, -85.0),  # hands as high as the shoulders reach: above the head, a little forward
    _mirrored(-50.8, -39.9, -77.9),  # hands straight out sideways at shoulder height
)
"""Arm joint angles (rad, ``ARM_JOINTS`` order) of each ``Posture.arms`` preset."""


def arm_angles(arms: float) -> np.ndarray:
    """Arm joint angles for ``arms``: a preset, or the linear blend of the two presets around a fraction."""
    arms = min(max(arms, 0.0), len(ARM_POSES) - 1.0)
    low = int(np.floor(arms))
    high = min(low + 1, len(ARM_POSES) - 1)
    frac = arms - low
    return (1.0 - frac) * np.asarray(ARM_POSES[low]) + frac * np.asarray(ARM_POSES[high])


def axis_quaternion(axis: int, angle: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation by ``angle`` about coordinate axis ``axis``."""
    quat = np.zeros(4)
    quat[0], quat[1 + axis] = np.cos(angle / 2), np.sin(angle / 2)
    return quat


def multiply_quaternions(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product a ⊗ b of quaternions (w, x, y, z), MuJoCo's."""
    out = np.empty(4)
    mujoco.mju_mulQuat(out, a, b)
    return out


def posture_pose(
    model: mujoco.MjModel, posture: Posture, neutral: np.ndarray, arms: np.ndarray | None = None
) -> np.ndarray:
    """Statically balanced qpos realising ``posture``; ``neutral`` is the standing pose (`standing_pose`).

    ``arms``, when given, are the arm joint angles (``ARM_JOINTS`` order) instead of the preset's.

    Set by the posture: the knees (``crouch_knee`` of ``height``), the root orientation (trunk
    pitch, waist roll, torso yaw), abdomen_z and abdomen_x (so that the pelvis keeps no roll and
    no yaw) and the arms. Solved (`balance_legs`): root height, common hip_y angle, knee split.
    So ``height`` is exact for an upright torso; a lean moves the torso's height a little more. `BalanceError`
    naming the posture where no pose balances.
    """
    try:
        return _posed_legs(model, posture, neutral, arms)
    except BalanceError as error:
        raise BalanceError(f"{posture}: {error}") from None


def _posed_legs(model: mujoco.MjModel, posture: Posture, neutral: np.ndarray, arms: np.ndarray | None) -> np.ndarray:
    """`posture_pose`'s solve."""
    knees = joint_addresses(model, ("right_knee", "left_knee"))
    (abdomen_z,) = joint_addresses(model, ("abdomen_z",))
    (abdomen_x,) = joint_addresses(model, ("abdomen_x",))

    base = neutral.copy()
    if posture.height != 0.0:
        base[knees] = crouch_knee(model, posture.height, neutral)
    # Root = torso: pitch the trunk, roll the torso (+lean_left rolls the top toward +y, i.e. a
    # negative rotation about x), yaw the torso. The waist joints undo the roll and the yaw below
    # the torso, so the pelvis is the neutral one pitched by lean_forward:
    # R_pelvis = R_y(pitch) R_x(-roll) R_z(yaw) . R_z(-yaw) R_x(roll) = R_y(pitch).
    tilt = multiply_quaternions(axis_quaternion(1, posture.lean_forward), axis_quaternion(0, -posture.lean_left))
    base[3:7] = multiply_quaternions(tilt, axis_quaternion(2, posture.twist))
    base[abdomen_z] = -posture.twist
    base[abdomen_x] = posture.lean_left
    base[joint_addresses(model, ARM_JOINTS)] = arm_angles(posture.arms) if arms is None else arms
    return balance_legs(model, base, neutral, free_knee=False)


FALLBACK_HALVINGS = 12
"""How finely `nearest_pose` looks for the nearest posture it can balance: 1/4096 of the way."""


def nearest_pose(
    model: mujoco.MjModel,
    start: Posture,
    target: Posture,
    neutral: np.ndarray,
    start_arms: np.ndarray,
    target_arms: np.ndarray,
) -> np.ndarray:
    """`posture_pose` of ``target`` (arms at ``target_arms``); where no pose of it balances, that of the posture
    nearest to it, on the straight way from ``start`` (arms at ``start_arms``, a posture that balances), that does:
    the way halved `FALLBACK_HALVINGS` times. One warning line names the posture and how far it got.

    Why: the solver's convergence near a singular Jacobian differs from one CPU to another
    (docs/decisions/posture-fallback.md); a pose a little short of the one asked for is held, where an error would end
    the episode.
    """
    try:
        return posture_pose(model, target, neutral, target_arms)
    except BalanceError as error:
        failure = error
    low, high, nearest = 0.0, 1.0, None
    for _ in range(FALLBACK_HALVINGS):
        s = 0.5 * (low + high)
        try:
            nearest = posture_pose(model, blend(start, target, s), neutral, (1 - s) * start_arms + s * target_arms)
            low = s
        except BalanceError:
            high = s
    if nearest is None:
        nearest = posture_pose(model, start, neutral, start_arms)
    reason = " ".join(str(failure).split())  # one line: MINPACK's messages wrap
    log.warning("%s; holding the posture %.4f of the way to it from %s instead", reason, low, start)
    return nearest


def read_only(array: np.ndarray) -> np.ndarray:
    """`array`, made read-only: shared by every caller of a cache."""
    array.setflags(write=False)
    return array


@functools.lru_cache(maxsize=4096)
def commanded_pose(model: mujoco.MjModel, posture: Posture) -> np.ndarray:
    """The balanced pose (qpos, root x and y 0) realising ``posture`` on ``model``: for ``Posture()`` exactly the
    standing pose; else `nearest_pose` on the way from it. Solved once per (model, posture), in 2 to 10 ms, and cached;
    read-only. What a posed field's tracking target is (`task.tracking`) and what a teacher holds."""
    neutral = standing_pose(model)
    if posture == NEUTRAL:
        return neutral
    return read_only(nearest_pose(model, NEUTRAL, posture, neutral, arm_angles(NEUTRAL.arms), arm_angles(posture.arms)))


POSED = tuple(field for field in POSTURE_FIELDS if not field.presets)
"""The posture fields but the arm preset, whose ramp moves six joint angles: the fields a ramp compares one by one."""
ARMS = FIELDS["arms"]
"""The arm preset's row: its `rate`, `waypoint_step` and `gain_step` are of the arm joint with the farthest to go."""


def blend(start: Posture, target: Posture, s: float) -> Posture:
    """The posture fraction ``s`` of the way from ``start`` to ``target``, field by field."""
    return Posture(
        **{f.name: (1 - s) * getattr(start, f.name) + s * getattr(target, f.name) for f in dataclasses.fields(Posture)}
    )


def smoothstep(s: float) -> float:
    """The cubic 0 → 1 at `s` in [0, 1], with zero velocity at both ends: a ramp that starts or stops at full speed
    jolts the body."""
    return s * s * (3.0 - 2.0 * s)


def move_seconds(start: Posture, target: Posture, start_arms: np.ndarray | None = None) -> float:
    """Seconds the expert's setpoint takes from ``start`` (arms at ``start_arms``, if not a preset) to ``target``,
    at each field's ``rate`` (the arms': of the joint with the farthest to go)."""
    times = [
        abs(getattr(target, field.name) - getattr(start, field.name)) / field.rate
        for field in COMMAND_FIELDS
        if not field.presets
    ]
    arms_from = arm_angles(start.arms) if start_arms is None else start_arms
    times.append(float(np.abs(arm_angles(target.arms) - arms_from).max()) / ARMS.rate)
    return max(times)


class PosturePath:
    """Where a teacher's setpoint is, over time, on its way from one posture to the next: the slowest field at its
    ``rate`` (the arms': of the joint with the farthest to go), eased in and out, one env step of ``model`` per
    ``step``: the command filter.

    A teacher moves its reference along it (`teachers.postures.PostureRamp`); a policy on the "ramp" inputs runs it
    on the operator's command (`students.inputs.ramped_set`), so both read the same path from the same commands.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.dt = step_seconds(model)
        self._from_arms = arm_angles(0.0)  # arm angles where the move began, which a blend of presets may not name
        self.reset()

    def reset(self) -> None:
        """At the neutral posture, not moving."""
        self.target = NEUTRAL
        """The posture being moved to (or held)."""
        self.start = NEUTRAL
        """Where the current move began."""
        self.progress = 1.0
        """Fraction of the move's time elapsed, 1 once there."""
        self._from_arms[:] = arm_angles(0.0)
        self._increment = 1.0

    @property
    def moving(self) -> bool:
        return self.progress < 1.0

    @property
    def posture(self) -> Posture:
        """Where the setpoint is now, fieldwise between ``start`` and ``target`` (``arms``: the fraction of the way)."""
        return blend(self.start, self.target, smoothstep(self.progress))

    @property
    def from_arms(self) -> np.ndarray:
        """The arm angles where the current move began."""
        return self._from_arms

    def arms(self) -> np.ndarray:
        """The arm angles the setpoint has now (a move between presets passes through angles no preset names)."""
        s = smoothstep(self.progress)
        return (1 - s) * self._from_arms + s * arm_angles(self.target.arms)

    def hold(self, target: Posture) -> None:
        """Start a move to ``target`` from wherever the setpoint is now."""
        start = self.posture
        self._from_arms[:] = self.arms()
        self.start, self.target = start, target
        duration = move_seconds(start, target, self._from_arms)
        self._increment = 1.0 / max(1, int(np.ceil(duration / self.dt)))
        self.progress = 0.0

    def step(self) -> bool:
        """Advance one env step; True while there is still some way to go."""
        self.progress = min(1.0, self.progress + self._increment)
        return self.progress < 1.0
