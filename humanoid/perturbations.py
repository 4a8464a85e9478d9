"""Perturbations applied to the simulated body, as gymnasium wrappers (`make eval PUSH=`, `make finetune-rl PUSH=`,
the suite's `push*` and `kick*` conditions).

`TorsoPushes` reproduces the robustness test of the facts note: a horizontal force on the torso
for 0.1 s every 2 s, in a random direction. `VelocityKick` is the legged-robotics "push_robots" protocol: one
change of the root's horizontal velocity, in a seeded direction at a seeded time. How often pushes and kicks
topple the expert and each policy: docs/concepts/robustness-suite.md, "Where each controller stands"; which
directions topple them: docs/concepts/robustness-suite.md, "Which pushes topple".
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

if TYPE_CHECKING:
    import mujoco

from humanoid.env import model_and_data
from humanoid.physics import TORSO_BODY, heading

PUSH_STREAM = 2  # random stream of the push directions: (seed, 2); the action noise uses (seed, 1)
KICK_STREAM = 7  # random stream of a kick's time and direction: (seed, 7); humanoid.conditions lists the others


def relative_direction(push: np.ndarray, facing: float) -> float:
    """Direction (degrees in (-180, 180]) of the horizontal force `push` seen from a body facing `facing` (rad):
    0 pushes it forward (a push from behind), 90 to its left, 180 backward (a push on its chest)."""
    degrees = np.degrees(np.arctan2(push[1], push[0]) - facing)
    return float(180.0 - (180.0 - degrees) % 360.0)


def kick(data: mujoco.MjData, velocity: np.ndarray) -> None:
    """Change the root's horizontal velocity by `velocity` (m/s, world frame) at once: the whole body's, as a shove's
    impulse does (`VelocityKick`, and the keyboard's kick)."""
    data.qvel[:2] += velocity  # the free joint's linear velocity, world frame


def kick_force(velocity: np.ndarray, mass: float, dt: float) -> np.ndarray:
    """The force that gives a kick of `velocity` to a body of `mass` over one env step of `dt` s: how the push column
    (`common.columns.PUSH`) records a kick."""
    return np.asarray(velocity) * mass / dt


def toppling(starts: list[int], fell: bool) -> list[bool]:
    """Which of an episode's pushes (their start steps, in order) toppled it: the last one begun before a fall.

    A fall long after its last push is still put on it; under pushes alone the body that stood through
    a push's 2 s rarely falls later (docs/concepts/robustness-suite.md, "Which pushes topple").
    """
    return [fell and i == len(starts) - 1 for i in range(len(starts))]


class Perturbation(gym.Wrapper):
    """A wrapper that pushes the body: `pushes` lists the episode's pushes so far, (start step, direction relative
    to where the torso faced then, `relative_direction`), for the toppling breakdown (`toppling`)."""

    pushes: list[tuple[int, float]]

    def recorded_push(self, step: int) -> np.ndarray | None:
        """The push column (`common.columns.PUSH`) of env step `step`, taken next, or None where the perturbation is
        not known before its step (`TorsoPushes` draws each push's direction as it comes)."""
        return None


class TorsoPushes(Perturbation):
    """Pushes the torso with `force` newtons, horizontally, for `duration` s every `period` s.

    The first push comes one period after reset, once the body has settled from its drop. Each
    push draws its direction from a stream seeded by the reset's seed, so episodes repeat exactly.
    `set_force` changes the force from the next reset on (a curriculum, `rl.curriculum`): an
    episode is pushed with one force throughout, so it can be replayed from its start. `pushes` lists
    the episode's pushes so far: (start step, direction relative to where the torso faced then,
    `relative_direction`).
    """

    def __init__(self, env: gym.Env, force: float, period: float = 2.0, duration: float = 0.1) -> None:
        super().__init__(env)
        if not force >= 0 or not 0 < duration <= period:
            raise ValueError(f"need force >= 0 and 0 < duration <= period, got {force}, {duration}, {period}")
        self.force = self.next_force = force
        dt = env.unwrapped.dt
        self.period_steps = max(1, round(period / dt))
        self.duration_steps = max(1, round(duration / dt))
        model, self._data = model_and_data(env)
        self._torso = model.body(TORSO_BODY).id
        self._rng = np.random.default_rng()
        self._steps = 0
        self._push = np.zeros(3)
        self.pushes: list[tuple[int, float]] = []

    def set_force(self, force: float) -> None:
        """Push with `force` newtons from the next reset on."""
        if not force >= 0:
            raise ValueError(f"need force >= 0, got {force}")
        self.next_force = force

    def random_state(self) -> dict:
        """What the next episode's pushes depend on: the directions' random stream and the force, to resume a
        run exactly (`rl.vec_env` saves it at episode starts)."""
        return {"directions": self._rng.bit_generator.state, "force": self.next_force}

    def set_random_state(self, state: dict) -> None:
        self._rng.bit_generator.state = state["directions"]
        self.next_force = state["force"]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if seed is not None:
            self._rng = np.random.default_rng((seed, PUSH_STREAM))
        self._steps = 0
        self.pushes = []
        self.force = self.next_force
        obs, info = self.env.reset(seed=seed, options=options)
        self._data.xfrc_applied[self._torso] = 0.0
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        phase = self._steps % self.period_steps
        if self._steps >= self.period_steps and phase == 0:
            angle = self._rng.uniform(0.0, 2 * np.pi)
            self._push = self.force * np.array([np.cos(angle), np.sin(angle), 0.0])
            self.pushes.append((self._steps, relative_direction(self._push, heading(self._data, TORSO_BODY))))
        pushing = self._steps >= self.period_steps and phase < self.duration_steps
        # xfrc_applied holds (force, torque) in world coordinates at the body's centre of mass,
        # applied for every physics substep of this env step.
        self._data.xfrc_applied[self._torso, :3] = self._push if pushing else 0.0
        self._steps += 1
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "pushing": pushing}


KICK_SECONDS = (4.0, 8.0)
"""When the kick comes (uniform, seeded): after the 3 s the body takes to land and a schedule's first command to
start, well before an episode's end (15 s)."""


class VelocityKick(Perturbation):
    """One kick per episode: the root's horizontal velocity changed by `speed` m/s, in a direction and at a time
    (`KICK_SECONDS`) drawn from a stream seeded by the reset's seed, so episodes repeat exactly. An impulse of
    `speed` × the body's mass (`impulse`, N·s) at the centre of mass, as a shove or a collision gives; the body
    survives it if it still stands at the episode's end (the suite's rule)."""

    def __init__(self, env: gym.Env, speed: float, window: tuple[float, float] = KICK_SECONDS) -> None:
        super().__init__(env)
        if not (np.isfinite(speed) and speed >= 0):
            raise ValueError(f"a kick's speed must be a finite number >= 0 m/s, got {speed}")
        self.speed = speed
        self.window = window
        model, self._data = model_and_data(env)
        self._mass = float(model.body_subtreemass[0])
        self.impulse = speed * self._mass
        """The kick's impulse in N·s: its speed times the body's mass."""
        self._rng = np.random.default_rng()
        self._steps = self._at = 0
        self._change = np.zeros(2)
        self.pushes: list[tuple[int, float]] = []

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if seed is not None:
            self._rng = np.random.default_rng((seed, KICK_STREAM))
        self._at = round(self._rng.uniform(*self.window) / self.env.unwrapped.dt)
        angle = self._rng.uniform(0.0, 2 * np.pi)
        self._change = self.speed * np.array([np.cos(angle), np.sin(angle)])  # the episode's kick, m/s
        self._steps = 0
        self.pushes = []
        return self.env.reset(seed=seed, options=options)

    def recorded_push(self, step: int) -> np.ndarray:
        """The dataset's push column (`common.columns.PUSH`) at env step `step`, taken next: the force that gives the
        kick's impulse over that step (N, world frame), as the keyboard's kick records it; zeros before and after."""
        if step != self._at:
            return np.zeros(2)
        return kick_force(self._change, self._mass, self.env.unwrapped.dt)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        if self._steps == self._at:
            kick(self._data, self._change)
            self.pushes.append((self._steps, relative_direction(self._change, heading(self._data, TORSO_BODY))))
        self._steps += 1
        return self.env.step(action)


def perturbation(env: gym.Env) -> Perturbation | None:
    """The `Perturbation` wrapper around `env` (pushes or a kick), if any."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, Perturbation):
            return env
        env = env.env
    return None
