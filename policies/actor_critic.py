"""A stable-baselines3 actor-critic whose actor *is* an `MLPPolicy`: PPO fine-tunes the BC module itself.

SB3's `ActorCriticPolicy` maps observations through an "mlp_extractor" to a latent, then a linear
`action_net` to the mean action, with a state-independent log std. Here the extractor's actor
branch is the BC policy (normalisation, MLP, tanh scaling included) and `action_net` is the
identity, so the Gaussian's mean is exactly the BC policy's action; the critic is a separate MLP on the
gymnasium observation, normalised. The environment appends the actor's inputs to that observation
(`students.inputs.InputObservation`), computed as the live controller computes them: the actor reads
those, the critic all of it, the privileged observation included (an asymmetric actor-critic). Orthogonal
initialisation is off: it would overwrite the loaded weights. The log std starts small (`log_std_init`):
SB3's default std of 1 puts most samples far outside the ±0.4 action bounds.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import Schedule
from torch import nn

from policies.mlp import ACTIVATIONS, MLPPolicy, MLPSpec


class ActorCriticExtractor(nn.Module):
    """SB3's `mlp_extractor` contract (`forward_actor`, `forward_critic`, latent sizes) around an `MLPPolicy`.

    PPO's observation is the gymnasium observation, then the actor's inputs: the actor reads its last
    `input_dim` entries, the critic as many as `critic_normalisation` (mean, std) normalises: all of them.
    """

    def __init__(
        self, actor: MLPPolicy, critic_hidden: tuple[int, ...], critic_normalisation: tuple[torch.Tensor, torch.Tensor]
    ) -> None:
        super().__init__()
        self.actor = actor
        mean, std = critic_normalisation
        # Buffers, not trained: saved and restored with the policy (resume), copied to the samplers.
        self.register_buffer("critic_mean", mean.detach().clone().float())
        self.register_buffer("critic_std", std.detach().clone().float())
        layers: list[nn.Module] = []
        width = len(mean)
        for size in critic_hidden:
            layers += [nn.Linear(width, size), ACTIVATIONS[actor.spec.activation]()]
            width = size
        self.critic = nn.Sequential(*layers)
        self.latent_dim_pi = actor.spec.action_dim
        self.latent_dim_vf = width

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        """The mean action: the BC policy's output."""
        return self.actor(features[..., -self.actor.spec.input_dim :])

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        # The critic sees normalised inputs (the demonstrations' mean and std, not trained), clipped: a fall
        # or a push takes some of them hundreds of standard deviations from the demonstrations', and the
        # critic's outputs and value loss with them.
        normalised = (features[..., : len(self.critic_mean)] - self.critic_mean) / self.critic_std
        return self.critic(normalised.clamp(-CRITIC_INPUT_CLIP, CRITIC_INPUT_CLIP))


CRITIC_INPUT_CLIP = 10.0  # standard deviations, as SB3's VecNormalize clips observations


def scale_learning_rates(optimizer: torch.optim.Optimizer) -> None:
    """Multiply each parameter group's rate by its "lr_scale" (SB3 sets one rate for every group)."""
    for group in optimizer.param_groups:
        group["lr"] *= group.get("lr_scale", 1.0)


class BCActorCriticPolicy(ActorCriticPolicy):
    """PPO's policy with an `MLPPolicy` actor rebuilt from `actor_spec` and `actor_state` (its state_dict)."""

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Box,
        lr_schedule: Schedule,
        actor_spec: MLPSpec,
        actor_state: dict[str, torch.Tensor],
        critic_hidden: tuple[int, ...] = (256, 256),
        critic_lr_scale: float = 1.0,
        *,
        critic_normalisation: tuple[torch.Tensor, torch.Tensor],
        **kwargs: Any,
    ) -> None:
        # Plain data, set before nn.Module.__init__: `_build` (called by the parent) needs them.
        self.actor_spec, self.actor_state, self.critic_hidden = actor_spec, actor_state, critic_hidden
        self.critic_lr_scale = critic_lr_scale
        self.critic_normalisation = critic_normalisation
        super().__init__(observation_space, action_space, lr_schedule, ortho_init=False, **kwargs)

    def _build_mlp_extractor(self) -> None:
        actor = MLPPolicy(self.actor_spec)
        actor.load_state_dict(self.actor_state)
        self.mlp_extractor = ActorCriticExtractor(actor, self.critic_hidden, self.critic_normalisation)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()  # the actor already outputs the mean action
        # The parent's optimiser holds the linear action_net just replaced: rebuild it over the real parameters,
        # the critic's in a group of its own, whose rate is `critic_lr_scale` times the actor's.
        actor = {id(p) for p in self.actor_parameters()}
        groups = [
            {"params": self.actor_parameters()},
            {"params": [p for p in self.parameters() if id(p) not in actor], "lr_scale": self.critic_lr_scale},
        ]
        self.optimizer = self.optimizer_class(groups, lr=lr_schedule(1), **self.optimizer_kwargs)
        scale_learning_rates(self.optimizer)

    @property
    def actor(self) -> MLPPolicy:
        """The BC module being fine-tuned (save it with `policies.checkpoint.save`)."""
        return self.mlp_extractor.actor

    def actor_parameters(self) -> list[nn.Parameter]:
        """What PPO changes in the actor: its weights and the exploration log std."""
        return [*self.actor.parameters(), self.log_std]
