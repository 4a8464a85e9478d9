"""The controller interface the recorder drives, and the registry that builds one by name.

Every source of actions (the LQR expert, a random baseline, keyboard teleoperation, a learned
policy) implements `Controller`, so the recorder and the evaluator run any of them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import gymnasium as gym
import numpy as np


@runtime_checkable
class Controller(Protocol):
    """Maps a gymnasium observation to an action within the action bounds."""

    name: str

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode; stochastic controllers reseed from `seed`."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """A float32 action of shape (17,) for one 348-dim observation."""


class RandomController:
    """Uniform random actions: the baseline that falls within a few dozen steps."""

    name = "random"

    def __init__(self, action_space: gym.spaces.Box) -> None:
        self.low = action_space.low.astype(np.float32)
        self.high = action_space.high.astype(np.float32)
        self.rng = np.random.default_rng()

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(self.low, self.high).astype(np.float32)


def _expert(env: gym.Env) -> Controller:
    from teleop.expert import LQRExpert  # the LQR design imports scipy; only pay for it when used

    return LQRExpert(env.unwrapped.model)


CONTROLLERS: dict[str, Callable[[gym.Env], Controller]] = {
    "expert": _expert,
    "random": lambda env: RandomController(env.action_space),
}


def make_controller(name: str, env: gym.Env) -> Controller:
    """Build the controller registered as `name` for `env`; ValueError names the known ones."""
    try:
        factory = CONTROLLERS[name]
    except KeyError:
        raise ValueError(f"unknown controller {name!r} (known: {', '.join(CONTROLLERS)})") from None
    return factory(env)
