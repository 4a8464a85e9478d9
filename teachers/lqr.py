"""The LQR design behind the standing expert (`teachers.expert`) and its postures (`teachers.postures`).

The design, run once per model and cached on disk (docs/concepts/controllers.md, "The expert"):

1. the body's standing pose (`humanoid.balance.standing_pose`: knees at `STANCE_KNEE`, torso height and both hip_y
   angles solved so that inverse dynamics leaves no vertical force and no pitch moment on the root);
2. feed-forward control: the joint torques of that inverse dynamics, through the actuator moments
   (`humanoid.balance.feed_forward`);
3. a linear model of one env step (`humanoid.env.FRAME_SKIP` x ``mj_step``) by central finite differences,
   on a copy of the model whose constraint solver is converged (the env's PGS solver stops after
   one or two iterations, which turns small differences into noise);
4. discrete LQR on that model.

State (nx = 2 nv - 2): the position error in the tangent space of ``mj_differentiatePos``
(root x and y left out: they are translation-invariant and uncontrollable), then qvel.
At run time the action is ``ctrl_ff - gain @ state``, clipped to the motors' range.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass

import mujoco
import numpy as np

from common.cache import load_or_build
from humanoid import physics
from humanoid.balance import feed_forward, model_key, standing_pose
from humanoid.env import FRAME_SKIP

CTRL_LIMIT = 0.4
"""Every Humanoid-v5 motor accepts ctrl in [-CTRL_LIMIT, CTRL_LIMIT]."""

_CACHE_FORMAT = 1  # bump when design_lqr changes what it computes, so old cache files go stale
ROOT_XY = 2  # the free joint's leading x, y coordinates, left out of the LQR state
HEIGHT = 0  # index of the root height error in the position part of the state
VERTICAL_VEL = 2  # index of the root vertical velocity in qvel


@dataclass(frozen=True)
class LQRDesign:
    """Design parameters of the standing controller; every field is part of the cache key."""

    q_com: float = 1000.0
    """Cost weight on the horizontal offset of the centre of mass from the feet mid-point."""
    q_pos: float = 3.0
    """Cost weight on root height/orientation and joint angle errors."""
    q_vel: float = 0.1
    """Cost weight on velocities."""
    r: float = 10.0
    """Cost weight on control; 1 chatters against the +-0.4 limits."""
    height_clip: float = 0.02
    """Run-time clip of the height error (m): reset drops the body ~12 cm, beyond the linear model."""
    height_vel_clip: float = 0.2
    """Run-time clip of the vertical velocity (m/s), for the same reason."""
    landing_steps: int = 200
    """Env steps after each reset spent tracking the planned landing (``teachers.landing``); 0: none."""
    fd_eps: float = 1e-6
    """Finite-difference step of the linearisation."""
    solver_iterations: int = 300
    """Constraint-solver iterations of the linearisation model."""
    solver_tolerance: float = 1e-13
    """Constraint-solver tolerance of the linearisation model."""


@dataclass(frozen=True)
class LQRGains:
    """What ``design_lqr`` produces."""

    qpos_ref: np.ndarray
    """(nq,) balanced pose (root x, y = 0)."""
    ctrl_ff: np.ndarray
    """(nu,) feed-forward control that holds the balanced pose."""
    gain: np.ndarray
    """(nu, nx) feedback matrix K: ctrl = ctrl_ff - K @ state."""


def state_error(model: mujoco.MjModel, qpos_ref: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """LQR state of (qpos, qvel) around qpos_ref: tangent-space position error without root x, y, then qvel."""
    dq = np.empty(model.nv)
    mujoco.mj_differentiatePos(model, dq, 1.0, qpos_ref, qpos)
    return np.concatenate([dq[ROOT_XY:], qvel])


def _converged_copy(model: mujoco.MjModel, design: LQRDesign) -> mujoco.MjModel:
    """Copy of ``model`` whose Newton solver converges, so that finite differences are smooth."""
    sim = copy.deepcopy(model)
    sim.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    sim.opt.iterations = design.solver_iterations
    sim.opt.tolerance = design.solver_tolerance
    return sim


def linearise(
    model: mujoco.MjModel,
    qpos_ref: np.ndarray,
    ctrl_ref: np.ndarray,
    design: LQRDesign,
    qvel: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference Jacobians (A, B) of one env step from qpos_ref (at rest, or with ``qvel``) under ctrl_ref.

    The next state's error is taken from where the unperturbed step goes: from rest in a balanced pose
    that is qpos_ref itself (the steady design keeps using it); along the landing (``teachers.landing``)
    it is the step's own result.
    """
    sim = _converged_copy(model, design)
    nominal = mujoco.MjData(sim)
    nominal.qpos[:], nominal.ctrl[:] = qpos_ref, ctrl_ref
    scratch = mujoco.MjData(sim)
    nx = 2 * sim.nv - ROOT_XY
    origin = qpos_ref
    if qvel is not None:
        nominal.qvel[:] = qvel
    mujoco.mj_forward(sim, nominal)
    if qvel is not None:
        mujoco.mj_copyData(scratch, sim, nominal)
        mujoco.mj_step(sim, scratch, nstep=FRAME_SKIP)
        origin = scratch.qpos.copy()

    def step(z: np.ndarray) -> np.ndarray:
        """Next state after perturbing the nominal state by z[:nx] and its control by z[nx:]."""
        mujoco.mj_copyData(scratch, sim, nominal)
        dq = np.concatenate([np.zeros(ROOT_XY), z[: sim.nv - ROOT_XY]])
        mujoco.mj_integratePos(sim, scratch.qpos, dq, 1.0)
        scratch.qvel[:] += z[sim.nv - ROOT_XY : nx]
        scratch.ctrl[:] += z[nx:]
        mujoco.mj_step(sim, scratch, nstep=FRAME_SKIP)
        return state_error(sim, origin, scratch.qpos, scratch.qvel)

    eps = design.fd_eps
    jac = np.stack([(step(eps * e) - step(-eps * e)) / (2 * eps) for e in np.eye(nx + sim.nu)], axis=1)
    return jac[:, :nx], jac[:, nx:]


def design_lqr(model: mujoco.MjModel, design: LQRDesign = LQRDesign()) -> LQRGains:
    """Balanced pose, feed-forward and LQR feedback gain for ``model`` (under a second; cached: ``load_or_design``)."""
    qpos_ref = standing_pose(model).copy()
    ctrl_ff = feed_forward(model, qpos_ref)
    if np.abs(ctrl_ff).max() > CTRL_LIMIT:
        raise RuntimeError(f"feed-forward {np.abs(ctrl_ff).max():.3f} exceeds the motor range")
    return LQRGains(qpos_ref=qpos_ref, ctrl_ff=ctrl_ff, gain=design_gain(model, qpos_ref, ctrl_ff, design))


def design_gain(
    model: mujoco.MjModel,
    qpos_ref: np.ndarray,
    ctrl_ff: np.ndarray,
    design: LQRDesign = LQRDesign(),
    discount: float = 1.0,
) -> np.ndarray:
    """LQR feedback gain K (nu, nx) around the rest pose ``qpos_ref`` held by ``ctrl_ff`` (0.05 to 0.2 s).

    The model has an uncontrollable mode on the unit circle (the yaw of the line between the two
    planted feet: friction holds it, no motor moves it), which makes the Riccati equation
    ill-posed; at the neutral pose round-off happens to let it through. ``discount`` < 1 (cost of
    step k weighted discount**k) moves that mode inside the unit circle so the equation solves
    anywhere; the default 1 is the plain LQR of ``design_lqr``.
    """
    return riccati(model, qpos_ref, ctrl_ff, design, discount)[0]


def riccati(
    model: mujoco.MjModel,
    qpos_ref: np.ndarray,
    ctrl_ff: np.ndarray,
    design: LQRDesign = LQRDesign(),
    discount: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``design_gain``'s gain K and the cost-to-go matrix P it comes from (the landing's recursion ends in P)."""
    import scipy.linalg  # noqa: PLC0415 - scipy costs 0.3 s to import; only a design (cache miss) needs it

    a, b = linearise(model, qpos_ref, ctrl_ff, design)
    if discount != 1.0:
        a, b = np.sqrt(discount) * a, np.sqrt(discount) * b
    q, r = lqr_cost(model, qpos_ref, design)
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    return riccati_gain(a, b, r, p), p


def riccati_gain(a: np.ndarray, b: np.ndarray, r: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The LQR gain of one step of (a, b) with control cost r, given the next step's cost-to-go p."""
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)


def lqr_cost(model: mujoco.MjModel, qpos_ref: np.ndarray, design: LQRDesign) -> tuple[np.ndarray, np.ndarray]:
    """The design's state and control cost matrices (Q, R), the centre of mass's offset taken at qpos_ref."""
    import scipy.linalg  # noqa: PLC0415 - scipy costs 0.3 s to import; only a design (cache miss) needs it

    data = mujoco.MjData(model)
    data.qpos[:] = qpos_ref
    mujoco.mj_forward(model, data)
    jac = physics.com_over_feet_jacobian(model, data)[:, ROOT_XY:]
    npos = model.nv - ROOT_XY
    q = scipy.linalg.block_diag(
        design.q_com * jac.T @ jac + design.q_pos * np.eye(npos), design.q_vel * np.eye(model.nv)
    )
    return q, design.r * np.eye(model.nu)


def steady_action(
    model: mujoco.MjModel,
    design: LQRDesign,
    setpoint: tuple[np.ndarray, np.ndarray, np.ndarray],
    qpos: np.ndarray,
    qvel: np.ndarray,
) -> np.ndarray:
    """The steady law ``ctrl_ff - gain @ state`` for ``setpoint`` = (qpos_ref, ctrl_ff, gain): the height error
    and vertical velocity clipped (``LQRDesign.height_clip``), float32 within the motors' range."""
    qpos_ref, ctrl_ff, gain = setpoint
    x = state_error(model, qpos_ref, qpos, qvel)
    vz = model.nv - ROOT_XY + VERTICAL_VEL
    # Builtin min/max: np.clip costs microseconds per scalar call.
    x[HEIGHT] = min(max(x[HEIGHT], -design.height_clip), design.height_clip)
    x[vz] = min(max(x[vz], -design.height_vel_clip), design.height_vel_clip)
    return np.clip(ctrl_ff - gain @ x, -CTRL_LIMIT, CTRL_LIMIT).astype(np.float32)


def cache_key(model: mujoco.MjModel, design: LQRDesign) -> str:
    """Hash of the compiled model, the design, the MuJoCo version and the BLAS kernels: equal keys, equal gains."""
    return model_key(model, {"design": dataclasses.asdict(design), "format": _CACHE_FORMAT})


def load_or_design(model: mujoco.MjModel, design: LQRDesign = LQRDesign()) -> LQRGains:
    """``design_lqr`` through the on-disk cache: a file per (model, design) key, rebuilt when missing or stale."""
    return load_or_build("lqr", cache_key(model, design), LQRGains, lambda: design_lqr(model, design))
