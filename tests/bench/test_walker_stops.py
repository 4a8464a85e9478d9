"""`bench.walker.Stops`, which times the walker's stops, on made-up clock histories (known answers)."""

from __future__ import annotations

import pytest

from bench.walker import Stops


def run(history: list[tuple[bool, bool, bool]]) -> Stops:
    """`Stops` at 0.1 s a step over (walking, zero walk, done) per step."""
    stops = Stops(0.1)
    for t, (walking, zero_walk, done) in enumerate(history):
        stops.step(t, walking, zero_walk, done)
    return stops


WALK = (True, False, False)  # walking on a walk command
STEPS_ON = (True, True, False)  # walking under the zero walk
ENDED = (False, True, True)  # the walk just over (the clock's `done` holds until the next start)


def test_a_stop_is_timed_from_the_zero_walk_to_the_walks_end() -> None:
    stops = run([WALK] * 3 + [STEPS_ON] * 5 + [ENDED] * 4)
    assert stops.rests == pytest.approx([0.5]) and not stops.stopping


def test_a_walk_that_steps_again_under_the_zero_walk_was_not_over() -> None:
    stops = run([WALK] * 3 + [STEPS_ON] * 5 + [ENDED] * 4 + [STEPS_ON] * 6)
    assert stops.rests == [] and stops.stopping  # still asked to stop since step 3
    stops.step(18, False, True, True)
    assert stops.rests == pytest.approx([1.5])


def test_a_new_walk_command_after_a_stop_keeps_it() -> None:
    stops = run([WALK] * 3 + [STEPS_ON] * 5 + [ENDED] * 4 + [WALK] * 3 + [STEPS_ON] * 2 + [ENDED])
    assert stops.rests == pytest.approx([0.5, 0.2])
