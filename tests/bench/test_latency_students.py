"""bench.latency_students' seed ranges and table, from given cells: no recording, training or simulation."""

from __future__ import annotations

from bench.data_efficiency import EVAL_EPISODES, check_seeds
from bench.latency_students import DEMOS, FIRST_SEEDS, Cell, table
from common.seed_ranges import EVAL_SEED


def test_default_seed_ranges_miss_each_other_and_the_evaluation_seeds() -> None:
    check_seeds(list(FIRST_SEEDS), list(DEMOS), EVAL_SEED, EVAL_EPISODES)


def test_table_has_a_row_per_n_a_column_per_range_and_the_teacher_last() -> None:
    cells = [
        Cell(first, n, kind, n // 2, n // 3, {"clean": 20, "latency": n // 5 + (kind == "pending"), "noise": 9}, {})
        for first in (0, 100)
        for n in (20, 50)
        for kind in ("pending",)
    ]
    text = table(cells, ({"clean": 20, "latency": 12, "noise": 12}, {}))
    assert text.splitlines() == [
        "| N | inputs | seeds 0.. (clean, latency, noise) | seeds 100.. (clean, latency, noise) |",
        "|---|---|---|---|",
        "| 20 | pending | 20, 5, 9 | 20, 5, 9 |",
        "| 50 | pending | 20, 11, 9 | 20, 11, 9 |",
        "| teacher | expert-sensed | 20, 12, 12 (the same seeds 1000..1019 for every column) |",
    ]
