"""The capture point: where the body must step to come to rest (centre of mass + its velocity / ω), against the
segment between the feet (docs/decisions/stepping-teacher.md).

The feet are spheres with no ankle: while the capture point stays over the segment between the two contact points
the hips can stop the body where it stands; once it leaves, only a step can. `Support` measures a state (the
simulator's, or the leg odometry's estimate of it) on a copy of the nominal model; `off_segment` is the distance a
teacher's cost and its hand-over rule (`task.handover`) read.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from humanoid.physics import FOOT_GEOMS, TORSO_BODY

OMEGA = 3.4
"""sqrt(g / centre-of-mass height) of the standing body, 1/s: the capture point's time constant."""


def off_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (...) from points (..., 2) to the segments from a to b (..., 2)."""
    ab = b - a
    t = np.clip(((point - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-9), 0.0, 1.0)
    return np.linalg.norm(point - (a + t[..., None] * ab), axis=-1)


def capture_offset(com: np.ndarray, velocity: np.ndarray, left: np.ndarray, right: np.ndarray) -> tuple[float, float]:
    """(how far the capture point is off the segment between the feet (m), the centre of mass's horizontal speed
    (m/s)) of a centre of mass at `com` moving at `velocity` over feet at `left` and `right` (world, (≥ 2,) each)."""
    velocity = velocity[:2]
    capture = com[:2] + velocity / OMEGA
    return float(off_segment(capture, left[:2], right[:2])), float(np.linalg.norm(velocity))


class Support:
    """`capture_offset` of whole states (qpos, qvel) of the nominal model, computed by its kinematics."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = copy.copy(model)
        self.data = mujoco.MjData(self.model)
        self._torso = self.model.body(TORSO_BODY).id
        self._right, self._left = (self.model.geom(name).id for name in FOOT_GEOMS)

    def __call__(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[float, float]:
        data = self.data
        data.qpos[:] = qpos
        data.qvel[:] = qvel
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        mujoco.mj_comVel(self.model, data)
        mujoco.mj_subtreeVel(self.model, data)
        com, velocity = data.subtree_com[self._torso], data.subtree_linvel[self._torso]
        return capture_offset(com, velocity, data.geom_xpos[self._left], data.geom_xpos[self._right])
