"""`make train-bc`: behaviour cloning of the recorded actions, then an evaluation in the simulator.

1. Load every committed frame of DATASET into tensors (`bc.data`), checked against Humanoid-v5.
2. Hold out a seeded 10 % of the episodes (never single frames: neighbouring frames are nearly
   identical, so a frame split would measure memorisation) for validation.
3. Fit an MLP policy (`policies.mlp`) whose input normalisation comes from the training frames,
   with Adam on the mean squared error of the actions, minibatches drawn from tensors in memory,
   for EPOCHS passes or, on a small dataset, as many as MIN_UPDATES Adam steps take, the rate annealed on a
   cosine; the last epoch's weights are kept (docs/decisions/bc-epochs.md).
4. Write the checkpoint to POLICY (weights, the run's full config, the dataset's identity and
   fingerprint, learning curve, TensorBoard logs with the config as text) through a hidden
   staging folder: an existing checkpoint is replaced only with --overwrite and only once the new
   one is complete.
5. Evaluate it on EVAL_EPISODES unseen seeds, next to the expert on the same seeds: POLICY/eval.json.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure  # the object API draws to files without choosing a GUI backend
from torch.nn import functional as F
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from bc.data import Demonstrations, episode_delays, load_demonstrations, no_walks, split_by_episode
from common import columns, paths
from common.cli import (
    DatasetError,
    UserError,
    check_non_negative,
    check_positive,
    check_seed,
    config_dict,
    config_text,
    run_cli,
    setting,
    write_json,
)
from common.figures import save_figure
from common.seed_ranges import EVAL_SEED
from common.workers import default_workers, torch_threads
from evaluation.evaluate import evaluate_each, evaluation_pool
from humanoid.env import make_env, nominal_model, step_seconds
from policies import checkpoint
from policies.folder import CONFIG_TAG, EVAL_FILE, LEARNING_CURVE_FILE, TENSORBOARD_DIR
from policies.mlp import MLPPolicy, MLPSpec
from rollout.controllers import KEYBOARD, KEYBOARD_EXPERT, built
from students.inputs import INPUTS, STUDENT_INPUTS, input_set_named
from task.command_fields import VELOCITY_NAMES, field_positions
from task.schedules import FIRST_NEUTRAL_SECONDS
from task.tracking import error_text
from teachers.registry import TEACHER, TEACHERS
from teleop.dataset_reader import read_commanded_frames, read_episodes

VAL_FRACTION = 0.1
"""Share of the episodes held out for validation (at least one): whole episodes, never single frames."""
ACTIVATION = "elu"
"""Hidden units: students from a few demonstrations stand where ReLU ones fell (docs/decisions/activation.md)."""
MIN_UPDATES = 5000
"""Adam steps that made the sensed-expert students stand from 10 and 20 demonstrations (docs/decisions/bc-epochs.md);
30 epochs of 50 demonstrations are about as many."""


@dataclass
class TrainConfig:
    """Settings of one behaviour-cloning run."""

    dataset: Path = setting(paths.DATASET, "LeRobot dataset folder recorded by `make record`")
    policy: Path = setting(paths.BC_POLICY, "checkpoint folder to write")
    inputs: str = setting(
        STUDENT_INPUTS,
        "what the policy reads (docs/concepts/inputs.md): by default what a robot senses, the leg odometry "
        "computed from it, its command in flight under latency and the delay, and the operator's command as the "
        "teacher's setpoint moves toward it (pending+ramp); full: the simulator's whole observation, which no robot "
        "has (the standing recipe)",
        metavar="{" + ",".join(INPUTS) + "}",
    )
    overwrite: bool = setting(False, "replace an existing checkpoint at POLICY (once the new one is complete)")
    hidden: int = setting(256, "width of each hidden layer")
    layers: int = setting(2, "number of hidden layers")
    lr: float = setting(1e-3, "Adam's first learning rate, annealed to 0 on a cosine over training")
    batch_size: int = setting(256, "minibatch size")
    epochs: int = setting(30, "passes over the training frames (more if MIN_UPDATES needs them)")
    min_updates: int = setting(
        MIN_UPDATES,
        "train for at least this many Adam steps, so fewer demonstrations do not mean less training: a small "
        "dataset gets more than EPOCHS passes (docs/decisions/bc-epochs.md); 0 = exactly EPOCHS",
    )
    seed: int = setting(0, "seed of the split, the initial weights and the minibatch order")
    cache: bool = setting(True, "cache the decoded frames (.npy) to load the same dataset faster next time")
    eval_episodes: int = setting(
        20, f"episodes of the evaluation after training, on held-out seeds from {EVAL_SEED}; 0 = skip it"
    )
    progress: bool = setting(True, "show a progress bar")


@dataclass
class LearningCurves:
    """Losses per epoch (index 0 is the first epoch) and the untrained policy's validation loss."""

    initial_val_loss: float
    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    learning_rate: list[float] = field(default_factory=list)  # Adam's, at the end of each epoch

    @property
    def best_val_loss(self) -> float:
        return min(self.val_loss)


@dataclass
class TrainResult:
    """What a run produced, for the summary line and for callers (tests, benchmarks)."""

    policy_dir: Path
    policy: MLPPolicy
    train_episodes: list[int]
    val_episodes: list[int]
    train_frames: int
    val_frames: int
    curves: LearningCurves | None = None
    load_seconds: float = 0.0
    load_rows_per_s: float = 0.0
    loaded_from_cache: bool = False
    train_seconds: float = 0.0
    evaluation: dict[str, Any] | None = None

    def describe(self) -> str:
        curves = self.curves
        line = (
            f"{self.policy_dir}: {len(curves.val_loss)} epochs in {self.train_seconds:.1f} s, validation loss "
            f"{curves.val_loss[-1]:.3g} (untrained {curves.initial_val_loss:.3g}); {self.train_frames} training and "
            f"{self.val_frames} validation "
            f"frames loaded in {self.load_seconds:.2f} s ({self.load_rows_per_s:.3g} rows/s"
            f"{', cached' if self.loaded_from_cache else ''})"
        )
        if self.evaluation:
            ev = self.evaluation
            line += (
                f"; evaluation on seeds {ev['seeds'][0]}..{ev['seeds'][-1]}: survival {ev['survival_rate']:.0%}, "
                f"return {ev['mean_return']:.1f} ± {ev['std_return']:.1f} (expert {ev['expert_mean_return']:.1f})"
            )
            if ev["tracking"] is not None:
                line += "; settled error " + ", ".join(
                    f"{name} {error_text(error)} (expert {error_text(ev['expert_tracking']['settled_error'][name])})"
                    for name, error in ev["tracking"]["settled_error"].items()
                )
        return line


def validate(cfg: TrainConfig) -> None:
    """Reject bad settings before anything is read or written."""
    input_set_named(cfg.inputs)
    check_positive(cfg, "hidden", "layers", "batch_size", "epochs", "lr")
    check_non_negative(cfg, "min_updates", "eval_episodes")
    check_seed(cfg, "seed")


def rows_of(demos: Demonstrations, episodes: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """(inputs, actions) of the frames of `episodes`."""
    mask = torch.from_numpy(np.isin(demos.episode_index, episodes))
    return demos.inputs[mask], demos.actions[mask]


def planned_epochs(frames: int, cfg: TrainConfig) -> int:
    """EPOCHS, or the passes over `frames` training frames that MIN_UPDATES Adam steps take if that is more."""
    batches = math.ceil(frames / cfg.batch_size)
    return max(cfg.epochs, math.ceil(cfg.min_updates / batches))


def lr_factor(step: int, steps: int) -> float:
    """The learning rate after `step` of `steps` Adam steps, as a fraction of LR: a cosine that ends at 0, so the
    weights kept are not one noisy step's (a constant rate's students swung with the training seed:
    docs/decisions/bc-epochs.md)."""
    return 0.5 * (1 + math.cos(math.pi * min(step, steps) / steps))


def fit(
    policy: MLPPolicy,
    train: tuple[torch.Tensor, torch.Tensor],
    val: tuple[torch.Tensor, torch.Tensor],
    cfg: TrainConfig,
    writer: SummaryWriter | None,
) -> LearningCurves:
    """Minibatch Adam on the mean squared error of the actions, every planned epoch; `policy` keeps the last one's
    weights."""
    loss_fn = F.mse_loss
    optimiser = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    order = torch.Generator().manual_seed(cfg.seed)
    x_train, y_train = train
    x_val, y_val = val

    def validation_loss() -> float:
        policy.eval()
        with torch.no_grad():
            return loss_fn(policy(x_val), y_val).item()

    curves = LearningCurves(initial_val_loss=validation_loss())
    epochs = planned_epochs(len(x_train), cfg)
    steps = epochs * math.ceil(len(x_train) / cfg.batch_size)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: lr_factor(step, steps))
    bar = tqdm(
        range(epochs),
        unit="epoch",
        disable=not cfg.progress,
        file=sys.stderr,
        dynamic_ncols=True,
    )
    for epoch in bar:
        start = time.perf_counter()
        policy.train()
        total = 0.0
        for batch in torch.randperm(len(x_train), generator=order).split(cfg.batch_size):
            loss = loss_fn(policy(x_train[batch]), y_train[batch])
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            schedule.step()
            total += loss.item() * len(batch)
        curves.train_loss.append(total / len(x_train))
        curves.val_loss.append(validation_loss())
        curves.learning_rate.append(schedule.get_last_lr()[0])
        samples_per_s = len(x_train) / (time.perf_counter() - start)
        bar.set_postfix(
            train=f"{curves.train_loss[-1]:.3g}", val=f"{curves.val_loss[-1]:.3g}", samples_per_s=f"{samples_per_s:.0f}"
        )
        if writer is not None:  # step = epochs completed, so step 0 can hold the untrained loss
            if epoch == 0:
                writer.add_scalar("loss/validation", curves.initial_val_loss, 0)
            writer.add_scalar("loss/train", curves.train_loss[-1], epoch + 1)
            writer.add_scalar("loss/validation", curves.val_loss[-1], epoch + 1)
            writer.add_scalar("throughput/samples_per_s", samples_per_s, epoch + 1)
            writer.add_scalar("train/learning_rate", curves.learning_rate[-1], epoch + 1)
    bar.close()
    return curves


def plot_learning_curve(result: TrainResult, path: Path) -> None:
    """Training and validation loss per epoch, log scale, the untrained loss at 0."""
    curves = result.curves
    epochs = np.arange(1, len(curves.val_loss) + 1)
    figure = Figure(figsize=(6, 4))
    axes = figure.subplots()
    axes.semilogy(epochs, curves.train_loss, label="training")
    axes.semilogy([0, *epochs], [curves.initial_val_loss, *curves.val_loss], label="validation")
    axes.set_xlabel("epoch")
    axes.set_ylabel("mean squared error")
    axes.set_title(f"{result.policy_dir.name}: {result.train_frames} training frames")
    axes.legend()
    figure.tight_layout()
    save_figure(figure, path)


def main(cfg: TrainConfig, made_by: str = "bc.train") -> TrainResult:
    """Train, save and evaluate a behaviour-cloning policy on the dataset `cfg` names (`train_and_save`)."""
    validate(cfg)
    checkpoint.check_replaceable(cfg.policy, cfg.overwrite)  # before minutes of work, not after
    env = make_env()
    try:
        demos = load_demonstrations(cfg.dataset, env, cache=cfg.cache, inputs=cfg.inputs)
    finally:
        env.close()
    check_taught(cfg)
    return train_and_save(demos, cfg, env.action_space, made_by)


def check_taught(cfg: TrainConfig) -> None:
    """UserError in one line if `cfg.dataset` cannot teach `cfg.inputs`: the "pending" inputs teach acting through
    a step of action latency, which a dataset without a delayed episode never shows
    (docs/decisions/pending-inputs.md); a commanded set teaches following the command, which a dataset whose
    command never changes never shows."""
    input_set = input_set_named(cfg.inputs)
    if input_set.reads_latency and not episode_delays(cfg.dataset).any():
        raise UserError(
            f"--inputs {cfg.inputs} learns to act through action latency, and no episode of {cfg.dataset} was "
            "recorded with it: record the dataset with LATENCY>0 (make record LATENCY=0.5), or train on other --inputs"
        )
    if input_set.takes_command:
        try:
            commands = read_commanded_frames(cfg.dataset, [columns.OBS_COMMAND])[columns.OBS_COMMAND]
            lengths = read_episodes(cfg.dataset, ["length"])["length"].to_pylist()
        except (OSError, KeyError, ValueError) as error:
            raise DatasetError(f"cannot read the commands of {cfg.dataset}: {error}") from None
        if len(np.unique(commands, axis=0)) < 2:
            neutral = math.ceil(FIRST_NEUTRAL_SECONDS / step_seconds(nominal_model()))  # steps
            why = (
                f"make record's posture schedules hold the zero command for their first {FIRST_NEUTRAL_SECONDS:g} s: "
                f"record longer episodes, MAX_STEPS past {neutral}"
                if max(lengths, default=0) <= neutral
                else "record with TASK=posture (the default) or CONTROLLER=keyboard"
            )
            raise UserError(
                f"--inputs {cfg.inputs} learns to follow the operator's command, and {cfg.dataset} never changes it: "
                f"{why}"
            )
        if input_set.walks and not commands[:, field_positions(VELOCITY_NAMES)].any():
            raise no_walks(cfg.inputs, cfg.dataset)


def fit_demonstrations(
    demos: Demonstrations, cfg: TrainConfig, action_space: gym.spaces.Box, writer: SummaryWriter | None = None
) -> TrainResult:
    """A policy for `action_space` fitted to `demos` in memory as `cfg` says (its split, input normalisation and
    training); nothing is written but `writer`'s logs. The same `demos` and `cfg` give the same weights."""
    torch.set_num_threads(torch_threads())
    torch.manual_seed(cfg.seed)
    train_episodes, val_episodes = split_by_episode(demos.episodes, VAL_FRACTION, cfg.seed)
    train, val = rows_of(demos, train_episodes), rows_of(demos, val_episodes)
    input_set = input_set_named(cfg.inputs)
    spec = MLPSpec(
        input_keys=input_set.columns,
        inputs=cfg.inputs,
        inputs_version=input_set.version,
        input_dim=demos.inputs.shape[1],
        action_dim=demos.actions.shape[1],
        hidden=(cfg.hidden,) * cfg.layers,
        activation=ACTIVATION,
    )
    policy = MLPPolicy(spec, action_space.low, action_space.high)
    policy.fit_normalisation(train[0])
    result = TrainResult(
        policy_dir=cfg.policy,
        policy=policy,
        train_episodes=train_episodes,
        val_episodes=val_episodes,
        train_frames=len(train[0]),
        val_frames=len(val[0]),
        load_seconds=demos.seconds,
        load_rows_per_s=demos.frames / demos.seconds if demos.seconds else 0.0,
        loaded_from_cache=demos.from_cache,
    )
    start = time.perf_counter()
    result.curves = fit(policy, train, val, cfg, writer)
    result.train_seconds = time.perf_counter() - start
    return result


def train_and_save(
    demos: Demonstrations,
    cfg: TrainConfig,
    action_space: gym.spaces.Box,
    made_by: str = "bc.train",
    context: dict[str, Any] | None = None,
) -> TrainResult:
    """Fit a policy to `demos` (`fit_demonstrations`), write its checkpoint to `cfg.policy`, and evaluate it.

    config.json's `training` holds every setting, `made_by` (the command that ran: bc.train,
    bc.dagger, pipeline.run) and `context` (e.g. the DAgger settings), and so does TensorBoard's text.
    """
    settings = {**config_dict(cfg), "made_by": made_by, **(context or {})}
    with checkpoint.staged(cfg.policy, cfg.overwrite) as folder:
        writer = SummaryWriter(str(folder / TENSORBOARD_DIR))
        writer.add_text(CONFIG_TAG, config_text(settings), 0)
        try:
            result = fit_demonstrations(demos, cfg, action_space, writer)
        finally:
            writer.close()
        training = {
            **settings,
            "epochs_run": len(result.curves.val_loss),
            "val_loss": result.curves.val_loss[-1],
            "best_val_loss": result.curves.best_val_loss,
            "train_seconds": result.train_seconds,
        }
        dataset = {
            **demos.identity(),
            "train_episodes": result.train_episodes,
            "val_episodes": result.val_episodes,
            "train_frames": result.train_frames,
            "val_frames": result.val_frames,
        }
        checkpoint.save(result.policy, folder, training, dataset)
        plot_learning_curve(result, folder / LEARNING_CURVE_FILE)
        if cfg.eval_episodes:  # before publishing: a kill in the evaluation leaves the old checkpoint, or none
            result.evaluation = evaluation_of(result.policy, cfg)
            write_json(folder / EVAL_FILE, result.evaluation)
    return result


def teacher_of(dataset: Path) -> str:
    """Who labelled the dataset's actions (its episodes' labeller; the keyboard's episodes the expert the keys drive):
    the student's teacher, which its evaluation compares it with. Where several labelled it, or none that is a
    registered teacher (a policy's recording), one line on stderr names them and the one compared with: the registered
    teacher that labelled the most frames, else the default teacher."""
    table = read_episodes(dataset, [columns.EPISODE_LABELLER, "length"]).to_pydict()
    frames: dict[str, int] = {}
    for labeller, length in zip(table[columns.EPISODE_LABELLER], table["length"], strict=True):
        labeller = KEYBOARD_EXPERT if labeller == KEYBOARD else labeller
        frames[labeller] = frames.get(labeller, 0) + int(length)
    teachers = {name: count for name, count in frames.items() if name in TEACHERS}
    teacher = max(teachers, key=teachers.__getitem__) if teachers else TEACHER
    if len(frames) > 1 or not teachers:
        listed = ", ".join(f"{name} ({count} frames)" for name, count in sorted(frames.items(), key=lambda x: -x[1]))
        print(f"note: {dataset} was labelled by {listed}: the student is compared with {teacher}", file=sys.stderr)
    return teacher


def evaluation_of(policy: MLPPolicy, cfg: TrainConfig) -> dict[str, Any]:
    """`policy` (the checkpoint `cfg.policy` becomes) and its teacher (`teacher_of`) side by side on the same
    EVAL_EPISODES held-out seeds, on the task its inputs follow (held-out schedules for a policy that takes a
    command): what eval.json holds (its "expert_*" entries: the teacher's, named by "expert")."""
    settings = {"episodes": cfg.eval_episodes, "seed": EVAL_SEED, "task": input_set_named(cfg.inputs).task}
    teacher = teacher_of(cfg.dataset)
    runs = [((policy, str(cfg.policy)), settings), (built(teacher), settings)]
    with evaluation_pool(default_workers(len(runs))) as pool:
        evaluation, expert = evaluate_each(runs, pool)
    evaluation["expert"] = teacher
    evaluation["expert_mean_return"] = expert["mean_return"]
    evaluation["expert_survival_rate"] = expert["survival_rate"]
    evaluation["expert_tracking"] = expert["tracking"]
    evaluation["return_vs_expert"] = evaluation["mean_return"] / expert["mean_return"]
    return evaluation


def _main_and_print(cfg: TrainConfig) -> None:
    print(main(cfg).describe())


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, TrainConfig, argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(cli())
