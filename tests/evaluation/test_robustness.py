"""`make robustness`: every condition on the same seeds, a table, the JSON line, the files; bad input refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from evaluation.robustness import (
    FIGURE_FILE,
    RESULT_FILE,
    RobustnessConfig,
    cli,
    evaluate_suites,
    output_folder,
    push_sectors,
    run_suite,
    suite_runs,
    table,
)
from humanoid.conditions import SUITE


@pytest.mark.slow
def test_suite_prints_a_table_then_one_json_line_and_writes_the_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli(
        ["--policy", "expert", "--episodes", "2", "--seed", "1000", "--output", str(tmp_path), "--progress", "0"]
        + ["--task", "stand"]
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert code == 0
    summary = json.loads(lines[-1])
    assert summary["policy"] == "expert" and summary["seeds"] == [1000, 1001]
    assert list(summary["conditions"]) == list(SUITE)
    assert all(row["episodes"] == 2 and 0 <= row["survival_rate"] <= 1 for row in summary["conditions"].values())
    assert summary["conditions"]["clean"]["survival_rate"] == 1.0  # the expert stands on clean seeds
    assert [line.split()[0] for line in lines[1 : len(SUITE) + 1]] == list(SUITE)  # the table, a row per condition
    pushed = [name for name in SUITE if SUITE[name].push or SUITE[name].kick]
    assert [line.split()[0] for line in lines[len(SUITE) + 1 : -1]] == pushed  # then a line of directions each
    assert lines[-2].startswith("kick0.6 kicks of 25.27 N·s that toppled it, by direction")
    saved = json.loads((tmp_path / RESULT_FILE).read_text())
    assert len(saved["conditions"]["latency"]["returns"]) == 2
    assert "push_sectors" in saved["conditions"]["push20"] and "push_sectors" not in saved["conditions"]["clean"]
    assert (tmp_path / FIGURE_FILE).stat().st_size > 0


@pytest.mark.slow
def test_the_same_seeds_give_the_same_results_in_one_or_two_workers_alone_or_with_another_suite() -> None:
    """Rows depend on the seeds alone: not on the workers, nor on another suite submitted to the same pool first (as
    the pipeline's table submits every controller's)."""
    seeds = range(1000, 1002)
    one = run_suite("expert", ["mass", "latency"], seeds, workers=1)
    two = run_suite("expert", ["mass", "latency"], seeds, workers=2)
    assert one == two
    together = [suite_runs("random", ["clean"], seeds, 2), suite_runs("expert", ["mass", "latency"], seeds, 2)]
    first, second = evaluate_suites(together, workers=2)
    assert second == one
    assert first == run_suite("random", ["clean"], seeds, workers=1)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--conditions", "gravity"], "unknown condition 'gravity'"),
        (["--conditions", "clean,mass,clean"], "--conditions names clean twice"),
        (["--episodes", "0"], "--episodes must be positive"),
        (["--policy", "nowhere/policy"], "no policy checkpoint at nowhere/policy"),
        (["--policy", "keyboard"], "controller 'keyboard' is driven by a person"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code = cli(["--policy", "expert", "--output", str(tmp_path / "out"), "--progress", "0", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "out").exists()


def test_a_registered_controllers_results_go_under_policies() -> None:
    """A controller has no checkpoint folder: its results go to policies/<name>/, a checkpoint's to its folder."""
    assert output_folder(RobustnessConfig(policy="expert-sensed")) == Path("policies/expert-sensed")
    assert output_folder(RobustnessConfig(policy="policies/bc")) == Path("policies/bc")


def test_pushes_are_counted_in_the_sector_of_their_nearest_centre() -> None:
    """Sectors 45° wide centred on -135, ..., 180; -180 and 180 are the same sector (a push on the chest)."""
    sectors = push_sectors(
        [0.0, 22.4, 22.6, -157.0, 157.6, -180.0, 90.0], [True, False, True, False, True, True, False]
    )
    assert sectors["centres"] == [-135, -90, -45, 0, 45, 90, 135, 180]
    assert sectors["pushes"] == [1, 0, 0, 2, 1, 1, 0, 2]
    assert sectors["toppled"] == [0, 0, 0, 1, 1, 0, 0, 2]


def test_the_table_prints_an_error_no_command_settled_long_enough_to_measure_as_n_a() -> None:
    """Known answer: survivors, return and each tracked field's settled error; NaN (a run whose commands never held
    long enough, or all fell) prints as n/a, as the pipeline's table does."""
    tracking = {"settled_error": {"lean_forward": 0.0123, "height": float("nan")}, "settle_seconds": 1.0}
    result = {"conditions": {"clean": {"survival_rate": 0.5, "mean_return": 1234.56, "tracking": tracking}}}
    lines = table(result).splitlines()
    assert lines[0].split() == ["condition", "survival", "mean", "return", "lean_forward", "height"]
    assert lines[1].split() == ["clean", "50%", "1234.6", "0.012", "n/a"]
