"""Static balance of the Humanoid-v5 body: poses its contacts carry at rest, and the control that holds one.

The feet are spheres: each touches the floor at one point, so the body has no fore-aft support area and at rest the
centre of mass must lie in the vertical plane through the two contact points (`physics.com_over_feet` x = 0);
sideways the two feet span a base of about 0.2 m. A pose balances when inverse dynamics at rest leaves the root no
vertical force and no moment (`physics.static_root_residual`): the contacts carry the body without help.

- `standing_pose`: the body's standing pose, knees at `STANCE_KNEE`, the torso's height and both hip_y angles solved;
  every controller, the task's neutral posture and the estimator's feet start from it (cached on disk).
- `balance_legs`: a pose given everywhere but the legs, its legs solved to balance (the task's postures:
  `task.posture.posture_pose`; a drawn body's stance: `teachers.postures.body_gains`).
- `feed_forward`: the control whose motor torques hold a pose at rest.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from common.cache import load_or_build
from common.threads import openblas_kernels
from humanoid import physics

if TYPE_CHECKING:
    import scipy.optimize

STANCE_KNEE = -0.3
"""Knee angle (rad) of the standing pose: -0.1 also stands; -0.6 does not (docs/concepts/controllers.md)."""
_PITCH = 4  # free-joint dof of the moment about the body y axis
_FD_STEP = 1e-7  # rad: well above round-off, far below the curvature of the residual
_CACHE_FORMAT = 1  # bump when standing_pose changes what it computes


class BalanceError(RuntimeError):
    """No pose near the one asked for balances (the solver did not converge)."""


def model_key(model: mujoco.MjModel, settings: dict) -> str:
    """Hash of the compiled model, `settings` (JSON-ready), the MuJoCo version and the BLAS kernels: what a design on
    `model` depends on, so equal keys mean equal arrays (`common.cache.load_or_build`)."""
    # The MJB serialisation covers everything the XML compiles to (and Python-side edits).
    mjb = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, mjb)
    # The BLAS kernels too: what is designed under one is other numbers than under another (common.threads).
    meta = json.dumps({**settings, "mujoco": mujoco.__version__, "openblas": openblas_kernels()}, sort_keys=True)
    return hashlib.sha256(mjb.tobytes() + meta.encode()).hexdigest()


def balanced_pose(model: mujoco.MjModel, knee: float) -> np.ndarray:
    """Pose with both knees at ``knee`` whose height and hip_y angles leave no vertical force or pitch moment.

    Enough for a left-right symmetric body, which needs no roll moment; a body with drawn masses does, and
    `balance_legs` balances that too.
    """
    hips = joint_addresses(model, ("right_hip_y", "left_hip_y"))
    knees = joint_addresses(model, ("right_knee", "left_knee"))
    data = mujoco.MjData(model)

    def pose(height: float, hip: float) -> np.ndarray:
        qpos = model.qpos0.copy()
        qpos[2], qpos[hips], qpos[knees] = height, hip, knee
        return qpos

    # Start with the feet just touching the floor, so the contacts exist from the first guess.
    data.qpos[:] = pose(0.0, 0.0)
    mujoco.mj_kinematics(model, data)
    lowest = min(data.geom(g).xpos[2] - model.geom(g).size[0] for g in physics.FOOT_GEOMS)

    def residual(x: np.ndarray) -> np.ndarray:
        data.qpos[:] = pose(*x)
        return physics.static_inverse_dynamics(model, data)[[2, _PITCH]]

    import scipy.optimize  # noqa: PLC0415 - scipy costs 0.3 s to import; only a design (cache miss) needs it

    solution = scipy.optimize.root(residual, x0=[-lowest, 0.0], tol=1e-12)
    if not solution.success:
        raise BalanceError(f"no balanced pose for knee={knee}: {solution.message}")
    return pose(*solution.x)


@dataclass(frozen=True)
class _Stance:
    qpos: np.ndarray


@functools.cache
def standing_pose(model: mujoco.MjModel) -> np.ndarray:
    """The standing pose of `model` (`balanced_pose` at `STANCE_KNEE`; root x, y = 0): once per model object and
    process, through the disk cache; read-only."""
    key = model_key(model, {"kind": "stance", "knee": STANCE_KNEE, "format": _CACHE_FORMAT})
    qpos = load_or_build("stance", key, _Stance, lambda: _Stance(balanced_pose(model, STANCE_KNEE))).qpos
    qpos.setflags(write=False)  # shared by every caller
    return qpos


def feed_forward(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Control whose actuator forces equal the joint torques that hold ``qpos`` at rest."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    torque = physics.static_inverse_dynamics(model, data)
    moment = np.zeros((model.nu, model.nv))
    mujoco.mju_sparse2dense(moment, data.actuator_moment, data.moment_rownnz, data.moment_rowadr, data.moment_colind)
    # Only the joints are actuated; the root's residual is what the pose's solve drove to zero.
    ctrl, *_ = np.linalg.lstsq(moment[:, 6:].T, torque[6:], rcond=None)
    return ctrl


def joint_addresses(model: mujoco.MjModel, names: tuple[str, ...]) -> list[int]:
    """Where the joints `names` sit in qpos."""
    return [int(model.joint(name).qposadr[0]) for name in names]


def _solve(
    fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, tol: float, method: str = "hybr"
) -> scipy.optimize.OptimizeResult:
    """``scipy.optimize.root`` by `method` with a central-difference Jacobian of absolute step ``_FD_STEP``.

    MINPACK's own differences scale the step with |x|, which for an unknown starting at 0 (the
    knee split) is a step of 1e-30 or so: a Jacobian of pure noise.
    """

    def jac(x: np.ndarray) -> np.ndarray:
        steps = _FD_STEP * np.eye(len(x))
        return np.stack([(fun(x + e) - fun(x - e)) / (2 * _FD_STEP) for e in steps], axis=1)

    import scipy.optimize  # noqa: PLC0415 - scipy costs 0.3 s to import, and only a posture command needs it

    return scipy.optimize.root(fun, x0=x0, jac=jac, tol=tol, method=method)


ATTEMPTS = (("hybr", "hybr"), ("lm", "hybr"), ("lm", "lm"))
"""The methods `balance_legs` places the feet and then balances the forces with, tried in turn until one balances:
Powell's hybrid method first (every pose the tables hold was solved by it), Levenberg-Marquardt where it stalls. It
stalls where the Jacobian is nearly singular: a shin vertical, whose knee then barely moves its foot up or down (a
waypoint of the schedule of seed 9613, on some CPUs); damped steps get through (docs/decisions/posture-fallback.md)."""
RESIDUAL_TOLERANCE = 1e-6
"""The largest static residual (N, N·m) a Levenberg-Marquardt solve may leave and still count as balanced: a least
squares method also stops at a minimum that is no root. (Powell's method converges only to a root, which it leaves
within about 1e-8.)"""


def balance_legs(model: mujoco.MjModel, base: np.ndarray, neutral: np.ndarray, free_knee: bool) -> np.ndarray:
    """``base`` with the legs solved so that ``physics.static_root_residual`` vanishes; `BalanceError` if they cannot.

    Unknowns: a right-minus-left knee split, a common hip_y angle, and either the common knee
    angle (``free_knee``; the root height stays that of ``base``) or the root height (the knees
    keep ``base``'s angle, plus and minus the split). ``neutral`` is the standing pose.
    """
    hips = joint_addresses(model, ("right_hip_y", "left_hip_y"))
    knees = joint_addresses(model, ("right_knee", "left_knee"))
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
    for placing, balancing in ATTEMPTS:
        guess = _solve(placement, x0, 1e-10, placing)
        solution = _solve(residual, guess.x, 1e-12, balancing)
        if solution.success and (balancing == "hybr" or np.abs(residual(solution.x)).max() <= RESIDUAL_TOLERANCE):
            return pose(solution.x)
    raise BalanceError(f"no balanced pose: {solution.message}")


def crouch_knee(model: mujoco.MjModel, height: float, neutral: np.ndarray) -> float:
    """Knee angle at which the otherwise neutral stance holds the torso ``height`` above (or below) ``neutral``'s."""
    base = neutral.copy()
    base[2] += height
    (knee,) = joint_addresses(model, ("right_knee",))
    return float(balance_legs(model, base, neutral, free_knee=True)[knee])
