"""PPO whose rollouts are sampled inside the environments' workers: the learner only updates.

SB3's `collect_rollouts` runs the policy in the learner, once per environment step: it computes
the actions of all environments, sends them to the workers, waits for every worker to step, and
starts again, so the workers wait for the learner's forward pass and then for the slowest of
them, at every step. Here each worker holds a copy of the policy (without its optimiser) and
collects its environments' share of a whole rollout on its own (`Sampler`): the actions, values
and log-probabilities SB3 would record, the bootstrapping at time limits, the episode starts.
The learner sends the weights once per rollout, gathers the shares, hands them to the rollout
buffer and SB3's callbacks step by step, then runs PPO's update, on every core: the workers are
idle then.

The exploration noise of each environment comes from its own random stream (seeded by the run's
seed and the environment's index), so the worker count changes the speed, not the result, as
long as every worker holds at least 4 environments: MKL multiplies matrices of 1 to 3 rows by
another path, whose rounding differs.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv

from policies.actor_critic import scale_learning_rates
from rl.vec_env import WorkerGroupVecEnv


@dataclass
class Segment:
    """A rollout of some environments: per step and environment (axes 0 and 1), then their state at its end."""

    observations: np.ndarray  # the observation each action was chosen from
    actions: np.ndarray  # sampled, before clipping to the action bounds (what PPO's ratio needs)
    rewards: np.ndarray  # times the reward scale, plus gamma * V(final observation) where an episode hit its time limit
    episode_starts: np.ndarray  # whether the observation is the first of an episode
    values: np.ndarray
    log_probs: np.ndarray
    dones: np.ndarray
    infos: list[list[dict]]  # per step, SB3's info keys of each environment
    last_observations: np.ndarray
    last_values: np.ndarray

    @staticmethod
    def concatenate(parts: list[Segment]) -> Segment:
        """The segments of consecutive groups of environments as one, in environment order."""
        per_step = {name: np.concatenate([getattr(part, name) for part in parts], axis=1) for name in STEP_ARRAYS}
        return Segment(
            **per_step,
            infos=[[info for part in parts for info in part.infos[t]] for t in range(len(parts[0].infos))],
            last_observations=np.concatenate([part.last_observations for part in parts]),
            last_values=np.concatenate([part.last_values for part in parts]),
        )


# The fields of a Segment that hold one array per step, stacked along axis 0.
STEP_ARRAYS = ("observations", "actions", "rewards", "episode_starts", "values", "log_probs", "dones")


def without_optimiser(policy: ActorCriticPolicy) -> ActorCriticPolicy:
    """A copy of `policy` to act with, light to send to the workers: no optimiser, nor its arguments."""
    saved = policy.optimizer, policy.optimizer_kwargs
    policy.optimizer, policy.optimizer_kwargs = None, {}
    try:
        return copy.deepcopy(policy)
    finally:
        policy.optimizer, policy.optimizer_kwargs = saved


class Sampler:
    """A worker's share of PPO's rollouts: its copy of the policy and one noise stream per environment."""

    def __init__(
        self, policy: ActorCriticPolicy, env_indices: range, seed: int, gamma: float, reward_scale: float = 1.0
    ) -> None:
        self.policy = policy
        self.gamma, self.reward_scale = gamma, reward_scale
        self.generators = [
            torch.Generator().manual_seed(int(np.random.SeedSequence((seed, i)).generate_state(1)[0]))
            for i in env_indices
        ]

    def random_state(self) -> list[torch.Tensor]:
        """The exploration noise streams, to resume them exactly."""
        return [generator.get_state() for generator in self.generators]

    def set_random_state(self, states: list[torch.Tensor]) -> None:
        for generator, state in zip(self.generators, states, strict=True):
            generator.set_state(state)

    def value(self, observations: np.ndarray) -> np.ndarray:
        return self.policy.predict_values(self.policy.obs_to_tensor(observations)[0]).flatten().numpy()

    def collect(
        self,
        step: Any,
        observations: np.ndarray,
        episode_starts: np.ndarray,
        state: dict[str, torch.Tensor],
        n_steps: int,
    ) -> Segment:
        """`n_steps` steps of SB3's `collect_rollouts` for these environments; `step(actions)` steps them.

        `step` returns what `_Share.step` does: observations (after auto-reset), rewards, dones, infos.
        """
        torch.set_num_threads(1)  # a worker, or the learner between updates: idle torch threads would spin
        self.policy.load_state_dict(state)
        self.policy.set_training_mode(False)
        low, high = self.policy.action_space.low, self.policy.action_space.high
        records: dict[str, list] = {name: [] for name in (*STEP_ARRAYS, "infos")}
        with torch.no_grad():
            for _ in range(n_steps):
                obs = self.policy.obs_to_tensor(observations)[0]
                distribution = self.policy.get_distribution(obs)
                noise = torch.stack([torch.randn(low.shape, generator=g) for g in self.generators])
                actions = distribution.distribution.mean + distribution.distribution.stddev * noise
                log_probs = distribution.log_prob(actions)
                values = self.policy.predict_values(obs).flatten()
                actions = actions.numpy()
                next_observations, rewards, dones, infos = step(np.clip(actions, low, high))
                rewards = rewards * self.reward_scale
                for i, info in enumerate(infos):
                    # SB3's bootstrapping at time limits (stable-baselines3 issue #633), one observation at a time
                    if dones[i] and info.get("TimeLimit.truncated") and "terminal_observation" in info:
                        rewards[i] += self.gamma * self.value(info["terminal_observation"][None])[0]
                step_record = {
                    "observations": observations,
                    "actions": actions,
                    "rewards": rewards,
                    "episode_starts": episode_starts,
                    "values": values.numpy(),
                    "log_probs": log_probs.numpy(),
                    "dones": dones,
                    "infos": infos,
                }
                for name, value in step_record.items():
                    records[name].append(value)
                observations, episode_starts = next_observations, dones
            infos = records.pop("infos")
            return Segment(
                **{name: np.stack(values) for name, values in records.items()},
                infos=infos,
                last_observations=observations,
                last_values=self.value(observations),
            )


class WorkerRolloutPPO(PPO):
    """SB3's PPO with its rollouts sampled in the workers of a `WorkerGroupVecEnv` (see the module)."""

    def __init__(self, *args: Any, update_threads: int = 1, reward_scale: float = 1.0, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.update_threads, self.reward_scale = update_threads, reward_scale
        self._samplers_of: VecEnv | None = None  # the environments whose workers hold samplers

    def _update_learning_rate(self, optimizers: list[torch.optim.Optimizer] | torch.optim.Optimizer) -> None:
        super()._update_learning_rate(optimizers)
        for optimizer in optimizers if isinstance(optimizers, list) else [optimizers]:
            scale_learning_rates(optimizer)

    def train(self) -> None:
        rollout_threads = torch.get_num_threads()
        torch.set_num_threads(self.update_threads)
        try:
            super().train()
        finally:
            torch.set_num_threads(rollout_threads)

    def ensure_samplers(self, env: VecEnv) -> None:
        """Give `env`'s workers their samplers, once (a resumed run then sets their noise streams)."""
        if not isinstance(env, WorkerGroupVecEnv):
            raise TypeError(f"WorkerRolloutPPO samples in a WorkerGroupVecEnv's workers, got {type(env).__name__}")
        if self._samplers_of is not env:
            acting = without_optimiser(self.policy)
            env.install_samplers(lambda group: Sampler(acting, group, self.seed or 0, self.gamma, self.reward_scale))
            self._samplers_of = env

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        self.ensure_samplers(env)
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        segment = Segment.concatenate(env.sample(self.policy.state_dict(), n_rollout_steps))
        for n_steps in range(n_rollout_steps):
            self.num_timesteps += env.num_envs
            infos, dones = segment.infos[n_steps], segment.dones[n_steps]
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            rollout_buffer.add(
                segment.observations[n_steps],
                segment.actions[n_steps],
                segment.rewards[n_steps],
                segment.episode_starts[n_steps],
                torch.as_tensor(segment.values[n_steps]),
                torch.as_tensor(segment.log_probs[n_steps]),
            )
        self._last_obs, self._last_episode_starts = segment.last_observations, segment.dones[-1]
        rollout_buffer.compute_returns_and_advantage(
            last_values=torch.as_tensor(segment.last_values), dones=segment.dones[-1]
        )
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True
