"""`task.command_fields`: the command's fields as one table, which every user reads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from humanoid.env import QPOS_OBS, QVEL_OBS, nominal_model
from humanoid.sensors import body_axes
from task.command_fields import COMMAND_FIELDS, COMMAND_NAMES, FIELDS, Readout
from task.posture import NEUTRAL, Posture, axis_quaternion, multiply_quaternions
from task.schedules import task_for
from task.tracking import Tracking
from teachers.postures import posture_reference
from teleop.keyboard import KEY_ACTIONS, TeleopSession


def test_the_posture_has_one_keyword_per_row_in_the_rows_order() -> None:
    assert tuple(field.name for field in dataclasses.fields(Posture)) == COMMAND_NAMES
    assert NEUTRAL == Posture(**dict.fromkeys(COMMAND_NAMES, 0.0))


def test_clipping_keeps_a_value_inside_its_rows_limits_and_a_preset_whole() -> None:
    lean, arms = FIELDS["lean_forward"], FIELDS["arms"]
    assert (lean.clip(1.0), lean.clip(-1.0), lean.clip(0.12)) == (0.3, -0.2, 0.12)
    assert (arms.clip(2.6), arms.clip(-1.0), arms.clip(7.0)) == (3.0, 0.0, 3.0)
    assert Posture(height=-1.0, twist=0.7, arms=1.4).clipped() == Posture(height=-0.18, twist=0.55, arms=1.0)


def test_a_task_string_names_each_field_away_from_neutral_with_its_rows_phrase() -> None:
    assert task_for(Posture(height=-0.04, twist=-0.1, arms=3.0)) == "Crouch, twist right, arms out while standing."
    assert task_for(Posture(lean_forward=-0.05, lean_left=0.05)) == "Lean back, lean left while standing."


def test_the_readout_reads_every_field_and_a_balanced_pose_reads_its_posture() -> None:
    """Each row's achieved value comes from the readout; the pose that realises a posture reads that posture back
    (the height: the neutral pose's plus the command, as the knees place an upright torso)."""
    model = nominal_model()
    readout = Readout(model)
    posture = Posture(lean_forward=0.1, lean_left=-0.1, twist=0.2, arms=2.0)
    rest = np.zeros(model.nv)
    read = readout(posture_reference(model, posture)[0][2:], rest)
    assert tuple(read) == COMMAND_NAMES
    assert [read[name].shape for name in COMMAND_NAMES] == [(1,), (1,), (1,), (1,), (6,), (1,), (1,), (1,)]
    for name in ("lean_forward", "lean_left", "twist"):
        assert read[name][0] == pytest.approx(getattr(posture, name), abs=1e-9)
    crouched = readout(posture_reference(model, Posture(height=-0.06))[0][2:], rest)["height"]
    neutral = readout(posture_reference(model, NEUTRAL)[0][2:], rest)["height"]
    assert crouched - neutral == pytest.approx(-0.06, abs=1e-6)


@pytest.mark.parametrize("field", COMMAND_FIELDS, ids=lambda field: field.name)
def test_every_rows_keys_change_that_field_by_its_step(field) -> None:
    """The keys come from the rows: a signed field's raise keys add a step, its lower keys take one away; a preset
    field's keys select their preset."""

    class Recorded:
        def set_command(self, command: np.ndarray) -> None:
            pass

    session = TeleopSession.__new__(TeleopSession)
    session.controller, session.target = Recorded(), NEUTRAL
    if field.presets:
        for preset, keys in enumerate(field.keys):
            for key in keys:
                KEY_ACTIONS[key](session)
                assert getattr(session.target, field.name) == preset
        return
    (lower, raise_), start = field.keys, Posture(**{field.name: field.clip(field.step / 2)})
    for keys, sign in ((raise_, 1), (lower, -1)):
        for key in keys:
            session.target = start
            KEY_ACTIONS[key](session)
            assert getattr(session.target, field.name) == field.clip(getattr(start, field.name) + sign * field.step)


def test_the_velocities_read_in_the_heading_of_the_untwisted_torso() -> None:
    """A body twisted at the waist (0.3 rad) and turned 0.5 rad about the vertical, moving 0.3 m/s along that heading
    and 0.1 m/s to its left, turning at 0.2 rad/s: the readout gives those three numbers, the twist turning no walk."""
    model = nominal_model()
    qpos = posture_reference(model, Posture(twist=0.3))[0].copy()
    qpos[3:7] = multiply_quaternions(axis_quaternion(2, 0.5), qpos[3:7])
    qvel = np.zeros(model.nv)
    heading = np.array([np.cos(0.5), np.sin(0.5)])
    qvel[0:2] = 0.3 * heading + 0.1 * np.array([-heading[1], heading[0]])
    qvel[3:6] = body_axes(qpos[3:7]) @ np.array([0.0, 0.0, 0.2])  # the world's yaw rate in the root's frame: R^T w
    read = Readout(model)(qpos[2:], qvel)
    assert read["forward_speed"][0] == pytest.approx(0.3, abs=1e-9)
    assert read["sideways_speed"][0] == pytest.approx(0.1, abs=1e-9)
    assert read["turn_rate"][0] == pytest.approx(0.2, abs=1e-9)


def test_a_velocity_is_tracked_as_its_commanded_value_clipped_to_its_row() -> None:
    """A velocity row is not posed: tracking compares the reading with the commanded value (clipped to the row's
    limits), the posed fields as before."""
    model = nominal_model()
    tracking = Tracking(model)
    stand = posture_reference(model, NEUTRAL)[0][2:]
    observation = np.zeros((1, 348))
    observation[0, QPOS_OBS], observation[0, QVEL_OBS.start] = stand, 0.25
    speed = COMMAND_NAMES.index("forward_speed")
    for commanded, error in ((0.4, 0.15), (0.25, 0.0), (1.0, 0.35)):  # 1.0 is clipped to the row's 0.6
        command = np.zeros((1, len(COMMAND_NAMES)))
        command[0, speed] = commanded
        np.testing.assert_allclose(
            tracking.errors(observation, command)[0, : speed + 1], [0] * speed + [error], atol=1e-9
        )
