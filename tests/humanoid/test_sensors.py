"""The sensed features and the observation split (humanoid.sensors), checked against MuJoCo's own data."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from humanoid.env import make_env, model_and_data, observation_names
from humanoid.sensors import (
    ObservationSplit,
    Proprioception,
    observation_index,
    privileged_names,
    proprioception_names,
)
from teachers.expert import LQRExpert


def contact_force(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> np.ndarray:
    """The world-frame force the contacts of the last substep exert on `geom` (mj_contactForce, per contact).

    A contact's force is in its frame, whose first axis, the normal, points from geom1 to geom2: it
    pushes geom2 along it and geom1 the other way.
    """
    total, wrench = np.zeros(3), np.zeros(6)
    for i, contact in enumerate(data.contact[: data.ncon]):
        if geom in (contact.geom1, contact.geom2):
            mujoco.mj_contactForce(model, data, i, wrench)
            force = contact.frame.reshape(3, 3).T @ wrench[:3]  # the frame's rows are its axes in the world
            total += force if geom == contact.geom2 else -force
    return total


def rollout(steps: int, fall_after: int) -> tuple[list[np.ndarray], list[dict[str, np.ndarray]]]:
    """Observations and what MjData says at the same instants: the expert stands, then random actions topple it.

    The sensed values are computed here from MjData (joint addresses, the torso's rotation matrix and
    body velocity, the contact list and each contact's force), independently of the gymnasium
    observation. After a step, qpos and qvel are integrated but the derived quantities are the last
    substep's: the orientation and velocity come from a copy brought up to date (mj_forward), the
    contacts and their forces from that substep's contact list, as the observation's contact wrenches
    do. MuJoCo's contacts act within a margin (1 mm), so a foot touches when it is in the list, not
    only when it penetrates.
    """
    env = make_env()
    model, data = model_and_data(env)
    expert = LQRExpert(model)
    rng = np.random.default_rng(0)
    hinges = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    torso = model.body("torso").id
    feet = [model.geom(name).id for name in ("right_foot", "left_foot")]
    obs, _ = env.reset(seed=3)
    expert.reset(3)
    observations, truths = [], []
    current = mujoco.MjData(model)
    for t in range(steps):
        current.qpos[:], current.qvel[:] = data.qpos, data.qvel
        mujoco.mj_forward(model, current)
        velocity = np.zeros(6)  # (angular, linear) in the world frame
        mujoco.mj_objectVelocity(model, current, mujoco.mjtObj.mjOBJ_BODY, torso, velocity, 0)
        rotation = current.xmat[torso].reshape(3, 3)  # torso frame to world
        touching = [any(foot in (c.geom1, c.geom2) for c in data.contact[: data.ncon]) for foot in feet]
        forces = [rotation.T @ contact_force(model, data, foot) for foot in feet]
        observations.append(obs)
        truths.append(
            {
                "joint_positions": data.qpos[model.jnt_qposadr[hinges]].copy(),
                "joint_velocities": data.qvel[model.jnt_dofadr[hinges]].copy(),
                "gyro": rotation.T @ velocity[:3],
                "gravity": rotation.T @ np.array([0.0, 0.0, -1.0]),
                "contacts": np.array(touching, float),
                "forces": np.concatenate(forces),
            }
        )
        action = expert.act(obs) if t < fall_after else rng.uniform(-0.4, 0.4, 17)
        obs, _, terminated, _, _ = env.step(action.astype(np.float32))
        if terminated:
            break
    env.close()
    return observations, truths


@pytest.fixture(scope="module")
def sensed() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    observations, truths = rollout(steps=400, fall_after=150)
    env = make_env()
    features = Proprioception(env.unwrapped.model)(np.array(observations))
    env.close()
    return features, {key: np.array([truth[key] for truth in truths]) for key in truths[0]}


def test_joint_readings_are_the_hinge_joints(sensed: tuple) -> None:
    """Positions and velocities of the 17 hinges, in joint order, exactly as MjData holds them."""
    features, truth = sensed
    np.testing.assert_array_equal(features[:, :17], truth["joint_positions"])
    np.testing.assert_array_equal(features[:, 17:34], truth["joint_velocities"])


def test_gyro_is_the_torso_angular_velocity_in_its_frame(sensed: tuple) -> None:
    features, truth = sensed
    np.testing.assert_allclose(features[:, 34:37], truth["gyro"], atol=1e-9)


def test_gravity_is_the_world_down_direction_in_the_torso_frame(sensed: tuple) -> None:
    features, truth = sensed
    np.testing.assert_allclose(features[:, 37:40], truth["gravity"], atol=1e-9)
    assert np.ptp(features[:, 37:39], axis=0).min() > 0.05  # the torso tilted both ways: more than one attitude


def test_contacts_are_the_feet_touching_something(sensed: tuple) -> None:
    """1.0 while a foot sphere penetrates a geom, else 0.0; the rollout saw both for each foot."""
    features, truth = sensed
    np.testing.assert_array_equal(features[:, 40:42], truth["contacts"])
    assert {0.0, 1.0} <= set(features[:, 40]) and {0.0, 1.0} <= set(features[:, 41])


def test_forces_are_each_foot_contact_force_in_the_torso_frame(sensed: tuple) -> None:
    """The sum of the contact forces on each foot, rotated into the torso frame; standing, they carry the body."""
    features, truth = sensed
    np.testing.assert_allclose(features[:, 42:48], truth["forces"], rtol=1e-6, atol=1e-6)
    standing = features[60:150]  # the expert stands on both feet, past the landing
    weight = float(make_env().unwrapped.model.body_mass.sum()) * 9.81
    np.testing.assert_allclose((standing[:, 44] + standing[:, 47]).mean(), weight, rtol=0.05)


def test_split_parts_join_back_to_the_observation_bit_for_bit() -> None:
    """state + environment_state hold every observation entry once; joined by name they are the observation."""
    env = make_env()
    model = env.unwrapped.model
    observations, _ = rollout(steps=50, fall_after=50)
    state, environment_state = ObservationSplit(model)(np.array(observations))
    names = proprioception_names(model) + privileged_names(model)
    index = observation_index(names, model)
    env.close()
    assert state.shape[1] == len(proprioception_names(model)) == 48
    assert len(set(names)) == len(names)
    joined = np.concatenate([state, environment_state], axis=1)[:, index]
    assert joined.tobytes() == np.array(observations).tobytes()


def test_privileged_part_holds_what_no_sensor_gives() -> None:
    """The torso's height, orientation and linear velocity and MuJoCo's derived quantities are not sensed."""
    env = make_env()
    model = env.unwrapped.model
    env.close()
    privileged = privileged_names(model)
    assert privileged[:8] == ["root.z", "root.qw", "root.qx", "root.qy", "root.qz", "root.vx", "root.vy", "root.vz"]
    assert not any(
        name.split(".")[1].startswith(("cinert", "cvel", "cfrc_ext", "qfrc")) for name in proprioception_names(model)
    )
    assert set(privileged) | set(proprioception_names(model)) >= set(observation_names(model))


def test_a_missing_name_cannot_give_the_observation() -> None:
    env = make_env()
    model = env.unwrapped.model
    env.close()
    assert observation_index(proprioception_names(model)) is None
