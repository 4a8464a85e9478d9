"""`make pipeline`: each stage reuses its output only if made from the same inputs, says why it runs, refuses
to touch what someone else made, and ends with `bc.report`'s table.

One tiny real pipeline runs first (2 episodes, a few BC epochs, 256 PPO steps a run); each test works on a
copy of its outputs, with the relative paths the configs saved, so the copy is the same pipeline's.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from bc import report, tutorial
from bc import train as bc_train
from bc.baseline import BaselineConfig
from bc.finetune import FinetuneConfig
from bc.pipeline import (
    MADE_BY,
    REMAKE,
    RESUME,
    REUSE,
    Deployable,
    PipelineConfig,
    Stages,
    bc_decision,
    dataset_decision,
    ppo_decision,
    run,
    stages,
    suite,
)
from bc.train import TrainConfig
from bc.tutorial import TutorialConfig
from common import paths
from common.cli import UserError
from humanoid.conditions import SUITE
from policies import checkpoint
from policies.folder import CONFIG_FILE, EVAL_FILE, WEIGHTS_FILE
from support import snapshot
from teleop import recordings
from teleop.dataset_reader import fingerprint
from teleop.record import SENSED_LATENCY, SENSED_NOISE, RecordConfig, record

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

TUTORIAL_LINE = (
    "pipeline: the tutorial's learners: tutorial_preferred, tutorial_ppo (reused if finished; "
    "trained beside the others)"
)


def tiny_stages(record: dict | None = None, train: dict | None = None, ppo: dict | None = None) -> Stages:
    """The pipeline's stages at a tiny size, in the current folder (relative paths)."""
    ppo = {
        "bc_policy": Path("bc"),
        "baseline": Path("scratch"),
        "timesteps": 256,
        "envs": 4,
        "workers": 1,
        "rollout_steps": 256,
        "batch_size": 64,
        "epochs": 1,
        "eval_freq": 256,
        "eval_episodes": 1,
        "final_eval_episodes": 1,
        "critic_warmup": 0,
        "progress": False,
        **(ppo or {}),
    }
    record = {
        "dataset": Path("data"),
        "episodes": 2,
        "max_steps": 40,
        "writer": "inline",
        "progress": False,
        **(record or {}),
    }
    train = {
        "dataset": Path("data"),
        "policy": Path("bc"),
        "hidden": 16,
        "epochs": 2,
        "min_updates": 0,
        "batch_size": 32,
        "eval_episodes": 1,
        "tensorboard": False,
        "progress": False,
        **(train or {}),
    }
    sensed = {
        **record,
        "dataset": Path("sensed"),
        "controller": "expert-sensed",
        "noise": SENSED_NOISE,
        "latency": SENSED_LATENCY,
    }
    return Stages(
        record=RecordConfig(**record),
        train=TrainConfig(**train),
        deployable=Deployable(
            proprio=TrainConfig(**{**train, "policy": Path("bc_proprio"), "inputs": "proprio"}),
            record=RecordConfig(**sensed),
            odometry=TrainConfig(
                **{**train, "dataset": Path("sensed"), "policy": Path("bc_odometry"), "inputs": "pending"}
            ),
        ),
        baseline=BaselineConfig(policy=Path("scratch"), **ppo),
        finetune=FinetuneConfig(policy=Path("ppo"), **ppo),
        tutorial=TutorialConfig(
            preferred_policy=Path("tutorial_preferred"),
            ppo_policy=Path("tutorial_ppo"),
            timesteps=64,
            final_eval_episodes=1,
            progress=False,
        ),
    )


def run_here(folder: Path, run_stages: Stages) -> list[str]:
    """`run(run_stages)` in `folder`: the lines it printed."""
    out = io.StringIO()
    cwd = Path.cwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stdout(out):
            run(run_stages)
    finally:
        os.chdir(cwd)
    return out.getvalue().splitlines()


def pipeline_lines(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("pipeline: ")]


def report_table() -> list[str]:
    """What `python -m bc.report` prints for every policy of the pipeline, in the current folder."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        policies = ["bc", "bc_proprio", "bc_odometry", "ppo", "scratch", "tutorial_preferred", "tutorial_ppo"]
        assert report.main(policies) == 0
    return out.getvalue().splitlines()


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
    """From nothing, each stage runs, one line saying so, in the order record, BC, the deployable BC policies,
    scratch, fine-tuning."""
    assert pipeline_lines(first_run[1]) == [
        TUTORIAL_LINE,
        "pipeline: recording data: no dataset there yet",
        "pipeline: training bc: no checkpoint there yet",
        "pipeline: training bc_proprio: no checkpoint there yet",
        "pipeline: recording sensed: no dataset there yet",
        "pipeline: training bc_odometry: no checkpoint there yet",
        "pipeline: training from scratch scratch: no checkpoint there yet",
        "pipeline: fine-tuning ppo: no checkpoint there yet",
    ]


def test_first_run_prints_a_summary_line_per_tutorial_learner(first_run: tuple[Path, list[str]]) -> None:
    """Each learner trained says what it cost and how it stood, as the other stages' summary lines do."""
    summaries = [line for line in first_run[1] if line.startswith(("tutorial_preferred: ", "tutorial_ppo: "))]
    assert [line.split(":")[0] for line in summaries] == ["tutorial_preferred", "tutorial_ppo"]
    assert all(" steps in " in line and "survival" in line for line in summaries)


def test_tutorial_learners_trained_beside_the_others_are_those_a_run_of_their_own_makes(
    first_run: tuple[Path, list[str]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The learners train in a process of their own (`bc.background`); what they make does not depend on it."""
    monkeypatch.chdir(tmp_path)
    alone = tutorial.main(tiny_stages().tutorial, MADE_BY)
    for learner, folder in (("preferred", "tutorial_preferred"), ("ppo", "tutorial_ppo")):
        beside = json.loads((first_run[0] / folder / EVAL_FILE).read_text())
        assert beside["returns"] == alone[learner]["returns"]
    assert (first_run[0] / "tutorial_preferred" / WEIGHTS_FILE).read_bytes() == Path(
        "tutorial_preferred", WEIGHTS_FILE
    ).read_bytes()


def test_second_run_reuses_everything_and_prints_the_reports_table(outputs: Path) -> None:
    """Run again with the same inputs: nothing is made or changed, and the table is `bc.report`'s, line for line."""
    before = snapshot(outputs)
    lines = run_here(outputs, tiny_stages())
    assert pipeline_lines(lines) == [
        TUTORIAL_LINE,
        "pipeline: data holds the 2 episodes asked for, recorded so: not recording",
        "pipeline: bc was made from this dataset with these settings: not training",
        "pipeline: bc_proprio was made from this dataset with these settings: not training",
        "pipeline: sensed holds the 2 episodes asked for, recorded so: not recording",
        "pipeline: bc_odometry was made from this dataset with these settings: not training",
        "pipeline: scratch was made from this BC policy with these settings: not training from scratch",
        "pipeline: ppo was made from this BC policy with these settings: not fine-tuning",
    ]
    assert lines[len(pipeline_lines(lines)) :] == report_table()
    assert snapshot(outputs) == before


def test_dataset_recorded_otherwise_is_recorded_again_and_everything_after_it(outputs: Path) -> None:
    """Other noise: the pipeline's own dataset is recorded again, so both BC runs on it are trained again, so both
    PPO runs are; the sensed expert's dataset is another dataset, and stays."""
    lines = pipeline_lines(run_here(outputs, tiny_stages(record={"noise": 0.02})))
    assert lines == [
        TUTORIAL_LINE,
        "pipeline: recording data again: it was recorded with --noise 0.05, not 0.02",
        "pipeline: training bc again: it was made from another dataset",
        "pipeline: training bc_proprio again: it was made from another dataset",
        "pipeline: sensed holds the 2 episodes asked for, recorded so: not recording",
        "pipeline: bc_odometry was made from this dataset with these settings: not training",
        "pipeline: training from scratch scratch again: it was made from another BC policy",
        "pipeline: fine-tuning ppo again: it was made from another BC policy",
    ]
    assert [line["config"]["noise"] for line in recordings.read(Path("data"))] == [0.02]
    assert json.loads(Path("bc/dataset.json").read_text())["fingerprint"] == fingerprint(Path("data"))


def test_other_training_setting_retrains_the_pipelines_checkpoint(outputs: Path) -> None:
    """A BC setting that differs from the saved config makes BC again, replacing it (--overwrite)."""
    decision = bc_decision(tiny_stages(train={"epochs": 3}).train, overwrite=False)
    assert (decision.action, decision.line) == (REMAKE, "training bc again: it was made with --epochs 2, not 3")
    assert decision.config.overwrite and decision.config.epochs == 3


def test_changed_dataset_retrains_bc(outputs: Path) -> None:
    """An episode added to the dataset changes its fingerprint: BC, trained on the old one, is made again."""
    record(RecordConfig(dataset=Path("data"), episodes=1, max_steps=40, writer="inline", progress=False))
    decision = bc_decision(tiny_stages().train, overwrite=False)
    assert (decision.action, decision.line) == (REMAKE, "training bc again: it was made from another dataset")


def test_retrained_bc_policy_makes_the_ppo_runs_again(outputs: Path) -> None:
    """PPO runs record the BC weights they started from: new weights, new runs."""
    bc_train.main(tiny_stages(train={"epochs": 1, "overwrite": True}).train)
    for config in (tiny_stages().baseline, tiny_stages().finetune):
        assert ppo_decision(config, "--ppo-policy", overwrite=False).line.endswith("it was made from another BC policy")


def test_speed_settings_are_not_compared(outputs: Path) -> None:
    """Worker counts, threads and progress bars change no output, so they are no reason to make one again."""
    speed = {"workers": 2, "update_threads": 1, "progress": True}
    assert ppo_decision(tiny_stages(ppo=speed).finetune, "--ppo-policy", overwrite=False).action == REUSE
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
    decision = bc_decision(tiny_stages().train, overwrite=False)
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
    decision = bc_decision(tiny_stages().train, overwrite=False)
    assert (decision.action, decision.line) == (
        REMAKE,
        f"training bc again: it has no {EVAL_FILE} (its evaluation did not finish)",
    )


def assert_refused_untouched(outputs: Path, stages: Stages, message: str) -> None:
    """Running `stages` fails with exactly `message` and changes nothing under `outputs`."""
    before = snapshot(outputs)
    with pytest.raises(UserError) as refusal:
        run(stages)
    assert str(refusal.value) == message
    assert snapshot(outputs) == before


def test_user_recorded_dataset_that_differs_is_refused_and_left_alone(outputs: Path) -> None:
    """A dataset `make record` made with other settings: one line naming the setting, nothing touched."""
    made_by_someone_else(outputs / "data")
    assert_refused_untouched(
        outputs,
        tiny_stages(record={"noise": 0.02}),
        "data was recorded with --noise 0.05, not 0.02, and the pipeline did not record it: it is left as it is "
        "(ask for what it holds, or choose another --dataset)",
    )


def test_user_recorded_dataset_with_the_same_settings_is_used(outputs: Path) -> None:
    """What `make record` recorded with the pipeline's settings is what the pipeline would record: reused."""
    made_by_someone_else(outputs / "data")
    assert dataset_decision(tiny_stages().record).action == REUSE


def test_user_made_checkpoint_downstream_is_refused_before_anything_runs(outputs: Path) -> None:
    """BC would be made again, so PPO would too; a PPO run the pipeline did not make is refused before BC trains."""
    edit_json(outputs / "ppo" / CONFIG_FILE, {"made_by": "bc.finetune"})
    assert_refused_untouched(
        outputs,
        tiny_stages(train={"epochs": 3}),
        "ppo was made from the BC policy the pipeline makes again, and the pipeline did not make it: it is left as "
        "it is (--overwrite true replaces it; or choose another --ppo-policy)",
    )


def test_overwrite_lets_the_pipeline_replace_a_user_made_checkpoint(outputs: Path) -> None:
    """With --overwrite true a differing checkpoint made by `make train-bc` is made again like the pipeline's own."""
    edit_json(outputs / "bc" / CONFIG_FILE, {"made_by": "bc.train"})
    with pytest.raises(UserError):
        bc_decision(tiny_stages(train={"epochs": 3}).train, overwrite=False)
    assert bc_decision(tiny_stages(train={"epochs": 3}).train, overwrite=True).action == REMAKE


def test_folder_that_is_not_a_checkpoint_is_refused(outputs: Path) -> None:
    """Something else at a checkpoint's place is never replaced."""
    shutil.rmtree(outputs / "scratch")
    (outputs / "scratch").mkdir()
    (outputs / "scratch" / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="scratch is not a policy checkpoint"):
        ppo_decision(tiny_stages().baseline, "--scratch-policy", overwrite=False)


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


def test_pipeline_defaults_are_the_stages() -> None:
    """Unset, every pipeline setting is the stage's own default: the same configs as `make <stage>` alone."""
    assert stages(PipelineConfig()) == Stages(
        RecordConfig(),
        TrainConfig(),
        BaselineConfig(),
        FinetuneConfig(),
        TutorialConfig(timesteps=FinetuneConfig().timesteps),
        Deployable(
            TrainConfig(policy=paths.PROPRIO_POLICY, inputs="proprio"),
            RecordConfig(
                dataset=paths.SENSED_DATASET, controller="expert-sensed", noise=SENSED_NOISE, latency=SENSED_LATENCY
            ),
            TrainConfig(dataset=paths.SENSED_DATASET, policy=paths.ODOMETRY_POLICY, inputs="pending"),
        ),
    )


def test_ppo_starts_from_the_odometry_student_by_default() -> None:
    """Fine-tuning refines the actor on what a robot senses, and scratch takes its shape and normalisation."""
    run_stages = stages(PipelineConfig())
    assert run_stages.baseline.bc_policy == run_stages.finetune.bc_policy == paths.ODOMETRY_POLICY


def test_ppo_from_the_odometry_student_makes_both_ppo_runs_again_with_the_students_actor(outputs: Path) -> None:
    """Switching the PPO stages' start remakes them (their --bc-policy differs), and the fine-tuned actor then
    reads what the student reads."""
    lines = pipeline_lines(run_here(outputs, tiny_stages(ppo={"bc_policy": Path("bc_odometry")})))
    assert lines[-2:] == [
        "pipeline: training from scratch scratch again: it was made with --bc-policy bc, not bc_odometry",
        "pipeline: fine-tuning ppo again: it was made with --bc-policy bc, not bc_odometry",
    ]
    assert checkpoint.load(Path("ppo")).spec.inputs == "pending"


def test_remade_odometry_student_is_foreseen_to_make_ppo_again(outputs: Path) -> None:
    """PPO from the odometry student: a sensed dataset recorded again remakes the student, so a PPO run the
    pipeline did not make is refused before anything runs (the BC_POLICY chain is not what it depends on)."""
    edit_json(outputs / "ppo" / CONFIG_FILE, {"made_by": "bc.finetune"})
    run_stages = tiny_stages(ppo={"bc_policy": Path("bc_odometry")})
    run_stages.deployable.record.noise = 0.02
    assert_refused_untouched(
        outputs,
        run_stages,
        "ppo was made from the BC policy the pipeline makes again, and the pipeline did not make it: it is left as "
        "it is (--overwrite true replaces it; or choose another --ppo-policy)",
    )


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"episodes": 1}, "--episodes must be at least 2"),
        ({"robustness_episodes": -1}, "--robustness-episodes must be >= 0"),
        ({"sensed_noise": -1.0}, "--sensed-noise must be >= 0"),
        ({"sensed_latency": 3.0}, "--sensed-latency must be a share in [0, 1]"),
        (
            {"args": "--bogus"},
            "--args '--bogus' holds something other than flags of python -m bc.baseline: unrecognized",
        ),
        ({"args": "--keep last"}, "--args '--keep last': --keep was removed; the run keeps the guarded actor"),
    ],
)
def test_bad_pipeline_settings_are_refused_naming_them(settings: dict, message: str) -> None:
    """Settings of the pipeline's own: one message naming the pipeline's flag, before any stage is planned."""
    with pytest.raises(UserError) as refusal:
        stages(PipelineConfig(**settings))
    assert str(refusal.value).startswith(message) and "\n" not in str(refusal.value)


def test_a_dataset_folder_holding_something_else_is_refused_before_anything_runs(
    outputs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """DATASET naming a folder of the user's files: refused before the first stage says a word, untouched."""
    (outputs / "mine").mkdir()
    (outputs / "mine" / "notes.txt").write_text("keep")
    assert_refused_untouched(
        outputs,
        tiny_stages(record={"dataset": Path("mine")}),
        "mine is not empty and holds no LeRobot dataset (no meta/info.json); choose an empty or new folder",
    )
    assert capsys.readouterr().out == ""


def test_two_outputs_in_one_folder_are_refused_before_anything_runs(outputs: Path) -> None:
    """SENSED_DATASET naming DATASET would record two experts into one dataset: one line, nothing touched."""
    run_stages = tiny_stages()
    run_stages.deployable.record.dataset = Path("data")
    assert_refused_untouched(
        outputs, run_stages, "--dataset and --sensed-dataset both name data: each output needs its own folder"
    )


def test_pipeline_settings_and_args_reach_their_stages() -> None:
    """WORKERS goes to both recordings and both PPO runs, EPISODES to both recordings, EPOCHS to every BC run,
    SENSED_NOISE to the sensed expert's recording only, ARGS to both PPO runs."""
    run_stages = stages(
        PipelineConfig(episodes=3, workers=1, epochs=4, sensed_noise=0.01, args="--target-kl 0.01 --eval-episodes 2")
    )
    assert (run_stages.record.episodes, run_stages.record.workers, run_stages.train.epochs) == (3, 1, 4)
    deployable = run_stages.deployable
    assert (deployable.record.episodes, deployable.record.workers, deployable.record.noise) == (3, 1, 0.01)
    assert run_stages.record.noise == RecordConfig().noise
    assert (deployable.proprio.epochs, deployable.odometry.epochs) == (4, 4)
    for config in (run_stages.baseline, run_stages.finetune):
        assert (config.workers, config.target_kl, config.eval_episodes) == (1, 0.01, 2)
    assert run_stages.baseline.learning_rate == BaselineConfig().learning_rate  # each keeps its own defaults


def test_args_may_not_repeat_a_pipeline_setting() -> None:
    """--timesteps in ARGS would silently lose to TIMESTEPS: refused, naming the flag."""
    with pytest.raises(UserError, match="--args sets --timesteps, a setting of the pipeline's own"):
        stages(PipelineConfig(args="--timesteps 5"))


def test_the_suite_table_counts_survivors_per_condition(outputs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The closing suite table: a row per policy with its clean return and survivors under every condition;
    a second pipeline run reuses the results made after the policy."""
    first = suite("bc", 1, workers=1)
    assert suite("bc", 1, workers=1) == first and "reusing" in capsys.readouterr().out
    table = report.suite_table({"bc": first}).splitlines()
    assert table[0] == "| policy | clean return | suite mean return | " + " | ".join(SUITE) + " |"
    survivors = [f"{round(c['survival_rate'])}/1" for c in first["conditions"].values()]
    assert table[2].startswith(f"| bc | {first['conditions']['clean']['mean_return']:,.1f} | ")
    assert table[2].endswith(" | " + " | ".join(survivors) + " |")


def test_the_suite_runs_on_the_others_while_the_tutorials_learners_train_and_rows_every_policy(
    outputs: Path,
) -> None:
    """With the tutorial's PPO to train again, the others' suite runs meanwhile; the table still has a row for
    each expert and every policy, in the order of the clean table, the tutorial's learners last."""
    shutil.rmtree(outputs / "tutorial_ppo")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        run(tiny_stages(), robustness_episodes=1)
    lines = out.getvalue().splitlines()
    table = lines[next(i for i, line in enumerate(lines) if line.startswith("| policy | clean return")) :]
    rows = [line.split(" | ")[0].removeprefix("| ") for line in table[2:] if line.startswith("| ")]
    assert rows == [
        "expert",
        "expert-sensed",
        *("bc", "bc_proprio", "bc_odometry", "ppo", "scratch", "tutorial_preferred", "tutorial_ppo"),
    ]
    assert (outputs / "tutorial_ppo" / EVAL_FILE).is_file()


def test_the_suite_table_averages_the_returns_over_the_conditions() -> None:
    """Known answer: two conditions with returns 1,000 and 3,000 average to 2,000.0."""
    result = {
        "seeds": [1000, 1001],
        "conditions": {
            "clean": {"survival_rate": 1.0, "mean_return": 3000.0, "episodes": 2},
            "push10": {"survival_rate": 0.5, "mean_return": 1000.0, "episodes": 2},
        },
    }
    assert report.suite_table({"p": result}).splitlines()[2] == "| p | 3,000.0 | 2,000.0 | 2/2 | 1/2 |"


def test_tutorial_runs_made_by_someone_else_are_refused_and_left_alone(outputs: Path) -> None:
    """The tutorial's folders hold a run `make tutorial-rl` made with other settings: one line, nothing touched."""
    edit_json(outputs / "tutorial_ppo" / CONFIG_FILE, {"made_by": "bc.tutorial", "ent_coef": 0.01})
    assert_refused_untouched(
        outputs, tiny_stages(), "tutorial_ppo already holds a checkpoint; pass --overwrite true to replace it"
    )
