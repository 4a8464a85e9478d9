"""`make tutorial-rl`: the seed tutorial's two learners, on the PPO stages' budget but outside `make pipeline`.

What a reader of that tutorial would have got:

- **preferred action** (`PreferredActionLearner`): one mean action for every state; each step acts
  with it plus Gaussian exploration noise, and moves the mean a step toward the action taken when
  that step's reward was positive; the noise decays geometrically over the run. Saved as an
  `MLPPolicy` checkpoint whose output is that constant action (zero weights, the mean in the last
  bias), so `make eval`, `make robustness` and `make record CONTROLLER=` run it like any policy.
- **PPO** (`tutorial_ppo`): stable-baselines3's `PPO("MlpPolicy", env, learning_rate=0.005,
  ent_coef=0.005)` on one environment, every other setting SB3's default; saved by SB3
  (`policies.folder.SB3_FILE`) and run by `students.learned.SB3Controller`.

Both train to stand, on the clean task without a command, for TIMESTEPS environment steps (by default the
PPO stages' budget). The pipeline leaves them out: its table is about following commands, which neither
takes (docs/decisions/pipeline-task.md). Where the tutorial names no value (the mean's step, the noise's start
and end), the choice and the measured result are in docs/decisions/tutorial-learners.md.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from common import paths
from common.cli import (
    UserError,
    check_positive,
    check_seed,
    config_dict,
    config_text,
    flag,
    run_cli,
    setting,
    write_json,
)
from common.seed_ranges import EVAL_SEED
from evaluation.evaluate import evaluate
from humanoid.env import make_env
from policies import checkpoint
from policies.folder import CONFIG_FILE, CONFIG_TAG, EVAL_FILE, SB3_FILE, TENSORBOARD_DIR, finished_with
from policies.mlp import MLPPolicy, MLPSpec
from rl.finetune import FinetuneConfig
from students.inputs import FullInputs

LEARNERS = ("preferred", "ppo")
MADE_BY = "rl.tutorial"
"""Who a run names as its maker in config.json (`make tutorial-rl`; outside `make pipeline`)."""
LOG_EVERY = 2048  # steps between the preferred learner's TensorBoard points: one SB3 PPO rollout


@dataclass
class TutorialConfig:
    """Settings of the tutorial's learners (`make tutorial-rl`)."""

    learners: str = setting("preferred,ppo", "which of the tutorial's learners to train: preferred, ppo, or both")
    preferred_policy: Path = setting(
        paths.TUTORIAL_PREFERRED_POLICY, "checkpoint folder of the preferred-action learner"
    )
    ppo_policy: Path = setting(paths.TUTORIAL_PPO_POLICY, "folder of the tutorial's SB3 PPO (saved by SB3)")
    timesteps: int = setting(FinetuneConfig.timesteps, "environment steps of training, each learner (the PPO stages')")
    learning_rate: float = setting(0.005, "PPO: Adam learning rate (the tutorial's)")
    seed: int = setting(0, "seed of the learners and their training environments")
    final_eval_episodes: int = setting(20, "episodes of the final evaluation (seeds 1000...)")
    overwrite: bool = setting(False, "replace existing checkpoints")
    progress: bool = setting(True, "show a progress bar")

    # The tutorial's own values, or where it names none the choice measured in docs/decisions/tutorial-learners.md:
    # fixed, as the rows they give are the tutorial's (docs/decisions/fixed-settings.md).
    step_size: ClassVar[float] = 0.01
    """Preferred action: fraction of the way the mean moves toward a rewarded action."""
    noise_start: ClassVar[float] = 0.2
    """Preferred action: exploration std at the start (half the ±0.4 action range)."""
    noise_end: ClassVar[float] = 0.01
    """Preferred action: exploration std at the end (geometric decay in between)."""
    ent_coef: ClassVar[float] = 0.005
    """PPO: entropy coefficient (the tutorial's)."""


def run_settings(cfg: TutorialConfig) -> dict[str, Any]:
    """What a run saves as its settings: every field, the fixed values and who ran it."""
    fixed = {name: getattr(cfg, name) for name in ("step_size", "noise_start", "noise_end", "ent_coef")}
    return {**config_dict(cfg), **fixed, "made_by": MADE_BY}


def selected(cfg: TutorialConfig) -> list[str]:
    names = [name.strip() for name in cfg.learners.split(",") if name.strip()]
    unknown = [name for name in names if name not in LEARNERS]
    if unknown or not names:
        raise UserError(f"{flag('learners')} {cfg.learners!r}: choose from {', '.join(LEARNERS)}")
    return names


def validate(cfg: TutorialConfig) -> list[str]:
    """The learners to run; UserError in one line for a bad setting."""
    check_positive(cfg, "timesteps", "learning_rate", "final_eval_episodes")
    check_seed(cfg, "seed")
    return selected(cfg)


@contextmanager
def tensorboard(folder: Path) -> Iterator[SummaryWriter]:
    writer = SummaryWriter(str(folder / TENSORBOARD_DIR))
    try:
        yield writer
    finally:
        writer.close()


def progress_bar(total: int, label: str, show: bool) -> tqdm:
    # mininterval 1 s: a bar over single steps redraws often enough for a person, and keeps logs short.
    return tqdm(
        total=total, unit="step", desc=label, disable=not show, file=sys.stderr, dynamic_ncols=True, mininterval=1
    )


class PreferredActionLearner:
    """The tutorial's "preferred action" learner (see the module), trained in memory on one environment."""

    def __init__(
        self,
        action_low: np.ndarray,
        action_high: np.ndarray,
        step_size: float,
        noise_start: float,
        noise_end: float,
        timesteps: int,
        seed: int,
    ) -> None:
        self.low, self.high = action_low.astype(np.float64), action_high.astype(np.float64)
        self.mean = (self.low + self.high) / 2  # zero torque: the tutorial starts from "do nothing"
        self.step_size, self.noise, self.noise_end = step_size, noise_start, noise_end
        self.decay = (noise_end / noise_start) ** (1 / timesteps)
        self.rng = np.random.default_rng((seed, 5))

    def act(self) -> np.ndarray:
        noisy = self.mean + self.noise * self.rng.standard_normal(self.mean.shape)
        return np.clip(noisy, self.low, self.high)

    def learn(self, action: np.ndarray, reward: float) -> None:
        """Move toward `action` if it earned a positive reward; decay the exploration noise either way."""
        if reward > 0:
            self.mean += self.step_size * (action - self.mean)
        self.noise *= self.decay

    def train(
        self, env: Any, timesteps: int, seed: int, bar: tqdm, writer: SummaryWriter | None = None
    ) -> dict[str, float]:
        """`timesteps` steps of `env` (auto-reset, episode i seeded seed+i); the share of positive rewards.
        `writer` gets, every LOG_EVERY steps and at the end, the mean return and length of the episodes that ended
        since and the exploration noise, under SB3's tags, so the two learners' curves share TensorBoard's charts."""
        positive, episode, episode_return, episode_start = 0, 0, 0.0, 0
        returns, lengths = [], []
        env.reset(seed=seed)
        for step in range(1, timesteps + 1):
            action = self.act()
            _, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
            self.learn(action, float(reward))
            positive += reward > 0
            episode_return += float(reward)
            if terminated or truncated:
                returns.append(episode_return)
                lengths.append(step - episode_start)
                episode += 1
                episode_return, episode_start = 0.0, step
                env.reset(seed=seed + episode)
            if writer is not None and returns and (step % LOG_EVERY == 0 or step == timesteps):
                writer.add_scalar("rollout/ep_rew_mean", float(np.mean(returns)), step)
                writer.add_scalar("rollout/ep_len_mean", float(np.mean(lengths)), step)
                writer.add_scalar("train/std", self.noise, step)
                returns, lengths = [], []
            bar.update(1)
        return {"positive_reward_share": positive / timesteps, "episodes": episode}

    def policy(self) -> MLPPolicy:
        """The constant mean action as an `MLPPolicy` on the full observation: zero weights, the action in the
        last bias (through the inverse of its tanh scaling), so every tool that runs a checkpoint runs it."""
        spec = MLPSpec(FullInputs.columns, 348, len(self.mean), hidden=(1,), inputs=FullInputs.name)
        policy = MLPPolicy(spec, self.low, self.high)
        mid, half = (self.high + self.low) / 2, (self.high - self.low) / 2
        unit = np.clip((self.mean - mid) / half, -1 + 1e-6, 1 - 1e-6)
        with torch.no_grad():
            for parameter in policy.net.parameters():
                parameter.zero_()
            policy.net[-1].bias.copy_(torch.as_tensor(np.arctanh(unit), dtype=torch.float32))
        return policy


def train_preferred(cfg: TutorialConfig, settings: dict[str, Any], folder: Path) -> dict[str, Any]:
    """Train the preferred-action learner and save its checkpoint into `folder`; its figures."""
    env = make_env()
    learner = PreferredActionLearner(
        env.action_space.low,
        env.action_space.high,
        cfg.step_size,
        cfg.noise_start,
        cfg.noise_end,
        cfg.timesteps,
        cfg.seed,
    )
    start = time.perf_counter()
    with progress_bar(cfg.timesteps, "preferred action", cfg.progress) as bar, tensorboard(folder) as writer:
        writer.add_text(CONFIG_TAG, config_text(settings), 0)
        stats = learner.train(env, cfg.timesteps, cfg.seed, bar, writer)
    env.close()
    seconds = time.perf_counter() - start
    record = {**settings, "learner": "preferred", "seconds": seconds, **stats, "mean_action": learner.mean.tolist()}
    checkpoint.save(learner.policy(), folder, record, {})
    return {"seconds": seconds, **stats}


def train_ppo(cfg: TutorialConfig, settings: dict[str, Any], folder: Path) -> dict[str, Any]:
    """Train SB3's PPO as the tutorial does and save it into `folder`; its figures."""
    torch.set_num_threads(1)  # one environment in-process: SB3's own default set-up, as the tutorial runs it
    model = PPO(
        "MlpPolicy",
        make_env(),
        learning_rate=cfg.learning_rate,
        ent_coef=cfg.ent_coef,
        seed=cfg.seed,
        device="cpu",
        verbose=0,
        # Also keeps SB3 from making an empty log folder under /tmp, as it does without one.
        tensorboard_log=str(folder / TENSORBOARD_DIR),
    )
    start = time.perf_counter()
    callback = ProgressBar(cfg.timesteps, cfg.progress, settings)
    model.learn(total_timesteps=cfg.timesteps, progress_bar=False, callback=callback, tb_log_name="ppo")
    seconds = time.perf_counter() - start
    model.save(folder / SB3_FILE)
    write_json(
        folder / CONFIG_FILE,
        {"format": "stable-baselines3/PPO", "training": {**settings, "learner": "ppo", "seconds": seconds}},
    )
    return {"seconds": seconds}


class ProgressBar(BaseCallback):
    """A tqdm bar over SB3's steps (SB3's own needs the `rich` extra); also puts the run's settings in TensorBoard."""

    def __init__(self, total: int, show: bool, settings: dict[str, Any]) -> None:
        super().__init__()
        self.total, self.show, self.settings = total, show, settings

    def _on_training_start(self) -> None:
        self.logger.record(CONFIG_TAG, config_text(self.settings), exclude=("stdout", "log", "json", "csv"))
        self.bar = progress_bar(self.total, "tutorial PPO", self.show)

    def _on_step(self) -> bool:
        self.bar.update(1)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


LEARNER_INDEPENDENT = frozenset({"progress", "overwrite", "learners", "preferred_policy", "ppo_policy", "made_by"})
"""Settings a learner's run does not depend on: a folder holding the run made with others is reused."""


TRAINERS = {"preferred": train_preferred, "ppo": train_ppo}


def folder_of(cfg: TutorialConfig, learner: str) -> Path:
    return cfg.preferred_policy if learner == "preferred" else cfg.ppo_policy


def plan(cfg: TutorialConfig) -> dict[str, bool]:
    """{learner: whether its folder holds this run, finished (reused)}; CheckpointError in one line, before any
    work, for a folder holding another run that may not be replaced (no `overwrite`) or not a policy at all."""
    settings = run_settings(cfg)
    reuse = {}
    for learner in validate(cfg):
        folder = folder_of(cfg, learner)
        reuse[learner] = finished_with(folder, settings, LEARNER_INDEPENDENT)
        if not reuse[learner]:
            checkpoint.check_replaceable(folder, cfg.overwrite)
    return reuse


def main(cfg: TutorialConfig) -> dict[str, dict[str, Any]]:
    """Train each selected learner (unless its folder holds this run, finished: reused), evaluate it on seeds
    1000..; returns {learner: final evaluation}, also written to each folder's eval.json. `overwrite` lets a
    folder holding another run be replaced."""
    settings = run_settings(cfg)
    results = {}
    for learner, reuse in plan(cfg).items():
        folder = folder_of(cfg, learner)
        if reuse:
            print(f"{folder} already holds this run, finished: not run again", file=sys.stderr)
            results[learner] = json.loads((folder / EVAL_FILE).read_text())
            continue
        # Trained and evaluated before it is published: a kill in the evaluation costs no finished training.
        with checkpoint.staged(folder, cfg.overwrite) as staging:
            stats = TRAINERS[learner](cfg, settings, staging)
            result = evaluate(str(staging), episodes=cfg.final_eval_episodes, seed=EVAL_SEED, progress=cfg.progress)
            result.update(policy=str(folder), timesteps=cfg.timesteps, **stats)
            write_json(staging / EVAL_FILE, result)
        results[learner] = result
    return results


def print_results(cfg: TutorialConfig, results: dict[str, dict[str, Any]]) -> None:
    for learner, result in results.items():
        print(
            f"{folder_of(cfg, learner)}: {result['timesteps']} steps in {result['seconds']:.0f} s; final on seeds "
            f"{result['seeds'][0]}..{result['seeds'][-1]}: survival {result['survival_rate']:.0%}, "
            f"return {result['mean_return']:.1f}"
        )


def _main_and_print(cfg: TutorialConfig) -> None:
    print_results(cfg, main(cfg))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, TutorialConfig, argv, description=__doc__, prog="python -m rl.tutorial")


if __name__ == "__main__":
    sys.exit(cli())
