"""Commanded postures as poses: every pose a schedule asks for balances, on any CPU (`humanoid.balance`), and one the
solver cannot balance falls back to the nearest that it can (`task.posture.nearest_pose`)."""

from __future__ import annotations

import logging

import pytest

from bench.posture_solves import ramp_poses, residual
from humanoid.balance import BalanceError, standing_pose
from humanoid.env import nominal_model
from task.posture import NEUTRAL, Posture, arm_angles, nearest_pose, posture_pose

SWEPT_SEEDS = (*range(9608, 9619), *range(1000, 1020))
"""The operator's schedules whose every ramp the sweep solves: the recording's seeds around 9613, whose waypoint
stalled Powell's method on an AMD EPYC, and the held-out evaluation's 20. `make bench` sweeps 202 schedules
(`bench.posture_solves`, about 30 s)."""
SEED_9613_WAYPOINT = Posture(
    lean_forward=-0.09642857286546912,
    lean_left=-0.0035714286246470027,
    twist=0.18571428848164423,
    arms=0.0714285714285714,
)
"""The waypoint of seed 9613's schedule that crashed `make record EPISODES=1 SEED=9613` there: a shin nearly
vertical, whose knee barely moves its foot up or down."""


BALANCED = 1e-3
"""What the contacts may leave unsupported (N, N·m) of a pose that balances: the standing pose leaves 7.6e-4 N·m of
roll (its solve balances the vertical force and the pitch, which a symmetric body needs), a posture's about 1e-8."""


def test_the_waypoint_that_crashed_a_recording_balances() -> None:
    model = nominal_model()
    pose = posture_pose(model, SEED_9613_WAYPOINT, standing_pose(model))
    assert residual(model, pose) < BALANCED


def test_a_posture_no_pose_balances_falls_back_to_the_nearest_that_does(caplog: pytest.LogCaptureFixture) -> None:
    """Rising 10 cm balances nowhere (the knees are nearly straight already): `posture_pose` says so, `nearest_pose`
    holds the posture nearest to it on the way from the stand that balances, with one warning."""
    model = nominal_model()
    neutral = standing_pose(model)
    impossible = Posture(height=0.1)
    with pytest.raises(BalanceError, match=r"^Posture\(lean_forward=0.0, lean_left=0.0, height=0.1, .+no balanced"):
        posture_pose(model, impossible, neutral)
    arms = arm_angles(0.0)
    with caplog.at_level(logging.WARNING):
        pose = nearest_pose(model, NEUTRAL, impossible, neutral, arms, arms)
    assert residual(model, pose) < BALANCED
    (warning,) = caplog.messages
    assert "\n" not in warning and warning.startswith("Posture(lean_forward=0.0, lean_left=0.0, height=0.1, ")
    assert " of the way to it from Posture(lean_forward=0.0, " in warning
    assert 0.0 < pose[2] - neutral[2] < 0.1  # risen, as far as a pose balances


@pytest.mark.slow
def test_every_pose_of_the_schedules_ramps_balances() -> None:
    """Every pose the LQR teacher's ramp solves under the operator's schedules of `SWEPT_SEEDS` (each command's
    balanced pose and the waypoints on the way to it, as `teachers.postures.PostureRamp.hold` plans them) balances:
    no command kills a recording (`bench.posture_solves` counts how each was solved)."""
    model = nominal_model()
    poses = 0
    for seed, t, pose in ramp_poses(model, SWEPT_SEEDS):
        assert residual(model, pose) < BALANCED, (seed, t)
        poses += 1
    assert poses > 20 * len(SWEPT_SEEDS)
