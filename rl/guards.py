"""The guard that keeps PPO from wrecking a pretrained actor: critic warm-up (the actor frozen at first).

A random critic's first updates wreck a pretrained actor (stable-baselines3 issue #543); see
docs/decisions/ppo-guards.md for what each guard changed in measured runs.
"""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback


class Guards(BaseCallback):
    """Critic warm-up: the actor frozen for the first `warmup` steps."""

    def __init__(self, warmup: int) -> None:
        super().__init__()
        self.warmup = warmup

    def _set_actor_trainable(self, trainable: bool) -> None:
        for parameter in self.model.policy.actor_parameters():
            parameter.requires_grad_(trainable)

    def _on_training_start(self) -> None:
        self._set_actor_trainable(self.warmup == 0)

    def _on_rollout_end(self) -> None:  # PPO updates right after this
        warm = self.num_timesteps >= self.warmup
        self._set_actor_trainable(warm)
        self.logger.record("train/actor_frozen", float(not warm))

    def _on_step(self) -> bool:
        return True
