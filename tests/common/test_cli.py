"""Removed flags and values (`common.cli.REMOVED_FLAGS`, `REMOVED_VALUES`) are refused in one line naming what to
use instead, before anything is written: argument parsing only, through each stage's real `cli`."""

from __future__ import annotations

import dataclasses
import errno
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from common.cli import (
    REMOVED_FLAGS,
    REMOVED_VALUES,
    UserError,
    check_file,
    counted,
    json_text,
    parse_config,
    run_cli,
)
from evaluation import evaluate
from pipeline import run as pipeline
from pipeline.targets import TARGETS
from rl import finetune
from teleop import record
from teleop.record import RecordConfig

ADAPTIVE = "error: controller 'expert-adaptive' was removed; use expert-sensed (docs/decisions/identification.md)\n"


def refused(cli: Callable[[list[str]], int], argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """What `cli(argv)` printed on stderr, after checking it exited 1 having printed that one line alone."""
    assert cli(argv) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1, err
    return err


def test_a_removed_controller_is_refused_by_the_recorder_and_nothing_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`make record CONTROLLER=expert-adaptive`: one line naming the controller to use, and no dataset folder."""
    dataset = tmp_path / "data"
    for argv in (["--controller", "expert-adaptive"], ["--controller=expert-adaptive"]):
        assert refused(record.cli, [*argv, "--dataset", str(dataset)], capsys) == ADAPTIVE
    assert not dataset.exists()


def test_a_removed_controller_is_refused_by_the_evaluator(capsys: pytest.CaptureFixture[str]) -> None:
    """`make eval POLICY=expert-adaptive`: the same line (the registry holds it once for every stage)."""
    assert refused(evaluate.cli, ["--policy", "expert-adaptive"], capsys) == ADAPTIVE


def test_a_flag_a_stage_no_longer_has_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`make finetune-rl ARGS="--tracking-width 0.5"`: argparse's one line and exit 2, and no checkpoint (a removed
    stage flag needs no entry of its own: only Make would ignore a variable silently)."""
    policy = tmp_path / "ppo"
    with pytest.raises(SystemExit) as exit_:
        finetune.cli(["--policy", str(policy), "--tracking-width", "0.5"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and "unrecognized arguments: --tracking-width" in err
    assert not policy.exists()


def test_the_pipelines_earlier_variables_say_what_to_use_instead(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`make pipeline PPO_FROM=full` names the command that fine-tunes another BC policy; `make pipeline EPOCHS=3`,
    a setting of the pipeline's before its stages nested, names the stages' settings of that name. Nothing is
    recorded."""
    dataset = tmp_path / "data"
    err = refused(pipeline.cli, ["--record.dataset", str(dataset), "--ppo-from=full"], capsys)
    assert err.startswith("error: --ppo-from was removed; ") and "make finetune-rl BC_POLICY=" in err
    err = refused(pipeline.cli, ["--record.dataset", str(dataset), "--epochs", "3"], capsys)
    listed = "--bc.epochs, --dagger.epochs or --ppo.epochs"
    assert err == f"error: --epochs is a stage's setting here: {listed} (`make help` lists Make's names)\n"
    err = refused(pipeline.cli, ["--record.dataset", str(dataset), "--dagger-episodes=3"], capsys)
    assert (
        err
        == "error: --dagger-episodes is a stage's setting here: --dagger.episodes (`make help` lists Make's names)\n"
    )
    # DAgger's noise is tied to the recording's (pipeline.run.TIES): only the recording's is named.
    err = refused(pipeline.cli, ["--record.dataset", str(dataset), "--noise", "0.1"], capsys)
    assert err == "error: --noise is a stage's setting here: --record.noise (`make help` lists Make's names)\n"
    # A removed value of a nested stage's setting is refused as its stage refuses it.
    err = refused(pipeline.cli, ["--record.dataset", str(dataset), "--record.controller=operator"], capsys)
    assert err.startswith("error: controller 'operator' was removed; ")
    assert not dataset.exists()


def test_a_current_value_and_flag_still_parse() -> None:
    """The registry refuses only what was removed: the sensed expert, say, is still a controller."""
    assert parse_config(RecordConfig, ["--controller", "expert-sensed"], "").controller == "expert-sensed"


def test_no_stage_has_a_flag_or_value_the_registry_calls_removed() -> None:
    """A removed flag is a field of no stage's config (else the stage would parse it as its own), and every removed
    value belongs to a field some stage has (else it could never be given)."""
    fields = {field.name for target in TARGETS.values() for field in dataclasses.fields(target.config)}
    assert not fields & set(REMOVED_FLAGS)
    assert {name for name, _ in REMOVED_VALUES} <= fields


def test_a_number_that_is_not_finite_is_written_null_in_strict_json() -> None:
    """Python's `json` writes NaN, which the JSON standard lacks and strict readers refuse: what a run prints and saves
    holds null there (known answer), numpy's floats and tuples included, everything else as `json.dumps` writes it."""
    content = {"error": float("nan"), "errors": (0.5, np.float64("inf")), "inner": {"x": -np.inf}, "n": 3, "s": "nan"}
    assert json_text(content) == '{"error": null, "errors": [0.5, null], "inner": {"x": null}, "n": 3, "s": "nan"}'


def test_a_count_names_its_noun_in_the_singular_only_for_one() -> None:
    assert [counted(n, "episode") for n in (0, 1, 2)] == ["0 episodes", "1 episode", "2 episodes"]


def test_a_file_setting_takes_its_suffix_and_no_folder(tmp_path: Path) -> None:
    """`check_file`: None passes, a path with the suffix (any case) passes, another suffix or a folder so named not."""

    @dataclasses.dataclass
    class Outputs:
        plot: Path | None

    for fine in (None, tmp_path / "new.png", tmp_path / "NEW.PNG"):
        check_file(Outputs(fine), "plot", ".png")
    (tmp_path / "folder.png").mkdir()
    for bad in (tmp_path / "x.txt", tmp_path / "folder.png"):
        with pytest.raises(UserError, match=r"^--plot must be a \.png file's path, got "):
            check_file(Outputs(bad), "plot", ".png")


@dataclasses.dataclass
class Nothing:
    """A stage with no setting."""


@pytest.mark.parametrize(
    ("error", "line"),
    [
        (OSError(errno.ENOSPC, "No space left on device"), "error: [Errno 28] No space left on device\n"),
        (PermissionError(errno.EACCES, "Permission denied", "/out/x"), "error: /out/x: Permission denied\n"),
    ],
)
def test_the_disks_refusal_is_one_line_with_or_without_a_file(
    error: OSError, line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """`run_cli` turns the disk's refusals (`PLACE_ERRORS`) into one line, naming the file where the error does; any
    other OS error keeps its traceback."""

    def fails(config: Nothing) -> None:
        raise error

    assert run_cli(fails, Nothing, [], "a stage") == 1
    out, err = capsys.readouterr()
    assert err.endswith(line) and out == ""
    with pytest.raises(FileNotFoundError):
        run_cli(lambda config: open("/no/such/file"), Nothing, [], "a stage")
