"""Operator commands: the posture an operator asks for, as a policy reads it, as a script draws it, and how
well a controller tracks it (docs/concepts/commands.md).

A command is a `humanoid.posture.Posture` (lean forward, lean left, height, twist, arms), carried as a vector
of `common.columns.COMMAND_NAMES` (the dataset's `observation.command`, a commanded policy's last inputs).
Standing still is the zero command.

- `command_schedule(seed, steps)`: a scripted operator (`make record CONTROLLER=operator`, and the held-out
  schedules of `make eval SCHEDULES=1`): after a neutral start, targets on the keyboard's grid
  (`Posture.STEP`), one to three fields at a time inside `SCALE` of each limit, some neutral, each held
  `HOLD_SECONDS` once the expert's setpoint has got there; drawn from the seed alone, so reproducible.
- `CommandedTask`: PPO's training episodes under schedules drawn from seeds no recording or evaluation uses, the
  tracking rewarded with an exponential kernel on the error (`tracking_reward`).
- `Tracking`: the error between commanded and achieved posture per field, from the observation alone
  (root orientation, height and the joint angles a recorded frame holds), and `tracking_summary` over an
  episode: the error once settled and the time to settle (defined under `SETTLED_SECONDS`, `TOLERANCE`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import UserError
from common.columns import COMMAND_NAMES
from common.seed_ranges import TRAINING_SEEDS
from humanoid.env import QPOS_OBS, nominal_model
from humanoid.posture import ARM_JOINTS, NEUTRAL, Posture, move_seconds, posture_reference
from humanoid.sensors import body_axes

COMMAND_SIZE = len(COMMAND_NAMES)
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
"""Targets stay within this share of each limit (`Posture.MIN`, `Posture.MAX`): at 0.7 the expert fell on 2 of 40
held-out schedules, at 0.5 on none (docs/decisions/command-schedules.md)."""


def command_vector(posture: Posture) -> np.ndarray:
    """The command `posture` as a policy reads it: float32, `COMMAND_NAMES` order."""
    return np.array([getattr(posture, name) for name in COMMAND_NAMES], np.float32)


def command_posture(command: np.ndarray) -> Posture:
    """The posture a command vector asks for (as given: the expert clips what it holds)."""
    return Posture(**{name: float(value) for name, value in zip(COMMAND_NAMES, command, strict=True)})


def _grid(name: str) -> np.ndarray:
    """The nonzero values of `name` on the keyboard's grid within SCALE of its limits."""
    step = Posture.STEP[name]
    if name == "arms":
        return np.arange(1.0, Posture.MAX["arms"] + 1.0)  # a preset: no fraction of one
    low, high = (int(SCALE * Posture.MIN[name] / step), int(SCALE * Posture.MAX[name] / step))
    return np.array([round(k * step, 6) for k in range(low, high + 1) if k != 0])


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
            target = NEUTRAL if previous != NEUTRAL else Posture(lean_forward=Posture.STEP["lean_forward"])
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
    """The task string naming a commanded posture: one phrase per field away from neutral."""
    phrases = []
    if posture.lean_forward:
        phrases.append("lean forward" if posture.lean_forward > 0 else "lean back")
    if posture.lean_left:
        phrases.append("lean left" if posture.lean_left > 0 else "lean right")
    if posture.height:
        phrases.append("crouch" if posture.height < 0 else "rise")
    if posture.twist:
        phrases.append("twist left" if posture.twist > 0 else "twist right")
    if posture.arms:
        phrases.append(f"arms {ARM_NAMES[round(posture.arms)]}")
    if not phrases:
        return DEFAULT_TASK
    return (", ".join(phrases) + " while standing.").capitalize()


ARM_NAMES = ("neutral", "forward", "up", "out")
"""`Posture.arms` presets by name (`humanoid.posture.ARM_POSES`)."""


# Tracking. The achieved posture is read from the observation's qpos part (`QPOS_OBS`), in both the full observation
# and a recorded frame.
TOLERANCE = {"lean_forward": 0.05, "lean_left": 0.05, "height": 0.02, "twist": 0.05, "arms": 0.1}
"""Settled means every field's error within this (rad; height m; arms: mean over the arm joints, rad): about one
key press (`Posture.STEP`), half of one for the twist."""
SETTLED_SECONDS = 1.0
"""The error once settled is the mean over the last this-many seconds of each command held, after the setpoint's move
to it (`move_seconds`), at least twice as long: as a schedule holds every command (`HOLD_SECONDS`) but the one the
episode's end cuts short, which may still be on its way."""


class Tracking:
    """Commanded against achieved posture, per field, for observations of `model`'s Humanoid-v5.

    Achieved: the trunk's pitch and sideways lean are those of the torso with its twist undone (the root's
    orientation times the abdomen_z rotation, as Euler angles z-y-x: pitch, then roll = -lean_left), the height
    is the root's, the twist is -abdomen_z, the arms their six joint angles. Commanded: the same coordinates of
    the balanced pose that realises the command (`posture_reference`), so a body held exactly there has no error.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.twist_at = int(model.joint("abdomen_z").qposadr[0]) - 2
        self.arms_at = [int(model.joint(name).qposadr[0]) - 2 for name in ARM_JOINTS]
        self._targets: dict[tuple[float, ...], np.ndarray] = {}

    def coordinates(self, qpos: np.ndarray) -> np.ndarray:
        """(..., 10): pitch, lean_left, height, twist, then the six arm angles, of (..., 22) qpos without x and y."""
        abdomen_z = qpos[..., self.twist_at]
        half = abdomen_z / 2
        zero = np.zeros_like(half)
        unyaw = np.moveaxis(np.array([np.cos(half), zero, zero, np.sin(half)]), 0, -1)
        frame = np.swapaxes(body_axes(unyaw) @ body_axes(qpos[..., 1:5]), -1, -2)  # R(root) R(unyaw)
        pitch = np.arcsin(np.clip(-frame[..., 2, 0], -1.0, 1.0))
        lean_left = -np.arctan2(frame[..., 2, 1], frame[..., 2, 2])
        return np.concatenate([np.stack([pitch, lean_left, qpos[..., 0], -abdomen_z], -1), qpos[..., self.arms_at]], -1)

    def target(self, command: np.ndarray) -> np.ndarray:
        """The coordinates (10,) of the balanced pose that realises `command` (clipped as the expert clips it)."""
        key = tuple(float(v) for v in command)
        if key not in self._targets:
            posture = command_posture(np.asarray(command)).clipped()
            self._targets[key] = self.coordinates(posture_reference(self.model, posture)[0][2:])
        return self._targets[key]

    def achieved(self, observations: np.ndarray) -> np.ndarray:
        """(T, 4) the achieved lean_forward, lean_left, height (from the neutral pose's) and twist of observations
        (T, >=22): what Foxglove plots beside the command (the `/command` channel)."""
        coordinates = self.coordinates(np.asarray(observations[:, QPOS_OBS], np.float64))[:, :4]
        return coordinates - [0.0, 0.0, self.target(np.zeros(COMMAND_SIZE))[2], 0.0]

    def errors(self, observations: np.ndarray, commands: np.ndarray) -> np.ndarray:
        """|commanded - achieved| (T, COMMAND_SIZE) of observations (T, >=22) under commands (T, COMMAND_SIZE)."""
        targets = np.empty((len(commands), 10))
        changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
        for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
            targets[start:end] = self.target(commands[start])
        return _fields(np.abs(self.coordinates(np.asarray(observations[:, QPOS_OBS], np.float64)) - targets))

    def error(self, qpos: np.ndarray, command: np.ndarray) -> np.ndarray:
        """`errors` of one state, (COMMAND_SIZE,) from qpos without x and y (22,) under `command`: the same numbers,
        a few times faster than through `errors` (PPO's reward computes it every step)."""
        return _fields(np.abs(self.coordinates(qpos) - self.target(command)))


def _fields(gap: np.ndarray) -> np.ndarray:
    """Per command field (..., COMMAND_SIZE) of a coordinates' gap (..., 10): the arms' six angles averaged."""
    return np.concatenate([gap[..., :4], gap[..., 4:].mean(axis=-1, keepdims=True)], axis=-1)


def tracking_summary(errors: np.ndarray, commands: np.ndarray, dt: float) -> dict[str, dict[str, float] | float]:
    """An episode's tracking: per field the mean error once settled (over the last SETTLED_SECONDS of each command
    held at least twice that after the setpoint's move to it), the same over only the commands that set that field
    away from neutral ("moved_error": the posture asked for rather than the stand held, which most commands leave
    most fields at), and the mean time from a command's change until every field stays within TOLERANCE (a command
    never settled counts its whole duration). NaN where no command was held long enough."""
    window = round(SETTLED_SECONDS / dt)
    tolerance = np.array([TOLERANCE[name] for name in COMMAND_NAMES])
    changes = np.flatnonzero(np.r_[True, (np.diff(commands, axis=0) != 0).any(axis=1)])
    settled, moved, times, previous = [], [], [], NEUTRAL
    for start, end in zip(changes, [*changes[1:], len(commands)], strict=True):
        inside = (errors[start:end] <= tolerance).all(axis=1)
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


def tracking_reward(errors: np.ndarray, width: float = 1.0) -> np.ndarray:
    """The tracking term of PPO's reward for errors (..., COMMAND_SIZE): the mean over the fields of
    exp(-(error / (width · TOLERANCE))²), as the public humanoid stacks reward a command (1 on it; at `width` 1,
    0.37 one key press off)."""
    tolerance = width * np.array([TOLERANCE[name] for name in COMMAND_NAMES])
    return np.exp(-np.square(errors / tolerance)).mean(axis=-1)


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
    `tracking_reward` (its kernel `width` TOLERANCEs wide) of the true posture reached against the command acted
    under (the simulator's, not the possibly noisy observation's). With `weight` 0 the reward is the environment's
    alone.
    """

    def __init__(self, env: gym.Env, weight: float, width: float = 1.0) -> None:
        super().__init__(env)
        self.weight, self.width = weight, width
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
        error = self.tracking.error(self.env.unwrapped.data.qpos[2:], command)
        reward += self.weight * float(tracking_reward(error, self.width))
        self.t = min(self.t + 1, len(self.commands) - 1)
        info[COMMAND_INFO] = self.commands[self.t]
        return obs, reward, terminated, truncated, info
