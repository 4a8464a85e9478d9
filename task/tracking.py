"""How well a controller follows the operator: the error per command field, and PPO's task of following it
(docs/concepts/commands.md).

- `Tracking`: the error between commanded and achieved command per field, from the observation alone (root
  orientation, height and the joint angles a recorded frame holds), and `tracking_summary` over an episode: the error
  once settled and the time to settle (defined under `SETTLED_SECONDS`, each field's tolerance).
- `CommandedTask`: PPO's training episodes under schedules drawn from seeds no recording or evaluation uses, the
  tracking rewarded with an exponential kernel on the error (`tracking_reward`).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from common.seed_ranges import TRAINING_SEEDS
from humanoid.env import QPOS_OBS, QVEL_OBS, nominal_model, step_seconds
from task.command_fields import (
    COMMAND_FIELDS,
    COMMAND_NAMES,
    COMMAND_SIZE,
    FIELDS,
    CommandField,
    Readout,
    field_positions,
    task_fields,
    tolerances,
)
from task.posture import NEUTRAL, commanded_pose, move_seconds
from task.schedules import command_posture, command_vector, task_commands

# Tracking. The achieved command is read from the observation's qpos and qvel parts (`QPOS_OBS`, `QVEL_OBS`), in both
# the full observation and a recorded frame; settled means every field's error within its row's tolerance (about one
# key press, half of one for the twist).
SPEED_SECONDS = 1.0
"""A walk's achieved velocity is its mean over the last this-many seconds (`Tracking.errors`): the body sways within a
stride (under the stepping teacher the torso's speed swings by about ±0.5 m/s, its yaw rate by up to ±5 rad/s), and
what a command asks for is the walk's speed, not the sway's (docs/decisions/walking-teacher.md)."""
SETTLED_SECONDS = 1.0
"""The error once settled is the mean over the last this-many seconds of each command held, after the setpoint's move
to it (`move_seconds`), at least twice as long: as a schedule holds every command (`HOLD_SECONDS`) but the one the
episode's end cuts short, which may still be on its way."""


class Tracking:
    """Commanded against achieved command, per field, for observations of `model`'s Humanoid-v5.

    Achieved: each field's coordinates as `task.command_fields.Readout` reads them from the body. Commanded: for a
    posed field the same coordinates of the balanced pose that realises the command (`commanded_pose`), so a body
    held exactly there has no error; for another (a velocity) its commanded value. A field's error is the mean over
    its coordinates (the arms' six angles). `fields`: those measured, in the table's order (a task's: `task_fields`);
    commands are whole command vectors (`COMMAND_NAMES` order) whatever the fields.
    """

    def __init__(self, model: mujoco.MjModel, fields: tuple[CommandField, ...] = COMMAND_FIELDS) -> None:
        self.model = model
        self.fields = fields
        self.tolerances = tolerances(fields)
        """Each field's tolerance, in `fields` order."""
        self.readout = Readout(model)
        self.speed_steps = round(SPEED_SECONDS / step_seconds(model))
        """`SPEED_SECONDS` in env steps."""
        self._rest = np.zeros(model.nv)
        read = self.readout(model.qpos0[2:], self._rest)
        widths = [read[field.name].shape[-1] for field in fields]
        ends = np.cumsum(widths)
        self.slices = [slice(end - width, end) for width, end in zip(widths, ends, strict=True)]
        """Where each field's coordinates sit among `coordinates`, in the table's order."""
        self._targets: dict[tuple[float, ...], np.ndarray] = {}

    def coordinates(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """(..., coordinates) every field's coordinates side by side, of a state: (..., nq - 2) qpos without x and y,
        (..., nv) qvel."""
        read = self.readout(qpos, qvel)
        return np.concatenate([read[field.name] for field in self.fields], axis=-1)

    def target(self, command: np.ndarray) -> np.ndarray:
        """The coordinates `command` asks for (clipped as the expert clips it): its posed fields' balanced pose's, its
        other fields' values."""
        key = tuple(float(v) for v in command)
        if key not in self._targets:
            posture = command_posture(np.asarray(command)).clipped()
            pose = commanded_pose(self.model, posture.posed())[2:]
            target = self.coordinates(pose, self._rest)
            for field, part in zip(self.fields, self.slices, strict=True):
                if not field.posed:
                    target[part] = getattr(posture, field.name)
            self._targets[key] = target
        return self._targets[key]

    def achieved(self, observations: np.ndarray) -> np.ndarray:
        """(T, plotted) the achieved value of each of these fields Foxglove plots beside its command (`PLOTTED`: those
        read from one coordinate; all of them for the whole table), from the neutral pose's, of observations
        (T, 348)."""
        coordinates = self.coordinates(*_state(observations))
        neutral = self.target(np.zeros(COMMAND_SIZE))
        columns = [self.slices[self.fields.index(field)].start for field in PLOTTED if field in self.fields]
        return coordinates[:, columns] - neutral[columns]

    def errors(self, observations: np.ndarray, commands: np.ndarray) -> np.ndarray:
        """|commanded - achieved| (T, fields) of observations (T, 348), consecutive steps of one episode, under commands
        (T, COMMAND_SIZE); a velocity's achieved value is its mean over the last `SPEED_SECONDS` (over the steps so far
        in the first ones)."""
        coordinates = self.coordinates(*_state(observations))
        for field, part in zip(self.fields, self.slices, strict=True):
            if not field.posed:
                coordinates[:, part] = trailing_mean(coordinates[:, part], self.speed_steps)
        targets = np.empty_like(coordinates)
        changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
        for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
            targets[start:end] = self.target(commands[start])
        return self._fields(np.abs(coordinates - targets))

    def error(self, qpos: np.ndarray, qvel: np.ndarray, command: np.ndarray) -> np.ndarray:
        """`errors` of one state, (fields,) from qpos without x and y and qvel under `command`: the same numbers for the
        posed fields, a few times faster than through `errors` (PPO's reward computes it every step); a velocity's
        error is this step's, unaveraged, as the public velocity tasks reward it."""
        return self._fields(np.abs(self.coordinates(qpos, qvel) - self.target(command)))

    def _fields(self, gap: np.ndarray) -> np.ndarray:
        """Per command field (..., fields) of a coordinates' gap: the mean over each field's coordinates."""
        return np.stack([gap[..., part].mean(axis=-1) for part in self.slices], axis=-1)

    def reward(self, errors: np.ndarray) -> np.ndarray:
        """`tracking_reward` of errors (..., fields) of these fields."""
        return tracking_reward(errors, self.tolerances)

    def summary(self, errors: np.ndarray, commands: np.ndarray, dt: float) -> dict[str, dict[str, float] | float]:
        """`tracking_summary` of `errors` (T, fields) under commands (T, COMMAND_SIZE), per field of these."""
        return tracking_summary(errors, commands, dt, self.fields)


def trailing_mean(values: np.ndarray, window: int) -> np.ndarray:
    """The mean of each row of `values` (T, k) and the `window` - 1 before it (fewer in the first rows)."""
    total = np.cumsum(values, axis=0)
    total[window:] -= total[:-window].copy()
    counts = np.minimum(np.arange(1, len(values) + 1), window)[:, None]
    return total / counts


def _state(observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qpos without x and y, qvel) of Humanoid-v5 observations (T, 348), in float64 (a frame is float32 on disk)."""
    observations = np.asarray(observations, np.float64)
    return observations[:, QPOS_OBS], observations[:, QVEL_OBS]


PLOTTED = tuple(field for field in COMMAND_FIELDS if field.mcap[2] is not None)
"""The fields whose achieved value `/command` carries (one coordinate each; the arms show in 3D)."""


def tracking_summary(
    errors: np.ndarray, commands: np.ndarray, dt: float, fields: tuple[CommandField, ...] = COMMAND_FIELDS
) -> dict[str, dict[str, float] | float]:
    """An episode's tracking: per field the mean error once settled (over the last SETTLED_SECONDS of each command
    held at least twice that after the setpoint's move to it), the same over only the commands that set that field
    away from neutral ("moved_error": the posture asked for rather than the stand held, which most commands leave
    most fields at), and the mean time from a command's change until every field stays within its tolerance (a command
    never settled counts its whole duration). NaN where no command was held long enough. `errors` (T, fields) are of
    `fields`, `commands` (T, COMMAND_SIZE) whole."""
    names = [field.name for field in fields]
    columns, allowed = field_positions(names), tolerances(fields)
    window = round(SETTLED_SECONDS / dt)
    changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
    settled, moved, times, previous = [], [], [], NEUTRAL
    for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
        inside = (errors[start:end] <= allowed).all(axis=1)
        outside = np.flatnonzero(~inside)
        times.append((outside[-1] + 1 if len(outside) else 0) * dt)
        target = command_posture(commands[start]).clipped()
        moving = int(np.ceil(move_seconds(previous, target) / dt - 1e-9))  # the expert's ramp: whole steps
        if end - start >= moving + 2 * window:
            settled.append(errors[end - window : end])
            away = (command_vector(target) != command_vector(NEUTRAL))[columns]
            moved.append(np.broadcast_to(away, (window, len(names))))
        previous = target
    if settled:
        held, asked = np.concatenate(settled), np.concatenate(moved)
        mean = held.mean(axis=0)
        with np.errstate(invalid="ignore"):  # NaN for a field no settled command moved
            moved_mean = (held * asked).sum(axis=0) / asked.sum(axis=0)
    else:
        mean = moved_mean = np.full(len(names), np.nan)
    return {
        "settled_error": dict(zip(names, map(float, mean), strict=True)),
        "moved_error": dict(zip(names, map(float, moved_mean), strict=True)),
        "settle_seconds": float(np.mean(times)) if times else float("nan"),
    }


ERROR_KINDS = ("settled_error", "moved_error")
"""The per-field errors a `tracking_summary` holds: a result file without one was written by an older version."""


def combine_tracking(summaries: list[dict]) -> dict[str, dict[str, float] | float]:
    """The mean over episodes of their `tracking_summary`s, each field's over the episodes where it is a number: NaN
    (without numpy's warning) where none is, as for a policy that falls before any command was held long enough."""

    def mean(values: list[float]) -> float:
        numbers = [value for value in values if not np.isnan(value)]
        return float(np.mean(numbers)) if numbers else float("nan")

    names = tracked_names(summaries[0])
    return {
        **{kind: {name: mean([s[kind][name] for s in summaries]) for name in names} for kind in ERROR_KINDS},
        "settle_seconds": mean([s["settle_seconds"] for s in summaries]),
    }


def tracked_names(summary: dict[str, Any]) -> tuple[str, ...]:
    """The fields a `tracking_summary` (or `combine_tracking`) measured, in the table's order."""
    return tuple(name for name in COMMAND_NAMES if name in summary["settled_error"])


def error_text(value: float | None, digits: int = 3) -> str:
    """An error of a `tracking_summary` to `digits` places as the tables print it; "n/a" where no command was held
    long enough to measure it (NaN, or null as a saved run's JSON holds it)."""
    return "n/a" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def tracking_reward(errors: np.ndarray, tolerances: np.ndarray) -> np.ndarray:
    """The tracking term of PPO's reward for errors (..., fields) of fields with `tolerances`: the mean over the
    fields of exp(-(error / tolerance)²), as the public humanoid stacks reward a command (1 on it, 0.37 one key press
    off; a kernel half or twice as wide did worse: docs/decisions/tracking-weight.md)."""
    return np.exp(-np.square(errors / tolerances)).mean(axis=-1)


def tracking_score(summary: dict[str, dict[str, float] | float]) -> float:
    """`tracking_reward` of the settled errors of a `tracking_summary` (or `combine_tracking`), over the fields it
    measured: 1 for exact tracking, 0 where nothing was held long enough to measure (NaN, or null as a saved run's JSON
    holds it: `common.cli.json_text`)."""
    names = tracked_names(summary)
    errors = np.array([summary["settled_error"][name] for name in names], dtype=float)  # None -> NaN
    return 0.0 if np.isnan(errors).any() else float(tracking_reward(errors, tolerances(FIELDS[name] for name in names)))


COMMAND_INFO = "command"
"""The info key under which `CommandedTask` gives the command in force (`students.inputs.InputObservation` reads it)."""
SCHEDULE_STREAM = 6  # random stream of the training schedules' seeds: (seed, 6); humanoid.conditions lists the others


class CommandedTask(gym.Wrapper):
    """PPO's task of following the operator (`make finetune-rl` from a student that takes a command).

    Each episode follows a schedule (`task.schedules.task_commands` of `task`: a neutral start, targets held a few
    seconds, some of them the zero command) whose seed is drawn from the wrapper's stream, seeded by the reset's seed,
    so episodes repeat exactly (and a resumed run replays them: `random_state`). The command in force goes out in
    `info[COMMAND_INFO]` at the reset and after every step, for the actor's inputs; each step's reward adds `weight` ×
    `tracking_reward` of the true posture reached against the command acted under (the simulator's, not the possibly
    noisy observation's). With `weight` 0 the reward is the environment's alone.
    """

    def __init__(self, env: gym.Env, weight: float, task: str) -> None:
        super().__init__(env)
        self.weight = weight
        self.task = task
        self.tracking = Tracking(nominal_model(), task_fields(task))  # the nominal body's, whatever is drawn later
        self._rng = np.random.default_rng()
        self.commands = np.zeros((env.spec.max_episode_steps, COMMAND_SIZE), np.float32)
        self.t = 0

    def random_state(self) -> dict:
        """The stream the next unseeded reset draws its schedule from (`rl.vec_env` saves it to resume)."""
        return {"schedules": self._rng.bit_generator.state}

    def set_random_state(self, state: dict) -> None:
        self._rng.bit_generator.state = state["schedules"]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if seed is not None:
            self._rng = np.random.default_rng((seed, SCHEDULE_STREAM))
        obs, info = self.env.reset(seed=seed, options=options)
        schedule = int(self._rng.integers(*TRAINING_SEEDS))
        self.commands = task_commands(self.task, schedule, self.env.spec.max_episode_steps, self.env.unwrapped.dt)
        self.t = 0
        info[COMMAND_INFO] = self.commands[0]
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        command = self.commands[self.t]
        data = self.env.unwrapped.data
        error = self.tracking.error(data.qpos[2:], data.qvel, command)
        reward += self.weight * float(self.tracking.reward(error))
        self.t = min(self.t + 1, len(self.commands) - 1)
        info[COMMAND_INFO] = self.commands[self.t]
        return obs, reward, terminated, truncated, info
