"""The operator's command, field by field, as data: `COMMAND_FIELDS` (docs/concepts/commands.md).

One row per field says everything the project does with it: its name (the entry of the dataset's
`observation.command`, `Posture`'s keyword, a policy's `command.<name>` input), unit and limits, one key press's
step (also the grid the scripted schedules draw from), the tolerance that counts as on the command, the keys
that change it, the phrase a task string names it with, the numbers of its MCAP `/command` fields, and how the
command filter ramps it (its `rate`; a posed field's `waypoint_step` and `gain_step`, which the LQR teacher's ramp
reads). Every user reads the table: `task.posture` (`Posture`, the command filter), `task.schedules` (schedules, task
strings), `task.tracking` (tracking and its reward), `teachers.postures` (the ramp), `teleop.keyboard` (bindings and
status line), `teleop.mcap_io.schema` (the `/command` message) and the dataset's feature names (`teleop.store`).

How the achieved value is read from the body is the one piece of code a field adds besides its row
(`Readout`): the trunk's pitch for `lean_forward`, the six arm joint angles for `arms`, and so on.

Adding a field: a row here (`posed=False` for one tracked as its value, not as a pose), its entry in
`Readout.__call__`, and the code that realises it (the standing expert realises a posed field as a balanced pose:
`task.posture.posture_pose`). Its MCAP numbers must be new ones: a file written before the field existed still
decodes with today's `Command` message (tests/teleop/test_mcap.py holds such a file; tests/task/
test_command_fields.py tracks a velocity row added to the table).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import mujoco
import numpy as np

from humanoid.sensors import body_axes, yaw_rate


@dataclass(frozen=True)
class CommandField:
    """One field of the operator's command."""

    name: str
    """The entry's name: in `observation.command` and its MCAP message, `Posture`'s keyword, `command.<name>`."""
    unit: str
    """The unit of its value (a preset field: "preset", a preset's index)."""
    low: float
    """The smallest value the expert holds: a command below it is clipped to it (and recorded clipped)."""
    high: float
    """The largest value the expert holds."""
    step: float
    """One key press's change; the scripted schedules draw their targets on this grid too."""
    tolerance: float
    """On the command: the achieved value within this (a field read from several coordinates: their mean error)."""
    keys: tuple[tuple[str, ...], ...]
    """The keys (terminal names) that change it: (lower, raise) for a signed field, one tuple per preset."""
    phrases: tuple[str, ...]
    """What a task string calls it: (below zero, above zero) for a signed field, one phrase per preset."""
    mcap: tuple[int, int, int | None]
    """The protobuf field numbers of its command, setpoint and achieved value on `/command` (None: no achieved value
    is plotted, as for the arms, which show in 3D): explicit and never reused, so old files keep decoding."""
    presets: bool = False
    """Whether its values name presets (0, 1, ... len(phrases) - 1) rather than a quantity."""
    posed: bool = True
    """Whether the standing expert realises it as a balanced pose (`task.posture.posture_pose`), whose coordinates
    are then its tracking target; otherwise the commanded value itself is (a velocity, say)."""
    group: str = "posture"
    """`POSTURE` (what the body holds where it stands) or `VELOCITY` (how it moves over the floor): the walking task
    commands both, the posture task the posture fields alone (`task_fields`)."""
    rate: float = 0.0
    """Mean speed (unit per second) at which the command filter moves the setpoint toward a new value
    (`task.posture.PosturePath`); the arm preset's: rad/s of the arm joint with the farthest to go."""
    waypoint_step: float = 0.0
    """A posed field's largest change between two of the balanced waypoints a teacher's ramp solves on its way
    (`teachers.postures.PostureRamp`, about 3 ms each); the arm preset's: of any arm joint, rad."""
    gain_step: float = 0.0
    """A posed field's largest change between two LQR gains designed on that way (0.05 to 0.2 s each)."""

    def clip(self, value: float) -> float:
        """`value` inside [low, high], a preset field's rounded to a preset."""
        clipped = min(max(value, self.low), self.high)
        return float(round(clipped)) if self.presets else clipped

    def phrase(self, value: float) -> str:
        """The words a task string uses for `value` (nonzero)."""
        if self.presets:
            return self.phrases[round(value)]
        return self.phrases[value > 0]


POSTURE, VELOCITY = "posture", "velocity"
"""The two groups of fields (`CommandField.group`)."""

COMMAND_FIELDS: tuple[CommandField, ...] = (
    # Limits measured by bench/posture_ranges.py (5 seeds, held 3 s after the ramp): about 75 % of the largest
    # magnitude that stayed up, and was reached, on every seed (docs/concepts/commands.md). Rates: crouching is slow
    # because the LQR teacher clips its height error to 2 cm (`teachers.lqr.LQRDesign.height_clip`, for the drop after
    # reset): at 0.05 m/s and more the torso lags the setpoint and the body falls; at 1.5 rad/s the arms' swing toppled
    # the body; a walk speeds up and slows down over about a second, as a step takes a third of one
    # (docs/decisions/walking-teacher.md).
    CommandField(
        "lean_forward",
        "rad",
        -0.2,
        0.3,
        0.05,
        0.05,
        keys=(("s",), ("w",)),
        phrases=("lean back", "lean forward"),
        mcap=(2, 10, 15),
        rate=0.5,
        waypoint_step=0.05,
        gain_step=0.2,
    ),
    CommandField(
        "lean_left",
        "rad",
        -0.3,
        0.3,
        0.05,
        0.05,
        keys=(("d",), ("a",)),
        phrases=("lean right", "lean left"),
        mcap=(3, 11, 16),
        rate=0.5,
        waypoint_step=0.05,
        gain_step=0.2,
    ),
    CommandField(
        "height",
        "m",
        -0.18,
        0.006,
        0.02,
        0.02,
        keys=(("f",), ("r",)),
        phrases=("crouch", "rise"),
        mcap=(4, 12, 17),
        rate=0.025,
        waypoint_step=0.01,
        gain_step=0.06,
    ),
    CommandField(
        "twist",
        "rad",
        -0.55,
        0.55,
        0.1,
        0.05,
        keys=(("e",), ("q",)),
        phrases=("twist right", "twist left"),
        mcap=(5, 13, 18),
        rate=0.8,
        waypoint_step=0.05,
        gain_step=0.3,
    ),
    CommandField(
        "arms",
        "preset",
        0.0,
        3.0,
        1.0,
        0.1,
        keys=(("0",), ("1",), ("2",), ("3",)),
        phrases=("arms neutral", "arms forward", "arms up", "arms out"),
        mcap=(6, 14, None),
        presets=True,
        rate=0.4,
        waypoint_step=0.1,
        gain_step=0.5,
    ),
    # Velocities in the world frame turned with the body's heading (`Readout`): the ranges of issue 61, which the
    # stepping expert walks (docs/decisions/walking-teacher.md); a key press is a tenth.
    CommandField(
        "forward_speed",
        "m/s",
        -0.3,
        0.6,
        0.1,
        0.1,
        keys=(("down",), ("up",)),
        phrases=("walk backward", "walk forward"),
        mcap=(19, 20, 21),
        posed=False,
        group=VELOCITY,
        rate=0.4,
    ),
    CommandField(
        "sideways_speed",
        "m/s",
        -0.2,
        0.2,
        0.1,
        0.1,
        keys=(("c",), ("z",)),
        phrases=("walk right", "walk left"),
        mcap=(22, 23, 24),
        posed=False,
        group=VELOCITY,
        rate=0.4,
    ),
    CommandField(
        "turn_rate",
        "rad/s",
        -0.5,
        0.5,
        0.1,
        0.1,
        keys=(("right",), ("left",)),
        phrases=("turn right", "turn left"),
        mcap=(25, 26, 27),
        posed=False,
        group=VELOCITY,
        rate=0.5,
    ),
)
"""Every field, in the order of `observation.command`: a dataset recorded before a field existed lacks its entry,
which reads as zero (`teleop.dataset_reader.command_columns`)."""

FIELDS = {field.name: field for field in COMMAND_FIELDS}
COMMAND_NAMES = tuple(FIELDS)
"""The fields' names in order: the names of `observation.command` (and of the expert's `setpoint`)."""
COMMAND_SIZE = len(COMMAND_NAMES)
POSTURE_FIELDS = tuple(field for field in COMMAND_FIELDS if field.group == POSTURE)
POSTURE_NAMES = tuple(field.name for field in POSTURE_FIELDS)
"""The posture fields' names: what a posture-commanded policy reads (`students.inputs`)."""
VELOCITY_NAMES = tuple(field.name for field in COMMAND_FIELDS if field.group == VELOCITY)


def field_positions(names: tuple[str, ...] | list[str]) -> list[int]:
    """Where the fields `names` sit in a command vector (`COMMAND_NAMES` order)."""
    return [COMMAND_NAMES.index(name) for name in names]


def tolerances(fields: Iterable[CommandField]) -> np.ndarray:
    """The fields' tolerances, in their order."""
    return np.array([field.tolerance for field in fields])


STAND, POSTURE_TASK, WALK = "stand", "posture", "walk"
TASKS = (STAND, POSTURE_TASK, WALK)
"""What the operator asks for (`TASK=`, every stage's `--task`): `stand` still (the zero command), follow `posture`
commands (the scripted operator's schedules of the posture fields; the pipeline's task), or `walk` too (schedules that
mix walks in: every field). A controller that follows them says so (`takes_command`, `walks`)."""


def task_fields(task: str) -> tuple[CommandField, ...]:
    """The fields `task` commands, tracks and scores: every field when walking, else the posture fields."""
    return COMMAND_FIELDS if task == WALK else POSTURE_FIELDS


ARM_JOINTS = (
    "right_shoulder1",
    "right_shoulder2",
    "right_elbow",
    "left_shoulder1",
    "left_shoulder2",
    "left_elbow",
)
"""The joints the arm presets set (`task.posture.ARM_POSES`), whose angles `Readout` reads for `arms`."""


class Readout:
    """The achieved value of every field, read from the body's state (qpos without root x and y, (..., nq - 2), and
    qvel (..., nv), which a field read from velocities needs).

    `lean_forward` and `lean_left` are the pitch and sideways lean of the torso with its twist undone (the root's
    orientation times the abdomen_z rotation, as Euler angles z-y-x: pitch, then roll = -lean_left), `height` the
    root's, `twist` -abdomen_z, `arms` the six `ARM_JOINTS` angles. The velocities are the root's, in the world frame
    turned with the heading of that untwisted torso (so twisting the waist turns no walk): `forward_speed` along the
    heading, `sideways_speed` to its left, `turn_rate` the yaw rate about the vertical.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.twist_at = int(model.joint("abdomen_z").qposadr[0]) - 2
        self.arms_at = [int(model.joint(name).qposadr[0]) - 2 for name in ARM_JOINTS]

    def __call__(self, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
        """Field name -> its coordinates (..., k), k = 1 but for the arms' 6."""
        abdomen_z = qpos[..., self.twist_at]
        half = abdomen_z / 2
        zero = np.zeros_like(half)
        unyaw = np.moveaxis(np.array([np.cos(half), zero, zero, np.sin(half)]), 0, -1)
        frame = np.swapaxes(body_axes(unyaw) @ body_axes(qpos[..., 1:5]), -1, -2)  # R(root) R(unyaw)
        heading = np.arctan2(frame[..., 1, 0], frame[..., 0, 0])
        cos, sin, vx, vy = np.cos(heading), np.sin(heading), qvel[..., 0], qvel[..., 1]
        return {
            "lean_forward": np.arcsin(np.clip(-frame[..., 2, 0], -1.0, 1.0))[..., None],
            "lean_left": -np.arctan2(frame[..., 2, 1], frame[..., 2, 2])[..., None],
            "height": qpos[..., 0:1],
            "twist": -abdomen_z[..., None],
            "arms": qpos[..., self.arms_at],
            "forward_speed": (cos * vx + sin * vy)[..., None],
            "sideways_speed": (cos * vy - sin * vx)[..., None],
            "turn_rate": yaw_rate(qpos[..., 1:5], qvel[..., 3:6])[..., None],
        }
