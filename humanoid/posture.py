"""Commanded postures of the standing expert: what a teleoperator's keys change.

Balancing 17 motors by hand is impossible, so a key changes *what* the LQR expert holds, and the
expert keeps the body up. A ``Posture`` names the setpoint in a few human terms (lean, crouch,
twist, arm pose); ``posture_reference`` turns it into a statically balanced pose and the
feed-forward control that holds it, which ``LQRExpert.hold`` moves the expert's setpoint to,
gradually (``PostureRamp``).

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
carry the body without help. Each posture also gets its own LQR gain (``posture_gain``): the
neutral one lets twisted, crouched or arms-out poses oscillate or fall.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from humanoid import physics
from humanoid.command_fields import ARM_JOINTS, COMMAND_FIELDS, VELOCITY_NAMES
from humanoid.lqr import LQRDesign, LQRGains, design_gain, feed_forward, load_or_design

if TYPE_CHECKING:
    import scipy.optimize


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
Posture.__doc__ = """A setpoint of the expert, one keyword per command field (`humanoid.command_fields`, in the unit
its row gives); every field 0 is the neutral standing pose of the design. What each posture field does to the body:
this module's docstring; the velocity fields leave the pose alone (`posed`) and the stepping expert walks them
(`humanoid.stepping`)."""


NEUTRAL = Posture()
"""The never-commanded posture: the design's own balanced pose."""


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


_FD_STEP = 1e-7  # rad: well above round-off, far below the curvature of the residual


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


def _joint_addresses(model: mujoco.MjModel, names: tuple[str, ...]) -> list[int]:
    return [int(model.joint(name).qposadr[0]) for name in names]


def _solve(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, tol: float) -> scipy.optimize.OptimizeResult:
    """``scipy.optimize.root`` with a central-difference Jacobian of absolute step ``_FD_STEP``.

    MINPACK's own differences scale the step with |x|, which for an unknown starting at 0 (the
    knee split) is a step of 1e-30 or so: a Jacobian of pure noise.
    """

    def jac(x: np.ndarray) -> np.ndarray:
        steps = _FD_STEP * np.eye(len(x))
        return np.stack([(fun(x + e) - fun(x - e)) / (2 * _FD_STEP) for e in steps], axis=1)

    import scipy.optimize  # noqa: PLC0415 - scipy costs 0.3 s to import, and only a posture command needs it

    return scipy.optimize.root(fun, x0=x0, jac=jac, tol=tol)


def _balance(model: mujoco.MjModel, base: np.ndarray, neutral: np.ndarray, free_knee: bool) -> np.ndarray:
    """``base`` with the legs solved so that ``physics.static_root_residual`` vanishes.

    Unknowns: a right-minus-left knee split, a common hip_y angle, and either the common knee
    angle (``free_knee``; the root height stays that of ``base``) or the root height (the knees
    keep ``base``'s angle, plus and minus the split).
    """
    hips = _joint_addresses(model, ("right_hip_y", "left_hip_y"))
    knees = _joint_addresses(model, ("right_knee", "left_knee"))
    data = mujoco.MjData(model)

    def pose(x: np.ndarray) -> np.ndarray:
        first, hip, split = x
        qpos = base.copy()
        knee = first if free_knee else base[knees[0]]
        if not free_knee:
            qpos[2] = first
        qpos[hips] = hip
        qpos[knees] = knee + split, knee - split
        return qpos

    def residual(x: np.ndarray) -> np.ndarray:
        data.qpos[:] = pose(x)
        return physics.static_root_residual(model, data)

    # Contacts exist only within the geoms' 2 mm margin of the floor: outside that band the
    # residual is flat. So first place both feet at the neutral pose's clearance with the centre
    # of mass over them (kinematics only), then balance the forces from there.
    def clearances(qpos: np.ndarray) -> np.ndarray:
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        return np.array([data.geom(g).xpos[2] - model.geom(g).size[0] for g in physics.FOOT_GEOMS])

    clearance = clearances(neutral)

    def placement(x: np.ndarray) -> np.ndarray:
        feet = clearances(pose(x)) - clearance
        mujoco.mj_comPos(model, data)
        return np.r_[feet, physics.com_over_feet(model, data)[0]]

    x0 = np.array([base[knees[0]] if free_knee else base[2], neutral[hips[0]], 0.0])
    guess = _solve(placement, x0, tol=1e-10)
    solution = _solve(residual, guess.x, tol=1e-12)
    if not solution.success:
        raise RuntimeError(f"no balanced pose: {solution.message}")
    return pose(solution.x)


def crouch_knee(model: mujoco.MjModel, height: float, neutral: np.ndarray) -> float:
    """Knee angle at which the otherwise neutral stance holds the torso ``height`` above (or below) ``neutral``'s."""
    base = neutral.copy()
    base[2] += height
    (knee,) = _joint_addresses(model, ("right_knee",))
    return float(_balance(model, base, neutral, free_knee=True)[knee])


def posture_pose(
    model: mujoco.MjModel, posture: Posture, neutral: np.ndarray, arms: np.ndarray | None = None
) -> np.ndarray:
    """Statically balanced qpos realising ``posture``; ``neutral`` is the design's balanced pose.

    ``arms``, when given, are the arm joint angles (``ARM_JOINTS`` order) instead of the preset's.

    Set by the posture: the knees (``crouch_knee`` of ``height``), the root orientation (trunk
    pitch, waist roll, torso yaw), abdomen_z and abdomen_x (so that the pelvis keeps no roll and
    no yaw) and the arms. Solved (``_balance``): root height, common hip_y angle, knee split.
    So ``height`` is exact for an upright torso; a lean moves the torso's height a little more.
    """
    knees = _joint_addresses(model, ("right_knee", "left_knee"))
    (abdomen_z,) = _joint_addresses(model, ("abdomen_z",))
    (abdomen_x,) = _joint_addresses(model, ("abdomen_x",))

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
    base[_joint_addresses(model, ARM_JOINTS)] = arm_angles(posture.arms) if arms is None else arms
    try:
        return _balance(model, base, neutral, free_knee=False)
    except RuntimeError as error:
        raise RuntimeError(f"{posture}: {error}") from None


@functools.cache
def _design(model: mujoco.MjModel, design: LQRDesign) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # The gains' own arrays, not a re-solve: the default expert's setpoint must stay bit-identical
    # even where the cached gains were computed elsewhere.
    gains = load_or_design(model, design)
    return tuple(_read_only(array.copy()) for array in (gains.qpos_ref, gains.ctrl_ff, gains.gain))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)  # shared by every caller of the caches
    return array


@functools.lru_cache(maxsize=4096)
def _reference(model: mujoco.MjModel, posture: Posture, design: LQRDesign) -> tuple[np.ndarray, np.ndarray]:
    qpos_ref, ctrl_ff, _ = _design(model, design)
    if posture == NEUTRAL:
        return qpos_ref, ctrl_ff
    qpos = posture_pose(model, posture, qpos_ref)
    return _read_only(qpos), _read_only(feed_forward(model, qpos))


def posture_reference(
    model: mujoco.MjModel, posture: Posture, design: LQRDesign = LQRDesign()
) -> tuple[np.ndarray, np.ndarray]:
    """(qpos_ref, ctrl_ff): the balanced pose realising ``posture`` and the control that holds it.

    For ``Posture()`` exactly the design's ``LQRGains.qpos_ref`` and ``ctrl_ff``. Solved once per
    (model, posture, design), in 2 to 10 ms, and cached; the returned arrays are read-only.
    ``ctrl_ff`` is not clipped: a posture whose feed-forward leaves the motors' range cannot be held.
    """
    return _reference(model, posture, design)


GAIN_DISCOUNT = 0.9999
"""Per-step discount of the posture gains' LQR cost (see ``design_gain``): the gain at the neutral pose is then
within 0.2 % of the plain one."""


@functools.lru_cache(maxsize=1024)
def posture_gain(model: mujoco.MjModel, posture: Posture, design: LQRDesign = LQRDesign()) -> np.ndarray:
    """LQR gain designed around ``posture_reference(posture)`` (0.05 to 0.2 s, cached; read-only).

    The neutral gain does not hold most postures (twisted, arms out, crouched: they oscillate or
    fall), so each posture gets its own; for ``Posture()`` exactly the design's ``LQRGains.gain``.
    """
    if posture == NEUTRAL:
        return _design(model, design)[2]
    return _read_only(design_gain(model, *posture_reference(model, posture, design), design, GAIN_DISCOUNT))


def body_gains(model: mujoco.MjModel, design: LQRDesign, neutral: np.ndarray) -> LQRGains:
    """The neutral stance balanced on ``model``, a body other than the design's, with its feed-forward and gain.

    ``neutral`` is the design's balanced pose. A body with other masses or motors (``humanoid.conditions``'
    randomisation) is not balanced by it: ``lqr.balanced_pose`` solves pitch only, which a symmetric body
    needs, and a drawn body is not symmetric. So the stance is solved as a posture's (root height, hip_y,
    knee split) and the gain designed there; not cached (0.05 to 0.2 s). Why: docs/decisions/expert-body.md.
    """
    qpos = posture_pose(model, NEUTRAL, neutral)
    ctrl = feed_forward(model, qpos)
    return LQRGains(qpos_ref=qpos, ctrl_ff=ctrl, gain=design_gain(model, qpos, ctrl, design, GAIN_DISCOUNT))


POSE_RATES: dict[str, float] = {
    "lean_forward": 0.5,
    "lean_left": 0.5,
    "height": 0.025,
    "twist": 0.8,
}
"""Mean speed (per second) at which ``PostureRamp`` moves each posture field toward its target.

Crouching is slow because the expert clips its height error to 2 cm (``LQRDesign.height_clip``,
for the drop after reset): at 0.05 m/s and more the torso lags the setpoint and the body falls."""
RATES: dict[str, float] = {
    **POSE_RATES,
    "forward_speed": 0.4,
    "sideways_speed": 0.4,
    "turn_rate": 0.5,
}
"""``POSE_RATES`` and the velocity fields' mean rates (m/s², rad/s²): a walk speeds up and slows down over about a
second, as a step takes a third of one (docs/decisions/walking-teacher.md)."""
ARM_RATE = 0.4
"""Mean speed (rad/s) of the arm joint that has the farthest to go: at 1.5 rad/s the arms' swing toppled the body."""
WAYPOINT_STEP: dict[str, float] = {
    "lean_forward": 0.05,
    "lean_left": 0.05,
    "height": 0.01,
    "twist": 0.05,
    "arms": 0.1,
}
"""Largest change of a field (arms: of any arm joint, rad) between two solved, balanced waypoints (about 3 ms each)."""
GAIN_STEP: dict[str, float] = {
    "lean_forward": 0.2,
    "lean_left": 0.2,
    "height": 0.06,
    "twist": 0.3,
    "arms": 0.5,
}
"""Largest change between two gains designed on the path (0.05 to 0.2 s each)."""


def _pieces(start: Posture, target: Posture, arm_change: float, step: dict[str, float]) -> int:
    """Into how many pieces to cut the path so that no field changes by more than ``step`` in one."""
    changes = [abs(getattr(target, name) - getattr(start, name)) / step[name] for name in POSE_RATES]
    return max(1, int(np.ceil(max(changes + [arm_change / step["arms"]]))))


def blend(start: Posture, target: Posture, s: float) -> Posture:
    """The posture fraction ``s`` of the way from ``start`` to ``target``, field by field."""
    return Posture(
        **{f.name: (1 - s) * getattr(start, f.name) + s * getattr(target, f.name) for f in dataclasses.fields(Posture)}
    )


def _smoothstep(s: float) -> float:
    # Zero velocity at both ends: a ramp that starts or stops at full speed jolts the body.
    return s * s * (3.0 - 2.0 * s)


@functools.lru_cache(maxsize=1024)
def _path_gain(
    model: mujoco.MjModel,
    design: LQRDesign,
    start: Posture,
    target: Posture,
    from_arms: tuple[float, ...],
    s: float,
) -> np.ndarray:
    """Gain designed at fraction ``s`` of the path from ``start`` (arms at ``from_arms``) to ``target``.

    Cached: a move made again (neutral to arms up and back, say) plans without designing.
    """
    arms = (1 - s) * np.asarray(from_arms) + s * arm_angles(target.arms)
    pose = posture_pose(model, blend(start, target, s), posture_reference(model, NEUTRAL, design)[0], arms)
    return _read_only(design_gain(model, pose, feed_forward(model, pose), design, GAIN_DISCOUNT))


def move_seconds(start: Posture, target: Posture, start_arms: np.ndarray | None = None) -> float:
    """Seconds the expert's setpoint takes from ``start`` (arms at ``start_arms``, if not a preset) to ``target``,
    at ``RATES`` and ``ARM_RATE``."""
    times = [abs(getattr(target, name) - getattr(start, name)) / rate for name, rate in RATES.items()]
    arms_from = arm_angles(start.arms) if start_arms is None else start_arms
    times.append(float(np.abs(arm_angles(target.arms) - arms_from).max()) / ARM_RATE)
    return max(times)


class PosturePath:
    """Where the expert's setpoint is, over time, on its way from one posture to the next: the slowest field at its
    ``RATES`` speed (the arms at ``ARM_RATE``), eased in and out, one env step of ``model`` under ``design`` per
    ``step``.

    ``PostureRamp`` moves the expert's reference along it; a policy on the "ramp" inputs runs it on the operator's
    command (``humanoid.inputs.ramped_set``), so both read the same path from the same commands.
    """

    def __init__(self, model: mujoco.MjModel, design: LQRDesign = LQRDesign()) -> None:
        self.dt = design.frame_skip * model.opt.timestep
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
        return blend(self.start, self.target, _smoothstep(self.progress))

    @property
    def from_arms(self) -> np.ndarray:
        """The arm angles where the current move began."""
        return self._from_arms

    def arms(self) -> np.ndarray:
        """The arm angles the setpoint has now (a move between presets passes through angles no preset names)."""
        s = _smoothstep(self.progress)
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


class PostureRamp:
    """Moves an expert's ``qpos_ref``, ``ctrl_ff`` and ``gain`` (written in place) to a posture's, gradually.

    A jump in the setpoint topples the body, so ``hold`` plans a path from where the setpoint is
    to the target and ``step`` follows it (``PosturePath``: its timing). Straight interpolation between two
    balanced poses is not balanced in between (raising the arms moves the centre of mass 7 mm
    forward midway, enough to topple the body), so the path runs through balanced waypoints
    ``WAYPOINT_STEP`` apart, solved in ``hold`` (about 3 ms each), and interpolates between them
    (the root's orientation along the geodesic). Likewise the gain blends linearly between gains
    designed on the path ``GAIN_STEP`` apart (the target's through ``posture_gain``, cached).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        design: LQRDesign,
        qpos_ref: np.ndarray,
        ctrl_ff: np.ndarray,
        gain: np.ndarray,
    ) -> None:
        self.model = model
        self.design = design
        self.qpos_ref = qpos_ref
        self.ctrl_ff = ctrl_ff
        self.gain = gain
        self.path = PosturePath(model, design)
        self._gains = gain[None].copy()  # (m + 1, nu, nx) gains designed along the path
        self._waypoints = qpos_ref[None].copy()  # (n + 1, nq) balanced poses along the path
        self._steps = np.zeros((0, model.nv))  # (n, nv) from each waypoint to the next
        self._ctrl = ctrl_ff[None].copy()  # (n + 1, nu) their feed-forwards

    @property
    def moving(self) -> bool:
        return self.path.moving

    @property
    def posture(self) -> Posture:
        """Where the setpoint is now (``PosturePath.posture``)."""
        return self.path.posture

    @property
    def target(self) -> Posture:
        """The posture being moved to (or held)."""
        return self.path.target

    def hold(self, posture: Posture, clip: bool = True) -> None:
        """Plan a move to ``posture.clipped()`` from wherever the setpoint is now.

        Costs a few ms per waypoint, plus the target's gain the first time (0.05 to 0.2 s).
        ``clip=False`` holds the posture as given: for measuring how far the limits could go.
        """
        target = posture.clipped() if clip else posture
        if target == self.target:
            return
        model, design = self.model, self.design
        self.path.hold(target)  # the velocities ramp too (the setpoint), but the pose and its gains know none
        start, target = self.path.start.posed(), target.posed()
        gain = posture_gain(model, target, design)
        qpos, ctrl = posture_reference(model, target, design)
        from_arms = self.path.from_arms
        arm_change = float(np.abs(arm_angles(target.arms) - from_arms).max())
        n = _pieces(start, target, arm_change, WAYPOINT_STEP)

        neutral = posture_reference(model, NEUTRAL, design)[0]
        to_arms = arm_angles(target.arms)
        waypoints = [self.qpos_ref.copy()]
        ctrls = [self.ctrl_ff.copy()]
        for k in range(1, n):
            s = k / n
            pose = posture_pose(model, blend(start, target, s), neutral, (1 - s) * from_arms + s * to_arms)
            waypoints.append(pose)
            ctrls.append(feed_forward(model, pose))
        waypoints.append(qpos)
        ctrls.append(ctrl)
        self._waypoints = np.array(waypoints)
        self._ctrl = np.array(ctrls)
        self._steps = np.zeros((n, model.nv))
        for k in range(n):
            mujoco.mj_differentiatePos(model, self._steps[k], 1.0, waypoints[k], waypoints[k + 1])
        # The gain blends linearly between knots designed on the path: blending straight from
        # the start's gain to the target's leaves the mid-path poses of combined moves (arms up
        # while twisting or crouching) without a stabilising gain.
        knots = _pieces(start, target, arm_change, GAIN_STEP)
        gains = [self.gain.copy()]
        key = tuple(from_arms)
        gains += [_path_gain(model, design, start, target, key, j / knots) for j in range(1, knots)]
        gains.append(gain)
        self._gains = np.array(gains)

    def step(self) -> bool:
        """Advance the setpoint by one env step; True while there is still some way to go."""
        if not self.path.step():
            # End exactly on the solved pose, not on a sum of increments.
            self._set(self.target)
            return False
        s = _smoothstep(self.path.progress) * len(self._steps)
        k = min(int(s), len(self._steps) - 1)
        frac = s - k
        self.qpos_ref[:] = self._waypoints[k]
        mujoco.mj_integratePos(self.model, self.qpos_ref, self._steps[k], frac)
        np.multiply(self._ctrl[k + 1] - self._ctrl[k], frac, out=self.ctrl_ff)
        self.ctrl_ff += self._ctrl[k]
        s *= (len(self._gains) - 1) / len(self._steps)
        j = min(int(s), len(self._gains) - 2)
        np.subtract(self._gains[j + 1], self._gains[j], out=self.gain)
        self.gain *= s - j
        self.gain += self._gains[j]
        return True

    def _set(self, posture: Posture) -> None:
        posture = posture.posed()
        self.qpos_ref[:], self.ctrl_ff[:] = posture_reference(self.model, posture, self.design)
        self.gain[:] = posture_gain(self.model, posture, self.design)

    def reset(self) -> None:
        """Back to the neutral setpoint at once: the env's reset has put the body back anyway."""
        self._set(NEUTRAL)
        self.path.reset()
