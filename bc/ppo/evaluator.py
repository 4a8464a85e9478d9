"""Evaluations during PPO training: the learning curve, a checkpoint per evaluation, the best actor."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from matplotlib.figure import Figure  # the object API draws to files without choosing a GUI backend
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from bc.evaluate import evaluate
from common.cli import config_text
from humanoid.learned import PolicyController
from policies import checkpoint

CURVE_FILE = "learning_curve.json"
CURVE_PNG = "learning_curve.png"
CHECKPOINTS_DIR = "checkpoints"
CONFIG_TAG = "config"  # the TensorBoard text of the run's settings


class Evaluator(BaseCallback):
    """Evaluates the deterministic actor at 0, after the first update past every `freq` steps, and at the end.

    Each evaluation saves a checkpoint (with `settings` as its training record); `settings` also go to
    TensorBoard as text (SB3's logger, so beside PPO's own curves) when training starts. The evaluator also
    remembers the best of them (the first on ties), so that a run that ends worse than it went, or
    worse than the BC policy it started from, can keep its best actor.
    """

    def __init__(
        self,
        *,
        episodes: int,
        seed: int,
        push: float,
        freq: int,
        settings: dict[str, Any],
        folder: Path,
        bar: tqdm,
    ) -> None:
        super().__init__()
        self.episodes, self.seed, self.push, self.freq = episodes, seed, push, freq
        self.settings, self.folder, self.bar = settings, folder, bar
        self.curve: list[dict[str, float]] = []
        self.next_at = 0
        self.best: dict[str, float] | None = None
        self.best_state: dict[str, torch.Tensor] = {}

    def evaluate_now(self) -> None:
        actor = self.model.policy.actor
        result = evaluate(PolicyController(actor, "ppo"), episodes=self.episodes, seed=self.seed, push=self.push)
        actor.train()
        point = {
            "timesteps": self.num_timesteps,
            "mean_return": result["mean_return"],
            "survival_rate": result["survival_rate"],
        }
        self.curve.append(point)
        if self.best is None or point["mean_return"] > self.best["mean_return"]:
            self.best, self.best_state = point, {k: v.detach().clone() for k, v in actor.state_dict().items()}
        self.logger.record("eval/mean_return", point["mean_return"])
        self.logger.record("eval/survival_rate", point["survival_rate"])
        checkpoint.save(actor, self.folder / CHECKPOINTS_DIR / f"step_{self.num_timesteps:08d}", self.settings, {})
        self.bar.set_postfix(eval_return=f"{point['mean_return']:.0f}", survival=f"{point['survival_rate']:.0%}")
        self.next_at = self.num_timesteps + self.freq

    def _on_training_start(self) -> None:
        self.logger.record(CONFIG_TAG, config_text(self.settings), exclude=("stdout", "log", "json", "csv"))
        if not self.curve:  # a resumed run (bc.ppo.resume) has its curve, step 0 included
            self.evaluate_now()

    def _on_rollout_start(self) -> None:
        # The actor changes only in PPO's updates, between rollouts: an evaluation here sees each version once.
        if self.num_timesteps >= self.next_at:
            self.evaluate_now()

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        if self.curve[-1]["timesteps"] != self.num_timesteps:
            self.evaluate_now()


def plot_curves(curves: dict[str, list[dict[str, float]]], bc_return: float | None, title: str, path: Path) -> None:
    """Evaluation return against training steps, one line per run, BC's level dashed."""
    figure = Figure(figsize=(7, 4))
    axes = figure.subplots()
    for label, curve in curves.items():
        axes.plot([p["timesteps"] for p in curve], [p["mean_return"] for p in curve], marker="o", label=label)
    if bc_return is not None:
        axes.axhline(bc_return, color="grey", linestyle="--", label="BC policy")
    axes.set_xlabel("environment steps")
    axes.set_ylabel("evaluation mean return")
    axes.set_title(title)
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
