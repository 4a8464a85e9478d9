"""`make finetune-rl`: PPO refinement of the BC policy, guarded against forgetting.

Data flow:

    BC checkpoint --(actor, normalisation)--> PPO policy (rl.learner) <--(weights once per rollout)
    ENVS environments in WORKERS processes (rl.vec_env), each sampling its share (rl.rollouts)
    rollouts --> PPO update, guarded (rl.guards) --> evaluation + checkpoint every EVAL_FREQ steps
    (rl.validation) --> the kept actor in the BC checkpoint format, eval.json, learning curve

1. The BC checkpoint's `MLPPolicy` becomes the actor of a stable-baselines3 PPO policy: at step 0
   PPO's deterministic actions are the BC policy's, exactly. The log std starts small.
2. Guards against the known failure (a random critic's first updates wreck a pretrained actor):
   critic warm-up, a conservative learning rate, clip range and target KL; and a critic that can
   learn (its own rate, scaled rewards, clipped inputs). The actor kept is the last one unless its
   clean return fell below the floor (`rl.validation.falls_back`; never for scratch): then the best evaluated.
3. The final actor is saved in the BC checkpoint format (`make eval` and `make record` run it),
   with eval.json and a learning curve beside BC's level and the curve of PPO from scratch. Its
   config.json holds every setting, who ran it and the BC weights' digest (`bc_policy_sha256`);
   TensorBoard gets the same as text.

`make scratch-rl` (`rl.scratch`) runs the same with fresh weights and without the guards against forgetting (the
same clip range and target KL). Why each default is what it is: docs/how-to/finetune-ppo.md; what was tried and
removed: docs/decisions/.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import sys
import time
from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import torch
from stable_baselines3.common.callbacks import CallbackList
from tqdm import tqdm

from bc.data import load_demonstrations
from common import paths
from common.cli import (
    UserError,
    check_non_negative,
    check_positive,
    check_seed,
    config_dict,
    flag,
    run_cli,
    setting,
    write_json,
)
from common.paths import NEWEST
from common.ray_backend import BACKENDS, check_backend
from common.seed_ranges import EVAL_SEED, VALIDATION_SEED
from common.workers import default_workers
from evaluation.evaluate import evaluate_each, evaluation_pool
from humanoid.conditions import SUITE, Randomization, parse_randomization
from humanoid.env import make_env
from policies import checkpoint
from policies.folder import (
    DATASET_FILE,
    EVAL_FILE,
    LEARNING_CURVE_FILE,
    TENSORBOARD_DIR,
    WEIGHTS_FILE,
    chosen_policy,
    finished_with,
    json_object,
)
from policies.mlp import normalisation
from rl import resume
from rl.curriculum import PushCurriculum, parse_stages, stage_width
from rl.guards import Guards
from rl.learner import build_model, fresh_actor, make_vec_env
from rl.rollouts import WorkerRolloutPPO
from rl.validation import CURVE_FILE, Validator, falls_back, plot_curves, selection_score
from rl.vec_env import WorkerGroupVecEnv
from students.inputs import input_set_named
from students.learned import PolicyController
from task.command_fields import STAND

EVAL_CONDITIONS = ("clean", "push20", "mass")
"""Robustness conditions (docs/concepts/robustness-suite.md) evaluated beside the validation one at every
evaluation during training: they choose the actor kept with it (`selection_score`; docs/decisions/keep-policy.md,
"The fall-back's score"), and go to the learning curve's survival panel and TensorBoard."""


# Sampling peaked at 14 workers on a 16-core machine (5.1x one worker): the learner's serial update and the
# rollout's transfer take the rest (docs/decisions/worker-counts.md).
MOST_WORKERS = 14
# Workers that each hold this many environments or more end the same run as one worker
# (docs/decisions/worker-counts.md), so the default changes no result: more workers only where each gets as many,
# and 2 otherwise, which every 2-core machine used before.
ENVS_PER_WORKER = 4


@dataclass
class FinetuneConfig:
    """Settings of one PPO run: fine-tuning the BC actor (`make finetune-rl`)."""

    bc_policy: Path = setting(
        Path(NEWEST),
        "the student whose actor PPO refines (`make scratch-rl`: only its shape, inputs and normalisation); "
        f"'{NEWEST}': the newest of {', '.join(map(str, paths.STUDENTS))}, which `make dagger` and `make train-bc` "
        "write; a student that takes a command trains on the operator's schedules (docs/how-to/finetune-ppo.md)",
    )
    policy: Path = setting(paths.PPO_POLICY, "checkpoint folder to write")
    timesteps: int = setting(
        2**19,
        "environment steps of training: 32 rollouts (the budget: docs/decisions/ppo-budget.md), rounded up to whole "
        "rollouts of --rollout-steps",
    )
    envs: int = setting(64, "environments, spread over the workers (each samples its share of every rollout)")
    workers: int | None = setting(
        None,
        "processes the environments are spread over (1: in the learner's own process); "
        "changes the speed, not the result, while each holds 4 or more environments; default: the machine's cores, "
        f"at most {MOST_WORKERS} and at most one per {ENVS_PER_WORKER} environments (but 2 where cores allow)",
    )
    backend: str = setting(
        "local",
        "where the workers run: 'local' (processes here) or 'ray' (Ray actors in the cluster at "
        "--ray-address, one CPU each: docs/concepts/ray.md); the same weights either way",
        choices=BACKENDS,
    )
    ray_address: str | None = setting(
        None, "HOST:PORT of a running Ray cluster's head (--backend ray); default: a local Ray for this run"
    )
    push: float = setting(0.0, "train with horizontal pushes of this many newtons on the torso (0.1 s every 2 s)")
    kick: float = setting(
        0.0,
        "train with one kick of the root's horizontal velocity per episode, in m/s, as the suite's kick conditions "
        "give it (0.2, 0.4 or 0.6), beside the pushes, and choose the actor kept under that condition too; 0 = none",
    )
    curriculum: str = setting(
        "0,2.5,5,7.5,10,15,20,30,40",
        "train with pushes whose force grows through these stages, in newtons (e.g. '0,10,20,40'; instead of "
        "--push), the --randomize ranges widening with them from nominal to whole: the next stage after a "
        "rollout whose ended episodes survived at --curriculum-advance (rl.curriculum; the stages and "
        "what they gave: docs/decisions/curriculum.md); 'none' = no curriculum",
    )
    curriculum_advance: float = setting(
        0.8, "share of a rollout's ended training episodes that must reach the time limit to move to the next stage"
    )
    curriculum_episodes: int = setting(
        16, "training episodes a rollout must end for its survival to count towards the next stage"
    )
    randomize: str = setting(
        "suite",
        "the training environments' physical parameters, drawn at every episode: a preset (none, mild, suite) "
        "or ranges like mass=0.8:1.2,friction=0.5:1.5,strength=0.8:1.2 (humanoid.conditions)",
    )
    latency_share: float = setting(
        0.5,
        "share of the training episodes run with the suite's step of action latency, growing with the curriculum's "
        "stages as the --randomize ranges do (without a curriculum: from the start); 0 = none",
    )
    obs_noise_share: float = setting(
        0.5,
        "share of the training episodes with the suite's sensor noise on what the actor reads, growing as "
        "--latency-share does; 0 = none",
    )
    tracking_weight: float = setting(
        10.0,
        "for a BC policy that takes a command: its training episodes follow the operator's command schedules, and "
        "each step's reward adds this times the tracking term (the mean over the fields of exp(-(error/tolerance)²), "
        "at most 1, beside standing's 5: task.tracking.CommandedTask; why 10: docs/decisions/tracking-weight.md); "
        "evaluations run held-out schedules",
    )
    overwrite: bool = setting(False, "replace an existing checkpoint at POLICY")
    learning_rate: float = setting(3e-5, "Adam learning rate of the actor")
    critic_learning_rate: float = setting(
        1e-3, "Adam learning rate of the critic (at the actor's rate the critic never fitted the returns)"
    )
    rollout_steps: int = setting(
        16_384,
        "environment steps per PPO update, over all environments (with 2,048 the "
        "updates were mostly noise and returns under pushes fell)",
    )
    batch_size: int = setting(2048, "PPO minibatch size")
    epochs: int = setting(5, "passes over each rollout")
    gamma: float = setting(0.99, "discount")
    gae_lambda: float = setting(0.95, "GAE lambda")
    clip_range: float = setting(0.1, "PPO clip range")
    target_kl: float = setting(
        0.02, "stop an update's epochs once the KL to the rollout policy exceeds 1.5x this; 0 = never"
    )
    critic_warmup: int = setting(50_000, "first steps that train the critic only (actor frozen); 0 = none")
    eval_freq: int = setting(
        65_536,
        "steps between evaluations (and checkpoints) during training, each after the first update past its mark: "
        "4 rollouts, since the clean evaluation runs --floor-episodes (docs/decisions/ppo-guards.md)",
    )
    eval_episodes: int = setting(5, "episodes of each evaluation during training but the clean one")
    floor_episodes: int = setting(
        20,
        "episodes of the clean evaluation during training, whose return and tracking score must hold the floor "
        "against step 0's (rl.validation.CLEAN_FLOOR); with 5, one fall crossed it (docs/decisions/ppo-guards.md)",
    )
    final_eval_episodes: int = setting(
        20,
        "episodes of the final evaluation (seeds 1000...); 0 = skip it (`make pipeline` does: its table evaluates "
        "every controller on those seeds)",
    )
    seed: int = setting(0, "seed of PPO and the environments")
    update_threads: int = setting(
        0,
        "torch threads of PPO's updates (0: one per core, or OMP_NUM_THREADS; the workers are idle then). "
        "The rollouts use one: idle torch threads spin and slow the simulation "
        "(docs/decisions/ppo-sampling.md)",
    )
    scratch_policy: Path = setting(
        paths.SCRATCH_POLICY, "PPO-from-scratch run whose learning curve the figure shows beside this one, if present"
    )
    progress: bool = setting(True, "show a progress bar")

    fresh: ClassVar[bool] = False
    """Whether the actor starts from fresh weights (`make scratch-rl`) rather than the BC checkpoint's."""
    reward_scale: ClassVar[float] = 0.01
    """Factor on the rewards PPO learns from (the returns reported are the environment's own): keeps the value loss
    below 1, not in the 1,000s, under the gradient-norm clip actor and critic share
    (docs/decisions/fixed-settings.md)."""
    log_std_init: ClassVar[float] = math.log(0.05)
    """Initial log std of the exploration noise: std 0.05, `make record`'s DART noise and the suite's `noise`
    condition; 0.03, the pipeline's recording noise, did worse (docs/decisions/fixed-settings.md)."""


def workers(cfg: FinetuneConfig) -> int:
    """The worker processes `cfg` asks for: --workers, else the machine's cores (`common.workers`) as far as the
    result stays the one 2 workers give (`ENVS_PER_WORKER`)."""
    if cfg.workers is not None:
        return cfg.workers
    return min(default_workers(MOST_WORKERS), max(2, cfg.envs // ENVS_PER_WORKER), cfg.envs)


def validate(cfg: FinetuneConfig) -> None:
    """Reject bad settings before anything is read or written; messages name the flags."""
    check_positive(
        cfg,
        "timesteps",
        "envs",
        "rollout_steps",
        "batch_size",
        "epochs",
        "eval_freq",
        "eval_episodes",
        "floor_episodes",
        "learning_rate",
        "critic_learning_rate",
        "clip_range",
        "curriculum_episodes",
    )
    if cfg.batch_size < 2:  # PPO normalises each minibatch's advantages: one sample has no spread
        raise UserError(f"--batch-size must be at least 2, got {cfg.batch_size}")
    if workers(cfg) <= 0:
        raise UserError(f"--workers must be positive, got {workers(cfg)}")
    check_non_negative(
        cfg,
        "push",
        "kick",
        "target_kl",
        "critic_warmup",
        "final_eval_episodes",
        "update_threads",
        "tracking_weight",
    )
    check_seed(cfg, "seed")
    check_backend(cfg.backend, cfg.ray_address)
    if workers(cfg) > cfg.envs:
        raise UserError(f"--workers ({workers(cfg)}) must not exceed --envs ({cfg.envs})")
    if cfg.rollout_steps % cfg.envs:
        raise UserError(f"--rollout-steps ({cfg.rollout_steps}) must be a multiple of --envs ({cfg.envs})")
    if cfg.batch_size > cfg.rollout_steps:  # a minibatch is cut from one rollout
        raise UserError(f"--batch-size ({cfg.batch_size}) must not exceed --rollout-steps ({cfg.rollout_steps})")
    if cfg.policy.resolve() == cfg.bc_policy.resolve():
        raise UserError("--policy must differ from --bc-policy: the BC checkpoint is never overwritten")
    for name in ("curriculum_advance", "latency_share", "obs_noise_share", "gamma", "gae_lambda"):
        if not 0 <= getattr(cfg, name) <= 1:
            raise UserError(f"{flag(name)} must be in [0, 1], got {getattr(cfg, name)}")
    if stages(cfg) and cfg.push:
        raise UserError("give --push or --curriculum, not both")
    if cfg.kick and kick_condition(cfg) not in SUITE:
        kicks = ", ".join(name.removeprefix("kick") for name in SUITE if name.startswith("kick"))
        raise UserError(f"--kick must be 0 or one of the suite's kick speeds ({kicks} m/s), got {cfg.kick:g}")
    randomization(cfg)


def stages(cfg: FinetuneConfig) -> list[float]:
    """The curriculum's push forces ([] for none); UserError in one line if malformed."""
    try:
        return parse_stages(cfg.curriculum)
    except ValueError as error:
        raise UserError(str(error)) from None


def randomization(cfg: FinetuneConfig) -> Randomization:
    try:
        return parse_randomization(cfg.randomize)
    except ValueError as error:
        raise UserError(str(error)) from None


def training_push(cfg: FinetuneConfig) -> float | None:
    """The training environments' first push force; None: they are not pushed."""
    if stages(cfg):
        return stages(cfg)[0]
    return cfg.push or None


def validation_push(cfg: FinetuneConfig) -> float:
    """The push of the evaluations during training, which choose the actor kept: the largest trained with."""
    return max(stages(cfg), default=cfg.push)


def kick_condition(cfg: FinetuneConfig) -> str:
    """The robustness condition of the training's kick (`humanoid.conditions.SUITE`'s "kick0.4" for 0.4 m/s)."""
    return f"kick{cfg.kick:g}"


def eval_conditions(cfg: FinetuneConfig) -> tuple[str, ...]:
    """The conditions evaluated beside the validation push during training: EVAL_CONDITIONS, and the training's kick
    if it has one (what it trains for then chooses the actor kept too)."""
    return (*EVAL_CONDITIONS, kick_condition(cfg)) if cfg.kick else EVAL_CONDITIONS


def widened(cfg: FinetuneConfig) -> dict[str, float]:
    """What grows with the curriculum's stages: the training environments' methods and their values at the last
    stage (`PushCurriculum`)."""
    grown = {
        "set_width": 1.0 if randomization(cfg).active else 0.0,
        "set_latency_share": cfg.latency_share,
        "set_noise_share": cfg.obs_noise_share,
    }
    return {method: last for method, last in grown.items() if last > 0}


def vec_env(cfg: FinetuneConfig) -> WorkerGroupVecEnv:
    """The training environments of `cfg`, on its `task`: the operator's schedules if the actor takes a command, with
    walks if it takes the velocity command (`rl.learner.training_env`)."""
    width = stage_width(0, len(stages(cfg)))  # a curriculum's first stage (1: no curriculum, the whole ranges)
    inputs = checkpoint.load(cfg.bc_policy).spec.inputs
    return make_vec_env(
        cfg.envs,
        workers(cfg),
        training_push(cfg),
        cfg.seed,
        cfg.backend,
        cfg.ray_address,
        randomization(cfg),
        width,
        inputs,
        latency=width * cfg.latency_share if cfg.latency_share else None,
        obs_noise=width * cfg.obs_noise_share if cfg.obs_noise_share else None,
        tracking=cfg.tracking_weight if task(cfg) != STAND else None,
        kick=cfg.kick,
    )


def task(cfg: FinetuneConfig) -> str:
    """The task the BC policy's inputs follow (`students.inputs.InputSet.task`): posture schedules if it takes a
    command, with walks if it takes the velocity command too; else standing."""
    return input_set_named(checkpoint.load(cfg.bc_policy).spec.inputs).task


def learner(cfg: FinetuneConfig, env: WorkerGroupVecEnv, tensorboard: Path | None = None) -> WorkerRolloutPPO:
    """The PPO learner of `cfg`: the BC actor (or a fresh one of its shape) and the configured hyperparameters."""
    bc = checkpoint.load(cfg.bc_policy)
    return build_model(
        fresh_actor(bc, cfg.seed) if cfg.fresh else bc,
        env,
        critic_normalisation=critic_normalisation(cfg, bc.spec.inputs),
        learning_rate=cfg.learning_rate,
        critic_learning_rate=cfg.critic_learning_rate,
        reward_scale=cfg.reward_scale,
        log_std_init=cfg.log_std_init,
        n_steps=cfg.rollout_steps // cfg.envs,
        batch_size=cfg.batch_size,
        n_epochs=cfg.epochs,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_range,
        target_kl=cfg.target_kl or None,
        seed=cfg.seed,
        update_threads=cfg.update_threads,
        tensorboard=tensorboard,
    )


def bc_dataset(bc_policy: Path) -> dict[str, Any]:
    """The BC checkpoint's record of its training data (path, episodes, frames, split); UserError in one line if it
    names none (the tutorial's learners): that data normalises the critic's inputs."""
    record = json_object(bc_policy / DATASET_FILE)
    if "path" not in record:
        raise UserError(
            f"{bc_policy} names no demonstrations ({DATASET_FILE}): PPO starts from a policy trained on a dataset "
            "(make train-bc, make dagger, or a PPO run from one), whose data normalise its critic's inputs"
        )
    return record


def weights_digest(policy: Path) -> str:
    """SHA-256 of a checkpoint's weights file: which BC policy a PPO run started from."""
    return hashlib.sha256((policy / WEIGHTS_FILE).read_bytes()).hexdigest()


def critic_normalisation(cfg: FinetuneConfig, inputs: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std (floored at `policies.mlp.STD_FLOOR`) of what the critic reads, the whole PPO observation: the
    gymnasium observation, then the actor's `inputs` (`InputObservation`), in the BC checkpoint's data. The critic
    keeps what the actor knows that the simulator's state does not say, such as the command in flight under
    latency."""
    dataset, env = Path(bc_dataset(cfg.bc_policy)["path"]), make_env()
    observations = load_demonstrations(dataset, env).inputs
    return normalisation(torch.cat([observations, load_demonstrations(dataset, env, inputs=inputs).inputs], dim=1))


def finished_result(cfg: FinetuneConfig, settings: dict[str, Any], on: str) -> dict[str, Any] | None:
    """POLICY/eval.json of a run already finished there with these settings (not re-run; its final evaluation run
    now if a kill cut it short); else None."""
    if cfg.overwrite or not finished_with(cfg.policy, settings, resume.PRESENTATION):
        return None
    print(f"{cfg.policy} already holds this run, finished: not run again", file=sys.stderr)
    result = json.loads((cfg.policy / EVAL_FILE).read_text())
    if cfg.final_eval_episodes and "seeds" not in result:  # killed during its final evaluation
        return final_evaluation(cfg, on, result)
    return result


def final_evaluation(
    cfg: FinetuneConfig, on: str, figures: dict[str, Any], pool: Executor | None = None
) -> dict[str, Any]:
    """The published actor at POLICY on FINAL_EVAL_EPISODES seeds from EVAL_SEED (none if 0), clean and under the
    validation push, on the `task` `on`, with the training's `figures`: what POLICY/eval.json then holds."""
    if not cfg.final_eval_episodes:
        return figures  # eval.json holds them already
    final = {"episodes": cfg.final_eval_episodes, "seed": EVAL_SEED, "task": on}
    pushes = [{"push": validation_push(cfg)}] if validation_push(cfg) else []
    result, *pushed = evaluate_each([(str(cfg.policy), {**final, **extra}) for extra in [{}, *pushes]], pool)
    if pushed:
        result["pushed"] = pushed[0]
    result.update(figures)
    write_json(cfg.policy / EVAL_FILE, result)
    return result


def main(cfg: FinetuneConfig, made_by: str = "rl.finetune") -> dict[str, Any]:
    """Train as configured; returns what POLICY/eval.json holds: the training's figures and the final evaluation
    (none with --final-eval-episodes 0).

    `made_by` (rl.finetune, rl.scratch, pipeline.run) is saved with the settings in config.json.
    """
    # 'newest' resolved first, so that validate compares POLICY with the student it names.
    student = chosen_policy(str(cfg.bc_policy), paths.STUDENTS, "make train-bc (after make record)")
    cfg = dataclasses.replace(cfg, bc_policy=Path(student))
    validate(cfg)
    cfg = dataclasses.replace(cfg, workers=workers(cfg))  # saved as a number: a resume must split as this run did
    # A one-line CheckpointError now (missing, unreadable, other sizes) rather than after the environments start.
    PolicyController.load(cfg.bc_policy, make_env())
    demonstrations = bc_dataset(cfg.bc_policy)
    on = task(cfg)
    settings = {
        **config_dict(cfg),
        # The fixed settings too, so that config.json still holds every setting the run used.
        **{name: getattr(cfg, name) for name in ("fresh", "reward_scale", "log_std_init")},
        "made_by": made_by,
        "bc_policy_sha256": weights_digest(cfg.bc_policy),
    }
    finished = finished_result(cfg, settings, on)
    if finished is not None:
        return finished
    checkpoint.check_replaceable(cfg.policy, cfg.overwrite)
    saved = resume.load(checkpoint.running_folder(cfg.policy))
    now = resume.comparable(settings)
    if saved is not None and saved["settings"] != now:
        first = next(name for name in {**saved["settings"], **now} if saved["settings"].get(name) != now.get(name))
        raise UserError(
            f"{checkpoint.running_folder(cfg.policy)} holds an interrupted run with other settings "
            f"({first}: {saved['settings'].get(first)!r} there, {now.get(first)!r} now): run it with its "
            f"settings to resume it, or remove that folder"
        )
    torch.set_num_threads(1)  # the rollouts' count; WorkerRolloutPPO raises it for its updates
    with evaluation_pool(min(cfg.workers, default_workers(1 + len(eval_conditions(cfg))))) as pool:
        with (
            contextlib.closing(vec_env(cfg)) as env,
            checkpoint.running(cfg.policy, cfg.overwrite) as folder,
        ):
            model = learner(cfg, env, folder / TENSORBOARD_DIR)
            # SB3 stops after the first whole rollout that reaches TIMESTEPS.
            steps = math.ceil(cfg.timesteps / cfg.rollout_steps) * cfg.rollout_steps
            bar = tqdm(total=steps, unit="step", disable=not cfg.progress, file=sys.stderr, dynamic_ncols=True)
            validator = Validator(
                episodes=cfg.eval_episodes,
                floor_episodes=cfg.floor_episodes,
                seed=VALIDATION_SEED,
                push=validation_push(cfg),
                freq=cfg.eval_freq,
                conditions=eval_conditions(cfg),
                task=on,
                settings=settings,
                demonstrations=demonstrations,
                folder=folder,
                bar=bar,
                pool=pool,
            )
            guards = Guards(cfg.critic_warmup)
            curriculum = (
                PushCurriculum(stages(cfg), cfg.curriculum_advance, cfg.curriculum_episodes, widened(cfg))
                if stages(cfg)
                else None
            )
            if saved is not None:
                resume.restore(saved, model, env, validator, curriculum)
                bar.update(model.num_timesteps)
                print(f"resuming {folder} at step {model.num_timesteps:,}", file=sys.stderr)
            snapshots = resume.Snapshots(folder, validator, settings, saved, curriculum)
            start, started_at = time.perf_counter(), model.num_timesteps  # past 0 when resumed
            model.learn(
                total_timesteps=cfg.timesteps - model.num_timesteps,
                # The curriculum after the guards (both act at a rollout's end) and before the snapshots.
                callback=CallbackList([guards, *([curriculum] if curriculum else []), validator, snapshots]),
                reset_num_timesteps=saved is None,
            )
            seconds = time.perf_counter() - start
            bar.close()
            actor = model.policy.actor
            keep_best = falls_back(validator.curve, cfg.fresh)  # the guarded actor
            kept = validator.best if keep_best else validator.curve[-1]
            if keep_best:
                actor.load_state_dict(validator.best_state)
            record = {**settings, "seconds": seconds, "kept": kept}
            if curriculum is not None:
                record["curriculum_stages"] = curriculum.history
            checkpoint.save(actor, folder, record, demonstrations)
            write_json(folder / CURVE_FILE, validator.curve, indent=1)
            bc_eval = cfg.bc_policy / EVAL_FILE
            bc = json.loads(bc_eval.read_text()) if bc_eval.is_file() else None
            figures = {
                "timesteps": steps,
                "seconds": seconds,  # this process's: a resumed run's from where it resumed
                "steps_per_s": (model.num_timesteps - started_at) / seconds,
                "resumed_at": started_at,
                "bc_mean_return": None if bc is None else bc.get("mean_return"),  # none if its evaluation was skipped
                "expert_mean_return": None if bc is None else bc.get("expert_mean_return"),
                "training_curve": validator.curve,
                "kept": kept,
            }
            plot_training(cfg, validator.curve, folder / LEARNING_CURVE_FILE)
            # Published with the weights: a kill during the final evaluation leaves a finished run (`finished_result`).
            write_json(folder / EVAL_FILE, figures)
            (folder / resume.RESUME_FILE).unlink()  # the run is whole: nothing to resume
        return final_evaluation(cfg, on, figures, pool)


def plot_training(cfg: FinetuneConfig, curve: list[dict[str, Any]], path: Path) -> None:
    """The run's validation curve at `path`, beside scratch's (BASELINE's, if it has one) when fine-tuning."""
    fine_tuning = not cfg.fresh
    curves = {"PPO fine-tuning" if fine_tuning else "PPO from scratch": curve}
    scratch_curve = cfg.scratch_policy / CURVE_FILE
    if cfg.scratch_policy.resolve() != cfg.policy.resolve() and scratch_curve.is_file():
        curves["PPO from scratch"] = json.loads(scratch_curve.read_text())
    plot_curves(
        curves,
        curve[0]["mean_return"] if fine_tuning else None,
        f"{cfg.policy.name}: validation on seeds {VALIDATION_SEED}.."
        f"{VALIDATION_SEED + cfg.eval_episodes - 1}"
        f"{f', {validation_push(cfg):g} N pushes' if validation_push(cfg) else ''}",
        path,
    )


def print_summary(cfg: FinetuneConfig, result: dict[str, Any]) -> None:
    curve = result["training_curve"]
    print(
        f"{cfg.policy}: {result['timesteps']} steps in {result['seconds']:.0f} s ({result['steps_per_s']:.0f}/s); "
        f"evaluations during training {min(p['mean_return'] for p in curve):.0f}.."
        f"{max(p['mean_return'] for p in curve):.0f} (first {curve[0]['mean_return']:.1f}), "
        f"kept step {result['kept']['timesteps']} (mean over its evaluations {selection_score(result['kept']):.1f})"
        + (
            f"; final on seeds {result['seeds'][0]}..{result['seeds'][-1]}: "
            f"survival {result['survival_rate']:.0%}, return {result['mean_return']:.1f}"
            + (f" (BC {result['bc_mean_return']:.1f})" if result["bc_mean_return"] else "")
            if "seeds" in result
            else ""
        )
    )


def _main_and_print(cfg: FinetuneConfig) -> None:
    print_summary(cfg, main(cfg))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, FinetuneConfig, argv, description=__doc__, prog="python -m rl.finetune")


if __name__ == "__main__":
    sys.exit(cli())
