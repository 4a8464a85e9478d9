"""A saved policy as a `humanoid.controllers.Controller`, so the recorder and the evaluator run it."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from policies.checkpoint import CheckpointError, load
from policies.mlp import MLPPolicy
from common import keys

# The inputs a controller can build from the gymnasium observation alone, in the observation's order.
OBSERVATION_KEYS = (keys.OBS_STATE, keys.OBS_ENV_STATE)


class PolicyController:
    """Deterministic actions of an `MLPPolicy` for one observation at a time."""

    def __init__(self, policy: MLPPolicy, name: str) -> None:
        self.policy = policy.eval()
        self.name = name

    @classmethod
    def load(cls, path: Path, env: gym.Env) -> PolicyController:
        """The checkpoint at `path`, checked to fit `env`'s observation and action sizes."""
        policy = load(path)
        spec = policy.spec
        if spec.input_keys != OBSERVATION_KEYS:
            # A policy conditioned on a command needs a command source besides the observation.
            raise CheckpointError(f"{path} takes inputs {list(spec.input_keys)}; a controller gives only "
                                  f"{list(OBSERVATION_KEYS)}")
        obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
        if (spec.input_dim, spec.action_dim) != (obs_dim, action_dim):
            raise CheckpointError(f"{path} maps {spec.input_dim} inputs to {spec.action_dim} actions; "
                                  f"{env.spec.id} has {obs_dim} observations and {action_dim} actions")
        return cls(policy, str(path))

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy is deterministic and has no memory."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return self.policy(torch.from_numpy(obs).float()).numpy()
