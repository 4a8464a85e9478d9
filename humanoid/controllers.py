"""The controller interface the recorder drives, and the registry that builds one by name.

Every source of actions (the LQR expert, a random baseline, keyboard teleoperation, a learned
policy) implements `Controller`, so the recorder and the evaluator run any of them. A name is
either registered in `CONTROLLERS` or the path of a policy checkpoint folder (`policies/`), or of a
folder holding a stable-baselines3 policy saved by SB3 (`policies.folder.SB3_FILE`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol, runtime_checkable

import gymnasium as gym
import mujoco
import numpy as np

from humanoid.conditions import action_delay
from policies.folder import checkpoint_problem, is_sb3_policy  # torch-free: policies are imported on use


@runtime_checkable
class Controller(Protocol):
    """Maps a gymnasium observation to an action within the action bounds.

    Before each `reset` the rollout tells it the episode's action latency (`set_delay`, `humanoid.episode.tell_delay`)
    and drawn body (`set_body`, `humanoid.episode.tell_body`), and after it, at each change, the operator's command
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
        """The operator's command (`humanoid.command_fields.COMMAND_NAMES`) from this step on, until the next."""

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


def _expert(env: gym.Env) -> Controller:
    from humanoid.expert import LQRExpert  # noqa: PLC0415 - the LQR design imports scipy; only pay for it when used

    # Designed on Humanoid-v5's own model, not `env`'s: a randomised env's model holds whatever body it drew
    # last. The rollout tells the expert each episode's body (`humanoid.episode.tell_body`).
    return LQRExpert(delay=action_delay(env))


def _sensed_expert(env: gym.Env) -> Controller:
    from humanoid.expert import SensedExpert  # noqa: PLC0415 - as _expert

    # The nominal model too, and never told the body: it acts on what a robot senses, its estimator included.
    return SensedExpert(delay=action_delay(env))


def _stepping_expert(env: gym.Env) -> Controller:
    from humanoid.stepping import SteppingExpert  # noqa: PLC0415 - as _expert

    return SteppingExpert(delay=action_delay(env))


def _sensed_stepping_expert(env: gym.Env) -> Controller:
    from humanoid.stepping import SensedSteppingExpert  # noqa: PLC0415 - as _expert

    return SensedSteppingExpert(delay=action_delay(env))


CONTROLLERS: dict[str, Callable[[gym.Env], Controller]] = {
    "expert": _expert,
    "expert-sensed": _sensed_expert,
    "expert-stepping": _stepping_expert,
    "expert-sensed-stepping": _sensed_stepping_expert,
    "random": lambda env: RandomController(env.action_space),
}
# Controllers driven by a person in real time (`teleop.keyboard`): the recorder runs them, the evaluator cannot.
KEYBOARD = "keyboard"
KEYBOARD_EXPERT = "expert"
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
    if name in CONTROLLERS:
        return
    if not _is_path(name):
        known = ", ".join([*CONTROLLERS, *INTERACTIVE])
        raise ValueError(f"unknown controller {name!r} (known: {known}, or a policy checkpoint folder)")
    problem = None if is_sb3_policy(Path(name)) else checkpoint_problem(Path(name))
    if problem:
        raise ValueError(problem)


def make_controller(name: str, env: gym.Env) -> Controller:
    """Build the controller registered as `name`, or the policy saved in folder `name`, for `env`.

    ValueError for an unknown name; a `UserError` (CheckpointError) for a folder that is not a usable checkpoint.
    """
    if name in CONTROLLERS:
        return CONTROLLERS[name](env)
    check_controller(name, interactive=False)
    from humanoid.learned import PolicyController, SB3Controller  # noqa: PLC0415 - imports torch: only for policies

    if is_sb3_policy(Path(name)):
        return SB3Controller(Path(name))
    return PolicyController.load(Path(name), env)
