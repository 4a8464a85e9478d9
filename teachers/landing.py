"""The expert's landing: a time-varying LQR along its own noise-free fall from Humanoid-v5's reset pose.

``reset()`` starts the body about 12 cm above its stance, far from the standing pose the steady gain
is linearised at, and most of the expert's falls under action noise start in that landing
(docs/decisions/landing-plan.md). The plan, designed once per model and design and cached
on disk like the steady gains:

1. the nominal landing: the steady expert's own rollout from the nominal reset state (``qpos0`` at
   rest, no reset noise) on the env's model and solver, so the plan is what the env does;
2. the env-level linear model along it (`teachers.lqr.linearise` from each moving state);
3. the finite-horizon Riccati recursion with the steady design's costs, back from its cost-to-go,
   over ``SETTLE`` steps more than the plan keeps: its gains at the plan's end are then near the
   steady gain, and the hand-over is smooth.

At run time, step t after a reset: ``ctrl[t] - gain[t] @ (state - nominal state[t])``, clipped.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import mujoco
import numpy as np

from common.cache import load_or_build
from humanoid.env import FRAME_SKIP
from teachers.lqr import (
    CTRL_LIMIT,
    LQRDesign,
    LQRGains,
    cache_key,
    linearise,
    load_or_design,
    lqr_cost,
    riccati,
    riccati_gain,
    state_error,
    steady_action,
)

SETTLE = 100
"""Steps of the recursion past the plan's end: from the steady cost-to-go its gains need a few dozen steps to
settle, because the linear model along the trajectory is not exactly the one at rest."""

_CACHE_FORMAT = 1  # bump when design_landing changes what it computes


@dataclass(frozen=True)
class Landing:
    """What ``design_landing`` produces: the first ``len(self)`` steps after a reset."""

    qpos: np.ndarray
    """(T, nq) the nominal landing's poses."""
    qvel: np.ndarray
    """(T, nv) its velocities."""
    ctrl: np.ndarray
    """(T, nu) its actions."""
    gain: np.ndarray
    """(T, nu, nx) the feedback gain at each step, on `teachers.lqr.state_error` from the nominal state."""

    def __len__(self) -> int:
        return len(self.ctrl)

    def action(self, model: mujoco.MjModel, t: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The action (float32, within the motors' range) at step t after the reset, in state (qpos, qvel)."""
        x = state_error(model, self.qpos[t], qpos, qvel - self.qvel[t])
        return np.clip(self.ctrl[t] - self.gain[t] @ x, -CTRL_LIMIT, CTRL_LIMIT).astype(np.float32)


def nominal_landing(
    model: mujoco.MjModel, gains: LQRGains, design: LQRDesign, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos, qvel, ctrl), ``steps`` rows each: the steady expert's rollout from ``qpos0`` at rest, as the env steps."""
    data = mujoco.MjData(model)  # qpos0, qvel 0: Humanoid-v5's reset without its noise
    mujoco.mj_forward(model, data)
    qpos, qvel, ctrl = np.empty((steps, model.nq)), np.empty((steps, model.nv)), np.empty((steps, model.nu))
    setpoint = gains.qpos_ref, gains.ctrl_ff, gains.gain
    for t in range(steps):
        qpos[t], qvel[t] = data.qpos, data.qvel
        ctrl[t] = data.ctrl[:] = steady_action(model, design, setpoint, data.qpos, data.qvel)
        mujoco.mj_step(model, data, nstep=FRAME_SKIP)  # what MujocoEnv.do_simulation does
    return qpos, qvel, ctrl


def design_landing(model: mujoco.MjModel, gains: LQRGains, design: LQRDesign) -> Landing:
    """The landing plan of ``design.landing_steps`` steps for the expert with ``gains`` (seconds, not the
    design's fraction of one: a linear model per step; cached: ``load_or_design_landing``)."""
    horizon = design.landing_steps + SETTLE
    qpos, qvel, ctrl = nominal_landing(model, gains, design, horizon)
    q, r = lqr_cost(model, gains.qpos_ref, design)
    p = riccati(model, gains.qpos_ref, gains.ctrl_ff, design)[1]
    gain = np.empty((horizon, model.nu, q.shape[0]))
    for t in reversed(range(horizon)):
        a, b = linearise(model, qpos[t], ctrl[t], design, qvel=qvel[t])
        gain[t] = riccati_gain(a, b, r, p)
        p = q + a.T @ p @ (a - b @ gain[t])
        p = 0.5 * (p + p.T)  # round-off would otherwise grow an asymmetric part over the steps
    keep = slice(0, design.landing_steps)
    return Landing(qpos=qpos[keep], qvel=qvel[keep], ctrl=ctrl[keep], gain=gain[keep])


def load_or_design_landing(model: mujoco.MjModel, design: LQRDesign) -> Landing:
    """``design_landing`` for the steady gains of (model, design) through the on-disk cache
    (`common.cache.load_or_build`), keyed like those gains."""
    key = hashlib.sha256(f"{cache_key(model, design)} landing {_CACHE_FORMAT}".encode()).hexdigest()
    return load_or_build("landing", key, Landing, lambda: design_landing(model, load_or_design(model, design), design))
