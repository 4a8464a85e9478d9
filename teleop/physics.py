"""Physics queries on the Humanoid-v5 model: read-only measurements, no control logic.

Every function takes ``(model, data)`` and assumes ``data`` holds up-to-date kinematics
(``mj_forward``, ``mj_kinematics`` + ``mj_comPos``, or a step has been run), except
``static_inverse_dynamics`` which computes what it needs itself.
"""

from __future__ import annotations

import mujoco
import numpy as np

TORSO_BODY = "torso"
FOOT_GEOMS = ("right_foot", "left_foot")


def torso_height(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """Height (world z) of the torso body: the quantity the env's healthy check uses."""
    return float(data.body(TORSO_BODY).xpos[2])


def center_of_mass(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Whole-body centre of mass in world coordinates, shape (3,)."""
    # The world body's subtree is every body; the world itself has no mass.
    return data.subtree_com[0].copy()


def feet_midpoint(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Mid-point of the two foot spheres' centres in world coordinates, shape (3,)."""
    return np.mean([data.geom(name).xpos for name in FOOT_GEOMS], axis=0)


def com_over_feet(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Horizontal offset (x, y) of the centre of mass from the feet mid-point, shape (2,)."""
    return (center_of_mass(model, data) - feet_midpoint(model, data))[:2]


def com_over_feet_jacobian(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Jacobian of ``com_over_feet`` with respect to the generalised velocity, shape (2, nv)."""
    jac_com = np.zeros((3, model.nv))
    mujoco.mj_jacSubtreeCom(model, data, jac_com, 0)
    jac_feet = np.zeros((3, model.nv))
    for name in FOOT_GEOMS:
        jac_foot = np.zeros((3, model.nv))
        mujoco.mj_jacGeom(model, data, jac_foot, None, model.geom(name).id)
        jac_feet += jac_foot / len(FOOT_GEOMS)
    return (jac_com - jac_feet)[:2]


def static_inverse_dynamics(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Generalised force that holds ``data.qpos`` at rest (qvel = qacc = 0), contacts included.

    Sets ``data.qvel`` and ``data.qacc`` to zero and runs ``mj_inverse``. On the free joint,
    entries 0..2 are the residual force (world frame) and 3..5 the residual moment (body frame)
    that the contacts do not supply: all zero means the pose balances without help.
    Returns a copy of ``qfrc_inverse``, shape (nv,).
    """
    data.qvel[:] = 0.0
    data.qacc[:] = 0.0
    mujoco.mj_inverse(model, data)
    return data.qfrc_inverse.copy()
