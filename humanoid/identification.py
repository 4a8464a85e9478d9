"""Identifying the body from the landing: a learnt map from what a robot senses in its first steps to its masses.

The drop after each reset shakes the body more than standing does, so the first steps tell bodies apart
(docs/log.md, "Identifying the body from the landing"):

    simulated episodes of the sensed expert (masses drawn; action noise, sensor noise and delay mixed in)
        --first `steps` steps: sensed features and commanded actions--> ridge regression --> BodyIdentifier
    a live episode's first `steps` steps --BodyIdentifier--> mass scales (shrunk towards 1) --> that body's model

The map is fitted once per (model, design) and cached like the LQR gains (`humanoid.lqr.load_or_build`).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import gymnasium as gym
import mujoco
import numpy as np

from humanoid.conditions import ActionLatency, DomainRandomization, ObservationNoise, Randomization, scale_masses
from humanoid.env import make_env
from humanoid.lqr import CTRL_LIMIT, load_or_build
from humanoid.sensors import Proprioception

NOISE_STREAM = 6  # random stream of the training episodes' action noise: (seed, 6)
RUN_TIME = ("shrink", "clip")  # IdentificationDesign fields applied to the estimate, not part of the fit


@dataclass(frozen=True)
class IdentificationDesign:
    """How the identifier is fitted and used; every field but `RUN_TIME`'s is part of the cache key."""

    steps: int = 20
    """Env steps after reset read: the landing, which tells bodies apart better than standing (docs/log.md)."""
    episodes: int = 8000
    """Simulated training episodes (about a minute; more gained little)."""
    first_seed: int = 60000
    """Seed of the first training episode: far from every recording and evaluation seed."""
    mass: tuple[float, float] = (0.8, 1.2)
    """Range of the drawn mass scales, the robustness suite's `mass`."""
    action_noise: float = 0.05
    """Std of the action noise of every third training episode (the suite's `noise`), so noise is not read as mass."""
    ridge: float = 10.0
    """Ridge penalty on the standardised features."""
    shrink: float = 0.3
    """Share of the estimated deviation from the nominal masses acted on: the full estimate misreads action noise
    as a body, and more of it stands more bodies but fewer noisy episodes (the trade: docs/log.md)."""
    clip: float = 0.3
    """Largest deviation of an acted-on scale from 1."""


@dataclass(frozen=True)
class IdentifierWeights:
    """The fitted map: standardisation and ridge weights (arrays only, for the cache)."""

    mean: np.ndarray
    """(steps * features,) mean of the training features."""
    std: np.ndarray
    """(steps * features,) their std."""
    weights: np.ndarray
    """(steps * features, nbody - 1) from standardised features to mass scale minus 1."""


class Acting(Protocol):
    """What the training episodes run: an expert that acts on the gymnasium observation.

    `humanoid.controllers.Controller` says the same, but importing it would close a cycle back through the
    expert (controllers -> expert -> identification), as would `humanoid.episode`'s noise and rollout."""

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs: np.ndarray) -> np.ndarray: ...


class BodyIdentifier:
    """Collects a live episode's first `steps` steps and estimates its body's mass scales from them."""

    def __init__(self, model: mujoco.MjModel, weights: IdentifierWeights, design: IdentificationDesign) -> None:
        self.model = model
        self.weights = weights
        self.design = design
        self._rows: list[np.ndarray] = []

    def reset(self) -> None:
        self._rows = []

    @property
    def done(self) -> bool:
        return len(self._rows) >= self.design.steps

    def observe(self, sensed: np.ndarray, action: np.ndarray) -> None:
        """One step: the sensed features acted on (`Proprioception`) and the action commanded (what the robot
        knows it sent)."""
        if not self.done:
            self._rows.append(step_features(sensed, action))

    def scales(self) -> np.ndarray:
        """The body's mass scales as acted on: the estimate's deviation from 1, shrunk and clipped."""
        return acted_scales(self.weights, self.design, np.concatenate(self._rows))

    def body(self) -> mujoco.MjModel:
        """A copy of the nominal model with the estimated masses."""
        return scaled_body(self.model, self.scales())


def step_features(sensed: np.ndarray, action: np.ndarray) -> np.ndarray:
    """One step's input to the map: the sensed features and the commanded action, float32 as trained."""
    return np.concatenate([sensed, action]).astype(np.float32)


def acted_scales(weights: IdentifierWeights, design: IdentificationDesign, features: np.ndarray) -> np.ndarray:
    """Mass scales from the flattened first steps' features: 1 + shrink * estimate, within 1 +- clip."""
    deviation = ((features.astype(np.float64) - weights.mean) / weights.std) @ weights.weights
    return 1.0 + np.clip(design.shrink * deviation, -design.clip, design.clip)


def scaled_body(model: mujoco.MjModel, scales: np.ndarray) -> mujoco.MjModel:
    """A copy of `model` with each body's mass and inertia times its scale (as `DomainRandomization` draws them)."""
    body = copy.copy(model)
    scale_masses(body, scales)
    return body


def training_env(delay: bool, sensor_noise: bool, design: IdentificationDesign) -> gym.Env:
    """The environment of one kind of training episode: masses drawn, maybe delayed, maybe noisy sensors."""
    env: gym.Env = DomainRandomization(make_env(), Randomization(mass=design.mass))
    if delay:
        env = ActionLatency(env, 1)
    if sensor_noise:
        env = ObservationNoise(env, 1.0)
    return env


def episode_kind(seed: int) -> tuple[int, bool, bool]:
    """(delay, sensor noise, action noise) of a training episode: a quarter delayed, a fifth with noisy sensors,
    a third with action noise, independently of each other by the seed."""
    return int(seed % 4 == 0), seed % 5 == 0, seed % 3 == 0


def collect(
    make_expert: Callable[[mujoco.MjModel, int], Acting], design: IdentificationDesign
) -> tuple[np.ndarray, np.ndarray]:
    """(features (n, steps * features), mass scales (n, nbody - 1)) of the training episodes that did not fall early."""
    envs = {(d, s): training_env(bool(d), s, design) for d in (0, 1) for s in (False, True)}
    model = envs[0, False].unwrapped.model  # the nominal body between draws: experts are designed on it
    nominal = copy.copy(model)
    experts = {delay: make_expert(nominal, delay) for delay in (0, 1)}
    sensed = Proprioception(nominal)
    features, targets = [], []
    for seed in range(design.first_seed, design.first_seed + design.episodes):
        delay, sensor_noise, noisy = episode_kind(seed)
        env, expert = envs[delay, sensor_noise], experts[delay]
        noise = np.random.default_rng((seed, NOISE_STREAM)).normal(0.0, design.action_noise, (design.steps, model.nu))
        obs, info = env.reset(seed=seed)
        expert.reset(seed)
        rows = []
        for t in range(design.steps):
            action = expert.act(obs)
            rows.append(step_features(sensed(obs), action))
            executed = np.clip(action + noise[t], -CTRL_LIMIT, CTRL_LIMIT) if noisy else action
            obs, _, terminated, _, _ = env.step(executed)
            if terminated:
                break
        if len(rows) == design.steps:
            features.append(np.concatenate(rows))
            targets.append(info["parameters"]["mass_scale"])
    for env in envs.values():
        env.close()
    return np.array(features), np.array(targets)


def fit(features: np.ndarray, targets: np.ndarray, ridge: float) -> IdentifierWeights:
    """Ridge regression of the mass scales' deviation from 1 on the standardised features."""
    x = features.astype(np.float64)
    mean, std = x.mean(axis=0), x.std(axis=0) + 1e-6
    x = (x - mean) / std
    weights = np.linalg.solve(x.T @ x + ridge * np.eye(x.shape[1]), x.T @ (targets - 1.0))
    return IdentifierWeights(mean=mean, std=std, weights=weights)


def load_or_fit(
    model: mujoco.MjModel,
    design: IdentificationDesign,
    expert_key: str,
    make_expert: Callable[[mujoco.MjModel, int], Acting],
) -> BodyIdentifier:
    """The identifier of `model`, fitted on `make_expert`'s episodes (a minute) or loaded from the cache.

    `expert_key` names the expert's own design (its LQR cache key): another expert lands otherwise.
    """
    fitting = {k: v for k, v in dataclasses.asdict(design).items() if k not in RUN_TIME}
    meta = json.dumps({"design": fitting, "expert": expert_key}, sort_keys=True)
    key = hashlib.sha256(meta.encode()).hexdigest()

    def build() -> IdentifierWeights:
        return fit(*collect(make_expert, design), design.ridge)

    return BodyIdentifier(model, load_or_build("identifier", key, IdentifierWeights, build), design)
