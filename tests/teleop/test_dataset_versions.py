"""A dataset recorded before the velocity fields existed still loads, trains and merges.

`tests/data/dataset_v1` is `make record` at 9f472b2 (two episodes of 10 steps, seeds 5 and 6, noise 0): its
`observation.command` and `setpoint` name the five posture fields only.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from bc.data import load_demonstrations
from common import columns
from humanoid.env import make_env
from students.inputs import STUDENT_INPUTS
from task.command_fields import COMMAND_NAMES, POSTURE_NAMES, VELOCITY_NAMES
from teleop.dataset_reader import command_columns, read_frames, read_info, read_transitions
from teleop.merge import MergeConfig, main

OLD = Path(__file__).parents[1] / "data" / "dataset_v1"
VELOCITIES = [COMMAND_NAMES.index(name) for name in VELOCITY_NAMES]


def test_the_old_datasets_commands_read_as_todays_the_velocities_zero() -> None:
    info = read_info(OLD)
    assert info["features"][columns.OBS_COMMAND]["names"] == list(POSTURE_NAMES)  # the fixture is what it says
    raw = read_frames(OLD, [columns.OBS_COMMAND, columns.SETPOINT])
    wide = command_columns(info, raw)
    for key in (columns.OBS_COMMAND, columns.SETPOINT):
        assert wide[key].shape == (20, len(COMMAND_NAMES))
        np.testing.assert_array_equal(wide[key][:, : len(POSTURE_NAMES)], raw[key])
        assert not wide[key][:, VELOCITIES].any()
    assert [episode.commands.shape for episode in read_transitions(OLD)] == [(11, len(COMMAND_NAMES))] * 2


def test_the_student_trains_on_an_old_dataset() -> None:
    """The deployable student's inputs read the posture fields by name: the old dataset gives its 20 frames."""
    env = make_env()
    demos = load_demonstrations(OLD, env, cache=False, inputs=STUDENT_INPUTS)
    env.close()
    assert demos.frames == 20 and np.isfinite(demos.inputs.numpy()).all()


def test_an_old_shard_merges_into_todays_layout(tmp_path: Path) -> None:
    shard = tmp_path / "old"
    shutil.copytree(OLD, shard)
    merged = tmp_path / "merged"
    assert main(MergeConfig(shards=str(shard), dataset=merged, progress=False)) == 2
    assert read_info(merged)["features"][columns.OBS_COMMAND]["names"] == list(COMMAND_NAMES)
    old = read_frames(OLD, [columns.OBS_COMMAND])[columns.OBS_COMMAND]
    new = read_frames(merged, [columns.OBS_COMMAND])[columns.OBS_COMMAND]
    np.testing.assert_array_equal(new[:, : len(POSTURE_NAMES)], old)
    assert not new[:, VELOCITIES].any()
