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


PELVIS_BODY = "pelvis"


def heading(data: mujoco.MjData, body: str) -> float:
    """Yaw (rad, about world z) of a body's x axis projected on the floor: where it faces (Humanoid faces +x)."""
    x_axis = data.body(body).xmat.reshape(3, 3)[:, 0]
    return float(np.arctan2(x_axis[1], x_axis[0]))


def torso_tilt(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[float, float]:
    """(forward, left) tilt of the torso's up axis (rad), in the pelvis's heading frame.

    Forward: + when the top of the torso leans toward where the pelvis faces; left: + when it
    leans to the pelvis's left. Measured in the pelvis's heading so that a twist of the torso or a
    drift in the body's yaw does not mix the two.
    """
    up = data.body(TORSO_BODY).xmat.reshape(3, 3)[:, 2]
    facing = heading(data, PELVIS_BODY)
    cos, sin = np.cos(facing), np.sin(facing)
    forward, left = cos * up[0] + sin * up[1], -sin * up[0] + cos * up[1]
    return float(np.arctan2(forward, up[2])), float(np.arctan2(left, up[2]))


def torso_yaw_relative_to_pelvis(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """Yaw of the torso relative to the pelvis (rad), + when the torso turns left (counter-clockwise from above)."""
    relative = data.body(PELVIS_BODY).xmat.reshape(3, 3).T @ data.body(TORSO_BODY).xmat.reshape(3, 3)
    return float(np.arctan2(relative[1, 0], relative[0, 0]))


def static_root_residual(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """What the contacts leave unsupported at rest in ``data.qpos``: (vertical force, world x, y moments), shape (3,).

    Gravity and the (vertical) contact normals make no horizontal force and no moment about the
    vertical, so these three are the whole of the root's static imbalance; all zero means the pose
    balances on its feet. Runs ``static_inverse_dynamics`` (which sets qvel, qacc to zero).
    """
    residual = static_inverse_dynamics(model, data)
    moment = data.xmat[model.body(TORSO_BODY).id].reshape(3, 3) @ residual[3:6]
    return np.array([residual[2], moment[0], moment[1]])


def turned(qpos: np.ndarray, qvel: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Copies of a state (qpos, qvel) turned by `yaw` (rad) about the vertical through the root: the root's orientation
    and its world-frame linear velocity turned (its body-frame angular velocity and the joints as they are). The
    dynamics do not change with the heading, so a controller designed facing +x acts on `turned(q, v, -heading)`."""
    qpos, qvel = qpos.copy(), qvel.copy()
    half = 0.5 * yaw
    rotation = np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
    mujoco.mju_mulQuat(qpos[3:7], rotation, qpos[3:7].copy())
    c, s = np.cos(yaw), np.sin(yaw)
    qpos[:2] = c * qpos[0] - s * qpos[1], s * qpos[0] + c * qpos[1]
    qvel[:2] = c * qvel[0] - s * qvel[1], s * qvel[0] + c * qvel[1]
    return qpos, qvel
