"""`make finetune-rl`: PPO refinement of the BC policy, guarded against forgetting; `make baseline-rl`: PPO from scratch.

1. The BC checkpoint's `MLPPolicy` becomes the actor of a stable-baselines3 PPO policy
   (`policies.actor_critic`): the mean action is the BC module itself, so at step 0 PPO's
   deterministic actions are the BC policy's, exactly. The log std starts small.
2. Guards against the known failure (a random critic's first updates wreck a pretrained actor,
   stable-baselines3 issue #543), each a flag:
   - critic warm-up: the first CRITIC_WARMUP steps train the value function only;
   - a DAPG-style behaviour-cloning term on the demonstrations, added to PPO's gradient at every
     optimiser step with a weight that decays by BC_DECAY per update (`DemonstrationTerm`);
   - a conservative learning rate, clip range and target KL;
   and a critic that can learn: its own, larger learning rate, scaled rewards, and inputs
   clipped where falls and pushes send them far from the demonstrations'.
3. ENVS environments over WORKERS processes (`bc.vec_env`), each sampling its share of every
   rollout with its own copy of the policy (`bc.rollouts`; the worker count changes the speed,
   not the result, while each worker holds 4 or more), optional torso pushes (PUSH, as `make eval`),
   TensorBoard logs, a progress bar, an evaluation (and checkpoint) every EVAL_FREQ steps.
4. The final actor is saved in the BC checkpoint format (`make eval` and `make record` run it),
   with eval.json and a learning curve beside BC's level and the scratch baseline's curve.

`--scratch` is the baseline: the same network shape and budget, fresh weights (the input
normalisation still comes from the BC checkpoint's data), no guards.
"""

from __future__ import annotations

import functools
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from matplotlib.figure import Figure
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv
from tqdm import tqdm

from bc.data import load_demonstrations
from bc.evaluate import EVAL_SEED, evaluate
from bc.rollouts import WorkerRolloutPPO
from bc.vec_env import WorkerGroupVecEnv
from policies import DATASET_FILE, EVAL_FILE, checkpoint
from policies.actor_critic import BCActorCriticPolicy
from policies.controller import PolicyController
from policies.mlp import MLPPolicy
from teleop.cli import UserError, run_cli, setting
from teleop.env import make_env
from teleop.perturbations import TorsoPushes

CURVE_FILE = "learning_curve.json"
CURVE_PNG = "learning_curve.png"
CHECKPOINTS_DIR = "checkpoints"
SCRATCH_POLICY = Path("policies/ppo_scratch_humanoid_stand")
# Evaluations during training run on seeds 2000.. (validation) and select the actor kept; the
# final evaluation runs on 1000.. (EVAL_SEED), as every other policy's does.
VALIDATION_SEED = 2000


@dataclass
class FinetuneConfig:
    """Settings of one PPO run (fine-tuning by default, `--scratch` for the baseline)."""

    bc_policy: Path = setting(Path("policies/bc_humanoid_stand"), "BC checkpoint: the actor to refine (with "
                                                                   "--scratch, only its shape and normalisation)")
    policy: Path = setting(Path("policies/ppo_humanoid_stand"), "checkpoint folder to write")
    scratch: bool = setting(False, "the baseline: fresh weights, no warm-up, no BC term")
    timesteps: int = setting(300_000, "environment steps of training")
    envs: int = setting(64, "environments, spread over the workers (each samples its share of every rollout)")
    workers: int = setting(2, "processes the environments are spread over (1: in the learner's own process); "
                              "changes the speed, not the result, while each holds 4 or more environments")
    push: float = setting(0.0, "train with horizontal pushes of this many newtons on the torso (0.1 s every 2 s)")
    overwrite: bool = setting(False, "replace an existing checkpoint at POLICY")
    learning_rate: float = setting(3e-5, "Adam learning rate (the scratch baseline uses --scratch-learning-rate)")
    scratch_learning_rate: float = setting(3e-4, "learning rate of the scratch baseline")
    critic_learning_rate: float = setting(1e-3, "Adam learning rate of the critic when fine-tuning (at the actor's "
                                              "rate the critic never fitted the returns)")
    reward_scale: float = setting(0.01, "factor on the rewards PPO learns from when fine-tuning (the returns "
                                        "reported are the environment's own): keeps the value loss below 1, not in "
                                        "the 1,000s, under the gradient-norm clip actor and critic share")
    log_std_init: float = setting(math.log(0.05), "initial log std of the exploration noise (std 0.05: the DART "
                                                  "noise the BC data was recorded with)")
    rollout_steps: int = setting(16_384, "environment steps per PPO update, over all environments (with 2,048 the "
                                        "updates were mostly noise and returns under pushes fell)")
    batch_size: int = setting(2048, "PPO minibatch size")
    epochs: int = setting(5, "passes over each rollout")
    gamma: float = setting(0.99, "discount")
    gae_lambda: float = setting(0.95, "GAE lambda")
    clip_range: float = setting(0.1, "PPO clip range")
    target_kl: float = setting(0.02, "stop an update's epochs once the KL to the rollout policy exceeds 1.5x this; "
                                     "0 = never")
    critic_warmup: int = setting(50_000, "first steps that train the critic only (actor frozen); 0 = none")
    bc_weight: float = setting(0.0, "weight of the BC term on the demonstrations added to PPO's loss; 0 = none")
    bc_decay: float = setting(0.95, "factor applied to the BC weight after every PPO update")
    eval_freq: int = setting(20_000, "steps between evaluations (and checkpoints) during training; each runs "
                                    "after the first update past its mark")
    eval_episodes: int = setting(5, "episodes of each evaluation during training")
    validation_seed: int = setting(VALIDATION_SEED, "first seed of the evaluations during training: apart from "
                                                    "the final evaluation's, since they choose the actor kept")
    keep: str = setting("best", "the actor saved: 'best' (highest return of the evaluations during training, "
                                "step 0 included, earliest on ties) or 'last'", choices=("best", "last"))
    final_eval_episodes: int = setting(20, "episodes of the final evaluation (seeds 1000...)")
    seed: int = setting(0, "seed of PPO, the environments and the demonstration minibatches")
    update_threads: int = setting(0, "torch threads of PPO's updates (0: one per core; the workers are idle then). "
                                     "The rollouts use one: idle torch threads spin, and slowed the simulation by "
                                     "a tenth to a fifth")
    progress: bool = setting(True, "show a progress bar")


def validate(cfg: FinetuneConfig) -> None:
    """Reject bad settings before anything is read or written."""
    for name, value in {"TIMESTEPS": cfg.timesteps, "ENVS": cfg.envs, "WORKERS": cfg.workers,
                        "ROLLOUT_STEPS": cfg.rollout_steps, "BATCH_SIZE": cfg.batch_size, "EPOCHS": cfg.epochs,
                        "EVAL_FREQ": cfg.eval_freq, "EVAL_EPISODES": cfg.eval_episodes}.items():
        if value <= 0:
            raise UserError(f"{name} must be positive, got {value}")
    if cfg.workers > cfg.envs:
        raise UserError(f"WORKERS ({cfg.workers}) must not exceed ENVS ({cfg.envs})")
    if cfg.rollout_steps % cfg.envs:
        raise UserError(f"ROLLOUT_STEPS ({cfg.rollout_steps}) must be a multiple of ENVS ({cfg.envs})")
    for name, value in {"VALIDATION_SEED": cfg.validation_seed, "PUSH": cfg.push, "BC_WEIGHT": cfg.bc_weight,
                        "TARGET_KL": cfg.target_kl, "CRITIC_WARMUP": cfg.critic_warmup,
                        "FINAL_EVAL_EPISODES": cfg.final_eval_episodes, "UPDATE_THREADS": cfg.update_threads}.items():
        if not (math.isfinite(value) and value >= 0):
            raise UserError(f"{name} must be >= 0, got {value}")
    if not (0 < cfg.learning_rate and 0 < cfg.scratch_learning_rate and 0 < cfg.critic_learning_rate
            and 0 < cfg.reward_scale and 0 < cfg.bc_decay <= 1):
        raise UserError("learning rates and REWARD_SCALE must be positive, BC_DECAY in (0, 1]")
    if cfg.keep not in ("best", "last"):
        raise UserError(f"KEEP must be 'best' or 'last', got {cfg.keep!r}")
    if cfg.policy.resolve() == cfg.bc_policy.resolve():
        raise UserError("POLICY must differ from BC_POLICY: the BC checkpoint is never overwritten")


def training_env(push: float) -> gym.Env:
    """One training environment (module-level, so worker processes can build it).

    SB3's `Monitor` records each episode's return and length (the environment's own rewards, before
    REWARD_SCALE) for TensorBoard's rollout/ep_rew_mean and ep_len_mean.
    """
    env = make_env()
    return Monitor(TorsoPushes(env, push) if push > 0 else env)


def make_vec_env(cfg: FinetuneConfig) -> VecEnv:
    factories = [functools.partial(training_env, cfg.push)] * cfg.envs
    env = WorkerGroupVecEnv(factories, cfg.workers)
    env.seed(cfg.seed)
    return env


def initial_actor(cfg: FinetuneConfig) -> MLPPolicy:
    """The BC checkpoint's policy, or for the scratch baseline the same shape re-initialised around its normalisation."""
    bc = checkpoint.load(cfg.bc_policy)
    if not cfg.scratch:
        return bc
    torch.manual_seed(cfg.seed)
    fresh = MLPPolicy(bc.spec)
    buffers = dict(bc.named_buffers())
    fresh.load_state_dict({**fresh.state_dict(), **buffers})
    return fresh


class DemonstrationTerm:
    """λ_k · MSE(actor(demo obs), demo action) on a fresh demonstration minibatch, λ_k = λ_0 · decay^k (DAPG).

    `add_gradient` is called by `RegularisedAdam.step`, after PPO's backward pass: the update then
    follows the gradient of PPO's loss plus this term, in one optimiser.
    """

    def __init__(self, inputs: torch.Tensor, actions: torch.Tensor, weight: float, decay: float, batch_size: int,
                 seed: int) -> None:
        self.inputs, self.actions = inputs, actions
        self.initial_weight, self.decay, self.batch_size = weight, decay, batch_size
        self.updates = 0  # actor updates so far (set by `Guards`)
        self.active = False  # off while the critic warms up
        self.actor: MLPPolicy | None = None
        self.generator = torch.Generator().manual_seed(seed)

    @property
    def weight(self) -> float:
        return self.initial_weight * self.decay ** self.updates

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


class Evaluator(BaseCallback):
    """Evaluates the deterministic actor at 0, after the first update past every `freq` steps, and at the end.

    Each evaluation saves a checkpoint. The evaluator also remembers the best of them (the first on
    ties), so that a run that ends worse than it went, or worse than the BC policy it started from,
    can keep its best actor.
    """

    def __init__(self, cfg: FinetuneConfig, folder: Path, bar: tqdm) -> None:
        super().__init__()
        self.cfg, self.folder, self.bar = cfg, folder, bar
        self.curve: list[dict[str, float]] = []
        self.next_at = 0
        self.best: dict[str, float] | None = None
        self.best_state: dict[str, torch.Tensor] = {}

    def evaluate_now(self) -> None:
        actor = self.model.policy.actor
        result = evaluate(PolicyController(actor, "ppo"), episodes=self.cfg.eval_episodes,
                          seed=self.cfg.validation_seed, push=self.cfg.push)
        actor.train()
        point = {"timesteps": self.num_timesteps, "mean_return": result["mean_return"],
                 "survival_rate": result["survival_rate"]}
        self.curve.append(point)
        if self.best is None or point["mean_return"] > self.best["mean_return"]:
            self.best, self.best_state = point, {k: v.detach().clone() for k, v in actor.state_dict().items()}
        self.logger.record("eval/mean_return", point["mean_return"])
        self.logger.record("eval/survival_rate", point["survival_rate"])
        checkpoint.save(actor, self.folder / CHECKPOINTS_DIR / f"step_{self.num_timesteps:08d}", asdict(self.cfg), {})
        self.bar.set_postfix(eval_return=f"{point['mean_return']:.0f}", survival=f"{point['survival_rate']:.0%}")
        self.next_at = self.num_timesteps + self.cfg.eval_freq

    def _on_training_start(self) -> None:
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


def build_model(cfg: FinetuneConfig, env: VecEnv, term: DemonstrationTerm | None,
                tensorboard: Path | None = None) -> WorkerRolloutPPO:
    """The PPO learner with the (BC or fresh) actor; nothing is trained yet."""
    actor = initial_actor(cfg)
    policy_kwargs = {"actor_spec": actor.spec, "actor_state": actor.state_dict(), "critic_hidden": actor.spec.hidden,
                     "log_std_init": cfg.log_std_init, "optimizer_class": RegularisedAdam,
                     "critic_lr_scale": 1.0 if cfg.scratch else cfg.critic_learning_rate / cfg.learning_rate,
                     "optimizer_kwargs": {"term": term}}
    model = WorkerRolloutPPO(
        BCActorCriticPolicy, env, update_threads=cfg.update_threads or len(os.sched_getaffinity(0)),
        reward_scale=1.0 if cfg.scratch else cfg.reward_scale,
        learning_rate=cfg.scratch_learning_rate if cfg.scratch else cfg.learning_rate,
        n_steps=cfg.rollout_steps // cfg.envs, batch_size=cfg.batch_size, n_epochs=cfg.epochs, gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range, target_kl=cfg.target_kl or None,
        policy_kwargs=policy_kwargs, seed=cfg.seed, device="cpu",
        tensorboard_log=None if tensorboard is None else str(tensorboard), verbose=0)
    if tensorboard is None:
        # SB3's own default would create an empty log folder under /tmp for every learner.
        model.set_logger(Logger(folder=None, output_formats=[]))
    if term is not None:
        term.actor = model.policy.actor
    return model


def bc_dataset(bc_policy: Path) -> dict[str, Any]:
    """The BC checkpoint's record of its training data (path, episodes, frames, split)."""
    return json.loads((bc_policy / DATASET_FILE).read_text())


def demonstration_term(cfg: FinetuneConfig) -> DemonstrationTerm | None:
    """The BC term on the BC checkpoint's own training data, or None when off."""
    if cfg.scratch or cfg.bc_weight == 0:
        return None
    demos = load_demonstrations(Path(bc_dataset(cfg.bc_policy)["path"]), make_env())
    return DemonstrationTerm(demos.inputs, demos.actions, cfg.bc_weight, cfg.bc_decay, cfg.batch_size, cfg.seed)


def plot_curves(curves: dict[str, list[dict[str, float]]], bc_return: float | None, title: str, path: Path) -> None:
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


def main(cfg: FinetuneConfig) -> dict[str, Any]:
    """Train as configured; returns the final evaluation written to POLICY/eval.json."""
    validate(cfg)
    checkpoint.check_replaceable(cfg.policy, cfg.overwrite)
    # A one-line CheckpointError now (missing, unreadable, other sizes) rather than after the environments start.
    PolicyController.load(cfg.bc_policy, make_env())
    torch.set_num_threads(1)  # the rollouts' count; WorkerRolloutPPO raises it for its updates
    term = demonstration_term(cfg)
    env = make_vec_env(cfg)
    try:
        with checkpoint.staged(cfg.policy, cfg.overwrite) as folder:
            model = build_model(cfg, env, term, folder / "tensorboard")
            # SB3 stops after the first whole rollout that reaches TIMESTEPS.
            steps = math.ceil(cfg.timesteps / cfg.rollout_steps) * cfg.rollout_steps
            bar = tqdm(total=steps, unit="step", disable=not cfg.progress, file=sys.stderr, dynamic_ncols=True)
            evaluator = Evaluator(cfg, folder, bar)
            start = time.perf_counter()
            callbacks = [evaluator] if cfg.scratch else [Guards(cfg.critic_warmup, term), evaluator]
            model.learn(total_timesteps=cfg.timesteps, callback=CallbackList(callbacks))
            seconds = time.perf_counter() - start
            bar.close()
            actor = model.policy.actor
            kept = evaluator.best if cfg.keep == "best" else evaluator.curve[-1]
            if cfg.keep == "best":
                actor.load_state_dict(evaluator.best_state)
            checkpoint.save(actor, folder, {**asdict(cfg), "seconds": seconds, "kept": kept},
                            bc_dataset(cfg.bc_policy))
            (folder / CURVE_FILE).write_text(json.dumps(evaluator.curve, indent=1))
    finally:
        env.close()

    result = evaluate(str(cfg.policy), episodes=cfg.final_eval_episodes, seed=EVAL_SEED, progress=cfg.progress)
    if cfg.push:
        result["pushed"] = evaluate(str(cfg.policy), episodes=cfg.final_eval_episodes, seed=EVAL_SEED, push=cfg.push)
    bc_eval = cfg.bc_policy / EVAL_FILE
    bc = json.loads(bc_eval.read_text()) if bc_eval.is_file() else None
    result.update(timesteps=steps, seconds=seconds, steps_per_s=steps / seconds,
                  bc_mean_return=None if bc is None else bc["mean_return"],
                  expert_mean_return=None if bc is None else bc.get("expert_mean_return"),
                  training_curve=evaluator.curve, kept=kept)
    checkpoint.write_json(cfg.policy / EVAL_FILE, result)
    curves = {"PPO from scratch" if cfg.scratch else "PPO fine-tuning": evaluator.curve}
    scratch_curve = SCRATCH_POLICY / CURVE_FILE
    if not cfg.scratch and scratch_curve.is_file():
        curves["PPO from scratch"] = json.loads(scratch_curve.read_text())
    plot_curves(curves, evaluator.curve[0]["mean_return"] if not cfg.scratch else None,
                f"{cfg.policy.name}: validation on seeds {cfg.validation_seed}.."
                f"{cfg.validation_seed + cfg.eval_episodes - 1}"
                f"{f', {cfg.push:g} N pushes' if cfg.push else ''}", cfg.policy / CURVE_PNG)
    return result


def _main_and_print(cfg: FinetuneConfig) -> None:
    result = main(cfg)
    curve = result["training_curve"]
    print(f"{cfg.policy}: {result['timesteps']} steps in {result['seconds']:.0f} s ({result['steps_per_s']:.0f}/s); "
          f"evaluations during training {min(p['mean_return'] for p in curve):.0f}..{max(p['mean_return'] for p in curve):.0f}"
          f" (first {curve[0]['mean_return']:.1f}), kept step {result['kept']['timesteps']} "
          f"({result['kept']['mean_return']:.1f}); final on seeds {result['seeds'][0]}..{result['seeds'][-1]}: "
          f"survival {result['survival_rate']:.0%}, return {result['mean_return']:.1f}"
          + (f" (BC {result['bc_mean_return']:.1f})" if result["bc_mean_return"] else ""))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, FinetuneConfig, argv, description=__doc__, prog="python -m bc.finetune")


if __name__ == "__main__":
    sys.exit(cli())
