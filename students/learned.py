"""A saved policy as a `rollout.controllers.Controller`, so the recorder and the evaluator run it.

Two kinds: this project's `MLPPolicy` checkpoints (`PolicyController`), and policies stable-baselines3
saved itself (`SB3Controller`, the tutorial's PPO baseline of `rl.tutorial`).

The policy's checkpoint says what it reads (`MLPSpec.inputs`, see `humanoid.sensors`): the
controller computes that from each gymnasium observation, so a policy on the sensed features runs
wherever one on the full observation does, perturbations and sensor noise included; one on the
"pending" inputs is also told each episode's action latency and remembers the command it sent.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import torch

from humanoid.env import make_env, nominal_model
from policies.checkpoint import CheckpointError, load
from policies.folder import SB3_FILE
from policies.mlp import MLPPolicy
from students.inputs import INPUT_SETS, InputSet, removed_inputs
from task.command_fields import COMMAND_SIZE


class PolicyController:
    """Deterministic actions of an `MLPPolicy` for one observation at a time."""

    def __init__(self, policy: MLPPolicy, name: str, env: gym.Env | None = None) -> None:
        """`policy` run in `env` (any Humanoid-v5 if None: the observation layout is the environment's, not
        the model instance's), whose gymnasium observations it turns into the inputs it was trained on, computed on
        the nominal body whatever `env` has drawn (as the training inputs are)."""
        own = env is None
        env = make_env() if env is None else env
        try:
            check_fits(policy, env, name)
            self.input_set: InputSet = INPUT_SETS[policy.spec.inputs](nominal_model())
        finally:
            if own:
                env.close()
        self.policy = policy.eval()
        self.name = name
        self.takes_command = self.input_set.takes_command
        self.walks = self.input_set.walks
        self.command = np.zeros(COMMAND_SIZE, np.float32)

    @classmethod
    def load(cls, path: Path, env: gym.Env) -> PolicyController:
        """The checkpoint at `path`, checked to fit `env`'s observation and action sizes."""
        return cls(load(path), str(path), env)

    def reset(self, seed: int | None = None) -> None:
        """The policy is deterministic and has no memory; its inputs may (the "pending" inputs' estimator)."""
        self.input_set.reset()

    def set_delay(self, steps: int) -> None:
        """The episode's action latency, told by the rollout (`rollout.episode.tell_delay`) to the inputs."""
        self.input_set.set_delay(steps)

    def set_body(self, model: mujoco.MjModel) -> None:
        """A policy acts on what it reads, whatever the body."""

    def set_command(self, command: np.ndarray) -> None:
        """The command its inputs carry from now on (a policy on inputs without one acts as if standing)."""
        self.command[:] = command

    def setpoint(self) -> None:
        return None

    def act(self, obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            inputs = self.input_set(self.input_set.observe(obs, self.command))
            action = self.policy(torch.from_numpy(inputs).float()).numpy()
        self.input_set.sent(action)
        return action

    def ran(self, action: np.ndarray) -> None:
        """Its inputs carry what ran as the action in flight."""
        self.input_set.sent(action)


def check_fits(policy: MLPPolicy, env: gym.Env, name: str) -> None:
    """CheckpointError in one line unless `env` can give `policy` its inputs, as the code that trained it computed
    them (`InputSet.version`), and take its actions."""
    spec = policy.spec
    removed = removed_inputs(spec.inputs)
    if removed is not None:
        raise CheckpointError(f"{name} must be retrained: {removed.message()}")
    if spec.inputs not in INPUT_SETS or spec.input_keys != INPUT_SETS[spec.inputs].columns:
        # e.g. a policy conditioned on a command needs a command source besides the observation.
        raise CheckpointError(
            f"{name} reads {spec.inputs!r} from {list(spec.input_keys)}; a controller computes only "
            + ", ".join(f"{name!r} from {list(input_set.columns)}" for name, input_set in INPUT_SETS.items())
        )
    version = INPUT_SETS[spec.inputs].version
    if spec.inputs_version != version:
        raise CheckpointError(
            f"{name} must be retrained: it was trained on version {spec.inputs_version} of the {spec.inputs!r} inputs, "
            f"and this code computes version {version} (make train-bc INPUTS={spec.inputs} makes a student of them)"
        )
    inputs, action_dim = len(INPUT_SETS[spec.inputs].input_names(env.unwrapped.model)), env.action_space.shape[0]
    if (spec.input_dim, spec.action_dim) != (inputs, action_dim):
        raise CheckpointError(
            f"{name} maps {spec.input_dim} {spec.inputs} inputs to {spec.action_dim} actions; "
            f"{env.spec.id} gives {inputs} and takes {action_dim}"
        )


def input_set_of(folder: Path) -> type[InputSet] | None:
    """The input set the policy checkpoint in `folder` reads (whether it takes the command, walks), None if this
    version computes no set of that name."""
    return INPUT_SETS.get(load(folder).spec.inputs)


class SB3Controller:
    """The deterministic actions of a policy stable-baselines3 saved (`SB3_FILE` in `folder`), on the
    gymnasium observation as it is: SB3 clips them to the action bounds, as its `predict` does."""

    def __init__(self, folder: Path) -> None:
        from stable_baselines3 import PPO  # noqa: PLC0415 - only for SB3 folders

        try:
            self.model = PPO.load(folder / SB3_FILE, device="cpu")
        except (OSError, ValueError, KeyError) as error:
            raise CheckpointError(
                f"{folder / SB3_FILE} is not a readable stable-baselines3 PPO model: {error}"
            ) from None
        self.name = str(folder)

    takes_command = walks = False

    def set_command(self, command: np.ndarray) -> None:
        """It acts on the observation alone, whatever the command."""

    def setpoint(self) -> None:
        return None

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: deterministic, no memory."""

    def set_delay(self, steps: int) -> None:
        """It acts on the observation alone, whatever the delay."""

    def set_body(self, model: mujoco.MjModel) -> None:
        """It acts on the observation alone, whatever the body."""

    def ran(self, action: np.ndarray) -> None:
        """It acts on the observation alone, whatever ran."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(obs, deterministic=True)
        return action.astype(np.float32)
