"""Off-nominal conditions as gymnasium wrappers: domain randomisation, action latency, sensor noise.

A `Condition` says everything an episode's environment changes; `Condition.wrap` is the one builder of its stack,
which recording, evaluation, the robustness suite, DAgger and PPO all use, innermost first:

    Humanoid-v5 --DomainRandomization (masses, friction, motor strength; drawn at reset)
               --TorsoPushes (humanoid.perturbations), or --VelocityKick (one kick an episode)
               --ActionLatency (the env executes the action of k steps before; a share of the episodes)
               --ObservationNoise (what the policy reads; a share of the episodes)

Executed-action noise is not a wrapper: the rollout adds it (`rollout.episode.injected_noise`), as
it does for DART recordings. Every draw comes from a random stream of the reset's seed, so an
episode repeats exactly; the model's nominal values are restored before each draw and on close.
`parse_randomization` reads the `--randomize` setting (a preset of PRESETS or a list of ranges)
that recording (`make record RANDOMIZE=...`) draws its episodes' physical parameters with.
The suite's conditions and why each magnitude: docs/concepts/robustness-suite.md.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, fields
from typing import Any

import gymnasium as gym
import numpy as np

from common.cli import Range, parse_ranges
from humanoid.env import QPOS_OBS, QVEL_OBS, model_and_data
from humanoid.perturbations import TorsoPushes, VelocityKick

RANDOMIZATION_STREAM = 3  # random stream of the physical parameters: (seed, 3); pushes use 2, action noise 1
OBS_NOISE_STREAM = 4  # random stream of the sensor noise: (seed, 4)
LATENCY_STREAM = 5  # which episodes are delayed, when only a share is (PPO's training, recording): (seed, 5)
# (seed, 6): the schedules of PPO's training episodes on commands (task.tracking.SCHEDULE_STREAM)
# (seed, 7): a kick's time and direction (humanoid.perturbations.KICK_STREAM)
# (seed, 8): the stepping expert's samples (teachers.stepping.STEPPING_STREAM)
LATENCY_PARAMETER = "latency_steps"  # the episode's delay among its drawn parameters (ActionLatency's reset info)

# The sensed parts of the observation are its qpos and qvel (`QPOS_OBS`, `QVEL_OBS`); the rest is left noiseless.
OBS_NOISE_STD = {"qpos": 0.002, "qvel": 0.02}
"""Sensor noise std: joint angles and root orientation (rad; root height m), joint and root rates (rad/s; m/s)."""


SCALE_SUFFIX = "_scale"  # a drawn value is named after its parameter: mass -> mass_scale


def check_range(name: str, bounds: Range) -> None:
    """ValueError, saying which rule fails, unless `bounds` is a finite scale range 0 <= low <= high."""
    low, high = bounds
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"{name} scales must be finite, got {low:g}:{high:g}")
    if low < 0:
        raise ValueError(f"{name} scales must be >= 0, got {low:g}")
    if low > high:
        raise ValueError(f"{name} range has low {low:g} > high {high:g}")


@dataclass(frozen=True)
class Randomization:
    """Scale ranges of the physical parameters drawn at each reset; None leaves a parameter nominal."""

    mass: Range | None = None
    """Each body's mass and inertia times U(low, high), one draw per body."""
    friction: Range | None = None
    """Every geom's sliding friction times one U(low, high) draw (the floor's contacts scale with it)."""
    strength: Range | None = None
    """Each motor's gear times U(low, high), one draw per motor: the torque a given action gives."""

    def __post_init__(self) -> None:
        for spec in fields(self):
            bounds = getattr(self, spec.name)
            if bounds is not None:
                check_range(spec.name, bounds)

    @property
    def active(self) -> bool:
        return any(getattr(self, spec.name) is not None for spec in fields(self))

    @property
    def ranges(self) -> dict[str, list[float]]:
        """The randomised parameters' ranges, e.g. {"mass": [0.8, 1.2]} (JSON-ready; {} when nothing is randomised)."""
        bounds = {spec.name: getattr(self, spec.name) for spec in fields(self)}
        return {name: list(value) for name, value in bounds.items() if value is not None}

    def widened(self, width: float) -> Randomization:
        """These ranges at `width` of their size about 1 (0: nominal, 1: as they are), e.g. for a curriculum."""
        if width == 1:
            return self
        ranges = {name: (1 + width * (low - 1), 1 + width * (high - 1)) for name, (low, high) in self.ranges.items()}
        return Randomization(**ranges)

    @property
    def parameters(self) -> tuple[str, ...]:
        """The names of the drawn values (`DomainRandomization.parameters`), e.g. ("mass_scale",); () for none."""
        return tuple(f"{name}{SCALE_SUFFIX}" for name in self.ranges)


def subtree_masses(model: Any) -> None:
    """Recompute `body_subtreemass` from `body_mass` (MuJoCo does it only at compile time, in mj_setConst).

    mj_comPos divides by it to place each subtree's centre of mass, so it must follow the masses.
    """
    model.body_subtreemass[:] = model.body_mass
    for body in range(model.nbody - 1, 0, -1):
        model.body_subtreemass[model.body_parentid[body]] += model.body_subtreemass[body]


def scale_masses(model: Any, scale: np.ndarray) -> None:
    """Each body's mass and inertia times its scale (`scale`: one per body, the world excluded), in place: the same
    density change, so the shape's inertia scales alike; the subtree masses follow."""
    model.body_mass[1:] *= scale
    model.body_inertia[1:] *= scale[:, None]
    subtree_masses(model)


class DomainRandomization(gym.Wrapper):
    """Draws the physical parameters of `randomization` from the seed at every seeded reset.

    `parameters` holds the last draw (scale factors, JSON-ready), also returned in the reset's info
    under "parameters"; an unseeded reset draws from the stream the last seed left.
    """

    def __init__(self, env: gym.Env, randomization: Randomization, width: float = 1.0) -> None:
        super().__init__(env)
        self.randomization = randomization
        self._model, _ = model_and_data(env)
        self._nominal = {
            "body_mass": self._model.body_mass.copy(),
            "body_inertia": self._model.body_inertia.copy(),
            "body_subtreemass": self._model.body_subtreemass.copy(),
            "geom_friction": self._model.geom_friction.copy(),
            "actuator_gear": self._model.actuator_gear.copy(),
        }
        self._rng = np.random.default_rng()
        self.set_width(width)
        self.parameters: dict[str, Any] = {}

    def set_width(self, width: float) -> None:
        """Draw from the ranges at `width` of their size about 1 from the next reset on (a curriculum's stage)."""
        if not 0 <= width <= 1:
            raise ValueError(f"need 0 <= width <= 1, got {width}")
        self.width = width

    def random_state(self) -> dict:
        """What the next draw depends on: the random stream and the width, to resume a PPO run exactly
        (`rl.vec_env` saves it at episode starts)."""
        return {"draws": self._rng.bit_generator.state, "width": self.width}

    def set_random_state(self, state: dict) -> None:
        self._rng.bit_generator.state = state["draws"]
        self.width = state["width"]

    def restore(self) -> None:
        """Put the model's nominal masses, inertias, friction and gears back."""
        for name, value in self._nominal.items():
            getattr(self._model, name)[:] = value

    def draw(self) -> dict[str, Any]:
        """Restore, then apply a new draw; returns it."""
        self.restore()
        model, r = self._model, self.randomization.widened(self.width)
        parameters: dict[str, Any] = {}
        if r.mass is not None:
            scale = self._rng.uniform(*r.mass, size=model.nbody - 1)  # the world body has no mass
            scale_masses(model, scale)
            parameters["mass" + SCALE_SUFFIX] = scale.round(6).tolist()
        if r.friction is not None:
            scale = float(self._rng.uniform(*r.friction))
            model.geom_friction[:, 0] *= scale
            parameters["friction" + SCALE_SUFFIX] = round(scale, 6)
        if r.strength is not None:
            scale = self._rng.uniform(*r.strength, size=model.nu)
            model.actuator_gear[:, 0] *= scale
            parameters["strength" + SCALE_SUFFIX] = scale.round(6).tolist()
        self.parameters = parameters
        return parameters

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if seed is not None:
            self._rng = np.random.default_rng((seed, RANDOMIZATION_STREAM))
        parameters = self.draw()  # before the reset, so the first observation is of the drawn body
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, "parameters": parameters}

    def close(self) -> None:
        self.restore()
        super().close()


class EpisodeShare:
    """Which episodes a wrapper's condition applies to: each with probability `share`, drawn at reset from the
    stream (seed, `stream`), which the wrapper may go on drawing from within the episode (`rng`).

    At share 1 (the suite's conditions) or 0 nothing is drawn, so those streams stay as they were. `state`
    is part of a PPO run's resume snapshot (as `TorsoPushes.random_state`).
    """

    def __init__(self, name: str, stream: int, share: float) -> None:
        self.name, self.stream = name, stream
        self.rng = np.random.default_rng()
        self.set(share)

    def set(self, share: float) -> None:
        """ValueError unless `share` is a probability; it applies from the next `draw` on."""
        if not 0 <= share <= 1:
            raise ValueError(f"{self.name} share must be in [0, 1], got {share}")
        self.share = share

    def draw(self, seed: int | None) -> bool:
        """Whether the episode reset with `seed` is affected (unseeded: drawn on from the last seed's stream)."""
        if seed is not None:
            self.rng = np.random.default_rng((seed, self.stream))
        return self.share >= 1 or (self.share > 0 and bool(self.rng.random() < self.share))

    def state(self) -> dict:
        return {"draws": self.rng.bit_generator.state, "share": self.share}

    def set_state(self, state: dict) -> None:
        self.rng.bit_generator.state = state["draws"]
        self.share = state["share"]


class ActionLatency(gym.Wrapper):
    """The environment executes the action given `steps` steps before (zeros until then).

    With `share` < 1 only that share of the episodes is delayed, each drawn at reset from the seed's
    stream (seed, LATENCY_STREAM): demonstrations with and without the delay (`make record LATENCY=`),
    and training under the suite's conditions (`rl.finetune`), where a curriculum changes the share from the
    next reset on (`set_latency_share`). `delay` is the episode's.
    """

    def __init__(self, env: gym.Env, steps: int = 1, share: float = 1.0) -> None:
        super().__init__(env)
        if steps < 0:
            raise ValueError(f"latency must be >= 0 steps, got {steps}")
        self.steps = self.delay = steps
        self.episodes = EpisodeShare("latency", LATENCY_STREAM, share)
        self._queue: deque[np.ndarray] = deque()

    @property
    def latency_share(self) -> float:
        return self.episodes.share

    def set_latency_share(self, share: float) -> None:
        """Delay this share of the episodes from the next reset on."""
        self.episodes.set(share)

    def random_state(self) -> dict:
        """What the next episode's delay depends on, to resume a PPO run exactly."""
        return self.episodes.state()

    def set_random_state(self, state: dict) -> None:
        self.episodes.set_state(state)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        """As the env's, and the episode's delay joins the reset info's drawn "parameters" (`LATENCY_PARAMETER`),
        so that a recording stores it with the episode."""
        self.delay = self.steps if self.episodes.draw(seed) else 0
        zero = np.zeros(self.env.action_space.shape, self.env.action_space.dtype)
        self._queue = deque([zero] * self.delay)
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, "parameters": {**info.get("parameters", {}), LATENCY_PARAMETER: self.delay}}

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        self._queue.append(np.asarray(action))
        return self.env.step(self._queue.popleft())


def action_delay(env: gym.Env) -> int:
    """Steps of action latency the `ActionLatency` wrappers around `env` add to the current episode (drawn at
    its reset when only a share of the episodes is delayed; before the first reset, their `steps`).

    A known property of the system, as a robot's actuation delay is measured: the rollout tells it to
    every controller that can use it (`rollout.episode.tell_delay`), the expert predicting through it,
    a policy on the "pending" inputs reading it.
    """
    delay = 0
    while isinstance(env, gym.Wrapper):
        if isinstance(env, ActionLatency):
            delay += env.delay
        env = env.env
    return delay


def recording_condition(randomize: str, latency_share: float, kick: float = 0.0) -> Condition:
    """The condition `make record` (and DAgger's rollouts) records under, from their RANDOMIZE, LATENCY and KICK: the
    physical parameters drawn per episode (`parse_randomization`), one step of action latency on `latency_share` of
    the episodes (also drawn per episode), and one `kick` (m/s) per episode as the suite's kick conditions give it
    (`VelocityKick`, recorded in the push column)."""
    randomization = parse_randomization(randomize)
    return Condition(
        randomization=randomization, latency=1 if latency_share > 0 else 0, latency_share=latency_share, kick=kick
    )


def recorded_parameters(condition: Condition) -> tuple[str, ...]:
    """The names of the values `condition`'s stack draws for each episode (the dataset's `randomization.*` columns):
    the randomised parameters', and the delay's where a share of the episodes is delayed."""
    return (*condition.randomization.parameters, *((LATENCY_PARAMETER,) if condition.latency > 0 else ()))


class ObservationNoise(gym.Wrapper):
    """Gaussian noise on the sensed parts of the observation (`OBS_NOISE_STD` times `scale`), drawn from the seed.

    With `share` < 1 only that share of the episodes is noisy, as `ActionLatency` does with its delay
    (`set_noise_share`; the draw comes from the noise's own stream). `noisy` is the episode's.
    """

    def __init__(self, env: gym.Env, scale: float = 1.0, share: float = 1.0) -> None:
        super().__init__(env)
        if not (math.isfinite(scale) and scale >= 0):
            raise ValueError(f"observation noise scale must be >= 0, got {scale}")
        self.std = np.zeros(env.observation_space.shape)
        self.std[QPOS_OBS] = scale * OBS_NOISE_STD["qpos"]
        self.std[QVEL_OBS] = scale * OBS_NOISE_STD["qvel"]
        self.episodes = EpisodeShare("observation noise", OBS_NOISE_STREAM, share)
        self.noisy = True

    @property
    def noise_share(self) -> float:
        return self.episodes.share

    def set_noise_share(self, share: float) -> None:
        """Make this share of the episodes noisy from the next reset on."""
        self.episodes.set(share)

    def random_state(self) -> dict:
        """What the next episode's noise depends on, to resume a PPO run exactly."""
        return self.episodes.state()

    def set_random_state(self, state: dict) -> None:
        self.episodes.set_state(state)

    def _noisy(self, obs: np.ndarray) -> np.ndarray:
        # The noise comes from the stream the episode's draw came from: one stream per seed, as before shares.
        return obs + self.std * self.episodes.rng.standard_normal(obs.shape) if self.noisy else obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        self.noisy = self.episodes.draw(seed)
        obs, info = self.env.reset(seed=seed, options=options)
        return self._noisy(obs), info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._noisy(obs), reward, terminated, truncated, info


@dataclass(frozen=True)
class Condition:
    """What an episode's environment changes, each part off by default: a condition of the robustness suite, a
    recording's draws, PPO's training episodes."""

    action_noise: float = 0.0
    """Std of Gaussian noise added to every executed action (the rollout adds it)."""
    push: float | None = None
    """Newtons of a horizontal torso push for 0.1 s every 2 s (`TorsoPushes`); None: no pusher (0: one at 0 N, which
    a curriculum raises)."""
    kick: float = 0.0
    """Metres per second of one horizontal kick of the root's velocity (`VelocityKick`); 0: none."""
    randomization: Randomization = field(default_factory=Randomization)
    """The physical parameters drawn at each reset (`DomainRandomization`)."""
    width: float = 1.0
    """The share of the randomisation's ranges drawn from (a curriculum's stage: `DomainRandomization.set_width`)."""
    latency: int = 0
    """Env steps between choosing an action and its execution (`ActionLatency`); 0: none."""
    latency_share: float = 1.0
    """The share of the episodes so delayed, drawn at each reset (0 included: a curriculum raises it)."""
    obs_noise: float = 0.0
    """Scale of `OBS_NOISE_STD` on what the policy reads (`ObservationNoise`); 0: none."""
    obs_noise_share: float = 1.0
    """The share of the episodes with that noise, drawn at each reset."""

    def wrap(self, env: gym.Env) -> gym.Env:
        """`env` under this condition (the action noise excepted: pass `action_noise` to the rollout): the one
        builder of the stack, in the module's order."""
        if self.randomization.active:
            env = DomainRandomization(env, self.randomization, self.width)
        if self.push is not None:
            env = TorsoPushes(env, self.push)
        if self.kick > 0:
            env = VelocityKick(env, self.kick)
        if self.latency > 0:
            env = ActionLatency(env, self.latency, self.latency_share)
        if self.obs_noise > 0:
            env = ObservationNoise(env, self.obs_noise, self.obs_noise_share)
        return env


SUITE: dict[str, Condition] = {
    "clean": Condition(),
    "noise": Condition(action_noise=0.05),
    "push10": Condition(push=10.0),
    "push20": Condition(push=20.0),
    "push40": Condition(push=40.0),
    "kick0.2": Condition(kick=0.2),
    "kick0.4": Condition(kick=0.4),
    "kick0.6": Condition(kick=0.6),
    "mass": Condition(randomization=Randomization(mass=(0.8, 1.2))),
    "friction": Condition(randomization=Randomization(friction=(0.5, 1.5))),
    "strength": Condition(randomization=Randomization(strength=(0.8, 1.2))),
    "latency": Condition(latency=1),
    "obs_noise": Condition(obs_noise=1.0),
}
"""The robustness suite: each condition changes one thing (docs/concepts/robustness-suite.md says why each size)."""


def condition(name: str) -> Condition:
    """The suite's condition `name`; ValueError naming the known ones otherwise."""
    if name not in SUITE:
        raise ValueError(f"unknown condition {name!r}; known: {', '.join(SUITE)}")
    return SUITE[name]


# Domain randomisation as a setting (`make record RANDOMIZE=...`; later PPO): a preset or a list of ranges.
NO_RANDOMIZATION = "none"
PRESETS: dict[str, Randomization] = {
    NO_RANDOMIZATION: Randomization(),
    # Narrow: the link-mass range common in humanoid RL, half the suite's friction spread.
    "mild": Randomization(mass=(0.9, 1.1), friction=(0.7, 1.3), strength=(0.9, 1.1)),
    # The robustness suite's own ranges, all three at once: data from the conditions a policy is tested on.
    "suite": Randomization(
        mass=SUITE["mass"].randomization.mass,
        friction=SUITE["friction"].randomization.friction,
        strength=SUITE["strength"].randomization.strength,
    ),
}
"""Named randomisations (docs/decisions/randomisation-presets.md says why these sizes)."""
RANDOMIZE_EXAMPLE = "mass=0.8:1.2,friction=0.5:1.5"


def parse_randomization(text: str) -> Randomization:
    """`text` as a randomisation: a name of PRESETS ("none" randomises nothing) or a list NAME=LOW:HIGH,...

    NAME is a field of `Randomization` (mass, friction, strength) and LOW:HIGH the range of its
    scale factor. ValueError, one line naming --randomize, for an unknown preset or parameter, a
    parameter given twice, a malformed item, a non-finite or negative scale, or LOW > HIGH.
    """
    spec = text.strip()
    where = f"--randomize {text!r}"
    if "=" not in spec:
        if spec in PRESETS:
            return PRESETS[spec]
        raise ValueError(f"{where}: unknown preset; presets: {', '.join(PRESETS)}, or a list like {RANDOMIZE_EXAMPLE}")
    names = [f.name for f in fields(Randomization)]
    ranges = parse_ranges(spec, names, where, RANDOMIZE_EXAMPLE, check_range)
    return Randomization(**ranges)
