"""The controller interface every rollout drives, and the one place a controller is built from its name.

Every source of actions (a teacher, a random baseline, keyboard teleoperation, a learned policy) implements
`Controller`, so the recorder, the evaluator and DAgger run any of them. A name is a registered teacher
(`teachers.registry.TEACHERS`), `random`, the keyboard (the recorder's only), or the path of a policy checkpoint folder
(`policies/`), or of a folder holding a stable-baselines3 policy saved by SB3 (`policies.folder.SB3_FILE`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import gymnasium as gym
import mujoco
import numpy as np

from humanoid.conditions import action_delay
from policies.folder import checkpoint_problem, damage, is_sb3_policy  # torch-free: policies are imported on use
from teachers.base import Teacher
from teachers.expert import LQRExpert
from teachers.registry import TEACHERS


@runtime_checkable
class Controller(Protocol):
    """Maps a gymnasium observation to an action within the action bounds.

    Before each `reset` the rollout tells it the episode's action latency (`set_delay`, `rollout.episode.tell_delay`)
    and drawn body (`set_body`, `rollout.episode.tell_body`), and after it, at each change, the operator's command
    (`set_command`; zeros: stand still); one that has no use for them ignores them.
    """

    name: str
    takes_command: bool
    """Whether it follows the operator's command (the experts; a policy on commanded inputs)."""
    walks: bool
    """Whether it follows the command's velocity fields too (`expert-stepping`; a policy on a walking input set)."""

    def set_delay(self, steps: int) -> None:
        """The action latency, in steps, of the episodes from the next `reset` on."""

    def set_body(self, model: mujoco.MjModel) -> None:
        """The body (masses, friction, motors as drawn) of the episodes from the next `reset` on."""

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode; stochastic controllers reseed from `seed`."""

    def set_command(self, command: np.ndarray) -> None:
        """The operator's command (`task.command_fields.COMMAND_NAMES`) from this step on, until the next."""

    def setpoint(self) -> np.ndarray | None:
        """Where it steers now on its way to the command (the expert's setpoint), or None without one of its own."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """A float32 action of shape (17,) for one 348-dim observation."""

    def ran(self, action: np.ndarray) -> None:
        """What the env was sent this step when another controller chose it (a DAgger labeller's `act` only labels):
        one that keeps the actions it sent, in flight under latency, keeps this one instead of its own."""


class RandomController:
    """Uniform random actions: the baseline that falls within a few dozen steps."""

    name = "random"
    takes_command = walks = False

    def __init__(self, action_space: gym.spaces.Box) -> None:
        self.low = action_space.low.astype(np.float32)
        self.high = action_space.high.astype(np.float32)
        self.rng = np.random.default_rng()

    def set_delay(self, steps: int) -> None:
        """Random actions whatever the delay."""

    def set_body(self, model: mujoco.MjModel) -> None:
        """Random actions whatever the body."""

    def set_command(self, command: np.ndarray) -> None:
        """Random actions whatever the command."""

    def setpoint(self) -> None:
        return None

    def ran(self, action: np.ndarray) -> None:
        """Random actions whatever ran."""

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(self.low, self.high).astype(np.float32)


RANDOM = RandomController.name


def registered() -> tuple[str, ...]:
    """The names of the registered controllers now: the teachers (`teachers.registry`, a test may add one) and
    `random`."""
    return (*TEACHERS, RANDOM)


# Controllers driven by a person in real time (`teleop.keyboard`): the recorder runs them, the evaluator cannot.
KEYBOARD = "keyboard"
KEYBOARD_EXPERT = LQRExpert.name
"""Who the keys drive unless told a policy (`make play`): the expert told the simulator's state, which a keyboard
episode's labeller, KEYBOARD, stands for."""
INTERACTIVE = (KEYBOARD,)


def _is_path(name: str) -> bool:
    """Names that are not registered are paths if they look like one: `policies/x`, `./x`, an existing folder."""
    return "/" in name or Path(name).is_dir()


def check_controller(name: str, interactive: bool = True) -> None:
    """ValueError with a one-line reason unless `name` is registered or a checkpoint folder; imports no torch.
    Without `interactive`, also for a controller a person drives (only the recorder runs one)."""
    if name in INTERACTIVE:
        if interactive:
            return
        raise ValueError(f"controller {name!r} is driven by a person: only the recorder runs it")
    if name in registered():
        return
    if not _is_path(name):
        known = ", ".join([*registered(), *INTERACTIVE])
        raise ValueError(f"unknown controller {name!r} (known: {known}, or a policy checkpoint folder)")
    problem = None if is_sb3_policy(Path(name)) else checkpoint_problem(Path(name)) or damage(Path(name))
    if problem:
        raise ValueError(problem)


def built(name: str) -> str | type[Teacher]:
    """What a worker process builds the controller called `name` from: the teacher class registered so (sent along:
    one a test registered here is known there too), else the name."""
    return TEACHERS.get(name, name)


def make_controller(what: str | type[Teacher], env: gym.Env) -> Controller:
    """Build the teacher `what` (a class, or its registered name), the random baseline, or the policy saved in folder
    `what`, for `env`: a teacher is told `env`'s action latency as built (`cls(delay=...)`).

    ValueError for an unknown name; a `UserError` (CheckpointError) for a folder that is not a usable checkpoint.
    """
    if isinstance(what, type):
        return what(delay=action_delay(env))
    name = what
    if name in TEACHERS:
        return TEACHERS[name](delay=action_delay(env))
    if name == RANDOM:
        return RandomController(env.action_space)
    check_controller(name, interactive=False)
    from students.learned import PolicyController, SB3Controller  # noqa: PLC0415 - imports torch: only for policies

    if is_sb3_policy(Path(name)):
        return SB3Controller(Path(name))
    return PolicyController.load(Path(name), env)
