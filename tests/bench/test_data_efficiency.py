"""bench.data_efficiency's seed checks and table, from given cells: no recording, training or simulation."""

from __future__ import annotations

import pytest

from bench.data_efficiency import DEMOS, FIRST_SEEDS, Cell, check_seeds, notes, table


def cell(first_seed: int, demos: int, inputs: str, survived: int, fallen: int = 0) -> Cell:
    val = max(1, round(0.1 * demos))
    return Cell(first_seed, demos, inputs, fallen, demos - val, val, 1000 * (demos - val), survived, 20, 1234.4, 1.0)


def test_default_seed_ranges_miss_each_other_and_the_evaluation_seeds() -> None:
    check_seeds(FIRST_SEEDS, DEMOS, 1000, 20)
    check_seeds([0, 990], [5], 1000, 20)  # 990..994 is clear of the evaluation seeds 1000..1019
    with pytest.raises(ValueError, match="overlap"):
        check_seeds([0, 990], [5, 20], 1000, 20)  # N = 20 would record seeds 1000..1009
    with pytest.raises(ValueError, match="overlap"):
        check_seeds([0, 30], [50], 1000, 20)


def test_table_has_a_row_per_n_a_column_per_inputs_then_range_and_the_expert_last() -> None:
    cells = [
        cell(first, n, kind, survived=n // 5, fallen=n // 20)
        for first in (0, 10_000)
        for n in (5, 20)
        for kind in ("full", "proprio")
    ]
    text = table(cells, {"survived": 20, "episodes": 20, "mean_return": 4944.6})
    assert text.splitlines() == [
        "| demonstrations (train + validation) | full, seeds 0..19 | full, seeds 10000..10019 "
        "| proprio, seeds 0..19 | proprio, seeds 10000..10019 |",
        "|---|---|---|---|---|",
        "| N = 5 (4 + 1) | 1/20, 1,234 | 1/20, 1,234 | 1/20, 1,234 | 1/20, 1,234 |",
        "| N = 20 (18 + 2) | 4/20, 1,234 | 4/20, 1,234 | 4/20, 1,234 | 4/20, 1,234 |",
        "| the expert (reference) | 20/20, 4,945 |  |  |  |",
    ]
    said = notes(cells, 1000, 20)
    assert "N = 5 trains on 4 episodes" in said
    assert "seeds from 0: 0 of 5, 1 of 20; seeds from 10000: 0 of 5, 1 of 20" in said


def test_notes_count_each_teachers_falls_apart() -> None:
    """The expert and the expert on leg odometry record different datasets: their falls are reported apart."""
    cells = [cell(0, 5, "full", survived=0, fallen=1), cell(0, 5, "proprio", survived=0, fallen=1)]
    sensed = cell(0, 5, "pending", survived=3, fallen=2)
    sensed.teacher = "expert-sensed"
    said = notes([*cells, sensed], 1000, 20)
    assert "expert (full, proprio): seeds from 0: 1 of 5. expert-sensed (pending): seeds from 0: 2 of 5." in said
