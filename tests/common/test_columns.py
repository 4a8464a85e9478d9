"""`common.columns.drawn_parameters`: the drawn physical parameters among an episode's columns, by name."""

from __future__ import annotations

from common import columns


def test_the_drawn_parameters_are_the_prefixed_columns_without_the_prefix_in_order() -> None:
    """Known answer on an episode row: the other columns, and a column that holds the prefix past its start, are
    left out; the values are kept as they are and the order is the row's."""
    row = {
        columns.EPISODE_SEED: 3,
        "randomization.strength_scale": [0.9, 1.1],
        "stats/randomization.mass_scale/mean": [1.0],
        "randomization.latency_steps": 1,
        columns.EPISODE_MCAP: "mcap/episode_000003.mcap",
    }
    drawn = columns.drawn_parameters(row)
    assert drawn == {"strength_scale": [0.9, 1.1], "latency_steps": 1}
    assert list(drawn) == ["strength_scale", "latency_steps"]
    assert columns.drawn_parameters({columns.EPISODE_SEED: 0}) == {}
