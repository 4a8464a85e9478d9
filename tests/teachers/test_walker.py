"""The walker (`teachers.walker`): today's LQR expert while nothing triggers, foot placement and whole-body control
once a walk is commanded or a kick moves the capture point off the feet, and back to the LQR at rest.

Known answers: the whole-body solve carries the body's weight on its feet; the walker's actions are the LQR expert's,
bit for bit, on a posture schedule; the same state, gait clock and command give the same action; the up arrow walks
the body forward; a kick is stepped out of; the step law's last step lands the feet side by side. The gait file is
refused in one line naming `make tune-walker` when missing or of another version.
"""

from __future__ import annotations

import copy
import json

import mujoco
import numpy as np
import pytest

from common.cli import UserError
from common.seed_ranges import SELECTION_SEED
from humanoid.balance import standing_pose
from humanoid.conditions import Condition
from humanoid.env import EPISODE_STEPS, make_env, model_and_data, nominal_model
from humanoid.physics import turned
from students.inputs import input_set_named
from task.command_fields import COMMAND_NAMES
from task.gait import GAIT_VERSION, LAST_WIDTH, MAX_SIDE, SIDES, GaitClock, Points, load_gait, rotation, save_gait
from task.posture import Posture
from task.schedules import command_vector, task_commands
from teachers.expert import LQRExpert, SensedExpert
from teachers.walker import SensedWalker, Walker, WholeBody, attitude_task

LANDED = 200  # env steps after reset: the body has landed, the walker's rule is armed


def forward(speed: float) -> np.ndarray:
    command = np.zeros(len(COMMAND_NAMES), np.float32)
    command[COMMAND_NAMES.index("forward_speed")] = speed
    return command


def test_a_missing_or_foreign_gait_file_names_the_target_that_makes_it(tmp_path) -> None:
    with pytest.raises(UserError, match="make tune-walker") as missing:
        load_gait(tmp_path / "none.json")
    assert "\n" not in str(missing.value)
    gait = load_gait()
    path = tmp_path / "gait.json"
    save_gait(gait, path, {"command": "test"})
    assert load_gait(path) == gait
    saved = json.loads(path.read_text())
    path.write_text(json.dumps({**saved, "version": GAIT_VERSION + 1}))
    with pytest.raises(UserError, match="make tune-walker"):
        load_gait(path)


def test_the_whole_body_solve_carries_the_weight_on_both_feet() -> None:
    """At rest in the standing pose, asking for no acceleration: the feet's vertical forces are the body's weight and
    no torque exceeds its motor."""
    model = nominal_model()
    body = WholeBody(model, load_gait())
    qpos, qvel = standing_pose(model).copy(), np.zeros(model.nv)
    body._kinematics(qpos, qvel)
    data = body.data
    contacts = []
    for side in SIDES:
        point = data.geom_xpos[body.foot[side]] - np.array([0.0, 0.0, body.radius])
        contacts.append(body._point(point, body.foot_body[side]))
    still = (np.eye(model.nv), np.zeros(model.nv), 1.0)
    torque = body.solve([still], (np.array([], int), np.array([])), contacts, data.qfrc_bias - data.qfrc_passive)
    force = body.forces
    weight = float(model.body_mass.sum()) * -model.opt.gravity[2]
    assert force[2] + force[5] == pytest.approx(weight, rel=1e-3)
    assert np.all(np.abs(torque) <= body.limit + 1e-9)


def test_the_pelvis_turning_with_its_heading_is_asked_for_no_acceleration() -> None:
    """The attitude task feeds the heading's turn rate forward: a pelvis on its heading, turning as fast as the heading
    does, is left alone; standing still under that turn it is spun up, and turning under none it is slowed, by 2ω times
    the difference (a critically damped spring of natural frequency ω)."""
    frequency, rate = 6.0, 0.4
    facing = rotation(2, 0.3) @ rotation(1, 0.05)
    turning = np.array([0.0, 0.0, rate])
    np.testing.assert_allclose(attitude_task(frequency, facing, facing, turning, rate), 0.0, atol=1e-12)
    np.testing.assert_allclose(attitude_task(frequency, facing, facing, np.zeros(3), rate), 2 * frequency * turning)
    np.testing.assert_allclose(attitude_task(frequency, facing, facing, turning, 0.0), -2 * frequency * turning)
    # Behind its heading by a small yaw, it is pulled toward it by ω² times the angle.
    behind = rotation(2, -0.01) @ facing
    assert attitude_task(frequency, facing, behind, turning, rate)[2] == pytest.approx(frequency**2 * 0.01, rel=1e-3)


@pytest.mark.parametrize(("walker", "expert"), [(Walker, LQRExpert), (SensedWalker, SensedExpert)])
def test_on_a_posture_schedule_the_walker_is_the_lqr_expert_bit_for_bit(walker, expert) -> None:
    """Nothing triggers a step (no walk, no kick): every action is its balance's."""
    seed = 1003
    actions = []
    for controller in (walker(), expert()):
        env = make_env(EPISODE_STEPS)
        commands = task_commands("posture", seed, EPISODE_STEPS, env.unwrapped.dt)
        obs, _ = env.reset(seed=seed)
        controller.reset(seed)
        taken = []
        for t in range(EPISODE_STEPS):
            if t == 0 or (commands[t] != commands[t - 1]).any():
                controller.set_command(commands[t])
            taken.append(controller.act(obs))
            obs, _, terminated, _, _ = env.step(taken[-1])
            assert not terminated
        actions.append(np.array(taken))
        env.close()
    assert np.array_equal(actions[0], actions[1])


def walk(walker: Walker, env, seconds: float, command: np.ndarray, seed: int = 0) -> tuple[np.ndarray, bool]:
    """Land, then hold `command` for `seconds`: the root's (x, y) displacement under the command, and whether the body
    fell."""
    _, data = model_and_data(env)
    obs, _ = env.reset(seed=seed)
    walker.reset(seed)
    for _ in range(LANDED):
        obs, *_ = env.step(walker.act(obs))
    start = data.qpos[:2].copy()
    walker.set_command(command)
    for _ in range(round(seconds / env.unwrapped.dt)):
        obs, _, terminated, _, _ = env.step(walker.act(obs))
        if terminated:
            return data.qpos[:2] - start, True
    return data.qpos[:2] - start, False


def test_held_up_arrow_walks_the_body_forward() -> None:
    """`make play`'s ↑ pressed five times and held 5 s (0.5 m/s once the command filter has ramped): the body walks at
    least a metre forward and does not fall; its actions are a deterministic function of state, gait clock and
    command."""
    env = make_env(EPISODE_STEPS)
    walker = Walker()
    moved, fell = walk(walker, env, 5.0, forward(0.5))
    assert not fell
    assert moved[0] >= 1.0 and abs(moved[1]) < 0.5 * moved[0]
    assert walker.clock.active
    twin = copy.deepcopy(walker)
    obs = env.unwrapped._get_obs()
    assert np.array_equal(walker.act(obs), twin.act(obs))
    env.close()


@pytest.mark.parametrize("rate", [0.5, -0.5])
def test_asked_to_turn_in_place_the_body_turns_that_way(rate: float) -> None:
    """Asked to turn in place at 0.5 rad/s (either way) for 4 s, the pelvis turns at least 1 rad that way, the first
    second being the command filter's ramp; it turned 1.7 rad. With only the swing hip's yaw held, the stance leg spun
    about its point foot and the body turned 1.1 rad left but 0.2 right; with the yaw rate damped to zero, under 0.5
    either way (docs/decisions/walker-turning.md)."""
    env = make_env(EPISODE_STEPS)
    walker = Walker()
    _, fell = walk(walker, env, 4.0, command_vector(Posture(turn_rate=rate)), seed=SELECTION_SEED)
    assert not fell
    _, data = model_and_data(env)
    yaw = walker.clock.points(data.qpos, data.qvel).yaw  # the pelvis's, as the clock reads it
    assert np.sign(rate) * yaw >= 1.0
    env.close()


def test_a_kick_is_stepped_out_of() -> None:
    """Standing under the zero command, a 0.4 m/s kick: the walker steps and does not fall. (With the tuned gait the
    walk then steps on in place: its stop is the rule `test_the_last_step_lands_the_feet_side_by_side` holds,
    which the tuned gait's sway seldom meets: docs/decisions/walker-stopping.md.)"""
    env = Condition(kick=0.4).wrap(make_env(EPISODE_STEPS))
    walker = Walker()
    seed = 3  # the kick's direction and time are drawn from the seed (the walker stands 5 of seeds 0-7's 8 kicks)
    _, fell = walk(walker, env, (EPISODE_STEPS - LANDED) * env.unwrapped.dt, np.zeros(len(COMMAND_NAMES)), seed)
    assert not fell
    assert walker.stepped > 0
    env.close()


def test_the_last_step_lands_the_feet_side_by_side() -> None:
    """Known answers of the step law under the zero command: the capture point landing 0.05 m to the left of the
    right stance foot (inside the stop margin) asks for the last step, the left foot `LAST_WIDTH`'s least beside it
    (twice 0.05 is narrower); 0.25 m out it asks for a step on, at the legs' reach."""
    model = nominal_model()
    clock = GaitClock(model, load_gait())
    clock.start("left")  # the right foot stands
    feet = {"right": np.array([0.0, 0.0, 0.075]), "left": np.array([0.0, 0.2, 0.075])}

    def landing(sideways: float) -> tuple[np.ndarray, bool]:
        now = Points(np.array([0.0, sideways, 0.8]), np.zeros(3), feet, 0.0)
        return clock.placement(now, np.eye(2), np.zeros(3), 0.0)

    target, last = landing(0.05)
    assert last
    np.testing.assert_allclose(target, [0.0, LAST_WIDTH[0]])
    target, last = landing(0.25)
    assert not last and target[1] == pytest.approx(MAX_SIDE)


def test_the_sensed_walkers_odometry_trusts_only_the_feet_its_gait_holds_still() -> None:
    """Walking, the feet the odometry takes as still are those the clock holds still: the stance foot alone in single
    support."""
    env = make_env(EPISODE_STEPS)
    walker = SensedWalker()
    walk(walker, env, 2.0, forward(0.2))
    clock = walker.clock
    assert clock.active
    held = clock.still()
    assert held.sum() == (1 if clock.phase == clock.SINGLE else 2)
    if clock.phase == clock.SINGLE:
        assert held[SIDES.index(clock.stance)]
    np.testing.assert_array_equal(walker.balance.still, held)
    env.close()


def test_a_turned_state_is_the_same_state_seen_from_another_heading() -> None:
    model = nominal_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    data.qpos[:] = standing_pose(model)
    data.qpos[:2] = rng.normal(size=2)
    data.qvel[:] = rng.normal(size=model.nv)
    qpos, qvel = turned(data.qpos, data.qvel, 0.7)
    back = turned(qpos, qvel, -0.7)
    np.testing.assert_allclose(back[0], data.qpos, atol=1e-12)
    np.testing.assert_allclose(back[1], data.qvel, atol=1e-12)
    assert np.linalg.norm(qvel[:2]) == pytest.approx(np.linalg.norm(data.qvel[:2]))
    np.testing.assert_allclose(qvel[2:], data.qvel[2:])


def test_the_walkers_student_computes_the_walkers_gait_clock() -> None:
    """`pending+gait` runs the gait clock on its own leg odometry, which trusts the feet the clock holds still: live,
    its clock's features are `walker-sensed`'s step for step, through a kick standing, a start, steps and the zero
    walk after."""
    env = make_env(EPISODE_STEPS)
    walker = SensedWalker()
    inputs = input_set_named("pending+gait")(nominal_model())
    names = inputs.input_names(nominal_model())
    features = [names.index(f"gait.{name}") for name in GaitClock.FEATURES]
    obs, _ = env.reset(seed=0)
    walker.reset(0)
    inputs.set_delay(0)
    inputs.reset()
    walked = 0
    for t in range(LANDED + 400):
        if t == LANDED - 60:
            env.unwrapped.data.qvel[1] += 0.3  # a kick to the left while standing, the hand-over rule armed
        command = forward(0.3 if LANDED <= t < LANDED + 150 else 0.0)
        walker.set_command(command)
        action = walker.act(obs)
        read = inputs(inputs.observe(obs, command))
        np.testing.assert_array_equal(read[features], walker.clock.features(), err_msg=f"step {t}")
        walked += walker.clock.active
        inputs.sent(action)
        obs, _, terminated, _, _ = env.step(action)
        assert not terminated
    assert walked > 100
    env.close()
