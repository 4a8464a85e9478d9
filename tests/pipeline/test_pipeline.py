"""`make pipeline`: each stage reuses its output only if made from the same inputs, says why it runs, refuses
to touch what someone else made, and ends with `pipeline.report.command_table`.

One tiny real pipeline runs first (2 operator episodes of 250 steps, a few BC epochs, 256 PPO steps a run, one
episode per condition of the table); each test works on a copy of its outputs, with the relative paths the configs
saved, so the copy is the same pipeline's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bc import dagger as bc_dagger
from bc import train as bc_train
from bc.dagger import SOURCE_FILE, DaggerConfig
from bc.train import TrainConfig
from common import columns, paths
from common.cli import UserError, parse_config
from humanoid.conditions import SUITE
from pipeline import report
from pipeline import run as pipeline
from pipeline.run import (
    MADE_BY,
    REMAKE,
    RESUME,
    REUSE,
    PipelineConfig,
    Stages,
    bc_decision,
    check,
    dagger_decision,
    dataset_decision,
    measure,
    ppo_decision,
    run,
    stages,
)
from policies import checkpoint
from policies.folder import CONFIG_FILE, EVAL_FILE
from rl.finetune import FinetuneConfig
from rl.scratch import ScratchConfig
from students.inputs import BLIND_INPUTS, STUDENT_INPUTS
from support import snapshot
from task.command_fields import POSTURE_NAMES
from task.tracking import ERROR_KINDS
from teleop import recordings
from teleop.dataset_reader import fingerprint, read_frames
from teleop.record import DART_NOISE, LATENCY_SHARE, RecordConfig, record

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

CONDITIONS = ["clean", "push10"]
"""The tiny run's table: two conditions, one episode each."""


def tiny_stages(
    record: dict | None = None, train: dict | None = None, ppo: dict | None = None, dagger: dict | None = None
) -> Stages:
    """The pipeline's stages at a tiny size, in the current folder (relative paths). Episodes of 250 steps: the
    schedules' first command comes after a neutral start of 3 s (200 steps); one DAgger round of one rollout, its expert
    and conditions left to their defaults as `make pipeline` leaves them (DAgger resolves them: a second run compares
    them as resolved)."""
    ppo = {
        "bc_policy": Path("dagger"),
        "scratch_policy": Path("scratch"),
        "timesteps": 256,
        "envs": 4,
        "workers": 1,
        "rollout_steps": 256,
        "batch_size": 64,
        "epochs": 1,
        "eval_freq": 256,
        "eval_episodes": 1,
        "floor_episodes": 1,
        "final_eval_episodes": 1,
        "critic_warmup": 0,
        "progress": False,
        **(ppo or {}),
    }
    record = {
        "dataset": Path("data"),
        "episodes": 2,
        "max_steps": 250,
        "controller": "expert-sensed",
        "noise": DART_NOISE,
        "latency": LATENCY_SHARE,
        "task": "posture",
        "writer": "inline",
        "progress": False,
        **(record or {}),
    }
    train = {
        "dataset": Path("data"),
        "policy": Path("bc"),
        "inputs": STUDENT_INPUTS,
        "hidden": 16,
        "epochs": 2,
        "min_updates": 0,
        "batch_size": 32,
        "eval_episodes": 1,
        "progress": False,
        **(train or {}),
    }
    dagger = {
        "dataset": Path("data"),
        "output": Path("aggregate"),
        "policy": Path("dagger"),
        "inputs": STUDENT_INPUTS,
        "noise": DART_NOISE,
        "rounds": 1,
        "episodes": 1,
        "epochs": 2,
        "min_updates": 0,
        "eval_episodes": 1,
        "progress": False,
        **(dagger or {}),
    }
    return Stages(
        record=RecordConfig(**record),
        student=TrainConfig(**train),
        blind=TrainConfig(**{**train, "policy": Path("blind"), "inputs": BLIND_INPUTS}),
        dagger=DaggerConfig(**dagger),
        scratch=ScratchConfig(policy=Path("scratch"), **ppo),
        finetune=FinetuneConfig(policy=Path("ppo"), **ppo),
    )


def run_tiny(run_stages: Stages) -> str:
    """`run(run_stages)` with the tiny table: one episode of each of CONDITIONS."""
    return run(run_stages, episodes=1, conditions=CONDITIONS)


def run_here(folder: Path, run_stages: Stages) -> list[str]:
    """`run_tiny(run_stages)` in `folder`: the lines it printed."""
    out = io.StringIO()
    cwd = Path.cwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stdout(out):
            run_tiny(run_stages)
    finally:
        os.chdir(cwd)
    return out.getvalue().splitlines()


def pipeline_lines(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("pipeline: ")]


def stage_lines(lines: list[str]) -> list[str]:
    """The lines that say what each stage does (not the table's evaluations)."""
    return [
        line for line in pipeline_lines(lines) if " on held-out schedules: " not in line and "command zero" not in line
    ]


def table_lines(lines: list[str]) -> list[str]:
    """The closing table: from its head to the end."""
    return lines[next(i for i, line in enumerate(lines) if line.startswith("| controller | standing")) :]


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """A tiny pipeline run from nothing: its folder and what it printed."""
    folder = tmp_path_factory.mktemp("pipeline")
    return folder, run_here(folder, tiny_stages())


@pytest.fixture
def outputs(first_run: tuple[Path, list[str]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the first run's outputs, made the current folder."""
    copy = tmp_path / "copy"
    shutil.copytree(first_run[0], copy)
    monkeypatch.chdir(copy)
    return copy


def edit_json(path: Path, edit: dict) -> None:
    content = json.loads(path.read_text())
    content["training"].update(edit)
    path.write_text(json.dumps(content))


def made_by_someone_else(dataset: Path) -> None:
    """recordings.jsonl as `make record` would have written it."""
    lines = [{**line, "made_by": "teleop.record"} for line in recordings.read(dataset)]
    (dataset / recordings.RECORDINGS_FILE).write_text("".join(json.dumps(line) + "\n" for line in lines))


def test_first_run_makes_every_output_saying_why(first_run: tuple[Path, list[str]]) -> None:
    """From nothing, each stage runs, one line saying so, in the order record, BC without and with the command,
    DAgger, scratch, fine-tuning; then the table's evaluations of the experts and every policy, with the command zero
    and on held-out schedules."""
    controllers = ["expert-sensed", "blind", "bc", "dagger", "ppo", "scratch"]
    assert pipeline_lines(first_run[1]) == [
        "pipeline: recording data: no dataset there yet",
        "pipeline: training blind: no checkpoint there yet",
        "pipeline: training bc: no checkpoint there yet",
        "pipeline: DAgger dagger: no checkpoint there yet",
        "pipeline: training from scratch scratch: no checkpoint there yet",
        "pipeline: fine-tuning ppo: no checkpoint there yet",
        *(f"pipeline: {name} with the command zero: 1 episodes" for name in controllers),
        *(f"pipeline: {name} on held-out schedules: 1 episodes x 2 conditions" for name in controllers),
    ]


def test_the_pipeline_records_the_operator_and_its_students_read_the_command_or_not(
    first_run: tuple[Path, list[str]],
) -> None:
    """The dataset follows schedules (its commands vary), the student reads the command, the blind one does not,
    the DAgger student reads it through the expert's ramp, labelled by the expert on leg odometry, and both PPO actors
    read the DAgger student's inputs."""
    folder = first_run[0]
    (run,) = recordings.read(folder / "data")
    assert run["config"]["task"] == "posture" and run["config"]["controller"] == "expert-sensed"
    assert len(np.unique(read_frames(folder / "data", [columns.OBS_COMMAND])[columns.OBS_COMMAND], axis=0)) > 1
    assert checkpoint.load(folder / "bc").spec.inputs == STUDENT_INPUTS
    assert checkpoint.load(folder / "blind").spec.inputs == BLIND_INPUTS
    assert checkpoint.load(folder / "dagger").spec.inputs == STUDENT_INPUTS
    assert [line["config"]["expert"] for line in recordings.read(folder / "aggregate")[1:]] == ["expert-sensed"]
    assert (
        checkpoint.load(folder / "ppo").spec.inputs == checkpoint.load(folder / "scratch").spec.inputs == STUDENT_INPUTS
    )


def test_the_table_rows_every_controller_with_survival_and_tracking_per_field(
    first_run: tuple[Path, list[str]],
) -> None:
    """The closing table: a row per controller (standing, then survivors and tracking score per condition, the mean
    return), then a row per condition and controller with the settled error of every command field."""
    table = table_lines(first_run[1])
    assert table[0] == "| controller | standing | clean | push10 | mean return |"
    assert [line.split(" | ")[0].removeprefix("| ") for line in table[2:8]] == [
        "expert-sensed",
        "blind",
        "bc",
        "dagger",
        "ppo",
        "scratch",
    ]
    assert table[2].startswith("| expert-sensed | 1/1 | 1/1 · 1.00 | ")  # the demonstrator follows the schedule
    fields = next(line for line in table if line.startswith("| condition | controller"))
    assert fields == "| condition | controller | survivors | " + " | ".join(POSTURE_NAMES) + " | settle (s) |"
    per_field = [line for line in table if line.startswith(("| clean | ", "| push10 | "))]
    assert len(per_field) == 12


def test_second_run_reuses_everything_and_prints_the_same_table(
    first_run: tuple[Path, list[str]], outputs: Path
) -> None:
    """Run again with the same inputs: nothing is made or changed (the table's evaluations on schedules reused), and
    the table is the first run's, line for line."""
    before = snapshot(outputs)
    lines = run_here(outputs, tiny_stages())
    assert stage_lines(lines) == [
        "pipeline: data holds the 2 episodes asked for, recorded so: not recording",
        "pipeline: blind was made from this dataset with these settings: not training",
        "pipeline: bc was made from this dataset with these settings: not training",
        "pipeline: dagger was made from this dataset with these settings: not DAgger",
        "pipeline: scratch was made from this BC policy with these settings: not training from scratch",
        "pipeline: ppo was made from this BC policy with these settings: not fine-tuning",
    ]
    assert sum("on held-out schedules: reusing" in line for line in lines) == 6  # every row
    assert table_lines(lines) == table_lines(first_run[1])
    assert snapshot(outputs) == before


def test_dataset_recorded_otherwise_is_recorded_again_and_everything_after_it(outputs: Path) -> None:
    """Other noise: the pipeline's own dataset is recorded again, so both BC runs on it are trained again, DAgger
    starts again from a new copy, and both PPO runs are made again."""
    lines = stage_lines(run_here(outputs, tiny_stages(record={"noise": 0.02}, dagger={"noise": 0.02})))
    assert lines == [
        "pipeline: recording data again: it was recorded with --noise 0.03, not 0.02",
        "pipeline: training blind again: it was made from another dataset",
        "pipeline: training bc again: it was made from another dataset",
        "pipeline: DAgger dagger again: it was made with --noise 0.03, not 0.02",
        "pipeline: making aggregate again: it is a copy of another dataset than data now",
        "pipeline: training from scratch scratch again: it was made from another BC policy",
        "pipeline: fine-tuning ppo again: it was made from another BC policy",
    ]
    assert [line["config"]["noise"] for line in recordings.read(Path("data"))] == [0.02]
    assert json.loads(Path("bc/dataset.json").read_text())["fingerprint"] == fingerprint(Path("data"))
    assert json.loads((Path("aggregate") / SOURCE_FILE).read_text())["fingerprint"] == fingerprint(Path("data"))


def test_other_training_setting_retrains_the_pipelines_checkpoint(outputs: Path) -> None:
    """A BC setting that differs from the saved config makes BC again, replacing it (--overwrite)."""
    decision = bc_decision(tiny_stages(train={"epochs": 3}).student, overwrite=False)
    assert (decision.action, decision.line) == (REMAKE, "training bc again: it was made with --epochs 2, not 3")
    assert decision.config.overwrite and decision.config.epochs == 3


def test_changed_dataset_retrains_bc(outputs: Path) -> None:
    """An episode added to the dataset changes its fingerprint: BC, trained on the old one, is made again."""
    record(dataclasses.replace(tiny_stages().record, episodes=1))
    decision = bc_decision(tiny_stages().student, overwrite=False)
    assert (decision.action, decision.line) == (REMAKE, "training bc again: it was made from another dataset")


def test_retrained_dagger_student_makes_the_ppo_runs_again(outputs: Path) -> None:
    """PPO runs record the weights they started from: the DAgger student trained again on its aggregate (one epoch,
    nothing rolled out: its round is there), new weights, new runs."""
    bc_dagger.main(tiny_stages(dagger={"epochs": 1, "overwrite": True}).dagger)
    for config in (tiny_stages().scratch, tiny_stages().finetune):
        assert ppo_decision(config, "--ppo.policy", overwrite=False).line.endswith("it was made from another BC policy")


def test_speed_settings_are_not_compared(outputs: Path) -> None:
    """Worker counts, threads and progress bars change no output, so they are no reason to make one again."""
    speed = {"workers": 2, "update_threads": 1, "progress": True}
    assert ppo_decision(tiny_stages(ppo=speed).finetune, "--ppo.policy", overwrite=False).action == REUSE
    assert dataset_decision(tiny_stages(record={"workers": 2, "writer": "process"}).record).action == REUSE


def edit_recordings(dataset: Path, edit: Callable[[dict], None]) -> None:
    """Apply `edit` to the config of every line of `dataset`'s recordings.jsonl."""
    lines = recordings.read(dataset)
    for line in lines:
        edit(line["config"])
    (dataset / recordings.RECORDINGS_FILE).write_text("".join(json.dumps(line) + "\n" for line in lines))


def test_outputs_made_before_a_setting_existed_are_made_again(outputs: Path) -> None:
    """A recording or checkpoint whose saved settings lack one of this version's was made by an older version: the
    pipeline makes its own again, saying so (docs/decisions/added-since.md)."""
    edit_recordings(outputs / "data", lambda config: config.pop("randomize"))
    decision = dataset_decision(tiny_stages().record)
    assert (decision.action, decision.line) == (
        REMAKE,
        "recording data again: it was recorded with no --randomize (an older version)",
    )
    config = json.loads((outputs / "bc" / CONFIG_FILE).read_text())
    del config["training"]["min_updates"]
    (outputs / "bc" / CONFIG_FILE).write_text(json.dumps(config))
    decision = bc_decision(tiny_stages().student, overwrite=False)
    assert decision.line == "training bc again: it was made with no --min-updates (an older version)"


def test_randomised_dataset_is_recorded_again(outputs: Path) -> None:
    """The pipeline records without randomisation: its dataset recorded with --randomize is not what it asks for."""
    edit_recordings(outputs / "data", lambda config: config.update(randomize="suite"))
    decision = dataset_decision(tiny_stages().record)
    assert (decision.action, decision.line) == (
        REMAKE,
        "recording data again: it was recorded with --randomize suite, not none",
    )


def test_dataset_with_an_older_sensed_layout_is_recorded_again(outputs: Path) -> None:
    """A dataset recorded before the feet's force sensors joined observation.state cannot train the sensed
    students: the pipeline records its own again."""
    info_path = outputs / "data" / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    state = info["features"]["observation.state"]
    state["names"], state["shape"] = state["names"][:42], [42]
    info_path.write_text(json.dumps(info))
    decision = dataset_decision(tiny_stages().record)
    assert (decision.action, decision.line) == (
        REMAKE,
        "recording data again: it records 42 sensed features as observation.state, not this version's 48",
    )


def test_checkpoint_without_its_evaluation_is_made_again(outputs: Path) -> None:
    """A run stopped during its final evaluation left no eval.json: the table needs it, so BC is made again."""
    (outputs / "bc" / EVAL_FILE).unlink()
    decision = bc_decision(tiny_stages().student, overwrite=False)
    assert (decision.action, decision.line) == (
        REMAKE,
        f"training bc again: it has no {EVAL_FILE} (its evaluation did not finish)",
    )


def test_a_checkpoint_made_without_an_evaluation_needs_none(outputs: Path) -> None:
    """The pipeline's BC and DAgger stages skip their own evaluation (the table evaluates every controller on the same
    seeds): a checkpoint made so has no eval.json and is reused."""
    (outputs / "bc" / EVAL_FILE).unlink()
    edit_json(outputs / "bc" / CONFIG_FILE, {"eval_episodes": 0})
    assert bc_decision(tiny_stages(train={"eval_episodes": 0}).student, overwrite=False).action == REUSE


def assert_refused_untouched(outputs: Path, stages: Stages, message: str) -> None:
    """Running `stages` fails with exactly `message` and changes nothing under `outputs`."""
    before = snapshot(outputs)
    with pytest.raises(UserError) as refusal:
        run_tiny(stages)
    assert str(refusal.value) == message
    assert snapshot(outputs) == before


def test_user_recorded_dataset_that_differs_is_refused_and_left_alone(outputs: Path) -> None:
    """A dataset `make record` made with other settings: one line naming the setting, nothing touched."""
    made_by_someone_else(outputs / "data")
    assert_refused_untouched(
        outputs,
        tiny_stages(record={"noise": 0.02}),
        "data was recorded with --noise 0.03, not 0.02, and the pipeline did not record it: it is left as it is "
        "(ask for what it holds, or choose another --record.dataset)",
    )


def test_user_recorded_dataset_with_the_same_settings_is_used(outputs: Path) -> None:
    """What `make record` recorded with the pipeline's settings is what the pipeline would record: reused."""
    made_by_someone_else(outputs / "data")
    assert dataset_decision(tiny_stages().record).action == REUSE


def test_user_made_checkpoint_downstream_is_refused_before_anything_runs(outputs: Path) -> None:
    """DAgger would be made again, so PPO would too; a PPO run the pipeline did not make is refused before anything
    trains."""
    edit_json(outputs / "ppo" / CONFIG_FILE, {"made_by": "rl.finetune"})
    assert_refused_untouched(
        outputs,
        tiny_stages(dagger={"epochs": 3}),
        "ppo was made from the BC policy the pipeline makes again, and the pipeline did not make it: it is left as "
        "it is (--overwrite true, OVERWRITE=1 with make, replaces it; or choose another --ppo.policy)",
    )


def test_overwrite_lets_the_pipeline_replace_a_user_made_checkpoint(outputs: Path) -> None:
    """With --overwrite true a differing checkpoint made by `make train-bc` is made again like the pipeline's own."""
    edit_json(outputs / "bc" / CONFIG_FILE, {"made_by": "bc.train"})
    with pytest.raises(UserError):
        bc_decision(tiny_stages(train={"epochs": 3}).student, overwrite=False)
    assert bc_decision(tiny_stages(train={"epochs": 3}).student, overwrite=True).action == REMAKE


def test_folder_that_is_not_a_checkpoint_is_refused(outputs: Path) -> None:
    """Something else at a checkpoint's place is never replaced."""
    shutil.rmtree(outputs / "scratch")
    (outputs / "scratch").mkdir()
    (outputs / "scratch" / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="scratch is not a policy checkpoint"):
        ppo_decision(tiny_stages().scratch, "--scratch-policy", overwrite=False)


def test_interrupted_recording_is_completed_into_the_same_dataset(outputs: Path, tmp_path: Path) -> None:
    """The pipeline's dataset holding the first episodes asked for gets the rest: the dataset one recording makes."""
    decision = dataset_decision(tiny_stages(record={"episodes": 3}).record)
    assert (decision.action, decision.line) == (
        RESUME,
        "data holds 2 of the 3 episodes asked for: recording the other 1",
    )
    assert (decision.config.episodes, decision.config.seed) == (1, 2)
    record(decision.config, made_by=MADE_BY)
    fresh = tiny_stages(record={"episodes": 3, "dataset": tmp_path / "fresh"}).record
    record(fresh)
    assert fingerprint(Path("data")) == fingerprint(fresh.dataset)
    assert dataset_decision(tiny_stages(record={"episodes": 3}).record).action == REUSE


def test_a_recording_killed_with_9_is_completed_too(outputs: Path) -> None:
    """A pipeline recording killed with -9 left its mark and no recordings.jsonl line: the pipeline still knows its
    episodes, records the rest, and the resumed recording logs the killed one."""
    data = Path("data")
    (line,) = recordings.read(data)
    (data / recordings.RECORDINGS_FILE).unlink()
    recordings.mark(data, line["made_by"], {**line["config"], "episodes": 3}, episodes=0)
    decision = dataset_decision(tiny_stages(record={"episodes": 3}).record)
    assert (decision.action, decision.line) == (
        RESUME,
        "data holds 2 of the 3 episodes asked for: recording the other 1",
    )
    record(decision.config, made_by=MADE_BY)
    assert [(run["complete"], run["episodes"]) for run in recordings.read(data)] == [(False, [0, 1]), (True, [2, 2])]
    assert dataset_decision(tiny_stages(record={"episodes": 3}).record).action == REUSE


def test_an_unset_teacher_or_latency_is_compared_as_it_records(outputs: Path) -> None:
    """Unset, the recording's teacher and share of delayed episodes are its task's (`teleop.record.effective`), which
    recordings.jsonl saves: what `make record` recorded on its defaults is what the pipeline asks for on its own, and
    the pipeline's own recording is reused by its next run rather than made again."""
    made_by_someone_else(outputs / "data")
    assert dataset_decision(tiny_stages(record={"controller": None, "latency": None}).record).action == REUSE


def test_pipeline_defaults_are_the_stages() -> None:
    """Unset, every stage is its target's defaults (`make record`, `make train-bc`, ...), tied as they chain, without
    the evaluations the stages make of their own after training (the table's); the blind student is the student
    without the command, PPO from scratch the fine-tuning's settings with the guards off."""
    student = TrainConfig(eval_episodes=0)
    finetune = FinetuneConfig(bc_policy=paths.DAGGER_POLICY, final_eval_episodes=0)
    assert stages(PipelineConfig()) == Stages(
        RecordConfig(),
        student,
        dataclasses.replace(student, policy=paths.BLIND_POLICY, inputs=BLIND_INPUTS),
        DaggerConfig(eval_episodes=0, randomize=RecordConfig().randomize, latency=RecordConfig().latency),
        ScratchConfig(bc_policy=paths.DAGGER_POLICY, final_eval_episodes=0),
        finetune,
    )
    assert check(PipelineConfig()) == list(SUITE)


def test_the_stage_targets_chain_on_their_defaults() -> None:
    """Each stage reads what the one before it writes: the recording's dataset is the students', the DAgger student
    is PPO's start, and what `make eval` takes is the newest of the chain's policies."""
    assert RecordConfig().dataset == TrainConfig().dataset == DaggerConfig().dataset == paths.DATASET
    assert TrainConfig().policy in paths.STUDENTS and DaggerConfig().policy in paths.STUDENTS
    assert TrainConfig().inputs == DaggerConfig().inputs == STUDENT_INPUTS
    assert str(FinetuneConfig().bc_policy) == paths.NEWEST and FinetuneConfig().policy in paths.LEARNED


def test_ppo_from_the_blind_student_makes_both_ppo_runs_again_with_its_actor(outputs: Path) -> None:
    """Switching the PPO stages' start remakes them (their --bc-policy differs), and the fine-tuned actor then
    reads what that student reads."""
    lines = stage_lines(run_here(outputs, tiny_stages(ppo={"bc_policy": Path("blind")})))
    assert lines[-2:] == [
        "pipeline: training from scratch scratch again: it was made with --bc-policy dagger, not blind",
        "pipeline: fine-tuning ppo again: it was made with --bc-policy dagger, not blind",
    ]
    assert checkpoint.load(Path("ppo")).spec.inputs == BLIND_INPUTS


def test_remade_student_is_foreseen_to_make_ppo_again(outputs: Path) -> None:
    """A dataset recorded again remakes the student, so a PPO run the pipeline did not make is refused before
    anything runs."""
    edit_json(outputs / "ppo" / CONFIG_FILE, {"made_by": "rl.finetune"})
    run_stages = tiny_stages(record={"noise": 0.02})
    assert_refused_untouched(
        outputs,
        run_stages,
        "ppo was made from the BC policy the pipeline makes again, and the pipeline did not make it: it is left as "
        "it is (--overwrite true, OVERWRITE=1 with make, replaces it; or choose another --ppo.policy)",
    )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--record.episodes", "1"], "--record.episodes must be at least 2"),
        (["--robustness-episodes", "0"], "--robustness-episodes must be at least 1"),
        (["--conditions", "clean,gale"], "unknown condition 'gale'"),
        (["--record.latency", "0"], "--record.latency 0: the students read pending's inputs, which learn to act"),
        (["--bc.dataset", "elsewhere"], "--bc.dataset elsewhere: the pipeline ties it to --record.dataset"),
        (["--ppo.bc-policy", "blind"], "--ppo.bc-policy blind: the pipeline ties it to --dagger.policy"),
        (["--ppo.scratch-policy", "x"], "--ppo.scratch-policy x: the pipeline ties it to --scratch-policy"),
        (["--record.task", "stand"], "--record.task stand: the students learn to follow the operator's"),
        (["--record.controller", "keyboard"], "--record.controller keyboard: the students learn to follow"),
    ],
)
def test_bad_pipeline_settings_are_refused_naming_them(argv: list[str], message: str) -> None:
    """The pipeline's own settings and its ties between the stages: one message naming the flag, before any stage
    is planned."""
    with pytest.raises(UserError) as refusal:
        stages(parse_config(PipelineConfig, argv, ""))
    assert str(refusal.value).startswith(message) and "\n" not in str(refusal.value)


def test_a_dataset_folder_holding_something_else_is_refused_before_anything_runs(
    outputs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """RECORD.DATASET naming a folder of the user's files: refused before the first stage says a word, untouched."""
    (outputs / "mine").mkdir()
    (outputs / "mine" / "notes.txt").write_text("keep")
    assert_refused_untouched(
        outputs,
        tiny_stages(record={"dataset": Path("mine")}),
        "mine is not empty and holds no LeRobot dataset (no meta/info.json); choose an empty or new folder",
    )
    assert capsys.readouterr().out == ""


def test_two_outputs_in_one_folder_are_refused_before_anything_runs(outputs: Path) -> None:
    """BLIND_POLICY naming BC.POLICY would train two students into one folder: one line, nothing touched."""
    run_stages = tiny_stages()
    run_stages.blind.policy = Path("bc")
    assert_refused_untouched(
        outputs, run_stages, "--bc.policy and --blind-policy both name bc: each output needs its own folder"
    )


def test_nested_settings_reach_their_stages() -> None:
    """`make pipeline RECORD.EPISODES=3 BC.EPOCHS=4 WORKERS=1 ARGS="--ppo.target-kl 0.01"`: each stage setting
    reaches its stage (the blind student takes the student's, PPO from scratch the fine-tuning's but its own
    guards), the recording's noise DAgger's rounds, WORKERS every stage that has workers."""
    argv = ["--record.episodes", "3", "--record.noise", "0.01", "--bc.epochs", "4", "--workers", "1"]
    run_stages = stages(
        parse_config(PipelineConfig, [*argv, "--ppo.target-kl", "0.01", "--ppo.eval-episodes", "2"], "")
    )
    assert (run_stages.record.episodes, run_stages.record.workers, run_stages.record.noise) == (3, 1, 0.01)
    assert (run_stages.student.epochs, run_stages.blind.epochs) == (4, 4)
    assert (run_stages.dagger.noise, run_stages.dagger.workers) == (0.01, 1)
    for config in (run_stages.scratch, run_stages.finetune):
        assert (config.workers, config.target_kl, config.eval_episodes) == (1, 0.01, 2)
    assert run_stages.scratch.learning_rate == ScratchConfig().learning_rate  # each keeps its own guards


def table_suite(conditions: list[str]) -> dict:
    """The table's suite of the checkpoint "bc" (1 episode per condition, in this process)."""
    return measure(["bc"], 1, conditions, workers=1)[1]["bc"]


def test_the_table_reuses_evaluations_made_after_the_policy_only(
    outputs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A policy's results on schedules are reused while they are newer than its weights and hold the conditions
    and the errors asked for; other conditions, an older version's file (without an error the table prints), a file
    cut short, or weights trained since, run them again."""
    first = table_suite(CONDITIONS)
    assert "reusing" in capsys.readouterr().out
    saved = Path("bc") / "robustness_schedules.json"
    older = json.loads(saved.read_text())
    for row in older["conditions"].values():
        del row["tracking"]["moved_error"]
    saved.write_text(json.dumps(older))
    assert set(ERROR_KINDS) <= set(table_suite(CONDITIONS)["conditions"]["clean"]["tracking"])
    assert "reusing" not in capsys.readouterr().out
    saved.write_text(saved.read_text()[:100])  # cut short (written before it was written whole)
    assert table_suite(CONDITIONS)["seeds"] == first["seeds"]
    assert "reusing" not in capsys.readouterr().out
    assert table_suite(["clean"])["conditions"].keys() == {"clean"}
    assert "reusing" not in capsys.readouterr().out
    bc_train.main(tiny_stages(train={"epochs": 1, "overwrite": True}).student)
    capsys.readouterr()
    assert table_suite(CONDITIONS)["seeds"] == first["seeds"]
    assert "reusing" not in capsys.readouterr().out


def test_the_table_known_answer() -> None:
    """Known answer: survivors out of episodes, the tracking score of the settled errors (each at its tolerance:
    exp(-1) = 0.37), the mean return over the conditions (1,000 and 3,000: 2,000.0), each field's error over every
    command and over those that moved it (twice the tolerance; n/a where none did), n/a for a field never settled."""
    at_tolerance = {"lean_forward": 0.05, "lean_left": 0.05, "height": 0.02, "twist": 0.05, "arms": 0.1}
    moved = {**{name: 2 * error for name, error in at_tolerance.items()}, "height": float("nan")}
    never = dict.fromkeys(POSTURE_NAMES, float("nan"))
    tracked = {
        "p": {
            "seeds": [1000, 1001],
            "conditions": {
                "clean": {
                    "survival_rate": 1.0,
                    "mean_return": 3000.0,
                    "episodes": 2,
                    "tracking": {"settled_error": at_tolerance, "moved_error": moved, "settle_seconds": 1.5},
                },
                "push10": {
                    "survival_rate": 0.5,
                    "mean_return": 1000.0,
                    "episodes": 2,
                    "tracking": {"settled_error": never, "moved_error": never, "settle_seconds": float("nan")},
                },
            },
        }
    }
    lines = report.command_table({"p": {"survival_rate": 0.5, "episodes": 2}}, tracked).splitlines()
    assert lines[2] == "| p | 1/2 | 2/2 · 0.37 | 1/2 · 0.00 | 2,000.0 |"
    assert (
        "| clean | p | 2/2 | 0.050 / 0.100 | 0.050 / 0.100 | 0.020 / n/a | 0.050 / 0.100 | 0.100 / 0.200 | 1.50 |"
        in lines
    )
    assert "| push10 | p | 1/2 | n/a / n/a | n/a / n/a | n/a / n/a | n/a / n/a | n/a / n/a | n/a |" in lines


def test_a_lost_dagger_student_is_trained_again_from_its_aggregate(
    outputs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The DAgger checkpoint deleted, its aggregate intact: the pipeline trains it again from the rounds there,
    rolling nothing out, and leaves the aggregate as it was."""
    before = fingerprint(Path("aggregate"))
    shutil.rmtree("dagger")
    pipeline.dagger_stage(tiny_stages().dagger, overwrite=False)
    assert pipeline_lines(capsys.readouterr().out.splitlines()) == ["pipeline: DAgger dagger: no checkpoint there yet"]
    assert fingerprint(Path("aggregate")) == before
    assert dagger_decision(tiny_stages().dagger, overwrite=False).action == REUSE


def test_an_aggregate_someone_else_made_is_refused_and_left_alone(outputs: Path) -> None:
    """DAgger's aggregate copied by `make dagger`, with rounds of other settings than the pipeline asks: one line,
    nothing touched."""
    source = json.loads((outputs / "aggregate" / SOURCE_FILE).read_text())
    (outputs / "aggregate" / SOURCE_FILE).write_text(json.dumps({**source, "made_by": "bc.dagger"}))
    assert_refused_untouched(
        outputs,
        tiny_stages(dagger={"rounds": 2}),
        "aggregate holds rounds rolled out with --rounds 1, and the pipeline did not make it: it is left as it is "
        "(choose another --dagger.output)",
    )
