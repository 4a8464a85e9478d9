"""Guards that keep PPO from wrecking a pretrained actor: critic warm-up and a decaying BC term.

A random critic's first updates wreck a pretrained actor (stable-baselines3 issue #543); see
docs/decisions/ppo-guards.md for what each guard changed in measured runs.
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3.common.callbacks import BaseCallback

from policies.mlp import MLPPolicy


class DemonstrationTerm:
    """λ_k · MSE(actor(demo obs), demo action) on a fresh demonstration minibatch, λ_k = λ_0 · decay^k (DAPG).

    `add_gradient` is called by `RegularisedAdam.step`, after PPO's backward pass: the update then
    follows the gradient of PPO's loss plus this term, in one optimiser.
    """

    def __init__(
        self, inputs: torch.Tensor, actions: torch.Tensor, weight: float, decay: float, batch_size: int, seed: int
    ) -> None:
        self.inputs, self.actions = inputs, actions
        self.initial_weight, self.decay, self.batch_size = weight, decay, batch_size
        self.updates = 0  # actor updates so far (set by `Guards`)
        self.active = False  # off while the critic warms up
        self.actor: MLPPolicy | None = None
        self.generator = torch.Generator().manual_seed(seed)

    @property
    def weight(self) -> float:
        return self.initial_weight * self.decay**self.updates

    def add_gradient(self) -> None:
        if self.actor is None or not self.active or self.weight == 0:
            return
        batch = torch.randint(len(self.inputs), (self.batch_size,), generator=self.generator)
        loss = self.weight * torch.nn.functional.mse_loss(self.actor(self.inputs[batch]), self.actions[batch])
        loss.backward()


class RegularisedAdam(torch.optim.Adam):
    """Adam whose step first adds the gradient of a `DemonstrationTerm` (SB3 builds it with these kwargs)."""

    def __init__(self, params: Any, term: DemonstrationTerm | None = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        self.term = term

    @torch.no_grad()
    def step(self, closure: Any = None) -> Any:
        if self.term is not None:
            with torch.enable_grad():
                self.term.add_gradient()
        return super().step(closure)


class Guards(BaseCallback):
    """Critic warm-up (actor frozen for the first `warmup` steps) and the decay of the BC term's weight."""

    def __init__(self, warmup: int, term: DemonstrationTerm | None) -> None:
        super().__init__()
        self.warmup, self.term = warmup, term
        self.actor_updates = 0

    def _set_actor_trainable(self, trainable: bool) -> None:
        for parameter in self.model.policy.actor_parameters():
            parameter.requires_grad_(trainable)

    def _on_training_start(self) -> None:
        self._set_actor_trainable(self.warmup == 0)

    def _on_rollout_end(self) -> None:  # PPO updates right after this
        warm = self.num_timesteps >= self.warmup
        self._set_actor_trainable(warm)
        self.logger.record("train/actor_frozen", float(not warm))
        if self.term is not None:
            self.term.active, self.term.updates = warm, self.actor_updates
            self.logger.record("train/bc_weight", self.term.weight if warm else 0.0)
        self.actor_updates += warm

    def _on_step(self) -> bool:
        return True
