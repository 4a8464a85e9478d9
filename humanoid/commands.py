"""Operator commands: the posture an operator asks for, as a policy reads it, as a script draws it, and how
well a controller tracks it (docs/concepts/commands.md).

A command is a `humanoid.posture.Posture`, carried as a vector in the order of `humanoid.command_fields`' table
(the dataset's `observation.command`, a commanded policy's last inputs); each field's limits, step, tolerance,
keys and words come from its row there. Standing still is the zero command.

- `command_schedule(seed, steps)`: the scripted operator (`make record`'s schedules, and the held-out
  schedules of `make eval`): after a neutral start, targets on the keyboard's grid (each field's
  `step`), one to three fields at a time inside `SCALE` of each limit, some neutral, each held
  `HOLD_SECONDS` once the expert's setpoint has got there; drawn from the seed alone, so reproducible.
- `CommandedTask`: PPO's training episodes under schedules drawn from seeds no recording or evaluation uses, the
  tracking rewarded with an exponential kernel on the error (`tracking_reward`).
- `Tracking`: the error between commanded and achieved posture per field, from the observation alone
  (root orientation, height and the joint angles a recorded frame holds), and `tracking_summary` over an
  episode: the error once settled and the time to settle (defined under `SETTLED_SECONDS`, each field's
  tolerance).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import UserError
from common.seed_ranges import TRAINING_SEEDS
from humanoid.command_fields import (
    COMMAND_FIELDS,
    COMMAND_NAMES,
    COMMAND_SIZE,
    FIELDS,
    TOLERANCES,
    CommandField,
    Readout,
)
from humanoid.env import QPOS_OBS, QVEL_OBS, nominal_model
from humanoid.posture import NEUTRAL, Posture, move_seconds, posture_reference

DEFAULT_TASK = "Stand still on both feet."
"""The task string of the zero command."""

# A scripted schedule. The first stretch is neutral: the body drops about 12 cm after reset and the expert's planned
# landing holds the neutral stance (humanoid.landing) for its first 3 s. Then each target is held HOLD_SECONDS once
# the setpoint has got there (move_seconds). Docs: docs/decisions/command-schedules.md.
FIRST_NEUTRAL_SECONDS = 3.0
HOLD_SECONDS = (2.0, 4.0)
NEUTRAL_SHARE = 0.2
"""Share of the targets after the first that are the neutral stand: standing stays in the data and the tests."""
FIELDS_AT_ONCE = (0.5, 0.35, 0.15)
"""Probabilities that a target moves 1, 2 or 3 fields away from neutral."""
SCALE = 0.5
"""Targets stay within this share of each field's limits: at 0.7 the expert fell on 2 of 40
held-out schedules, at 0.5 on none (docs/decisions/command-schedules.md)."""


def command_vector(posture: Posture) -> np.ndarray:
    """The command `posture` as a policy reads it: float32, `COMMAND_NAMES` order."""
    return np.array([getattr(posture, name) for name in COMMAND_NAMES], np.float32)


def command_posture(command: np.ndarray) -> Posture:
    """The posture a command vector asks for (as given: the expert clips what it holds)."""
    return Posture(**{name: float(value) for name, value in zip(COMMAND_NAMES, command, strict=True)})


def _grid(name: str) -> np.ndarray:
    """The nonzero values of field `name` on the keyboard's grid within SCALE of its limits (every preset)."""
    field = FIELDS[name]
    if field.presets:
        return np.arange(1.0, field.high + 1.0)  # a preset: no fraction of one
    low, high = (int(SCALE * field.low / field.step), int(SCALE * field.high / field.step))
    return np.array([round(k * field.step, 6) for k in range(low, high + 1) if k != 0])


def schedule_targets(seed: int, seconds: float) -> list[tuple[float, Posture]]:
    """(start time in s, target) of each command of the schedule drawn from `seed`, covering `seconds`."""
    if seed < 0:
        raise UserError(f"a schedule's seed must be >= 0, got {seed}")
    rng = np.random.default_rng((seed, 2))  # its own stream: the seed's noise and randomisation use others
    targets = [(0.0, NEUTRAL)]
    now, previous = FIRST_NEUTRAL_SECONDS, NEUTRAL
    while now < seconds:
        if rng.random() < NEUTRAL_SHARE:
            target = NEUTRAL
        else:
            count = 1 + int(rng.choice(len(FIELDS_AT_ONCE), p=FIELDS_AT_ONCE))
            fields = rng.choice(COMMAND_NAMES, size=count, replace=False)
            target = Posture(**{str(name): float(rng.choice(_grid(str(name)))) for name in fields})
        if target == previous:
            first = COMMAND_FIELDS[0]
            target = NEUTRAL if previous != NEUTRAL else Posture(**{first.name: first.step})
        targets.append((now, target))
        now += move_seconds(previous, target) + float(rng.uniform(*HOLD_SECONDS))
        previous = target
    return targets


def command_schedule(seed: int, steps: int, dt: float) -> np.ndarray:
    """The commands (steps, COMMAND_SIZE) float32 of the schedule drawn from `seed`, one row per env step of `dt` s."""
    commands = np.empty((steps, COMMAND_SIZE), np.float32)
    targets = schedule_targets(seed, steps * dt)
    for (start, target), (end, _) in zip(targets, [*targets[1:], (np.inf, NEUTRAL)], strict=True):
        commands[int(round(start / dt)) : int(min(round(end / dt), steps)) if np.isfinite(end) else steps] = (
            command_vector(target)
        )
    return commands


def task_for(posture: Posture) -> str:
    """The task string naming a commanded posture: its fields' phrases (their rows'), those away from neutral."""
    phrases = [field.phrase(value) for field in COMMAND_FIELDS if (value := getattr(posture, field.name))]
    if not phrases:
        return DEFAULT_TASK
    return (", ".join(phrases) + " while standing.").capitalize()


# Tracking. The achieved command is read from the observation's qpos and qvel parts (`QPOS_OBS`, `QVEL_OBS`), in both
# the full observation and a recorded frame; settled means every field's error within its row's tolerance (about one
# key press, half of one for the twist).
SETTLED_SECONDS = 1.0
"""The error once settled is the mean over the last this-many seconds of each command held, after the setpoint's move
to it (`move_seconds`), at least twice as long: as a schedule holds every command (`HOLD_SECONDS`) but the one the
episode's end cuts short, which may still be on its way."""


class Tracking:
    """Commanded against achieved command, per field, for observations of `model`'s Humanoid-v5.

    Achieved: each field's coordinates as `humanoid.command_fields.Readout` reads them from the body. Commanded: for a
    posed field the same coordinates of the balanced pose that realises the command (`posture_reference`), so a body
    held exactly there has no error; for another its commanded value. A field's error is the mean over its
    coordinates (the arms' six angles). `fields` and `readout`: the table and its reader, the project's by default;
    a new field's code passes both (tests/humanoid/test_command_fields.py adds a forward-speed row this way).
    """

    def __init__(
        self, model: mujoco.MjModel, fields: tuple[CommandField, ...] = COMMAND_FIELDS, readout: Readout | None = None
    ) -> None:
        self.model = model
        self.fields = fields
        self.readout = Readout(model) if readout is None else readout
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
            posed = {field.name: float(value) for field, value in zip(self.fields, command, strict=True) if field.posed}
            pose = posture_reference(self.model, Posture(**posed).clipped())[0][2:]
            target = self.coordinates(pose, self._rest)
            for field, value, part in zip(self.fields, command, self.slices, strict=True):
                if not field.posed:
                    target[part] = field.clip(float(value))
            self._targets[key] = target
        return self._targets[key]

    def achieved(self, observations: np.ndarray) -> np.ndarray:
        """(T, len(PLOTTED)) the achieved value of each field Foxglove plots beside its command (`PLOTTED`: those read
        from one coordinate), from the neutral pose's, of observations (T, 348)."""
        coordinates = self.coordinates(*_state(observations))
        neutral = self.target(np.zeros(len(self.fields)))
        columns = [self.slices[self.fields.index(field)].start for field in PLOTTED]
        return coordinates[:, columns] - neutral[columns]

    def errors(self, observations: np.ndarray, commands: np.ndarray) -> np.ndarray:
        """|commanded - achieved| (T, fields) of observations (T, 348) under commands (T, fields)."""
        coordinates = self.coordinates(*_state(observations))
        targets = np.empty_like(coordinates)
        changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
        for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
            targets[start:end] = self.target(commands[start])
        return self._fields(np.abs(coordinates - targets))

    def error(self, qpos: np.ndarray, qvel: np.ndarray, command: np.ndarray) -> np.ndarray:
        """`errors` of one state, (fields,) from qpos without x and y and qvel under `command`: the same numbers, a few
        times faster than through `errors` (PPO's reward computes it every step)."""
        return self._fields(np.abs(self.coordinates(qpos, qvel) - self.target(command)))

    def _fields(self, gap: np.ndarray) -> np.ndarray:
        """Per command field (..., fields) of a coordinates' gap: the mean over each field's coordinates."""
        return np.stack([gap[..., part].mean(axis=-1) for part in self.slices], axis=-1)


def _state(observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qpos without x and y, qvel) of Humanoid-v5 observations (T, 348), in float64 (a frame is float32 on disk)."""
    observations = np.asarray(observations, np.float64)
    return observations[:, QPOS_OBS], observations[:, QVEL_OBS]


PLOTTED = tuple(field for field in COMMAND_FIELDS if field.mcap[2] is not None)
"""The fields whose achieved value `/command` carries (one coordinate each; the arms show in 3D)."""


def tracking_summary(errors: np.ndarray, commands: np.ndarray, dt: float) -> dict[str, dict[str, float] | float]:
    """An episode's tracking: per field the mean error once settled (over the last SETTLED_SECONDS of each command
    held at least twice that after the setpoint's move to it), the same over only the commands that set that field
    away from neutral ("moved_error": the posture asked for rather than the stand held, which most commands leave
    most fields at), and the mean time from a command's change until every field stays within its tolerance (a command
    never settled counts its whole duration). NaN where no command was held long enough."""
    window = round(SETTLED_SECONDS / dt)
    changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
    settled, moved, times, previous = [], [], [], NEUTRAL
    for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
        inside = (errors[start:end] <= TOLERANCES).all(axis=1)
        outside = np.flatnonzero(~inside)
        times.append((outside[-1] + 1 if len(outside) else 0) * dt)
        target = command_posture(commands[start]).clipped()
        moving = int(np.ceil(move_seconds(previous, target) / dt - 1e-9))  # the expert's ramp: whole steps
        if end - start >= moving + 2 * window:
            settled.append(errors[end - window : end])
            moved.append(np.broadcast_to(command_vector(target) != command_vector(NEUTRAL), (window, COMMAND_SIZE)))
        previous = target
    if settled:
        held, asked = np.concatenate(settled), np.concatenate(moved)
        mean = held.mean(axis=0)
        with np.errstate(invalid="ignore"):  # NaN for a field no settled command moved
            moved_mean = (held * asked).sum(axis=0) / asked.sum(axis=0)
    else:
        mean = moved_mean = np.full(COMMAND_SIZE, np.nan)
    return {
        "settled_error": dict(zip(COMMAND_NAMES, map(float, mean), strict=True)),
        "moved_error": dict(zip(COMMAND_NAMES, map(float, moved_mean), strict=True)),
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

    return {
        **{kind: {name: mean([s[kind][name] for s in summaries]) for name in COMMAND_NAMES} for kind in ERROR_KINDS},
        "settle_seconds": mean([s["settle_seconds"] for s in summaries]),
    }


def tracking_reward(errors: np.ndarray) -> np.ndarray:
    """The tracking term of PPO's reward for errors (..., COMMAND_SIZE): the mean over the fields of
    exp(-(error / tolerance)²), as the public humanoid stacks reward a command (1 on it, 0.37 one key press off; a
    kernel half or twice as wide did worse: docs/decisions/tracking-weight.md)."""
    return np.exp(-np.square(errors / TOLERANCES)).mean(axis=-1)


def tracking_score(summary: dict[str, dict[str, float] | float]) -> float:
    """`tracking_reward` of the settled errors of a `tracking_summary` (or `combine_tracking`): 1 for exact tracking,
    0 where nothing was held long enough to measure."""
    errors = np.array([summary["settled_error"][name] for name in COMMAND_NAMES])
    return 0.0 if np.isnan(errors).any() else float(tracking_reward(errors))


COMMAND_INFO = "command"
"""The info key under which `CommandedTask` gives the command in force (`humanoid.inputs.InputObservation` reads it)."""
SCHEDULE_STREAM = 6  # random stream of the training schedules' seeds: (seed, 6); humanoid.conditions lists the others


class CommandedTask(gym.Wrapper):
    """PPO's task of following the operator (`make finetune-rl` from a student that takes a command).

    Each episode follows a schedule (`command_schedule`: a neutral start, targets held a few seconds, some of them
    the zero command) whose seed is drawn from the wrapper's stream, seeded by the reset's seed, so episodes repeat
    exactly (and a resumed run replays them: `random_state`). The command in force goes out in `info[COMMAND_INFO]`
    at the reset and after every step, for the actor's inputs; each step's reward adds `weight` ×
    `tracking_reward` of the true posture reached against the command acted
    under (the simulator's, not the possibly noisy observation's). With `weight` 0 the reward is the environment's
    alone.
    """

    def __init__(self, env: gym.Env, weight: float) -> None:
        super().__init__(env)
        self.weight = weight
        self.tracking = Tracking(nominal_model())  # the nominal body's targets, whatever is drawn later
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
        self.commands = command_schedule(schedule, self.env.spec.max_episode_steps, self.env.unwrapped.dt)
        self.t = 0
        info[COMMAND_INFO] = self.commands[0]
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        command = self.commands[self.t]
        data = self.env.unwrapped.data
        error = self.tracking.error(data.qpos[2:], data.qvel, command)
        reward += self.weight * float(tracking_reward(error))
        self.t = min(self.t + 1, len(self.commands) - 1)
        info[COMMAND_INFO] = self.commands[self.t]
        return obs, reward, terminated, truncated, info
