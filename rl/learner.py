"""The PPO learner: training environments over worker processes, and PPO with the BC actor.

The actor is the BC module itself (`policies.actor_critic`), so at step 0 PPO's deterministic
actions are the BC policy's, exactly.
"""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium as gym
import torch
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

from common.workers import torch_threads
from humanoid.conditions import SUITE, Condition, Randomization
from humanoid.env import make_env
from policies.actor_critic import BCActorCriticPolicy
from policies.mlp import MLPPolicy
from rl.rollouts import WorkerRolloutPPO
from rl.vec_env import WorkerGroupVecEnv
from students.inputs import InputObservation, input_set_named
from task.tracking import CommandedTask

NOMINAL = Randomization()  # nothing drawn: the nominal body and floor


def training_env(
    push: float | None,
    randomization: Randomization = NOMINAL,
    width: float = 1.0,
    inputs: str = "full",
    latency: float | None = None,
    obs_noise: float | None = None,
    tracking: float | None = None,
    kick: float = 0.0,
) -> gym.Env:
    """One training environment (module-level, so worker processes can build it).

    Its physical parameters are drawn from `randomization` at every reset, at `width` of its ranges
    (`DomainRandomization.set_width`); with `push` (newtons, 0 included) it is pushed as `TorsoPushes`
    does; with `latency` (a share of the episodes, 0 included) that share runs with the suite's step of
    action latency, and with `obs_noise` that share with its sensor noise on what the actor reads (and
    the estimator with it). A curriculum (`rl.curriculum`) changes all four from an episode to the
    next. With `tracking` (a reward weight, 0 included) the episodes follow the operator's command schedules and
    reward tracking them (`CommandedTask`), the actor told the
    command. With `kick` (m/s) every episode is kicked once, as the suite's kick conditions do (`VelocityKick`).
    The observation is the environment's, then what an actor on `inputs` reads (`InputObservation`).
    SB3's `Monitor` records each episode's return and length (the environment's own rewards, before any
    reward scale) for TensorBoard's rollout/ep_rew_mean and ep_len_mean.
    """
    env = training_condition(push, randomization, width, latency, obs_noise, kick).wrap(make_env())
    if tracking is not None:
        env = CommandedTask(env, tracking, input_set_named(inputs).task)
    return Monitor(InputObservation(env, inputs))


def training_condition(
    push: float | None,
    randomization: Randomization = NOMINAL,
    width: float = 1.0,
    latency: float | None = None,
    obs_noise: float | None = None,
    kick: float = 0.0,
) -> Condition:
    """What a training episode changes (`training_env`'s settings): the suite's latency and sensor noise on a share
    of the episodes (None: neither; 0 included: a curriculum raises the share)."""
    return Condition(
        push=push,
        kick=kick,
        randomization=randomization,
        width=width,
        latency=0 if latency is None else SUITE["latency"].latency,
        latency_share=latency or 0.0,
        obs_noise=0.0 if obs_noise is None else SUITE["obs_noise"].obs_noise,
        obs_noise_share=obs_noise or 0.0,
    )


def make_vec_env(
    envs: int,
    workers: int,
    push: float | None,
    seed: int,
    backend: str = "local",
    ray_address: str | None = None,
    randomization: Randomization = NOMINAL,
    width: float = 1.0,
    inputs: str = "full",
    latency: float | None = None,
    obs_noise: float | None = None,
    tracking: float | None = None,
    kick: float = 0.0,
) -> WorkerGroupVecEnv:
    """`envs` training environments (`training_env`) over `workers` processes (or Ray actors), seeded from
    `seed`, for an actor on `inputs`."""
    env = WorkerGroupVecEnv(
        [functools.partial(training_env, push, randomization, width, inputs, latency, obs_noise, tracking, kick)]
        * envs,
        workers,
        backend=backend,
        ray_address=ray_address,
        preload=(__name__,),  # training_env's modules
    )
    env.seed(seed)
    return env


def fresh_actor(like: MLPPolicy, seed: int) -> MLPPolicy:
    """`like`'s shape re-initialised from `seed`, keeping its input normalisation (the actor of PPO from scratch)."""
    torch.manual_seed(seed)
    fresh = MLPPolicy(like.spec)
    fresh.load_state_dict({**fresh.state_dict(), **dict(like.named_buffers())})
    return fresh


def build_model(
    actor: MLPPolicy,
    env: VecEnv,
    *,
    learning_rate: float,
    critic_learning_rate: float,
    reward_scale: float,
    log_std_init: float,
    n_steps: int,
    batch_size: int,
    n_epochs: int,
    gamma: float,
    gae_lambda: float,
    clip_range: float,
    target_kl: float | None,
    seed: int,
    update_threads: int = 0,
    tensorboard: Path | None = None,
    critic_normalisation: tuple[torch.Tensor, torch.Tensor],
) -> WorkerRolloutPPO:
    """The PPO learner around `actor` (its weights are copied); nothing is trained yet.

    `update_threads` 0 means one per core (or `OMP_NUM_THREADS`: `torch_threads`): the workers are idle during
    updates. `env`'s observation is Humanoid-v5's, then the actor's inputs (`training_env`): the actor reads those,
    the critic all of it, normalised with `critic_normalisation` (the demonstrations' mean and std of it).
    """
    policy_kwargs = {
        "actor_spec": actor.spec,
        "actor_state": actor.state_dict(),
        "critic_normalisation": critic_normalisation,
        "critic_hidden": actor.spec.hidden,
        "log_std_init": log_std_init,
        "critic_lr_scale": critic_learning_rate / learning_rate,
        # Not None: SB3 would then set Adam's eps to 1e-5; every measured run used torch's 1e-8.
        "optimizer_kwargs": {},
    }
    model = WorkerRolloutPPO(
        BCActorCriticPolicy,
        env,
        update_threads=update_threads or torch_threads(),
        reward_scale=reward_scale,
        learning_rate=learning_rate,
        n_steps=n_steps,
        batch_size=batch_size,
        n_epochs=n_epochs,
        gamma=gamma,
        gae_lambda=gae_lambda,
        clip_range=clip_range,
        target_kl=target_kl,
        policy_kwargs=policy_kwargs,
        seed=seed,
        device="cpu",
        tensorboard_log=None if tensorboard is None else str(tensorboard),
        verbose=0,
    )
    if tensorboard is None:
        # SB3's own default would create an empty log folder under /tmp for every learner.
        model.set_logger(Logger(folder=None, output_formats=[]))
    return model
