"""bench.training_seeds' folders and spread table, from given results: no training or simulation."""

from __future__ import annotations

from pathlib import Path

from bench.training_seeds import ROLES, seed_config, spread_table
from humanoid.conditions import SUITE
from pipeline.run import PipelineConfig, stages
from task.command_fields import COMMAND_NAMES


def test_seed_zero_is_the_pipelines_run_and_other_seeds_train_apart() -> None:
    assert seed_config(0, Path("s")) == PipelineConfig()
    other = seed_config(2, Path("s"))
    run = stages(other)
    folders = {*run.outputs().values()} - {run.record.dataset}
    assert {folder.parent for folder in folders} == {Path("s/seed_2")} and len(folders) == 6
    assert {run.student.seed, run.blind.seed, run.dagger.seed, run.finetune.seed, run.scratch.seed} == {2}
    assert run.record == stages(PipelineConfig()).record  # the same data: training alone varies


def result(survivors: int, error: float, mean_return: float) -> dict:
    tracking = {"settled_error": dict.fromkeys(COMMAND_NAMES, error), "settle_seconds": 1.0}
    row = {"survival_rate": survivors / 20, "episodes": 20, "mean_return": mean_return, "tracking": tracking}
    return {"conditions": dict.fromkeys(SUITE, row)}


def test_the_spread_is_the_lowest_and_highest_over_the_seeds() -> None:
    """Known answer: survivors 14 and 17, errors 0 (score 1) and far off (score 0), returns 1,000 and 2,000; one
    number where the seeds agree as printed."""
    runs = [
        (
            {role: {"survival_rate": 1.0, "episodes": 20} for role in ROLES},
            {role: result(14, 0.0, 1000.0) for role in ROLES},
        ),
        (
            {role: {"survival_rate": 1.0, "episodes": 20} for role in ROLES},
            {role: result(17, 9.0, 2000.0) for role in ROLES},
        ),
    ]
    lines = spread_table([0, 1], runs).splitlines()
    assert lines[2] == "| row | standing | " + " | ".join(SUITE) + " | mean return |"
    assert lines[4] == "| blind | 20 | " + " | ".join(["14–17 · 0.00–1.00"] * len(SUITE)) + " | 1000–2000 |"
    assert [line.split(" | ")[0] for line in lines[4:]] == [f"| {role}" for role in ROLES]
    nearly = [runs[0], (runs[0][0], {role: result(14, 1e-6, 1000.4) for role in ROLES})]
    assert spread_table([0, 1], nearly).splitlines()[4].endswith(" | 14 · 1.00 | 1000 |")
