"""Evaluations during PPO training: the learning curve, a checkpoint per evaluation, the best actor."""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import torch
from matplotlib.figure import Figure  # the object API draws to files without choosing a GUI backend
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from common.cli import config_text
from common.figures import save_figure
from evaluation.evaluate import evaluate_each
from evaluation.robustness import summarise
from policies import checkpoint
from policies.folder import CONFIG_TAG
from task.command_fields import STAND
from task.tracking import tracking_score

CURVE_FILE = "learning_curve.json"
CHECKPOINTS_DIR = "checkpoints"


def selection_score(point: dict[str, float]) -> float:
    """What chooses the actor kept: the mean return over the validation evaluation and each condition evaluated
    beside it. The validation push alone (the largest trained with) topples every actor and chose badly
    (docs/decisions/ppo-guards.md)."""
    returns = [value for key, value in point.items() if key == "mean_return" or key.endswith("_mean_return")]
    return sum(returns) / len(returns)


CLEAN_FLOOR = 0.9
"""Fine-tuning must never fall below this share of the BC policy's clean return, nor, on commands, of its tracking
score (the RL issues' floor)."""


def holds_floor(curve: Sequence[dict[str, float]]) -> bool:
    """Whether the last evaluation's clean return (the validation return where `clean` is not evaluated), and its
    tracking score where commands are evaluated, are at least CLEAN_FLOOR of step 0's: what a run asks of its last actor
    before keeping it, else it keeps the best (docs/decisions/keep-policy.md)."""
    keys = ["clean_mean_return" if "clean_mean_return" in curve[0] else "mean_return"]
    keys += ["tracking_score"] if "tracking_score" in curve[0] else []
    return all(curve[-1][key] >= CLEAN_FLOOR * curve[0][key] for key in keys)


def falls_back(curve: Sequence[dict[str, float]], fresh: bool) -> bool:
    """Whether a run keeps its best evaluated actor instead of its last: fine-tuning whose last actor gave up the floor
    (`holds_floor`). Never PPO from scratch (`fresh`), which has no guards against forgetting: its step 0 is no
    teacher, only its random start (docs/decisions/keep-policy.md)."""
    return not fresh and not holds_floor(curve)


def better(point: dict[str, float], best: dict[str, float], start: dict[str, float]) -> bool:
    """Whether `point` replaces `best` as the actor a run falls back on: it holds the floor against `start` (step 0)
    and scores higher (`selection_score`; the first on ties)."""
    return holds_floor([start, point]) and selection_score(point) > selection_score(best)


class Validator(BaseCallback):
    """Evaluates the deterministic actor at 0, after the first update past every `freq` steps, and at the end.

    Each evaluation saves a checkpoint (with `settings` as its training record); `settings` also go to
    TensorBoard as text (SB3's logger, so beside PPO's own curves) when training starts. The validator also
    remembers the best of them by `selection_score` (the first on ties) among those that hold the floor
    (`holds_floor`: step 0 does), so that a run that ends worse than it went, or worse than the BC policy it started
    from, can keep its best actor without giving up the floor. With a `pool` (`evaluation.evaluate.evaluation_pool`) an
    evaluation's runs go side by side while the sampling workers wait.
    """

    def __init__(
        self,
        *,
        episodes: int,
        floor_episodes: int,
        seed: int,
        push: float,
        freq: int,
        settings: dict[str, Any],
        demonstrations: dict[str, Any] | None = None,
        conditions: Sequence[str] = (),
        task: str = STAND,
        folder: Path,
        bar: tqdm,
        pool: Executor | None = None,
    ) -> None:
        super().__init__()
        self.episodes, self.seed, self.push, self.freq = episodes, seed, push, freq
        self.floor_episodes = floor_episodes  # the clean condition's, which holds the floor
        self.conditions = list(conditions)  # robustness conditions evaluated beside the validation one
        self.task = task  # what the operator commands: under schedules (with walks) the tracking is scored
        self.settings, self.folder, self.bar, self.pool = settings, folder, bar, pool
        self.demonstrations = demonstrations or {}  # what each checkpoint names as its training data (dataset.json)
        self.curve: list[dict[str, float]] = []
        self.next_at = 0
        self.best: dict[str, float] | None = None
        self.best_state: dict[str, torch.Tensor] = {}

    def evaluate_now(self) -> None:
        actor = self.model.policy.actor
        extras = [{"push": self.push}, *({"condition": name} for name in self.conditions)]
        parts = [[{**extra, **part} for part in self.parts(extra)] for extra in extras]
        runs = [((actor, "ppo"), part) for run in parts for part in run]
        evaluations = evaluate_each(runs, self.pool)
        result, *conditions = [summarise([next(evaluations) for _ in run]) for run in parts]
        actor.train()
        point = {
            "timesteps": self.num_timesteps,
            "mean_return": result["mean_return"],
            "survival_rate": result["survival_rate"],
        }
        for name, under in zip(self.conditions, conditions, strict=True):  # together they choose the actor kept
            if name == "clean" and self.task != STAND:
                point["tracking_score"] = tracking_score(under["tracking"])
                self.logger.record("eval/clean/tracking_score", point["tracking_score"])
            point[f"{name}_survival_rate"], point[f"{name}_mean_return"] = under["survival_rate"], under["mean_return"]
            self.logger.record(f"eval/{name}/survival_rate", under["survival_rate"])
            self.logger.record(f"eval/{name}/mean_return", under["mean_return"])
        self.curve.append(point)
        if self.best is None or better(point, self.best, self.curve[0]):
            self.best, self.best_state = point, {k: v.detach().clone() for k, v in actor.state_dict().items()}
        self.logger.record("eval/mean_return", point["mean_return"])
        self.logger.record("eval/survival_rate", point["survival_rate"])
        step = self.folder / CHECKPOINTS_DIR / f"step_{self.num_timesteps:08d}"
        checkpoint.save(actor, step, self.settings, self.demonstrations)  # each a start for another PPO run
        self.bar.set_postfix(eval_return=f"{point['mean_return']:.0f}", survival=f"{point['survival_rate']:.0%}")
        self.next_at = self.num_timesteps + self.freq

    def parts(self, run: dict[str, Any]) -> list[dict[str, Any]]:
        """The seeds of an evaluation's `run` (its push or condition) as `evaluate`'s settings, in parts of at most
        `episodes` that the pool runs side by side: `floor_episodes` for the clean condition, which holds the floor
        (`holds_floor`), `episodes` for the others."""
        total = self.floor_episodes if run.get("condition") == "clean" else self.episodes
        return [
            {"seed": self.seed + start, "episodes": min(self.episodes, total - start), "task": self.task}
            for start in range(0, total, self.episodes)
        ]

    def _on_training_start(self) -> None:
        self.logger.record(CONFIG_TAG, config_text(self.settings), exclude=("stdout", "log", "json", "csv"))
        if not self.curve:  # a resumed run (rl.resume) has its curve, step 0 included
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
    """Left: validation return against training steps, one line per run, BC's level dashed grey, and the clean
    return (dashed, right axis) where evaluated. Right: survival, in the validation episodes (solid) and under
    each robustness condition evaluated (one line style each)."""
    figure = Figure(figsize=(12, 4.5))
    returns, survival = figure.subplots(1, 2)
    styles = ["--", ":", "-.", (0, (1, 4))]
    # Under pushes the validation return is a fraction of the clean one: the clean return gets its own axis.
    clean = returns.twinx() if any("clean_mean_return" in p for curve in curves.values() for p in curve) else None
    for index, (label, curve) in enumerate(curves.items()):
        steps = [p["timesteps"] for p in curve]
        color = f"C{index}"
        returns.plot(steps, [p["mean_return"] for p in curve], marker="o", color=color, label=label)
        if clean is not None:
            values = [p.get("clean_mean_return", float("nan")) for p in curve]
            clean.plot(steps, values, linestyle="--", marker=".", color=color, label=f"{label}, clean")
        survival.plot(steps, [100 * p["survival_rate"] for p in curve], marker="o", color=color, label=label)
        conditions = [key.removesuffix("_survival_rate") for key in curve[0] if key.endswith("_survival_rate")]
        for name, style in zip(conditions, styles, strict=False):
            values = [100 * p.get(f"{name}_survival_rate", float("nan")) for p in curve]
            survival.plot(steps, values, linestyle=style, marker=".", color=color, label=f"{label}, {name}")
    if bc_return is not None:
        returns.axhline(bc_return, color="grey", linestyle="--", label="BC policy")
    returns.set_ylabel("validation mean return (solid)")
    if clean is not None:
        clean.set_ylabel("clean mean return (dashed)")
        clean.legend(fontsize="small", loc="lower right")
    survival.set_ylabel("survival (%)")
    survival.set_ylim(-5, 105)
    for axes in (returns, survival):
        axes.set_xlabel("environment steps")
        axes.legend(fontsize="small")
    figure.suptitle(title)
    figure.tight_layout()
    save_figure(figure, path)
