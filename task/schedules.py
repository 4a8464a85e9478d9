"""The scripted operator: the commands of a task, drawn from a seed, and the task strings that name them
(docs/concepts/commands.md).

A command is a `task.posture.Posture`, carried as a vector in the order of `task.command_fields`' table (the dataset's
`observation.command`, a commanded policy's last inputs); each field's limits, step and words come from its row there.
Standing still is the zero command.

- `task_commands(task, seed, steps, dt)`: what the operator commands over an episode of each task (`TASKS`): the zero
  command to stand, or the schedule drawn from the seed, of postures or of postures and walks.
- `command_schedule(seed, steps)`: the scripted operator (`make record`'s schedules, and the held-out
  schedules of `make eval`): after a neutral start, targets on the keyboard's grid (each field's
  `step`), one to three fields at a time inside `SCALE` of each limit, some neutral, each held
  `HOLD_SECONDS` once the setpoint has got there; drawn from the seed alone, so reproducible.
- `held_commands(posture, steps, dt)`: one command held as `make play`'s keys hold it (`make eval HOLD=`), and
  `parse_held(text)` the command from its fields' values.
- `task_for(posture)`: the task string naming a command (the dataset's `task`).
"""

from __future__ import annotations

import math

import numpy as np

from common.cli import UserError, assignments
from task.command_fields import (
    COMMAND_FIELDS,
    COMMAND_NAMES,
    COMMAND_SIZE,
    FIELDS,
    POSTURE_FIELDS,
    POSTURE_NAMES,
    STAND,
    TASKS,
    VELOCITY,
    VELOCITY_NAMES,
    WALK,
)
from task.posture import NEUTRAL, Posture, move_seconds

DEFAULT_TASK = "Stand still on both feet."
"""The task string of the zero command."""

# A scripted schedule. The first stretch is neutral: the body drops about 12 cm after reset and the expert's planned
# landing holds the neutral stance (teachers.landing) for its first 3 s. Then each target is held HOLD_SECONDS once
# the setpoint has got there (move_seconds). Docs: docs/decisions/command-schedules.md.
FIRST_NEUTRAL_SECONDS = 3.0
HOLD_SECONDS = (2.0, 4.0)
NEUTRAL_SHARE = 0.2
"""Share of the targets after the first that are the neutral stand: standing stays in the data and the tests."""
FIELDS_AT_ONCE = (0.5, 0.35, 0.15)
"""Probabilities that a target moves 1, 2 or 3 fields away from neutral."""
SCALE = 0.5
"""Posture targets stay within this share of each field's limits: at 0.7 the expert fell on 2 of 40
held-out schedules, at 0.5 on none (docs/decisions/command-schedules.md). Velocity targets span their whole range."""
WALKING_SHARE = 0.5
"""In a walking schedule, the share of the targets after the first that are a walk (one or two velocity fields, no
posture); of the others, `NEUTRAL_SHARE` stand still and the rest are postures, as in a posture schedule."""
WALK_FIELDS_AT_ONCE = (0.6, 0.4)
"""Probabilities that a walk sets 1 or 2 velocity fields."""
HELD_SECONDS = 5.0
"""How long `held_commands` holds its command: `make play`'s test holds ↑ this long and asks for a metre."""


def command_vector(posture: Posture) -> np.ndarray:
    """The command `posture` as a policy reads it: float32, `COMMAND_NAMES` order."""
    return np.array([getattr(posture, name) for name in COMMAND_NAMES], np.float32)


def command_posture(command: np.ndarray) -> Posture:
    """The posture a command vector asks for (as given: the expert clips what it holds)."""
    return Posture(**{name: float(value) for name, value in zip(COMMAND_NAMES, command, strict=True)})


def _grid(name: str) -> np.ndarray:
    """The nonzero values of field `name` on the keyboard's grid within SCALE of its limits (a velocity's: within its
    limits; every preset)."""
    field = FIELDS[name]
    if field.presets:
        return np.arange(1.0, field.high + 1.0)  # a preset: no fraction of one
    if field.group == VELOCITY:
        low, high = round(field.low / field.step), round(field.high / field.step)
    else:  # truncated, as it always was: lean_left's 0.5 * 0.3 / 0.05 falls just short of 3, so it stops at 0.1
        low, high = int(SCALE * field.low / field.step), int(SCALE * field.high / field.step)
    return np.array([round(k * field.step, 6) for k in range(low, high + 1) if k != 0])


def _target(rng: np.random.Generator, names: tuple[str, ...], at_once: tuple[float, ...]) -> Posture:
    """A target setting 1, 2, ... (probabilities `at_once`) of the fields `names` to values on their grids."""
    count = 1 + int(rng.choice(len(at_once), p=at_once))
    fields = rng.choice(names, size=count, replace=False)
    return Posture(**{str(name): float(rng.choice(_grid(str(name)))) for name in fields})


def schedule_targets(seed: int, seconds: float, walking: bool = False) -> list[tuple[float, Posture]]:
    """(start time in s, target) of each command of the schedule drawn from `seed`, covering `seconds`: postures, or
    with `walking` walks too (`WALKING_SHARE`)."""
    if seed < 0:
        raise UserError(f"a schedule's seed must be >= 0, got {seed}")
    rng = np.random.default_rng((seed, 2))  # its own stream: the seed's noise and randomisation use others
    targets = [(0.0, NEUTRAL)]
    now, previous = FIRST_NEUTRAL_SECONDS, NEUTRAL
    while now < seconds:
        if walking and rng.random() < WALKING_SHARE:
            target = _target(rng, VELOCITY_NAMES, WALK_FIELDS_AT_ONCE)
        elif rng.random() < NEUTRAL_SHARE:
            target = NEUTRAL
        else:
            target = _target(rng, POSTURE_NAMES, FIELDS_AT_ONCE)
        if target == previous:
            first = COMMAND_FIELDS[0]
            target = NEUTRAL if previous != NEUTRAL else Posture(**{first.name: first.step})
        targets.append((now, target))
        now += move_seconds(previous, target) + float(rng.uniform(*HOLD_SECONDS))
        previous = target
    return targets


def task_commands(task: str, seed: int, steps: int, dt: float) -> np.ndarray:
    """The commands (steps, COMMAND_SIZE) float32 the operator gives over an episode of `task` (`TASKS`) drawn from
    `seed`, one row per env step of `dt` s: zero to stand, else `command_schedule` (with walks for `walk`)."""
    if task not in TASKS:
        raise UserError(f"unknown task {task!r}; tasks: {', '.join(TASKS)}")
    if task == STAND:
        return np.zeros((steps, COMMAND_SIZE), np.float32)
    return command_schedule(seed, steps, dt, walking=task == WALK)


def command_schedule(seed: int, steps: int, dt: float, walking: bool = False) -> np.ndarray:
    """The commands (steps, COMMAND_SIZE) float32 of the schedule drawn from `seed` (`walking`: with walks), one row
    per env step of `dt` s."""
    commands = np.empty((steps, COMMAND_SIZE), np.float32)
    targets = schedule_targets(seed, steps * dt, walking)
    for (start, target), (end, _) in zip(targets, [*targets[1:], (np.inf, NEUTRAL)], strict=True):
        commands[int(round(start / dt)) : int(min(round(end / dt), steps)) if np.isfinite(end) else steps] = (
            command_vector(target)
        )
    return commands


def held_commands(posture: Posture, steps: int, dt: float) -> np.ndarray:
    """The commands (steps, COMMAND_SIZE) float32 of an operator who holds `posture` as `make play`'s keys would: the
    zero command for the first `FIRST_NEUTRAL_SECONDS` (the body lands), `posture` for `HELD_SECONDS`, then the zero
    command to the end."""
    commands = np.zeros((steps, COMMAND_SIZE), np.float32)
    commands[int(round(FIRST_NEUTRAL_SECONDS / dt)) : int(round((FIRST_NEUTRAL_SECONDS + HELD_SECONDS) / dt))] = (
        command_vector(posture)
    )
    return commands


def parse_held(text: str) -> Posture:
    """The command `text` names, FIELD=VALUE,... in each field's unit (`forward_speed=0.5`: ↑ pressed five times),
    clipped to the fields' limits as the keys clip it; UserError, one line, for an unknown field, a field given twice or
    a value that is no number."""
    values: dict[str, float] = {}
    try:
        for item, name, equals, value in assignments(text, "--hold"):
            if name not in FIELDS or not equals:
                raise UserError(f"--hold: {item!r} is not FIELD=VALUE with a field of {', '.join(COMMAND_NAMES)}")
            try:
                values[name] = float(value)
            except ValueError:
                values[name] = math.nan
            if not math.isfinite(values[name]):
                raise UserError(f"--hold: {item!r} is not FIELD=VALUE with a number VALUE")
    except ValueError as error:  # a field given twice
        raise UserError(str(error)) from None
    return Posture(**values).clipped()


def task_for(posture: Posture) -> str:
    """The task string naming a command: its fields' phrases (their rows'), those away from neutral, a velocity's with
    its value ("Walk forward at 0.4 m/s, turn left at 0.2 rad/s."), a posture alone "... while standing."."""
    moving = [
        f"{FIELDS[name].phrase(value)} at {abs(value):g} {FIELDS[name].unit}"
        for name in VELOCITY_NAMES
        if (value := round(getattr(posture, name), 6))
    ]
    posed = [field.phrase(value) for field in POSTURE_FIELDS if (value := getattr(posture, field.name))]
    if not moving and not posed:
        return DEFAULT_TASK
    sentence = ", ".join(moving + posed) + ("." if moving else " while standing.")
    return sentence[0].upper() + sentence[1:]
