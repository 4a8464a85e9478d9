"""The LQR teacher's postures: the gains and feed-forward that hold a commanded posture, and the ramp that moves its
setpoint there (docs/concepts/commands.md).

The task says what pose a posture is (`task.posture.commanded_pose`, a statically balanced pose) and how fast the
command filter moves toward it (`task.posture.PosturePath`, each field's `rate`); the teacher holds it with its own
feed-forward and LQR gain (`posture_reference`, `posture_gain`: the neutral gain lets twisted, crouched or arms-out
poses oscillate or fall) and moves its setpoint along balanced waypoints with gains designed on the way
(`PostureRamp`, each field's `waypoint_step` and `gain_step`).
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from humanoid.balance import feed_forward
from task.posture import (
    ARMS,
    NEUTRAL,
    POSED,
    Posture,
    PosturePath,
    arm_angles,
    blend,
    commanded_pose,
    nearest_pose,
    posture_pose,
    read_only,
    smoothstep,
)
from teachers.lqr import LQRDesign, LQRGains, design_gain, load_or_design


@functools.cache
def _design(model: mujoco.MjModel, design: LQRDesign) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # The gains' own arrays, not a re-solve: the default expert's setpoint must stay bit-identical
    # even where the cached gains were computed elsewhere.
    gains = load_or_design(model, design)
    return tuple(read_only(array.copy()) for array in (gains.qpos_ref, gains.ctrl_ff, gains.gain))


@functools.lru_cache(maxsize=4096)
def _reference(model: mujoco.MjModel, posture: Posture, design: LQRDesign) -> tuple[np.ndarray, np.ndarray]:
    qpos_ref, ctrl_ff, _ = _design(model, design)
    if posture == NEUTRAL:
        return qpos_ref, ctrl_ff
    qpos = commanded_pose(model, posture)
    return qpos, read_only(feed_forward(model, qpos))


def posture_reference(
    model: mujoco.MjModel, posture: Posture, design: LQRDesign = LQRDesign()
) -> tuple[np.ndarray, np.ndarray]:
    """(qpos_ref, ctrl_ff): the balanced pose realising ``posture`` (`commanded_pose`) and the control that holds it.

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
    return read_only(design_gain(model, *posture_reference(model, posture, design), design, GAIN_DISCOUNT))


def body_gains(model: mujoco.MjModel, design: LQRDesign, neutral: np.ndarray) -> LQRGains:
    """The neutral stance balanced on ``model``, a body other than the design's, with its feed-forward and gain.

    ``neutral`` is the design's balanced pose. A body with other masses or motors (``humanoid.conditions``'
    randomisation) is not balanced by it: `humanoid.balance.balanced_pose` solves pitch only, which a symmetric body
    needs, and a drawn body is not symmetric. So the stance is solved as a posture's (root height, hip_y,
    knee split) and the gain designed there; not cached (0.05 to 0.2 s). Why: docs/decisions/expert-body.md.
    """
    qpos = posture_pose(model, NEUTRAL, neutral)
    ctrl = feed_forward(model, qpos)
    return LQRGains(qpos_ref=qpos, ctrl_ff=ctrl, gain=design_gain(model, qpos, ctrl, design, GAIN_DISCOUNT))


def _pieces(start: Posture, target: Posture, arm_change: float, step: str) -> int:
    """Into how many pieces to cut the path so that no field changes by more than its row's ``step`` (`waypoint_step`
    or `gain_step`) in one."""
    changes = [abs(getattr(target, field.name) - getattr(start, field.name)) / getattr(field, step) for field in POSED]
    return max(1, int(np.ceil(max(changes + [arm_change / getattr(ARMS, step)]))))


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
    from_arms = np.asarray(from_arms)
    arms = (1 - s) * from_arms + s * arm_angles(target.arms)
    neutral = posture_reference(model, NEUTRAL, design)[0]
    pose = nearest_pose(model, start, blend(start, target, s), neutral, from_arms, arms)
    return read_only(design_gain(model, pose, feed_forward(model, pose), design, GAIN_DISCOUNT))


def waypoint_poses(
    model: mujoco.MjModel, neutral: np.ndarray, start: Posture, target: Posture, from_arms: np.ndarray, pieces: int
) -> list[np.ndarray]:
    """The balanced poses 1/``pieces``, 2/``pieces``, ... (``pieces`` - 1)/``pieces`` of the way from ``start`` (arms at
    ``from_arms``) to ``target``: the waypoints of a ramp's move; where one does not balance, the nearest on the way
    from the one before that does (`task.posture.nearest_pose`). ``neutral``: the standing pose."""
    to_arms = arm_angles(target.arms)
    poses = []
    for k in range(1, pieces):
        before, s = (k - 1) / pieces, k / pieces
        poses.append(
            nearest_pose(
                model,
                blend(start, target, before),
                blend(start, target, s),
                neutral,
                (1 - before) * from_arms + before * to_arms,
                (1 - s) * from_arms + s * to_arms,
            )
        )
    return poses


class PostureRamp:
    """Moves an expert's ``qpos_ref``, ``ctrl_ff`` and ``gain`` (written in place) to a posture's, gradually.

    A jump in the setpoint topples the body, so ``hold`` plans a path from where the setpoint is
    to the target and ``step`` follows it (``PosturePath``: its timing). Straight interpolation between two
    balanced poses is not balanced in between (raising the arms moves the centre of mass 7 mm
    forward midway, enough to topple the body), so the path runs through balanced waypoints
    each field's ``waypoint_step`` apart (`waypoint_poses`, solved in ``hold``, about 3 ms each), and interpolates
    between them (the root's orientation along the geodesic). Likewise the gain blends linearly between gains
    designed on the path each field's ``gain_step`` apart (the target's through ``posture_gain``, cached).
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
        self.path = PosturePath(model)
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
        n = _pieces(start, target, arm_change, "waypoint_step")

        neutral = posture_reference(model, NEUTRAL, design)[0]
        waypoints = [self.qpos_ref.copy()]
        ctrls = [self.ctrl_ff.copy()]
        for pose in waypoint_poses(model, neutral, start, target, from_arms, n):
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
        knots = _pieces(start, target, arm_change, "gain_step")
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
        s = smoothstep(self.path.progress) * len(self._steps)
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
