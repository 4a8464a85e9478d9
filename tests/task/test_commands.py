"""Operator commands (task.schedules): scripted schedules, the range check, tracking and its summary, and the
expert under the zero command and under schedules (real MuJoCo; known answers)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from common import columns
from common.cli import UserError
from common.seed_ranges import TRAINING_SEEDS
from humanoid.conditions import DomainRandomization, Randomization
from humanoid.env import EPISODE_STEPS, QPOS_OBS, QVEL_OBS, humanoid_model, make_env, nominal_model
from rollout.episode import run_episode
from support import join_observation, read_mcap_episode, record_short
from task.command_fields import COMMAND_FIELDS, COMMAND_NAMES, FIELDS, POSTURE_NAMES, VELOCITY_NAMES
from task.posture import NEUTRAL, Posture, move_seconds
from task.schedules import (
    DEFAULT_TASK,
    FIRST_NEUTRAL_SECONDS,
    HOLD_SECONDS,
    SCALE,
    command_posture,
    command_schedule,
    command_vector,
    held_commands,
    parse_held,
    schedule_targets,
    task_for,
)
from task.tracking import (
    COMMAND_INFO,
    PLOTTED,
    SCHEDULE_STREAM,
    CommandedTask,
    Tracking,
    tracking_reward,
    tracking_score,
    tracking_summary,
)
from teachers.expert import LQRExpert
from teachers.postures import posture_reference
from teleop.dataset_reader import read_episodes, read_frames
from teleop.mcap_io.writer import COMMAND_TOPIC

DT = 0.015  # Humanoid-v5's env step (s)
SECONDS = EPISODE_STEPS * DT  # a whole episode's schedule
# Past the neutral start (200 steps) by enough for the first command's move (0.3 s a key press) and part of its hold.
SHORT = 300


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return humanoid_model()


@pytest.fixture(scope="module")
def tracking(model: mujoco.MjModel) -> Tracking:
    return Tracking(model)


def observation_of(qpos: np.ndarray) -> np.ndarray:
    """A (1, 348) observation whose first 22 entries are `qpos` without root x and y, the rest zero."""
    obs = np.zeros((1, 348))
    obs[0, :22] = qpos[2:]
    return obs


def reference_observation(model: mujoco.MjModel, command: np.ndarray) -> np.ndarray:
    """The observation of the balanced pose that realises `command`, at rest."""
    return observation_of(np.array(posture_reference(model, command_posture(command).clipped())[0]))


# Schedules.


def test_a_schedule_is_reproducible_per_seed_and_differs_across_seeds() -> None:
    first = command_schedule(7, EPISODE_STEPS, DT)
    np.testing.assert_array_equal(first, command_schedule(7, EPISODE_STEPS, DT))
    assert first.shape == (EPISODE_STEPS, len(COMMAND_NAMES)) and first.dtype == np.float32
    others = [command_schedule(seed, EPISODE_STEPS, DT) for seed in (8, 9, 1000)]
    assert all(not np.array_equal(first, other) for other in others)


def test_targets_lie_on_the_keys_grid_within_scale_of_the_limits() -> None:
    """Every target of 50 seeds is a whole number of key presses from neutral, inside SCALE of each limit (the arms:
    a preset), moves one to three fields, and every field is commanded somewhere."""
    commanded = set()
    for seed in range(50):
        for _, target in schedule_targets(seed, SECONDS)[1:]:
            moved = [name for name in COMMAND_NAMES if getattr(target, name)]
            assert len(moved) <= 3, target
            commanded.update(moved)
            for name in moved:
                value = getattr(target, name)
                field = FIELDS[name]
                presses = value / field.step
                assert presses == pytest.approx(round(presses), abs=1e-6), (seed, name, value)
                if field.presets:
                    assert value in (1.0, 2.0, 3.0)
                else:
                    assert SCALE * field.low - 1e-9 <= value <= SCALE * field.high + 1e-9
    assert commanded == set(POSTURE_NAMES)


def test_walking_schedules_mix_walks_on_the_velocity_grid_with_postures_and_stands() -> None:
    """Over 50 seeds with walks: a target walks (one or two velocity fields, no posture) or poses (posture fields
    only, as a posture schedule) or stands; the walks are whole key presses over each velocity's range, and reach both
    ends of it; reproducible per seed. Without walks no velocity is ever commanded."""
    kinds, values = set(), {name: set() for name in VELOCITY_NAMES}
    for seed in range(50):
        targets = schedule_targets(seed, SECONDS, walking=True)
        assert targets == schedule_targets(seed, SECONDS, walking=True)
        for _, target in targets[1:]:
            walks = [name for name in VELOCITY_NAMES if getattr(target, name)]
            poses = [name for name in POSTURE_NAMES if getattr(target, name)]
            assert not (walks and poses) and len(walks) <= 2, target
            kinds.add("walk" if walks else "pose" if poses else "stand")
            for name in walks:
                value, field = getattr(target, name), FIELDS[name]
                assert value / field.step == pytest.approx(round(value / field.step), abs=1e-6)
                assert field.low - 1e-9 <= value <= field.high + 1e-9
                values[name].add(round(value, 6))
        assert not command_schedule(seed, EPISODE_STEPS, DT)[:, [COMMAND_NAMES.index(n) for n in VELOCITY_NAMES]].any()
    assert kinds == {"walk", "pose", "stand"}
    assert all({FIELDS[name].low, FIELDS[name].high} <= values[name] for name in VELOCITY_NAMES), values


def test_a_walks_task_string_names_its_speeds() -> None:
    assert task_for(Posture(forward_speed=0.4, turn_rate=-0.2)) == "Walk forward at 0.4 m/s, turn right at 0.2 rad/s."
    assert task_for(Posture(sideways_speed=-0.1, arms=2.0)) == "Walk right at 0.1 m/s, arms up."
    assert task_for(Posture(forward_speed=-0.3)) == "Walk backward at 0.3 m/s."


def test_a_held_command_is_zero_for_3_s_then_held_5_s_then_zero() -> None:
    """Known answers at Humanoid-v5's 0.015 s steps: rows 0-199 zero, 200-532 the command, from 533 zero; the text's
    fields clipped to their limits as the keys clip them (forward speed 0.6 m/s, turn −0.5 rad/s)."""
    held = parse_held("forward_speed=9, turn_rate=-2")
    assert held == Posture(forward_speed=0.6, turn_rate=-0.5)
    commands = held_commands(held, 1000, 0.015)
    assert commands.shape == (1000, len(COMMAND_NAMES)) and commands.dtype == np.float32
    walking = np.flatnonzero(commands.any(axis=1))
    assert walking[0] == 200 and walking[-1] == 532 and len(walking) == 333
    assert (commands[walking] == command_vector(held)).all()
    with pytest.raises(UserError, match="not FIELD=VALUE"):
        parse_held("forward_speed")
    with pytest.raises(UserError, match="forward_speed is given twice"):
        parse_held("forward_speed=0.5,forward_speed=0.2")


def test_the_expert_ramps_a_velocity_setpoint_and_clips_it_without_moving_its_pose() -> None:
    """A walk asked of the LQR expert (which stands: it does not step): the setpoint's speed is clipped to the row's
    limit (0.6 m/s) and gets there over 0.6 / 0.4 = 1.5 s; the pose it holds and its gain stay the neutral stand's."""
    expert, env = LQRExpert(), make_env()
    obs, _ = env.reset(seed=3)
    expert.reset(3)
    pose, gain = expert.qpos_ref.copy(), expert.gain.copy()
    expert.set_command(command_vector(Posture(forward_speed=2.0)))
    assert expert.target == Posture(forward_speed=0.6)
    speeds = []
    for _ in range(round(1.5 / DT) + 5):
        obs, *_ = env.step(expert.act(obs))
        speeds.append(expert.setpoint()[COMMAND_NAMES.index("forward_speed")])
    env.close()
    assert speeds[round(1.5 / DT) - 10] < 0.6 and speeds[-1] == pytest.approx(0.6)
    assert np.all(np.diff(speeds) >= 0)
    np.testing.assert_array_equal(expert.qpos_ref, pose)
    np.testing.assert_array_equal(expert.gain, gain)


def test_a_schedule_starts_neutral_then_changes_and_holds_some_neutral_targets() -> None:
    """Over 50 seeds: zero for the first FIRST_NEUTRAL_SECONDS and a command right after, consecutive targets
    differ, each is held at least HOLD_SECONDS[0] once the setpoint can have got there, and some targets after the
    first are the neutral stand."""
    first = round(FIRST_NEUTRAL_SECONDS / DT)
    neutral_later = 0
    for seed in range(50):
        commands = command_schedule(seed, EPISODE_STEPS, DT)
        assert not commands[:first].any() and commands[first].any(), seed
        targets = schedule_targets(seed, SECONDS)
        assert targets[0] == (0.0, NEUTRAL) and targets[1][0] == FIRST_NEUTRAL_SECONDS
        for (_, before), (start, target), (end, _) in zip(targets, targets[1:], targets[2:], strict=False):
            assert target != before
            assert end - start >= move_seconds(before, target) + HOLD_SECONDS[0], (seed, start)  # there, then held
        assert targets[-1][0] < SECONDS
        neutral_later += sum(target == NEUTRAL for _, target in targets[2:])
    assert neutral_later >= 10


def test_a_negative_seed_is_refused_in_one_line() -> None:
    for schedule in (lambda: schedule_targets(-1, SECONDS), lambda: command_schedule(-1, EPISODE_STEPS, DT)):
        with pytest.raises(UserError, match=r"^a schedule's seed must be >= 0, got -1$"):
            schedule()


def test_the_task_names_each_commanded_field() -> None:
    assert task_for(NEUTRAL) == DEFAULT_TASK
    assert task_for(Posture(lean_forward=-0.1, height=-0.04, arms=3.0)) == "Lean back, crouch, arms out while standing."
    assert task_for(Posture(lean_left=-0.05, twist=0.2)) == "Lean right, twist left while standing."


# Tracking.

POSED = command_vector(Posture(lean_forward=0.1, lean_left=-0.05, height=-0.04, twist=0.2, arms=2.0))


@pytest.mark.parametrize("command", [command_vector(NEUTRAL), POSED], ids=["neutral", "posed"])
def test_the_balanced_pose_of_a_command_tracks_it_exactly(
    model: mujoco.MjModel, tracking: Tracking, command: np.ndarray
) -> None:
    errors = tracking.errors(reference_observation(model, command), command[None])
    np.testing.assert_allclose(errors, 0.0, atol=1e-9)


def test_known_perturbations_give_known_errors(model: mujoco.MjModel, tracking: Tracking) -> None:
    """From the neutral stand: the twist joint 0.1 rad off is a twist error of 0.1 and nothing else; the torso
    pitched forward 0.1 rad (about the world y axis) leans forward 0.1; rolled 0.1 rad about x leans right 0.1;
    2 cm lower is a height error of 0.02; one arm joint 0.06 rad off is an arms error of 0.01 (mean of six). `error`
    of one state is the same row bit for bit."""
    zero = command_vector(NEUTRAL)[None]
    stand = reference_observation(model, zero[0])
    assert np.array_equal(stand[0, 1:5], [1.0, 0.0, 0.0, 0.0])  # upright: the rotations below are the torso's
    twisted, pitched, rolled, lowered, arm = (stand.copy() for _ in range(5))
    twisted[0, model.joint("abdomen_z").qposadr[0] - 2] += 0.1
    pitched[0, 1:5] = [np.cos(0.05), 0.0, np.sin(0.05), 0.0]
    rolled[0, 1:5] = [np.cos(0.05), np.sin(0.05), 0.0, 0.0]
    lowered[0, 0] -= 0.02
    arm[0, model.joint("right_elbow").qposadr[0] - 2] += 0.06
    expected = {
        "twisted": (twisted, [0, 0, 0, 0.1, 0, 0, 0, 0]),
        "pitched": (pitched, [0.1, 0, 0, 0, 0, 0, 0, 0]),
        "rolled": (rolled, [0, 0.1, 0, 0, 0, 0, 0, 0]),
        "lowered": (lowered, [0, 0, 0.02, 0, 0, 0, 0, 0]),
        "arm": (arm, [0, 0, 0, 0, 0.01, 0, 0, 0]),
    }
    for name, (obs, error) in expected.items():
        np.testing.assert_allclose(tracking.errors(obs, zero)[0], error, atol=1e-9, err_msg=name)
        # One state at a time (PPO's reward): the same numbers, bit for bit.
        one = tracking.error(obs[0, QPOS_OBS], obs[0, QVEL_OBS], zero[0])
        np.testing.assert_array_equal(one, tracking.errors(obs, zero)[0], err_msg=name)
    achieved = np.concatenate([tracking.achieved(obs) for obs in (pitched, rolled, lowered, twisted)])
    np.testing.assert_allclose(
        achieved[:, :4], [[0.1, 0, 0, 0], [0, -0.1, 0, 0], [0, 0, -0.02, 0], [0, 0, 0, -0.1]], atol=1e-9
    )


def test_tracking_summary_of_hand_made_errors() -> None:
    """dt 0.1 s, so settled is the mean of a command's last 10 steps if held 20 or more. Command A (30 steps): out of
    tolerance for 5 steps, in for 5, out once more (height 0.03 > 0.02) at step 10, then in: settles after 1.1 s;
    its last 10 steps' errors are known. Command B (15 steps): never in tolerance, too short to count as settled:
    its settle time is its whole 1.5 s. Mean settle time 1.3 s."""
    commands = np.zeros((45, len(COMMAND_NAMES)), np.float32)
    commands[30:, 0] = 0.1
    inside = np.array([field.tolerance for field in COMMAND_FIELDS]) / 2
    errors = np.tile(inside, (45, 1))
    errors[:5] = 1.0
    errors[10, 2] = 0.03
    errors[20:30] = np.linspace(0.0, 0.009, 10)[:, None]
    errors[30:] = 1.0
    summary = tracking_summary(errors, commands, 0.1)
    assert summary["settle_seconds"] == pytest.approx((1.1 + 1.5) / 2)
    assert summary["settled_error"] == pytest.approx(dict.fromkeys(COMMAND_NAMES, 0.0045))


@pytest.mark.parametrize(("held", "settled"), [(35, 0.001), (36, (0.001 + 0.003) / 2)])
def test_a_command_counts_as_settled_once_held_twice_the_window_after_its_move(held: int, settled: float) -> None:
    """dt 0.1 s: a crouch of 4 cm takes the setpoint 1.6 s (16 steps) at 2.5 cm/s. Held 35 steps (more than twice
    the 10-step window, but cut short 1 step before its move and twice the window are over, as the episode's end
    cuts a schedule's last command) it is not settled: only the neutral start's window counts; held 36, it is."""
    commands = np.zeros((30 + held, len(COMMAND_NAMES)), np.float32)
    commands[30:, COMMAND_NAMES.index("height")] = -0.04
    errors = np.full(commands.shape, 0.001)
    errors[30:] = 0.003
    summary = tracking_summary(errors, commands, 0.1)
    assert summary["settled_error"] == pytest.approx(dict.fromkeys(COMMAND_NAMES, settled))


def test_moved_error_counts_only_the_commands_that_move_the_field() -> None:
    """dt 0.1 s. Neutral for 30 steps (errors 0.001), then arms out (preset 3) for 60 steps (errors 0.5): both settle.
    Over every command each field's error is the mean of both windows; over the commands that moved it, only the arms
    have one (0.5), every other field none (NaN)."""
    commands = np.zeros((90, len(COMMAND_NAMES)), np.float32)
    commands[30:, COMMAND_NAMES.index("arms")] = 3.0
    errors = np.full(commands.shape, 0.001)
    errors[30:] = 0.5
    summary = tracking_summary(errors, commands, 0.1)
    assert summary["settled_error"] == pytest.approx(dict.fromkeys(COMMAND_NAMES, (0.001 + 0.5) / 2))
    assert summary["moved_error"]["arms"] == pytest.approx(0.5)
    assert all(np.isnan(summary["moved_error"][name]) for name in COMMAND_NAMES if name != "arms")


def test_tracking_summary_without_a_command_held_long_enough_is_nan() -> None:
    commands = np.zeros((15, len(COMMAND_NAMES)), np.float32)
    summary = tracking_summary(np.zeros((15, len(COMMAND_NAMES))), commands, 0.1)
    assert summary["settle_seconds"] == 0.0
    assert all(np.isnan(error) for error in [*summary["settled_error"].values(), *summary["moved_error"].values()])


# The expert.


def command_extras(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The setpoint (T, 5) and achieved posture (T, 4) of an MCAP file's /command messages."""
    setpoint, achieved = [], []
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, decoded in reader.iter_decoded_messages(topics=[COMMAND_TOPIC]):
            setpoint.append([getattr(decoded, f"setpoint_{name}") for name in COMMAND_NAMES])
            achieved.append([getattr(decoded, f"achieved_{field.name}") for field in PLOTTED])
    return np.array(setpoint), np.array(achieved)


@pytest.fixture(scope="module")
def short_env() -> Iterator[gym.Env]:
    env = make_env(SHORT)
    yield env
    env.close()


def test_the_zero_command_leaves_the_plain_expert_as_it_was(short_env: gym.Env) -> None:
    """run_episode without schedules tells the expert the zero command, which keeps its planned landing: the actions
    equal, bit for bit, those of the expert's own loop, never told a command; and so after an episode under
    schedules (the expert reused, as a recorder reuses it)."""
    expert = LQRExpert()
    obs, _ = short_env.reset(seed=3)
    expert.reset(3)
    actions, done = [], False
    while not done:
        actions.append(expert.act(obs))
        obs, _, terminated, truncated, _ = short_env.step(actions[-1])
        done = terminated or truncated
    plain = run_episode(short_env, LQRExpert(), 3)
    assert not plain.command.any() and not plain.setpoint.any() and set(plain.tasks) == {DEFAULT_TASK}
    np.testing.assert_array_equal(plain.action, np.array(actions))
    reused = LQRExpert()
    run_episode(short_env, reused, 4, task="posture")
    np.testing.assert_array_equal(run_episode(short_env, reused, 3).action, plain.action)


def test_the_operator_records_the_command_names_it_and_its_setpoint_moves_there(tmp_path: Path) -> None:
    """`make record CONTROLLER=expert` (under schedules): the dataset's command is the seed's schedule, the task of
    each step names it, and the setpoint starts each command where the last one was, moves steadily toward it and gets
    there within its move time."""
    seed = 5
    record_short(
        tmp_path / "operator", controller="expert", task="posture", episodes=1, seed=seed, max_steps=SHORT, noise=0.0
    )
    root = tmp_path / "operator"
    frames = read_frames(root, [columns.OBS_COMMAND, columns.SETPOINT, columns.TERMINATED])
    command, setpoint = frames[columns.OBS_COMMAND], frames[columns.SETPOINT]
    np.testing.assert_array_equal(command, command_schedule(seed, SHORT, DT))
    assert command.any() and not frames[columns.TERMINATED].any()
    episode = read_episodes(root).to_pylist()[0]
    assert episode[columns.EPISODE_CONTROLLER] == "expert"
    mcap = read_mcap_episode(root / episode[columns.EPISODE_MCAP])
    assert mcap.command_tasks == [task_for(command_posture(row)) for row in command]
    np.testing.assert_array_equal(mcap.command, command)
    # /command also carries the setpoint and the achieved posture, which Foxglove plots beside the command.
    mcap_setpoint, mcap_achieved = command_extras(root / episode[columns.EPISODE_MCAP])
    np.testing.assert_array_equal(mcap_setpoint, setpoint)
    observed = read_frames(root, [columns.OBS_STATE, columns.OBS_ENV_STATE])
    observation = join_observation(observed[columns.OBS_STATE], observed[columns.OBS_ENV_STATE])
    np.testing.assert_allclose(mcap_achieved, Tracking(humanoid_model()).achieved(observation), atol=1e-12)
    assert episode["tasks"][0] == DEFAULT_TASK and len(episode["tasks"]) >= 2
    changes = np.flatnonzero(np.r_[True, (np.diff(command, axis=0) != 0).any(axis=1)])
    for start, end in zip(changes, [*changes[1:], len(command)], strict=True):
        gap = np.abs(setpoint[start:end] - command[start]).max(axis=1)
        assert np.all(np.diff(gap) <= 1e-6), start  # never away from the command
        previous = command_posture(command[start - 1]) if start else NEUTRAL
        arrive = int(np.ceil(move_seconds(previous, command_posture(command[start])) / DT)) + 1
        assert arrive < end - start and gap[arrive:].max() < 1e-6, start  # there, and held
        if start:
            np.testing.assert_allclose(setpoint[start - 1], command[start - 1], atol=1e-6)  # from the last one
            assert gap[0] > 0


# PPO's task


def test_the_tracking_kernel_is_one_on_the_command_and_falls_with_the_error() -> None:
    """exp(-(error / tolerance)²) per field, averaged: 1 on the command; one field one tolerance off: (4 + 1/e) / 5,
    two fields: (3 + 2/e) / 5."""
    tolerances = np.array([FIELDS[name].tolerance for name in POSTURE_NAMES])
    assert tracking_reward(np.zeros(5), tolerances) == 1.0
    one_off = np.array([FIELDS["lean_forward"].tolerance, 0.0, 0.0, 0.0, 0.0])
    assert tracking_reward(one_off, tolerances) == pytest.approx((4 + np.exp(-1)) / 5)
    two_off = one_off + np.array([0.0, 0.0, FIELDS["height"].tolerance, 0.0, 0.0])
    assert tracking_reward(two_off, tolerances) == pytest.approx((3 + 2 * np.exp(-1)) / 5)
    assert tracking_score({"settled_error": dict.fromkeys(POSTURE_NAMES, 0.0)}) == 1.0
    assert tracking_score({"settled_error": dict.fromkeys(POSTURE_NAMES, float("nan"))}) == 0.0
    # A summary's score is over the fields it measured: a walk's velocity one tolerance off counts as one field of 8.
    walked = {**dict.fromkeys(COMMAND_NAMES, 0.0), "forward_speed": FIELDS["forward_speed"].tolerance}
    assert tracking_score({"settled_error": walked}) == pytest.approx((7 + np.exp(-1)) / 8)


def test_training_episodes_follow_schedules_no_evaluation_uses_and_reward_tracking() -> None:
    """Under `CommandedTask` the info carries the schedule's command at the reset and after each step (a neutral
    start, then a change), the same per reset seed, from a schedule seed past every evaluation's; the reward is the
    environment's plus the weight times the tracking kernel of the true posture against the command."""
    expert, task = LQRExpert(), CommandedTask(make_env(), weight=2.0, task="posture")
    bare = make_env()
    obs, info = task.reset(seed=11)
    bare.reset(seed=11)
    drawn = np.random.default_rng((11, SCHEDULE_STREAM)).integers(*TRAINING_SEEDS)  # the stream the reset seeds
    assert drawn >= TRAINING_SEEDS[0] > 2000 + 1000  # past the held-out evaluations' and PPO's validation seeds
    np.testing.assert_array_equal(task.commands, command_schedule(int(drawn), EPISODE_STEPS, bare.unwrapped.dt))
    commands = task.commands.copy()
    np.testing.assert_array_equal(info[COMMAND_INFO], np.zeros(len(COMMAND_NAMES)))
    seen, extra = [info[COMMAND_INFO]], []
    for t in range(int(FIRST_NEUTRAL_SECONDS / bare.unwrapped.dt) + 5):
        expert.set_command(seen[-1])
        action = expert.act(obs)
        obs, reward, *_, info = task.step(action)
        _, base, *_ = bare.step(action)
        data = task.unwrapped.data
        errors = task.tracking.error(data.qpos[2:], data.qvel, commands[t])
        assert errors.shape == (len(POSTURE_NAMES),)  # the posture task tracks the posture fields
        extra.append(reward - base)
        assert reward - base == pytest.approx(2.0 * task.tracking.reward(errors))
        seen.append(info[COMMAND_INFO])
    np.testing.assert_array_equal(np.array(seen), commands[: len(seen)])
    assert (np.array(seen)[-1] != 0).any()  # past the neutral start, a command
    assert all(0.0 < value <= 2.0 for value in extra)
    task.reset(seed=11)
    np.testing.assert_array_equal(task.commands, commands)
    task.reset(seed=12)
    assert not np.array_equal(task.commands, commands)


def test_a_saved_stream_draws_the_same_next_schedule() -> None:
    """`random_state` / `set_random_state` (what a resumed PPO run restores): the next unseeded reset repeats."""
    task = CommandedTask(make_env(), weight=1.0, task="posture")
    task.reset(seed=3)
    state = task.random_state()
    task.reset()
    first = task.commands.copy()
    task.set_random_state(state)
    task.reset()
    np.testing.assert_array_equal(task.commands, first)


def test_every_training_environment_measures_on_the_one_nominal_body() -> None:
    """PPO runs dozens of `CommandedTask`s per process: each measures on the process's nominal model, so a target one
    environment solved (`posture_reference` caches per model object) is the next one's too, and no body drawn in
    place reaches the targets."""
    drawn = CommandedTask(DomainRandomization(make_env(), Randomization(mass=(0.8, 1.2))), weight=1.0, task="posture")
    drawn.reset(seed=0)
    other = CommandedTask(make_env(), weight=1.0, task="posture")
    assert drawn.tracking.model is other.tracking.model is nominal_model()
    assert not np.array_equal(drawn.unwrapped.model.body_mass, nominal_model().body_mass)
    command = command_vector(Posture(lean_left=0.1, height=-0.05))
    np.testing.assert_array_equal(
        drawn.tracking.target(command), Tracking(humanoid_model(), drawn.tracking.fields).target(command)
    )
