"""Leg odometry (humanoid.estimator) against MuJoCo's true state, and the expert that acts on it."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from humanoid import estimator
from humanoid.conditions import ActionLatency
from humanoid.env import humanoid_model, make_env
from humanoid.estimator import (
    GRAVITY,
    LegOdometry,
    level_quaternion,
    odometry_names,
    unturned,
)
from humanoid.sensors import Proprioception, body_axes, gravity_direction
from rollout.controllers import make_controller
from rollout.episode import injected_noise, run_episode
from students.inputs import input_set_named
from task.posture import Posture, axis_quaternion, multiply_quaternions
from task.schedules import command_vector
from teachers.expert import LQRExpert, SensedExpert


def test_level_quaternion_sees_the_same_gravity_with_the_heading_removed() -> None:
    """A tilted, turned body: the level orientation has its gravity direction and the unturned body's orientation."""
    tilt = multiply_quaternions(
        axis_quaternion(1, 0.2), axis_quaternion(0, -0.3)
    )  # pitch, then roll: R = Ry Rx, no heading
    turned = multiply_quaternions(axis_quaternion(2, 1.1), tilt)  # R = Rz Ry Rx
    gravity = gravity_direction(body_axes(turned))
    level = level_quaternion(gravity)
    np.testing.assert_allclose(gravity_direction(body_axes(level)), gravity, atol=1e-12)
    np.testing.assert_allclose(level, tilt, atol=1e-12)


def expert_rollout(
    seed: int, steps: int, kick_at: int | None = None, kick: float = 0.0
) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """The privileged expert standing: each step's sensed features and MuJoCo's true (qpos, qvel); before step
    `kick_at`, `kick` m/s forward added to the root's velocity (the whole body, feet and all, as the suite's kicks)."""
    env = make_env()
    expert, sensed = LQRExpert(env.unwrapped.model), Proprioception(env.unwrapped.model)
    data = env.unwrapped.data
    obs, _ = env.reset(seed=seed)
    features, truth = [], []
    for t in range(steps):
        features.append(sensed(obs))
        truth.append((data.qpos.copy(), data.qvel.copy()))
        if t == kick_at:
            data.qvel[0] += kick
        obs, *_ = env.step(expert.act(obs))
    return features, truth


def test_standing_on_both_feet_the_estimate_is_the_true_height_and_velocity() -> None:
    """Past the landing from reset (and the vertical correction's settling), the torso's height is within
    0.5 mm (the feet rest inside the contacts' margin, not on the floor: 1 mm) and its velocity within 5 mm/s."""
    features, truth = expert_rollout(seed=1000, steps=200)
    model = humanoid_model()
    odometry = LegOdometry(model)
    errors = []
    for t, (sensed, (qpos, qvel)) in enumerate(zip(features, truth, strict=True)):
        estimate = odometry(sensed)
        if t >= 60:
            errors.append((abs(estimate[0][2] - qpos[2]), np.abs(estimate[1][:3] - qvel[:3]).max()))
    height, velocity = np.max(errors, axis=0)
    assert height < 5e-4 and velocity < 5e-3


def horizontal_velocity_error(seed: int, steps: int) -> float:
    """RMS error of the estimated horizontal torso velocity (steps 60 on; both in the world frame, whose heading
    the estimator integrates from reset) while the privileged expert stands under σ 0.05 noise on its executed
    actions."""
    env = make_env()
    model, data = env.unwrapped.model, env.unwrapped.data
    expert, sensed, odometry = LQRExpert(model), Proprioception(model), LegOdometry(model)
    obs, _ = env.reset(seed=seed)
    noise = injected_noise(seed, steps, 0.05, model.nu)
    errors = []
    for t in range(steps):
        _, qvel = odometry(sensed(obs))
        if t >= 60:
            errors.append(qvel[:2] - data.qvel[:2])  # a free joint's qvel[:3]: world frame
        obs, _, terminated, _, _ = env.step(expert.act(obs) + noise[t])
        assert not terminated
    return float(np.sqrt(np.mean(np.square(errors))))


def test_a_commanded_twist_turns_the_estimated_torso_as_it_turns_the_true_one() -> None:
    """The heading is integrated from the gyro: while the expert twists its torso 0.25 rad over the pelvis, the
    estimated orientation keeps its offset from the true one (the reset's own small turn, which the estimate starts
    without) to 5 mrad. Set to zero, the heading read the twist as a turn of the whole body: 0.25 rad off."""
    env = make_env()
    model, data = env.unwrapped.model, env.unwrapped.data
    expert, sensed, odometry = LQRExpert(model), Proprioception(model), LegOdometry(model)
    obs, _ = env.reset(seed=4)
    expert.set_command(command_vector(Posture(twist=0.25)))
    angles = []
    for _ in range(150):
        qpos, _ = odometry(sensed(obs))
        difference = np.zeros(3)
        mujoco.mju_subQuat(difference, qpos[3:7], data.qpos[3:7])
        angles.append(np.linalg.norm(difference))
        obs, *_ = env.step(expert.act(obs))
    assert data.joint("abdomen_z").qpos[0] < -0.2  # the torso did twist over the pelvis
    assert angles[0] < 0.02 and np.ptp(angles) < 5e-3


def test_the_feet_forces_cut_the_velocity_error_under_action_noise(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where a foot slips or rebounds its kinematics err; the force-predicted velocity they correct errs
    less than 0.7 of the kinematics alone's (gains of 1: the estimate is the feet's velocity whenever one is down)."""
    fused = horizontal_velocity_error(seed=1001, steps=400)
    monkeypatch.setattr(estimator, "HORIZONTAL_GAIN", 1.0)
    monkeypatch.setattr(estimator, "VERTICAL_GAIN", 1.0)
    kinematic = horizontal_velocity_error(seed=1001, steps=400)
    assert fused < 0.7 * kinematic


def test_with_a_contact_schedule_a_kick_is_taken_in_at_once() -> None:
    """The expert standing, kicked 0.4 m/s forward at 3 s (the whole body, feet and all, as the suite's kicks): told
    both feet are held still (a walker standing), the estimate the next step acts on has 3/4 of the kick; without a
    schedule the gain takes in a third of it (docs/decisions/leg-odometry.md). Before the kick the two agree."""
    features, _ = expert_rollout(seed=1000, steps=202, kick_at=200, kick=0.4)
    scheduled, unscheduled = LegOdometry(humanoid_model()), LegOdometry(humanoid_model())
    for reading in features[:-1]:
        np.testing.assert_array_equal(scheduled(reading, np.ones(2, bool))[1], unscheduled(reading)[1])
    kicked = features[-1]  # the first observation after the kick
    assert scheduled(kicked, np.ones(2, bool))[1][0] >= 0.7 * 0.4 and unscheduled(kicked)[1][0] <= 0.35 * 0.4


def test_in_flight_the_torso_falls_freely_from_rest() -> None:
    """Before the feet touch, the centre of mass gains g dt of downward speed per step, from zero at reset."""
    features, truth = expert_rollout(seed=3, steps=4)
    assert not any(f[-2:].any() for f in features)  # the drop from reset: no foot down yet
    odometry = LegOdometry(humanoid_model())
    vertical = np.array([odometry(f)[1][2] for f in features])
    np.testing.assert_allclose(vertical, [qvel[2] for _, qvel in truth], atol=0.01)
    assert vertical[-1] < -2.5 * GRAVITY * 0.015  # falling at 3 steps' worth of gravity, not held


def test_reset_forgets_the_previous_episode() -> None:
    """After reset the same readings give the same estimates as a fresh estimator's."""
    features, _ = expert_rollout(seed=5, steps=30)
    used, fresh = LegOdometry(humanoid_model()), LegOdometry(humanoid_model())
    for sensed in features:
        used(sensed)
    used.reset()
    for sensed in features[:15]:
        a, b = used(sensed), fresh(sensed)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])


def test_sensed_expert_stands_from_reset() -> None:
    """The expert on estimated height and velocity holds a whole episode."""
    env = make_env()
    episode = run_episode(env, make_controller("expert-sensed", env), seed=1000)
    assert not episode.fell and episode.length == 1000 and episode.episode_return > 4_900


def test_sensed_expert_reads_only_the_sensed_features() -> None:
    """Changing every entry of the observation outside the sensed features leaves its action unchanged."""
    env = make_env()
    obs, _ = env.reset(seed=2)
    sensed = Proprioception(env.unwrapped.model)
    privileged = np.setdiff1d(np.arange(obs.size), sensed.copied)
    # The gravity and contact features are computed from the quaternion and the feet's wrenches: keep those.
    privileged = np.setdiff1d(privileged, np.concatenate([sensed.quaternion, sensed.feet.ravel()]))
    changed = obs.copy()
    changed[privileged] += np.random.default_rng(0).normal(size=privileged.size)
    action = SensedExpert(env.unwrapped.model).act(obs)
    np.testing.assert_array_equal(action, SensedExpert(env.unwrapped.model).act(changed))
    assert not np.array_equal(action, LQRExpert(env.unwrapped.model).act(changed))  # the privileged one reads them


def test_sensed_expert_built_for_a_delayed_env_knows_the_delay() -> None:
    """As the privileged expert: the registry passes the env's action latency on."""
    env = ActionLatency(gym.make("Humanoid-v5"), steps=1)
    assert make_controller("expert-sensed", env).expert.delay == 1


def test_an_odometry_policy_reads_the_sensed_features_but_the_forces() -> None:
    """The forces reach it through the estimate only: its inputs are the other sensed features, in order, then
    the estimate's."""
    model = humanoid_model()
    names = odometry_names(model)
    sensed = Proprioception(model).names
    assert names[:42] == [name for name in sensed if not name.startswith("force.")]
    assert not any(name.startswith("force.") for name in names) and names[42] == "odometry.height"


def test_a_turned_body_unturned_has_the_unturned_bodys_velocity_and_inertias() -> None:
    """Known answer: the same pose and velocity with the whole body turned 1.1 rad about z, turned back by `unturned`,
    give the unturned body's `cinert` rows and velocity (to float rounding); in the world's frame they differ by up
    to 0.9. The walker's students read them so (`pending+gait`), the other sets in the world's frame."""
    model = humanoid_model()
    data = mujoco.MjData(model)
    data.qpos[7:] = np.random.default_rng(0).uniform(-0.3, 0.3, model.nq - 7)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    inertias, velocity = data.cinert[1:].copy(), np.array([0.3, 0.1, 0.05])
    heading = 1.1
    data.qpos[3:7] = axis_quaternion(2, heading)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    c, s = np.cos(heading), np.sin(heading)
    turned_velocity = np.array([c * 0.3 - s * 0.1, s * 0.3 + c * 0.1, 0.05])
    assert np.abs(data.cinert[1:] - inertias).max() > 0.5
    back_velocity, back_inertias = unturned(heading, turned_velocity, data.cinert[1:])
    np.testing.assert_allclose(back_inertias, inertias, atol=1e-12)
    np.testing.assert_allclose(back_velocity, velocity, atol=1e-15)
    assert input_set_named("pending+gait")(model).odometry.heading_frame
    assert not input_set_named("pending+ramp")(model).odometry.heading_frame
