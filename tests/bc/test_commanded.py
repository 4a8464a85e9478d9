"""Commanded policies through the stages (issues 42, 43): bc.train refuses a command input the dataset cannot teach,
trains one it can; evaluation.evaluate and evaluation.robustness report tracking under schedules and plot it;
rl.finetune trains one on schedules; the bad input of the commands (one line, non-zero exit, nothing written)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from bc import train as train_stage
from common import columns
from evaluation import evaluate as evaluate_stage
from evaluation import robustness
from evaluation.evaluate import plot_tracking, tracking
from humanoid.env import humanoid_model, make_env
from policies import checkpoint
from policies.mlp import MLPPolicy, MLPSpec
from rl import finetune
from rl.learner import training_env
from rollout.episode import run_episode
from students.inputs import INPUT_SETS
from students.learned import PolicyController, input_set_of
from support import SHORT_EPISODE, TINY_PPO, StandingWalker, record_short, registered, snapshot
from task.command_fields import COMMAND_NAMES, POSTURE_NAMES, task_fields
from task.schedules import command_schedule
from task.tracking import COMMAND_INFO, Tracking
from teachers.expert import LQRExpert
from teleop import record as record_stage
from teleop.dataset_reader import read_frames

TRACKING_FIELDS = {"settled_error", "moved_error", "settle_seconds"}
# Steps of a short operator episode: the neutral start (200 steps), then the first command, held long enough to settle
# (seed 1007's: lean forward 0.1 and left 0.1 from step 200 to 350), then a few steps of the next.
OPERATOR_STEPS = 360
OPERATOR_SEED = 1007
WALK_SEED = 0  # the first command of seeds 0 and 1's walking schedules (at 3 s) is a walk forward
PLANNER_STUDENT = "pending+walk"  # the stepping teacher's walking student (docs/decisions/walking-student.md)
DATASET_V1 = Path(__file__).parents[1] / "data" / "dataset_v1"
TINY = ["--hidden", "8", "--epochs", "1", "--min-updates", "0", "--eval-episodes", "0", "--progress", "false"]


def stage_cli(stage: object, args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], list[str]]:
    """Exit code, stdout lines and stderr lines of `python -m <stage> ARGS`."""
    code = stage.cli(args)
    out, err = capsys.readouterr()
    return code, out.strip().splitlines(), err.strip().splitlines()


def test_command_inputs_on_long_standing_episodes_are_told_to_record_the_schedules(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Episodes past a schedule's first zero command that still never change it were recorded standing: the refusal
    names the posture task, not the episodes' length."""
    record_short(tmp_path / "standing", episodes=2, max_steps=210)
    args = [*TINY, "--dataset", str(tmp_path / "standing"), "--policy", str(tmp_path / "p"), "--inputs", "full+command"]
    code, out, err = stage_cli(train_stage, args, capsys)
    assert code == 1 and out == [] and len(err) == 1
    assert err[0].endswith("never changes it: record with TASK=posture (the default) or CONTROLLER=keyboard")


@pytest.fixture(scope="module")
def operated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 short episodes of the scripted operator, each under a step of action latency: commands that change."""
    root = tmp_path_factory.mktemp("operated") / "dataset"
    record_short(
        root, controller="expert", task="posture", episodes=2, max_steps=OPERATOR_STEPS, latency=1.0, noise=0.02
    )
    return root


@pytest.fixture(scope="module")
def delayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 short plain expert episodes under a step of action latency: the command is zero throughout."""
    root = tmp_path_factory.mktemp("delayed") / "dataset"
    record_short(root, episodes=2, max_steps=SHORT_EPISODE, latency=1.0)
    return root


def full_checkpoint(folder: Path) -> Path:
    """An untrained policy on the full observation, which takes no command."""
    checkpoint.save(
        MLPPolicy(MLPSpec(("observation.state", "observation.environment_state"), 348, 17, hidden=(8,))), folder, {}, {}
    )
    return folder


# bc.train


@pytest.mark.parametrize("inputs", ["pending+command", "pending+ramp"])
def test_a_command_input_on_a_dataset_whose_command_never_changes_is_refused(
    delayed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], inputs: str
) -> None:
    """INPUTS=...+command on plain expert episodes (delayed ones, so that the pending set's own check passes): one
    line saying to record commanded demonstrations, no checkpoint, the dataset untouched."""
    before = snapshot(delayed)
    args = [*TINY, "--dataset", str(delayed), "--policy", str(tmp_path / "policy"), "--inputs", inputs]
    code, out, err = stage_cli(train_stage, args, capsys)
    assert code == 1 and out == [] and len(err) == 1
    assert f"--inputs {inputs} learns to follow the operator's command" in err[0]
    assert err[0].endswith("hold the zero command for their first 3 s: record longer episodes, MAX_STEPS past 200")
    assert not (tmp_path / "policy").exists() and snapshot(delayed) == before


@pytest.fixture(scope="module")
def walked(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """2 short episodes of walking schedules whose first command (at 3 s) is a walk, under a step of latency. A toy
    walker (`support.StandingWalker`, registered while the module's tests run) stands through them: cheap
    demonstrations whose commands hold velocities."""
    root = tmp_path_factory.mktemp("walked") / "dataset"
    with registered(StandingWalker):
        record_short(
            root,
            controller=StandingWalker.name,
            task="walk",
            seed=WALK_SEED,
            episodes=2,
            max_steps=OPERATOR_STEPS,
            latency=1.0,
            noise=0.02,
        )
        yield root


@pytest.mark.parametrize(
    ("dataset", "inputs", "recording"),
    [
        ("operated", PLANNER_STUDENT, "make record CONTROLLER=expert-sensed-stepping TASK=walk;"),
        ("old", PLANNER_STUDENT, "make record CONTROLLER=expert-sensed-stepping TASK=walk;"),
        ("operated", "pending+gait", "(make record TASK=walk;"),  # the walker's student: the walking task's teacher
    ],
)
def test_walking_inputs_on_a_dataset_without_walks_are_refused_naming_what_to_record(
    request: pytest.FixtureRequest,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    dataset: str,
    inputs: str,
    recording: str,
) -> None:
    """A walking input set on posture schedules, or on a dataset recorded before the velocity fields existed (read as
    the zero walk): one line naming the recording that teaches it, no checkpoint, the dataset untouched."""
    root = request.getfixturevalue("operated") if dataset == "operated" else DATASET_V1
    before = snapshot(root)
    args = [*TINY, "--dataset", str(root), "--policy", str(tmp_path / "policy"), "--inputs", inputs]
    code, out, err = stage_cli(train_stage, args, capsys)
    assert code == 1 and out == [] and len(err) == 1, err
    assert f"--inputs {inputs} learns to walk on velocity commands" in err[0]
    assert recording in err[0], err[0]
    assert not (tmp_path / "policy").exists() and snapshot(root) == before


def test_walking_inputs_train_on_walks_into_a_policy_that_walks_under_walking_schedules(
    walked: Path, tmp_path: Path
) -> None:
    """The same settings on demonstrations that hold walk commands train; the policy takes the velocity command, and
    its evaluation runs (and tracks) walking schedules."""
    assert read_frames(walked, [columns.OBS_COMMAND])[columns.OBS_COMMAND][:, 5:].any()
    folder = tmp_path / "policy"
    config = train_stage.TrainConfig(
        dataset=walked, policy=folder, inputs=PLANNER_STUDENT, hidden=8, epochs=1, min_updates=0, eval_episodes=1
    )
    train_stage.main(dataclasses.replace(config, progress=False))
    assert input_set_of(folder).walks and not input_set_of(full_checkpoint(tmp_path / "full")).walks
    evaluation = json.loads((folder / "eval.json").read_text())
    assert evaluation["task"] == "walk"
    assert set(evaluation["tracking"]["settled_error"]) == {field.name for field in task_fields("walk")}


def test_a_student_records_which_computation_of_its_inputs_it_was_trained_on(walked: Path, tmp_path: Path) -> None:
    """The walker's students' inputs are in their second computation (the odometry in the heading's frame): a student
    trained on them says so in its checkpoint, and runs; the same checkpoint saying the first is refused in one line
    that names the command retraining it, as a checkpoint written before the field is."""
    folder = tmp_path / "policy"
    config = train_stage.TrainConfig(
        dataset=walked, policy=folder, inputs="pending+gait", hidden=8, epochs=1, min_updates=0, eval_episodes=0
    )
    train_stage.main(dataclasses.replace(config, progress=False))
    assert checkpoint.load(folder).spec.inputs_version == INPUT_SETS["pending+gait"].version == 2
    env = make_env()
    try:
        PolicyController.load(folder, env)
        saved = json.loads((folder / checkpoint.CONFIG_FILE).read_text())
        del saved["policy"]["inputs_version"]
        (folder / checkpoint.CONFIG_FILE).write_text(json.dumps(saved))
        with pytest.raises(checkpoint.CheckpointError) as refused:
            PolicyController.load(folder, env)
    finally:
        env.close()
    message = str(refused.value)
    assert "\n" not in message and "trained on version 1 of the 'pending+gait' inputs" in message
    assert "make train-bc INPUTS=pending+gait" in message


def test_pending_command_inputs_without_latency_are_refused_for_the_latency(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = [*TINY, "--dataset", str(recorded), "--policy", str(tmp_path / "policy"), "--inputs", "pending+command"]
    code, _, err = stage_cli(train_stage, args, capsys)
    assert code == 1 and len(err) == 1 and "--inputs pending+command learns to act through action latency" in err[0]
    assert not (tmp_path / "policy").exists()


def test_commanded_inputs_train_on_the_operators_episodes_into_a_policy_that_takes_the_command(
    operated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same settings on the operator's episodes train; the checkpoint says it takes a command, and its controller
    reads it: the same seed under a held lean acts otherwise than under the zero command."""
    folder = tmp_path / "policy"
    args = [*TINY, "--dataset", str(operated), "--policy", str(folder), "--inputs", "pending+command"]
    code, _, err = stage_cli(train_stage, args, capsys)
    assert code == 0, err
    assert input_set_of(folder).takes_command and not input_set_of(full_checkpoint(tmp_path / "full")).takes_command
    env = make_env(SHORT_EPISODE)
    try:
        controller = PolicyController.load(folder, env)
        assert controller.takes_command
        steps = env.spec.max_episode_steps
        lean = np.zeros((steps, len(COMMAND_NAMES)), np.float32)
        lean[:, COMMAND_NAMES.index(POSTURE_NAMES[0])] = 0.2
        zero, leaned = (run_episode(env, controller, 0, commands=c) for c in (np.zeros_like(lean), lean))
    finally:
        env.close()
    shared = min(zero.length, leaned.length)
    assert shared > 1 and np.abs(zero.action[1:shared] - leaned.action[1:shared]).max() > 1e-4


# make play / teleop.record


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--policy", "policies/somewhere"], "--policy is driven by the keys: it needs --controller keyboard"),
        (["--controller", "keyboard", "--policy", "nowhere/policy"], "no policy checkpoint at nowhere/policy"),
    ],
)
def test_bad_command_settings_of_the_recorder_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code, out, err = stage_cli(record_stage, ["--progress", "false", "--dataset", str(tmp_path / "new"), *args], capsys)
    assert code == 1 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "new").exists()


def test_play_refuses_a_policy_that_takes_no_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`make play POLICY=...` on a policy without the command: the keys would change nothing; one line."""
    folder = full_checkpoint(tmp_path / "full")
    args = [
        "--progress",
        "false",
        "--dataset",
        str(tmp_path / "new"),
        "--controller",
        "keyboard",
        "--policy",
        str(folder),
    ]
    code, _, err = stage_cli(record_stage, args, capsys)
    assert code == 1 and len(err) == 1 and f"{folder} takes no command" in err[0]
    assert not (tmp_path / "new").exists()


def untrained(folder: Path, inputs: str) -> Path:
    """An untrained policy on `inputs`."""
    kind = INPUT_SETS[inputs]
    size = len(kind.input_names(humanoid_model()))
    spec = MLPSpec(kind.columns, size, 17, hidden=(8,), inputs=inputs, inputs_version=kind.version)
    checkpoint.save(MLPPolicy(spec), folder, {}, {})
    return folder


@pytest.mark.parametrize("inputs", ["pending+ramp", PLANNER_STUDENT])
def test_play_says_in_one_line_when_the_policy_takes_no_velocity_command(tmp_path: Path, inputs: str) -> None:
    """`make play POLICY=...` on a policy that follows postures only: one line says the walking keys change nothing,
    before anything else (here the refusal of a stdin that is no terminal, which the suite has); on a walking policy,
    no such line."""
    folder = untrained(tmp_path / inputs, inputs)
    args = ["--dataset", str(tmp_path / "new"), "--controller", "keyboard", "--policy", str(folder)]
    played = subprocess.run(
        [sys.executable, "-m", "teleop.record", *args], stdin=subprocess.DEVNULL, capture_output=True, text=True
    )
    code, err = played.returncode, played.stderr.strip().splitlines()
    notice = f"{folder} takes no velocity command: the arrows and z/c change nothing"
    assert code == 1 and err[-1].startswith("error: ") and not (tmp_path / "new").exists()
    if inputs == PLANNER_STUDENT:
        assert len(err) == 1
    else:
        assert len(err) == 2 and err[0].startswith(notice)


# evaluation.evaluate


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--plot", "TMP/x.txt"], "--plot must be a .png file's path, got TMP/x.txt"),
        (["--plot", "TMP"], "--plot must be a .png file's path, got TMP"),
        (
            ["--seed", "-1", "--task", "posture"],
            "--seed must be a seed, at least 0 and below 2**32, got -1",
        ),  # a schedule's seed, too
        (["--walking", "true"], "--walking was removed; give --task (TASK=stand|posture|walk; WALKING=1 is TASK=walk)"),
        (["--schedules", "0"], "--schedules was removed; give --task (TASK=stand|posture|walk; SCHEDULES=0 is"),
    ],
)
def test_bad_tracking_settings_of_eval_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    args = [arg.replace("TMP", str(tmp_path)) for arg in args]
    code, out, err = stage_cli(evaluate_stage, ["--policy", "random", "--progress", "false", *args], capsys)
    assert code == 1 and out == [] and len(err) == 1 and message.replace("TMP", str(tmp_path)) in err[0]
    assert list(tmp_path.iterdir()) == []


def test_tracking_of_the_expert_on_a_short_schedule_and_its_plot(tmp_path: Path) -> None:
    """Over a short operator episode the expert leans as commanded, its settled error is well within the tolerance
    on every field, and `plot_tracking` writes a PNG with a panel per field."""
    env = make_env(OPERATOR_STEPS)
    try:
        episode = run_episode(env, LQRExpert(), OPERATOR_SEED, task="posture")
        measure = Tracking(env.unwrapped.model, task_fields("posture"))
        result = tracking([episode], measure, env.unwrapped.dt)
        plot_tracking(episode, measure, env.unwrapped.dt, tmp_path / "tracking.png")
    finally:
        env.close()
    lean = command_schedule(OPERATOR_SEED, OPERATOR_STEPS, env.unwrapped.dt)[200]  # the seed's first command
    assert lean[:2].all() and not lean[2:].any()  # a lean forward and to the side, held until step 343
    assert episode.length == OPERATOR_STEPS and np.array_equal(episode.command[200:340], np.tile(lean, (140, 1)))
    achieved = measure.achieved(episode.observation[330:340])[:, :4]  # the posture fields Foxglove plots
    np.testing.assert_allclose(achieved, [[*lean[:2], 0, 0]] * 10, atol=0.01)
    assert set(result) == TRACKING_FIELDS | {"episodes"} and set(result["settled_error"]) == set(POSTURE_NAMES)
    assert all(0 <= error < 0.02 for error in result["settled_error"].values()), result
    assert 0 < result["settle_seconds"] < OPERATOR_STEPS * env.unwrapped.dt
    image = matplotlib.image.imread(tmp_path / "tracking.png")
    assert image.shape[:2] == (900, 800) and image.std() > 0  # 8 x 9 in at 100 dpi, not blank


def test_eval_plots_the_first_episode_without_schedules(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--plot alone: the PNG of the (zero) command and what was achieved; no tracking in the JSON."""
    path = tmp_path / "plots" / "random.png"
    args = ["--policy", "random", "--episodes", "1", "--plot", str(path), "--progress", "false", "--task", "stand"]
    code, out, _ = stage_cli(evaluate_stage, args, capsys)
    result = json.loads(out[-1])
    assert code == 0 and result["tracking"] is None and result["takes_command"] is False
    assert matplotlib.image.imread(path).shape[:2] == (900, 800)


def test_a_policy_that_falls_at_once_has_no_settled_error_and_no_warning(recwarn: pytest.WarningsRecorder) -> None:
    """Random actions fall before any command is held long enough: NaN per field, quietly."""
    result = evaluate_stage.evaluate("random", episodes=2, task="posture")
    assert all(np.isnan(error) for error in result["tracking"]["settled_error"].values())
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_eval_under_schedules_reports_tracking_and_plots_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`make eval POLICY=expert SCHEDULES=1 PLOT=...` for one whole episode: the expert survives it and tracks every
    field within the tolerance; the PNG is written."""
    path = tmp_path / "tracking.png"
    args = ["--policy", "expert", "--episodes", "1", "--seed", "1000", "--task", "posture", "--plot", str(path)]
    code, out, _ = stage_cli(evaluate_stage, [*args, "--progress", "false"], capsys)
    result = json.loads(out[-1])
    assert code == 0 and result["survival_rate"] == 1.0 and result["takes_command"] is True
    assert TRACKING_FIELDS <= set(result["tracking"]) and set(result["tracking"]["settled_error"]) == set(POSTURE_NAMES)
    assert all(0 <= error < 0.02 for error in result["tracking"]["settled_error"].values())
    assert matplotlib.image.imread(path).shape[:2] == (900, 800)


# evaluation.robustness


def test_robustness_under_schedules_adds_tracking_to_the_rows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["--policy", "expert", "--episodes", "1", "--seed", "1000", "--conditions", "clean", "--task", "posture"]
    args += ["--workers", "1", "--output", str(tmp_path), "--progress", "0"]
    code, out, _ = stage_cli(robustness, args, capsys)
    summary = json.loads(out[-1])
    row = summary["conditions"]["clean"]
    assert code == 0 and row["survival_rate"] == 1.0 and TRACKING_FIELDS <= set(row["tracking"])
    assert set(row["tracking"]["settled_error"]) == set(POSTURE_NAMES)  # the posture task's fields
    assert out[0].split() == ["condition", "survival", "mean", "return", *POSTURE_NAMES]  # the table's columns
    saved = json.loads((tmp_path / "robustness_schedules.json").read_text())  # beside the standing suite's file
    assert (
        saved["conditions"]["clean"]["tracking"] == row["tracking"] and not (tmp_path / robustness.RESULT_FILE).exists()
    )


# rl.finetune


def test_a_commanded_actor_reads_the_command_its_training_episode_follows() -> None:
    """PPO's environment for an actor on `pending+command`: the inputs' last entries are the schedule's command in
    force, zero at the neutral start and the schedule's first target after it."""
    env = training_env(None, inputs="pending+command", tracking=1.0)
    expert = LQRExpert()
    obs, info = env.reset(seed=5)
    commands = []
    for _ in range(210):  # past the 3 s neutral start
        np.testing.assert_array_equal(obs[-len(POSTURE_NAMES) :], info[COMMAND_INFO][: len(POSTURE_NAMES)])
        commands.append(info[COMMAND_INFO])
        expert.set_command(info[COMMAND_INFO])
        obs, _, terminated, _, info = env.step(expert.act(obs[:348]))
        assert not terminated
    assert not np.any(commands[0]) and np.any(commands[-1])


def test_ppo_from_a_commanded_student_scores_tracking_on_held_out_schedules(
    operated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A student on `pending+command` fine-tuned for one rollout: every evaluation scores its tracking (what the
    floor guards besides the clean return) and the final one runs held-out schedules."""
    student = tmp_path / "student"
    args = [*TINY, "--dataset", str(operated), "--policy", str(student), "--inputs", "pending+command"]
    assert stage_cli(train_stage, args, capsys)[0] == 0
    config = finetune.FinetuneConfig(bc_policy=student, policy=tmp_path / "ppo", timesteps=256, **TINY_PPO)
    result = finetune.main(config)
    assert [p["timesteps"] for p in result["training_curve"]] == [0, 256]
    assert all(0.0 <= p["tracking_score"] <= 1.0 for p in result["training_curve"])
    assert result["takes_command"] and set(result["tracking"]) >= TRACKING_FIELDS


def test_ppo_from_a_walking_student_trains_and_is_judged_on_walking_schedules(walked: Path, tmp_path: Path) -> None:
    """A student on `pending+walk`: PPO's environments draw walking schedules and reward the velocities' tracking too;
    its validation and final evaluation run held-out walking schedules and score every field."""
    env = training_env(None, inputs=PLANNER_STUDENT, tracking=1.0)
    env.reset(seed=5)
    assert env.get_wrapper_attr("task") == "walk" and env.get_wrapper_attr("commands")[:, 5:].any()
    student = tmp_path / "student"
    train_stage.main(
        train_stage.TrainConfig(
            dataset=walked, policy=student, inputs=PLANNER_STUDENT, hidden=8, epochs=1, min_updates=0, eval_episodes=0
        )
    )
    config = finetune.FinetuneConfig(bc_policy=student, policy=tmp_path / "ppo", timesteps=256, **TINY_PPO)
    result = finetune.main(config)
    assert all(0.0 <= p["tracking_score"] <= 1.0 for p in result["training_curve"])
    assert result["task"] == "walk"
    assert set(result["tracking"]["settled_error"]) == {field.name for field in task_fields("walk")}
