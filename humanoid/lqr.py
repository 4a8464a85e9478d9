"""The LQR design behind the standing expert (`humanoid.expert`) and its postures (`humanoid.posture`).

The design, run once per model and cached on disk (docs/concepts/controllers.md, "The expert"):

1. a statically balanced pose: knees at ``LQRDesign.knee``, torso height and both hip_y angles
   solved so that inverse dynamics leaves no vertical force and no pitch moment on the root;
2. feed-forward control: the joint torques of that inverse dynamics, through the actuator moments;
3. a linear model of one env step (``frame_skip`` x ``mj_step``) by central finite differences,
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
import hashlib
import json
import logging
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import mujoco
import numpy as np

from common.paths import cache_dir
from common.threads import openblas_kernels
from humanoid import physics

log = logging.getLogger(__name__)

T = TypeVar("T")  # what load_or_build caches (a TypeVar, not 3.12's syntax: tests/test_layout.py says why)

CTRL_LIMIT = 0.4
"""Every Humanoid-v5 motor accepts ctrl in [-CTRL_LIMIT, CTRL_LIMIT]."""

_CACHE_FORMAT = 1  # bump when design_lqr changes what it computes, so old cache files go stale
ROOT_XY = 2  # the free joint's leading x, y coordinates, left out of the LQR state
HEIGHT = 0  # index of the root height error in the position part of the state
VERTICAL_VEL = 2  # index of the root vertical velocity in qvel
_PITCH = 4  # free-joint dof of the moment about the body y axis


@dataclass(frozen=True)
class LQRDesign:
    """Design parameters of the standing controller; every field is part of the cache key."""

    knee: float = -0.3
    """Knee angle of the balanced pose (rad). -0.1 also stands; -0.6 does not."""
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
    """Env steps after each reset spent tracking the planned landing (``humanoid.landing``); 0: none."""
    fd_eps: float = 1e-6
    """Finite-difference step of the linearisation."""
    frame_skip: int = 5
    """mj_step calls per env step (Humanoid-v5's default)."""
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


def balanced_pose(model: mujoco.MjModel, knee: float) -> np.ndarray:
    """Pose with both knees at ``knee`` whose height and hip_y angles leave no vertical force or pitch moment.

    Enough for a left-right symmetric body, which needs no roll moment; a body with drawn masses does, and
    ``humanoid.posture.body_gains`` balances that too.
    """
    hips = [model.joint(f"{side}_hip_y").qposadr[0] for side in ("right", "left")]
    knees = [model.joint(f"{side}_knee").qposadr[0] for side in ("right", "left")]
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
        raise RuntimeError(f"no balanced pose for knee={knee}: {solution.message}")
    return pose(*solution.x)


def feed_forward(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Control whose actuator forces equal the joint torques that hold ``qpos`` at rest."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    torque = physics.static_inverse_dynamics(model, data)
    moment = np.zeros((model.nu, model.nv))
    mujoco.mju_sparse2dense(moment, data.actuator_moment, data.moment_rownnz, data.moment_rowadr, data.moment_colind)
    # Only the joints are actuated; the root's residual is what balanced_pose drove to zero.
    ctrl, *_ = np.linalg.lstsq(moment[:, 6:].T, torque[6:], rcond=None)
    return ctrl


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
    that is qpos_ref itself (the steady design keeps using it); along the landing (``humanoid.landing``)
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
        mujoco.mj_step(sim, scratch, nstep=design.frame_skip)
        origin = scratch.qpos.copy()

    def step(z: np.ndarray) -> np.ndarray:
        """Next state after perturbing the nominal state by z[:nx] and its control by z[nx:]."""
        mujoco.mj_copyData(scratch, sim, nominal)
        dq = np.concatenate([np.zeros(ROOT_XY), z[: sim.nv - ROOT_XY]])
        mujoco.mj_integratePos(sim, scratch.qpos, dq, 1.0)
        scratch.qvel[:] += z[sim.nv - ROOT_XY : nx]
        scratch.ctrl[:] += z[nx:]
        mujoco.mj_step(sim, scratch, nstep=design.frame_skip)
        return state_error(sim, origin, scratch.qpos, scratch.qvel)

    eps = design.fd_eps
    jac = np.stack([(step(eps * e) - step(-eps * e)) / (2 * eps) for e in np.eye(nx + sim.nu)], axis=1)
    return jac[:, :nx], jac[:, nx:]


def design_lqr(model: mujoco.MjModel, design: LQRDesign = LQRDesign()) -> LQRGains:
    """Balanced pose, feed-forward and LQR feedback gain for ``model`` (under a second; cached: ``load_or_design``)."""
    qpos_ref = balanced_pose(model, design.knee)
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
    import scipy.linalg  # noqa: PLC0415 - as in balanced_pose

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
    import scipy.linalg  # noqa: PLC0415 - as in balanced_pose

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
    # The MJB serialisation covers everything the XML compiles to (and Python-side edits).
    mjb = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, mjb)
    # The BLAS kernels too: gains designed under one are other numbers than under another (common.threads).
    meta = json.dumps(
        {
            "design": dataclasses.asdict(design),
            "mujoco": mujoco.__version__,
            "format": _CACHE_FORMAT,
            "openblas": openblas_kernels(),
        },
        sort_keys=True,
    )
    return hashlib.sha256(mjb.tobytes() + meta.encode()).hexdigest()


def load_or_design(model: mujoco.MjModel, design: LQRDesign = LQRDesign()) -> LQRGains:
    """``design_lqr`` through the on-disk cache: a file per (model, design) key, rebuilt when missing or stale."""
    return load_or_build("lqr", cache_key(model, design), LQRGains, lambda: design_lqr(model, design))


def load_or_build(kind: str, key: str, cls: type[T], build: Callable[[], T]) -> T:
    """The dataclass of arrays ``cls`` cached under ``key`` (a file per kind and key), or ``build()`` written there."""
    path = cache_dir() / f"{kind}-{key[:16]}.npz"
    fields = [f.name for f in dataclasses.fields(cls)]
    try:
        with np.load(path) as cached:
            if str(cached["key"]) == key:
                return cls(**{name: cached[name] for name in fields})
    # Missing, truncated, or written by an older format:
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as error:
        log.debug("no usable cache at %s: %s", path, error)

    built = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Write-then-rename, so concurrent processes never read a half-written file.
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as tmp:
            np.savez(tmp, key=key, **dataclasses.asdict(built))
        os.replace(tmp.name, path)
    except OSError as error:
        log.warning("could not cache %s at %s: %s", kind, path, error)
    return built
