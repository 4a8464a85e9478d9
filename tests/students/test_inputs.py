"""The input sets (students.inputs): one computation, the same features live, offline and in PPO's environments."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from bc import dagger
from bc import train as bc_train
from bc.data import load_demonstrations
from common import columns
from common.cli import UserError
from humanoid.conditions import LATENCY_PARAMETER, ActionLatency, DomainRandomization, Randomization
from humanoid.env import humanoid_model, make_env
from humanoid.estimator import odometry_names
from humanoid.perturbations import VelocityKick
from policies.checkpoint import CheckpointError
from policies.mlp import MLPPolicy, MLPSpec
from rl.learner import training_env
from rollout.episode import Episode, run_episode
from students.inputs import INPUT_SETS, INPUTS, RAMP_NAMES, WALK_NAMES, PendingInputs, episode_inputs, input_set_named
from students.learned import PolicyController
from support import record_short
from task.command_fields import COMMAND_NAMES, POSTURE_NAMES, VELOCITY_NAMES, Readout
from task.posture import arm_angles
from task.schedules import FIRST_NEUTRAL_SECONDS, command_schedule
from teachers.expert import LQRExpert
from teachers.stepping import SensedSteppingExpert
from teleop.dataset_reader import read_episodes, read_frames, read_parameters

STEPS = 40
SCHEDULED_STEPS = round(FIRST_NEUTRAL_SECONDS / 0.015) + 30  # the first command of a schedule, and 30 steps of it
OBSERVATION = 348


def tiny_policy(inputs: str, env: gym.Env) -> PolicyController:
    """A live controller of an untrained policy on `inputs`: what it reads is all that matters here."""
    kind = INPUT_SETS[inputs]
    spec = MLPSpec(
        kind.columns, len(kind.input_names(humanoid_model())), 17, (8,), inputs=inputs, inputs_version=kind.version
    )
    return PolicyController(MLPPolicy(spec, env.action_space.low, env.action_space.high), inputs, env)


@pytest.fixture(scope="module")
def delayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short episodes of the scripted operator recorded by the real recorder, each with one step of action
    latency and no action noise (so the executed actions, replayed, are the ones the recording labels), long
    enough for the schedule's first command."""
    root = tmp_path_factory.mktemp("inputs") / "dataset"
    record_short(
        root, episodes=2, max_steps=SCHEDULED_STEPS, latency=1.0, noise=0.0, controller="expert", task="posture"
    )
    return root


@pytest.mark.parametrize("inputs", INPUTS)
def test_live_offline_and_ppo_inputs_are_one_computation(inputs: str, delayed: Path) -> None:
    """Each recorded episode replayed in PPO's training env (its seed, its executed actions): the inputs the env
    appends to its observation equal, bit for bit, those the live controller's computation gives on the same
    observations and operator's commands (the env's command set as the recording's); the offline loader's equal,
    bit for bit, that computation run on the frames as recorded (float32), and the live ones to the recording's
    float32 rounding (carried through the estimator's memory for "pending", hence the tolerance)."""
    offline = load_demonstrations(delayed, make_env(), cache=False, inputs=inputs).inputs.numpy()
    frames = read_frames(delayed, [columns.EXECUTED_ACTION, columns.ACTION, columns.OBS_COMMAND, "episode_index"])
    assert len(np.unique(frames[columns.OBS_COMMAND], axis=0)) > 1  # the command changes within the recording
    seeds = read_episodes(delayed, [columns.EPISODE_SEED])[columns.EPISODE_SEED].to_pylist()
    assert [drawn[LATENCY_PARAMETER] for drawn in read_parameters(delayed)] == [1, 1]
    env = training_env(None, inputs=inputs, latency=1.0)
    command = env.get_wrapper_attr("command")  # the array PPO's environment appends the inputs under
    live = tiny_policy(inputs, env).input_set
    appended, computed, observed = [], [], []
    for episode, seed in enumerate(seeds):
        rows = frames["episode_index"] == episode
        commands = frames[columns.OBS_COMMAND][rows]
        command[:] = commands[0]
        obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs[:OBSERVATION], make_env().reset(seed=seed)[0])  # the env's, as it is
        live.set_delay(1)
        live.reset()
        steps = zip(frames[columns.EXECUTED_ACTION][rows], frames[columns.ACTION][rows], commands, strict=True)
        for t, (executed, label, now) in enumerate(steps):
            np.testing.assert_array_equal(executed, label)  # no noise: the action sent is the one executed
            frame = live.observe(obs[:OBSERVATION], now)
            observed.append(frame)
            computed.append(live(frame))
            appended.append(obs[OBSERVATION:])
            live.sent(label)
            command[:] = commands[min(t + 1, len(commands) - 1)]
            obs, *_ = env.step(executed)
    np.testing.assert_array_equal(np.array(appended), np.array(computed))
    recorded = np.array(observed, np.float32)
    delays = np.ones(len(recorded), np.int64)
    replayed = episode_inputs(
        inputs, recorded, frames[columns.ACTION], frames["episode_index"], delays, humanoid_model()
    )
    np.testing.assert_array_equal(offline, replayed)
    np.testing.assert_allclose(offline, np.array(computed), rtol=0, atol=1e-4)
    assert offline.shape == (2 * SCHEDULED_STEPS, len(INPUT_SETS[inputs].input_names(humanoid_model())))


def expert_episode(delay: int, seed: int) -> Episode:
    env = ActionLatency(make_env(STEPS), delay) if delay else make_env(STEPS)
    return run_episode(env, LQRExpert(delay=delay), seed, noise_std=0.05)


def test_the_pending_command_is_the_previous_label_in_a_delayed_episode_only() -> None:
    """Known answer: zeros at the first step (the env executes zeros then) and throughout an undelayed episode."""
    model = humanoid_model()
    episode = expert_episode(1, seed=0)
    frames = PendingInputs(model).observe(episode.observation, episode.command)
    index = np.zeros(episode.length, np.int64)
    pending = slice(-1 - model.nu, -1)
    delayed = episode_inputs("pending", frames, episode.action, index, np.ones(episode.length), model)
    np.testing.assert_array_equal(delayed[0, pending], 0.0)
    np.testing.assert_array_equal(delayed[1:, pending], episode.action[:-1])
    np.testing.assert_array_equal(delayed[:, -1], 1.0)
    undelayed = episode_inputs("pending", frames, episode.action, index, np.zeros(episode.length), model)
    np.testing.assert_array_equal(undelayed[:, pending.start :], 0.0)


@pytest.mark.parametrize("delay", [0, 1])
def test_a_policy_on_pending_inputs_is_told_the_delay_and_remembers_its_command(delay: int) -> None:
    env = ActionLatency(make_env(20), 1) if delay else make_env(20)
    controller = tiny_policy("pending", env)
    episode = run_episode(env, controller, seed=0)
    assert controller.input_set.delay == delay
    np.testing.assert_array_equal(controller.input_set.pending, episode.action[-1] if delay else 0.0)


def test_a_delay_beyond_one_step_is_refused_in_one_line() -> None:
    with pytest.raises(
        UserError,
        match=r"^a policy on the 'pending' inputs acts through at most 1 step of action "
        r"latency; this episode delays its actions by 2$",
    ):
        PendingInputs(humanoid_model()).set_delay(2)


ODOMETRY_REMOVED = (
    "inputs 'odometry' was removed; use pending: the same inputs, then the command in flight and the delay "
    "(docs/decisions/pending-inputs.md)"
)


PROPRIO_COMMAND_REMOVED = (
    "inputs 'proprio+command' was removed; use pending+command (with the leg odometry, which standing needs) or "
    "pending+ramp, the students' default (docs/decisions/command-features.md)"
)


@pytest.mark.parametrize("cli", [bc_train.cli, dagger.cli])
@pytest.mark.parametrize(
    ("inputs", "message"), [("odometry", ODOMETRY_REMOVED), ("proprio+command", PROPRIO_COMMAND_REMOVED)]
)
def test_the_removed_inputs_are_refused_naming_what_replaced_them(
    cli: object, inputs: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`make train-bc INPUTS=odometry` and `make dagger INPUTS=proprio+command`: one line naming the input set to use,
    exit 1, nothing written (the dataset is not even looked at)."""
    folders = ["--dataset", str(tmp_path / "data"), "--policy", str(tmp_path / "policy")]
    if cli is dagger.cli:
        folders += ["--output", str(tmp_path / "aggregate")]
    assert cli([*folders, "--inputs", inputs]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {message}"]
    assert list(tmp_path.iterdir()) == []


def test_a_checkpoint_on_the_removed_odometry_inputs_is_refused_naming_pending() -> None:
    """A policy saved reading "odometry" (as an earlier version wrote them): the live controller and PPO's start
    (`input_set` of its spec) refuse it in one line naming pending, as the command line does."""
    spec = MLPSpec((columns.OBS_STATE,), len(odometry_names(humanoid_model())), 17, (8,), inputs="odometry")
    policy = MLPPolicy(spec, -np.ones(17, np.float32), np.ones(17, np.float32))
    with pytest.raises(CheckpointError, match=rf"^policies/old must be retrained: {re.escape(ODOMETRY_REMOVED)}$"):
        PolicyController(policy, "policies/old")  # in an env of its own, which it closes
    with pytest.raises(UserError, match=rf"^{re.escape(ODOMETRY_REMOVED)}$"):
        input_set_named("odometry")


def test_a_commanded_set_reads_its_base_then_the_command_as_it_is() -> None:
    """Known answer: "pending+command" is "pending"'s inputs, then the five posture fields of the command, whatever
    they are; the velocities it does not read."""
    model = humanoid_model()
    episode = expert_episode(0, seed=0)
    posture = np.array([0.1, -0.05, -0.04, 0.2, 3.0], np.float32)
    command = np.concatenate([posture, [0.4, -0.1, 0.3]]).astype(np.float32)
    base, commanded = INPUT_SETS["pending"](model), INPUT_SETS["pending+command"](model)
    frame = commanded.observe(episode.observation[5], command)
    np.testing.assert_array_equal(frame[-5:], posture)
    inputs = commanded(frame)
    np.testing.assert_array_equal(inputs[:-5], base(base.observe(episode.observation[5], command)))
    np.testing.assert_array_equal(inputs[-5:], posture)
    assert commanded.input_names(model)[-5:] == [f"command.{name}" for name in POSTURE_NAMES]
    assert commanded.observed_names(model)[-5:] == list(POSTURE_NAMES) == list(COMMAND_NAMES[:5])
    assert commanded.takes_command and not base.takes_command


RAMP_SEED = 41  # its schedule's first command (at 3 s) leans left, crouches and puts the arms out, a 3.4 s move
RAMP_STEPS = round(FIRST_NEUTRAL_SECONDS / 0.015) + 250


def test_a_ramped_set_reads_the_setpoint_the_expert_moves_along() -> None:
    """Known answer: along the expert's scheduled episode, "pending+ramp" is "pending"'s inputs, then the expert's own
    setpoint step for step (its lean, lean, height and twist), then arm angles that leave the neutral ones when the
    command changes, move monotonically and end on the commanded preset's."""
    model = humanoid_model()
    env = make_env(RAMP_STEPS)
    schedule = command_schedule(RAMP_SEED, RAMP_STEPS, env.unwrapped.dt)
    expert, ramped, base = LQRExpert(), INPUT_SETS["pending+ramp"](model), INPUT_SETS["pending"](model)
    obs, _ = env.reset(seed=RAMP_SEED)
    expert.reset(RAMP_SEED)
    ramped.reset()
    base.reset()
    setpoints, ramps = [], []
    for t, command in enumerate(schedule):
        if t == 0 or (command != schedule[t - 1]).any():
            expert.set_command(command)
        action = expert.act(obs)
        inputs = ramped(ramped.observe(obs, command))
        np.testing.assert_array_equal(inputs[: -len(RAMP_NAMES)], base(base.observe(obs, command)))
        setpoints.append(expert.setpoint())
        ramps.append(inputs[-len(RAMP_NAMES) :])
        obs, *_ = env.step(action)
    setpoints, ramps = np.array(setpoints), np.array(ramps)
    np.testing.assert_array_equal(ramps[:, :4].astype(np.float32), setpoints[:, :4])  # a command vector's float32
    start = round(FIRST_NEUTRAL_SECONDS / env.unwrapped.dt)
    arms = ramps[:, 4:]
    np.testing.assert_array_equal(arms[:start], np.broadcast_to(arm_angles(0.0), (start, 6)))
    np.testing.assert_allclose(arms[-1], arm_angles(schedule[-1][4]), rtol=0, atol=1e-12)
    moves = np.diff(arms[start - 1 :], axis=0) * np.sign(arm_angles(3.0))
    assert (moves >= 0).all() and (moves[0] > 0).all()
    assert schedule[-1][4] == 3.0 and (np.abs(setpoints[-1] - schedule[-1]) < 1e-6).all()  # the move ended in time


def test_a_policy_made_after_a_drawn_body_estimates_on_the_nominal_one() -> None:
    """A policy's inputs compute on the nominal body whatever its env drew last, as its training inputs were: DAgger
    builds each round's controller in an env that has run episodes (`teleop.parallel.Simulator.act_with`)."""
    env = DomainRandomization(make_env(), Randomization(mass=(0.8, 1.2)))
    env.reset(seed=0)
    controller = tiny_policy("pending", env)
    assert controller.input_set.odometry.odometry.mass == pytest.approx(float(humanoid_model().body_mass.sum()), 1e-12)
    assert controller.input_set.odometry.odometry.mass != pytest.approx(float(env.unwrapped.model.body_mass.sum()))


WALK_STEPS = 130
WALK_AT = 20  # steps: the walk commanded (with a twist)
PUSH_AT = 90  # steps: after the landing, a push of the root (m/s, world x and y) the estimate must follow
PUSH = (0.12, -0.06)
SETTLE = 10  # steps the estimate takes to catch up with a push no force sensor felt


def test_a_walking_set_reads_the_ramped_set_then_the_velocities_on_their_ramp_and_as_estimated() -> None:
    """Known answer: under a walk command with a twist, "pending+walk" is "pending"'s inputs, then the expert's own
    setpoint step for step (the posture's, as "pending+ramp" reads it, then the velocities'), whether that setpoint
    has left the zero walk (as the walking teacher's hand-over: `planning`), then the velocities the leg odometry
    estimates, which follow the true ones (`Readout` of MuJoCo's state, turned by the heading with the twist undone)
    to 1 cm/s and 0.01 rad/s before a push and once it has caught up with it."""
    model = humanoid_model()
    names = INPUT_SETS["pending+walk"].input_names(model)
    at = {name: names.index(name) for name in names}
    ramped = [at[f"ramp.{name}"] for name in (*POSTURE_NAMES[:4], *VELOCITY_NAMES)]
    estimates = [at[f"estimate.{name}"] for name in VELOCITY_NAMES]
    env = make_env(WALK_STEPS)
    data = env.unwrapped.data
    walk_command = np.zeros(len(COMMAND_NAMES), np.float32)
    walk_command[COMMAND_NAMES.index("twist")] = 0.2
    walk_command[[COMMAND_NAMES.index(name) for name in VELOCITY_NAMES]] = (0.3, -0.1, 0.2)
    expert, walk, base = LQRExpert(), INPUT_SETS["pending+walk"](model), INPUT_SETS["pending"](model)
    readout = Readout(model)
    obs, _ = env.reset(seed=7)
    expert.reset(7)
    walk.reset()
    base.reset()
    command = np.zeros_like(walk_command)
    setpoints, ramps, planning, estimated, true = [], [], [], [], []
    for t in range(WALK_STEPS):
        if t == WALK_AT:
            command = walk_command
            expert.set_command(command)
        if t == PUSH_AT:
            data.qvel[:2] += PUSH
        action = expert.act(obs)
        inputs = walk(walk.observe(obs, command))
        np.testing.assert_array_equal(inputs[: base.size], base(base.observe(obs, command)))
        setpoints.append(expert.setpoint()[[0, 1, 2, 3, 5, 6, 7]])
        ramps.append(inputs[ramped])
        planning.append(inputs[at["planning"]])
        estimated.append(inputs[estimates])
        achieved = readout(data.qpos[2:], data.qvel)
        true.append([achieved[name][0] for name in VELOCITY_NAMES])
        obs, *_ = env.step(action)
    np.testing.assert_array_equal(np.array(ramps).astype(np.float32), np.array(setpoints))  # a command's float32
    assert 0 < ramps[WALK_AT + 10][4] < ramps[-1][4] == np.float32(0.3)  # the forward speed ramps up to the command
    assert planning == [0.0] * WALK_AT + [1.0] * (WALK_STEPS - WALK_AT)
    errors = np.abs(np.array(estimated) - np.array(true))
    assert np.abs(np.array(true)[PUSH_AT + 2 :, :2]).max() > 0.1  # the push moved the body
    # The push changes the velocity without a force the feet's sensors feel: the feet's kinematics take a few steps.
    settled = np.concatenate([errors[PUSH_AT - 30 : PUSH_AT], errors[PUSH_AT + SETTLE :]])
    assert settled.max() < 0.01, settled.max(axis=0)
    assert names[-len(WALK_NAMES) :] == list(WALK_NAMES) and len(names) == base.size + len(RAMP_NAMES) + 7
    assert INPUT_SETS["pending+walk"].walks and not INPUT_SETS["pending+ramp"].walks


HAND_OVER_STEPS = 30


def test_planning_flips_on_the_step_the_walking_teacher_hands_over() -> None:
    """Known answer: under a walk commanded at step WALK_AT, "pending+walk"'s `planning` is 0 while
    `expert-sensed-stepping` balances and 1 from the step its walking planner takes over (the command's step: the
    ramp's first) to the end."""
    model = humanoid_model()
    at = INPUT_SETS["pending+walk"].input_names(model).index("planning")
    env = make_env(HAND_OVER_STEPS)
    teacher, walk = SensedSteppingExpert(), INPUT_SETS["pending+walk"](model)
    walk_command = np.zeros(len(COMMAND_NAMES), np.float32)
    walk_command[COMMAND_NAMES.index("forward_speed")] = 0.3
    obs, _ = env.reset(seed=7)
    teacher.reset(7)
    walk.reset()
    command, flags, handed = np.zeros_like(walk_command), [], []
    for t in range(HAND_OVER_STEPS):
        if t == WALK_AT:
            command = walk_command
            teacher.set_command(command)
        action = teacher.act(obs)
        flags.append(walk(walk.observe(obs, command))[at])
        handed.append(teacher.walked)
        obs, *_ = env.step(action)
    assert flags == [float(h) for h in handed] == [0.0] * WALK_AT + [1.0] * (HAND_OVER_STEPS - WALK_AT)
    assert teacher.planned == HAND_OVER_STEPS - WALK_AT  # the walking planner acted from that step on


KICKED_AT = 277  # the env step of seed 0's kick (`VelocityKick`'s draw)
KICK_STEPS = KICKED_AT + 25


def test_planning_flips_on_the_step_the_kick_planner_takes_over() -> None:
    """Known answer: under the zero command and a 0.4 m/s kick at step KICKED_AT, "pending+walk"'s `planning` is 0
    while `expert-sensed-stepping` balances and 1 from the step its kick planner takes over, a few steps after the
    kick (when the leg odometry's estimate, which both read, puts the capture point off the feet) to the end."""
    model = humanoid_model()
    at = INPUT_SETS["pending+walk"].input_names(model).index("planning")
    env = VelocityKick(make_env(KICK_STEPS), 0.4)
    teacher, student = SensedSteppingExpert(), INPUT_SETS["pending+walk"](model)
    obs, _ = env.reset(seed=0)
    teacher.reset(0)
    student.reset()
    command = np.zeros(len(COMMAND_NAMES), np.float32)
    flags, handed = [], []
    for _ in range(KICK_STEPS):
        action = teacher.act(obs)
        flags.append(student(student.observe(obs, command))[at])
        handed.append(float(teacher.planned > 0))
        obs, *_ = env.step(action)
    assert env.pushes and env.pushes[0][0] == KICKED_AT
    first = handed.index(1.0)
    assert flags == handed == [0.0] * first + [1.0] * (KICK_STEPS - first)
    assert KICKED_AT < first < KICKED_AT + 10, first
