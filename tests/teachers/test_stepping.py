"""The stepping expert: stands as the LQR expert does until a kick, then steps instead of falling."""

from __future__ import annotations

import numpy as np
import pytest

from common.seed_ranges import SELECTION_SEED
from humanoid.capture import off_segment
from humanoid.env import make_env
from humanoid.perturbations import VelocityKick
from humanoid.sensors import body_axes, yaw_rate
from rollout.controllers import make_controller
from task.posture import Posture
from task.schedules import command_vector
from teachers.expert import LQRExpert, SensedExpert
from teachers.stepping import STANCE_WIDTH, SteppingDesign, SteppingExpert, planning_model, stance

KICK_SEED = 1000
KICK_STEPS = 260  # the kick at 2 s (133 steps), then about 2 s: the LQR expert is down by step 159
"""A short episode with its kick early: the known answer below."""
AGAIN_STEPS = 200
"""The run again, to 67 steps (1 s) past the kick: the plans it repeats (the planner takes about 50 ms a step)."""


def test_the_capture_point_is_measured_off_the_segment_between_the_feet() -> None:
    left, right = np.array([0.0, 0.09]), np.array([0.0, -0.09])
    points = np.array([[0.0, 0.0], [0.05, 0.0], [0.0, 0.19], [-0.03, -0.13]])
    assert off_segment(points, left, right) == pytest.approx([0.0, 0.05, 0.1, 0.05])


def test_the_stance_is_read_in_the_torsos_heading() -> None:
    design = SteppingDesign()
    model = planning_model(design)
    import mujoco  # noqa: PLC0415

    data = mujoco.MjData(model)
    data.qpos[:] = LQRExpert().gains.qpos_ref
    for yaw in (0.0, 1.0):  # the same stance whichever way the body faces
        data.qpos[3:7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        mujoco.mj_forward(model, data)
        fore, side = stance(data.sensordata)
        assert fore == pytest.approx(0.0, abs=1e-6)
        assert side == pytest.approx(STANCE_WIDTH, abs=1e-6)


def _episode(controller: object, env: object, seed: int, steps: int | None = None) -> tuple[bool, list[np.ndarray]]:
    """Whether the controller stood the episode (or its first `steps`), and its actions."""
    obs, _ = env.reset(seed=seed)
    controller.reset(seed)
    actions = []
    for _ in range(steps or env.spec.max_episode_steps):
        actions.append(controller.act(obs))
        obs, _, terminated, _, _ = env.step(actions[-1])
        if terminated:
            return False, actions
    return True, actions


@pytest.mark.parametrize(
    ("name", "balance"), [("expert-stepping", LQRExpert), ("expert-sensed-stepping", SensedExpert)]
)
def test_without_a_kick_it_never_plans_and_acts_as_its_balance(name: str, balance: type) -> None:
    """Without a kick or a walk the stepping experts are their balance, bit for bit: the expert told the simulator's
    state, or the expert on leg odometry (the walking student's teacher)."""
    env = make_env(max_episode_steps=300)
    stepping = make_controller(name, env)
    stood, actions = _episode(stepping, env, 1000)
    _, balanced = _episode(balance(), env, 1000)
    assert stood and stepping.planned == 0 and stepping.walks
    np.testing.assert_array_equal(np.array(actions), np.array(balanced))


@pytest.mark.slow  # the planner, about 50 ms a step, over about 190 steps
def test_a_kick_that_topples_the_lqr_expert_is_survived_by_stepping_the_same_way_each_time() -> None:
    env = VelocityKick(make_env(max_episode_steps=KICK_STEPS), 0.4, window=(2.0, 2.0))
    lqr_stood, _ = _episode(LQRExpert(), env, KICK_SEED)
    stepping = SteppingExpert()
    stood, actions = _episode(stepping, env, KICK_SEED)
    assert not lqr_stood
    assert stood and stepping.planned > 100
    _, again = _episode(stepping, env, KICK_SEED, AGAIN_STEPS)  # the kick and the first steps out of it
    np.testing.assert_array_equal(np.array(actions[:AGAIN_STEPS]), np.array(again))


def test_the_yaw_rate_is_the_local_angular_velocity_turned_into_the_world() -> None:
    """Known answer: a body pitched 90 degrees (its local x up) spinning about its local x turns about the vertical."""
    qpos, qvel = np.zeros(7), np.zeros(6)
    qpos[3:7] = [np.cos(np.pi / 4), 0.0, -np.sin(np.pi / 4), 0.0]  # -90 degrees about y: local x -> world z
    qvel[3] = 0.3
    assert yaw_rate(qpos[3:7], qvel[3:6]) == pytest.approx(0.3)


WALK_SEED, WALK_FROM, WALK_STEPS = SELECTION_SEED, 150, 400  # 3.75 s of a 0.4 m/s walk (it goes 0.68 m)


@pytest.mark.slow  # the planner, about 50 ms a step, over 250 steps
def test_a_forward_command_walks_the_body_along_its_heading() -> None:
    """Under a forward speed of 0.4 m/s (ramped at 0.4 m/s^2) the walking planner takes over and the body moves
    forward along its heading, upright; the LQR expert, told the same, stands."""
    moved = {}
    for controller in (SteppingExpert(), LQRExpert()):
        env = make_env()
        obs, _ = env.reset(seed=WALK_SEED)
        controller.set_body(env.unwrapped.model)
        controller.reset(WALK_SEED)
        start = None
        for t in range(WALK_STEPS):
            if t == WALK_FROM:
                controller.set_command(command_vector(Posture(forward_speed=0.4)))
                start = env.unwrapped.data.qpos[:2].copy()
            obs, _, terminated, _, _ = env.step(controller.act(obs))
            assert not terminated, (controller, t)
        heading = body_axes(env.unwrapped.data.qpos[3:7])[0, :2]
        moved[type(controller)] = float((env.unwrapped.data.qpos[:2] - start) @ heading / np.linalg.norm(heading))
        env.close()
    assert moved[SteppingExpert] > 0.5 and abs(moved[LQRExpert]) < 0.05, moved
