"""`make dagger`: DAgger with the scripted expert (EXPERT: on the full state, or on leg odometry) as the oracle.

Behaviour cloning only ever sees the states the expert visits; a cloned policy drifts into states
it never saw and its errors compound. DAgger (Ross et al., 2011) collects labels where the policy
itself goes:

1. Copy DATASET to OUTPUT (once; OUTPUT is then a dataset of its own, appended to).
2. Train a policy on OUTPUT (`bc.train`).
3. Each round: roll the current policy out for EPISODES episodes; at every visited state store
   the expert's action as the label (`action`) and the policy's as what ran (`executed_action`);
   append them to OUTPUT with `dagger_round` = the round and `labeller` = EXPERT; retrain on the
   whole aggregate.
4. The last round's policy is the checkpoint at POLICY, evaluated like any BC policy (eval.json).

Rounds continue the seeds after the dataset's last one; a second run on the same OUTPUT adds
further rounds. The run's settings go with what it writes: a line in OUTPUT/recordings.jsonl for
the episodes it added, and "dagger" in the final checkpoint's config.json (and its TensorBoard text).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bc.train import MIN_UPDATES, TrainConfig, TrainResult
from bc.train import main as train
from common import keys, paths
from common.cli import DatasetError, UserError, config_dict, flag, run_cli, setting
from humanoid.controllers import make_controller
from humanoid.env import make_env
from humanoid.episode import EpisodeBuffer, run_episode
from humanoid.expert import LQRExpert, SensedExpert
from humanoid.inputs import INPUTS
from humanoid.learned import PolicyController
from policies import checkpoint
from teleop import recordings
from teleop.dataset_reader import read_episodes
from teleop.store import CommittedEpisode, DatasetSpec, EpisodeStore

MADE_BY = "bc.dagger"


@dataclass
class DaggerConfig:
    """Settings of a DAgger run."""

    dataset: Path = setting(paths.DATASET, "demonstrations to start from (left unchanged)")
    output: Path = setting(paths.DAGGER_DATASET, "aggregate dataset: a copy of DATASET, then every round appended")
    policy: Path = setting(paths.DAGGER_POLICY, "checkpoint folder of the final policy")
    inputs: str = setting(
        "full",
        "what the student reads (see `make train-bc`); EXPERT labels from the full state or the sensed features",
        choices=INPUTS,
    )
    expert: str = setting(
        LQRExpert.name,
        "who labels the policy's states: the expert on the full state, or the expert on leg odometry (the teacher "
        "whose law INPUTS=odometry can read; docs/robustness.md)",
        choices=(LQRExpert.name, SensedExpert.name),
    )
    rounds: int = setting(6, "rounds of roll out, label, aggregate, retrain")
    episodes: int = setting(10, "policy episodes rolled out and labelled per round")
    epochs: int = setting(30, "training epochs of every round's policy (more if MIN_UPDATES needs them)")
    min_updates: int = setting(MIN_UPDATES, "at least this many Adam steps in every round's training (bc.train's)")
    patience: int = setting(
        0,
        "early stopping patience of each training (0 = train all EPOCHS: on DAgger "
        "data the validation loss says little about standing)",
    )
    overwrite: bool = setting(False, "replace an existing checkpoint at POLICY")
    eval_episodes: int = setting(20, "episodes of the final evaluation; 0 = skip it")
    progress: bool = setting(True, "show progress bars")


@dataclass
class RoundReport:
    """How the policy that was rolled out in a round did (its own rollouts, before retraining)."""

    round: int
    episodes: int
    frames: int
    mean_return: float
    survived: int


@dataclass
class DaggerResult:
    """The rounds and the final training."""

    rounds: list[RoundReport] = field(default_factory=list)
    final: TrainResult | None = None

    def describe(self) -> str:
        lines = [
            f"round {r.round}: the policy stood {r.survived}/{r.episodes} episodes, mean return "
            f"{r.mean_return:.1f}; {r.frames} frames labelled"
            for r in self.rounds
        ]
        return "\n".join([*lines, self.final.describe()])


def validate(cfg: DaggerConfig) -> None:
    for name in ("rounds", "episodes", "epochs"):
        if getattr(cfg, name) <= 0:
            raise UserError(f"{flag(name)} must be positive, got {getattr(cfg, name)}")
    for name in ("patience", "min_updates", "eval_episodes"):
        if getattr(cfg, name) < 0:
            raise UserError(f"{flag(name)} must be >= 0, got {getattr(cfg, name)}")
    if cfg.output.resolve() == cfg.dataset.resolve():
        raise UserError("--output must differ from --dataset: DAgger leaves the demonstrations unchanged")
    if not (cfg.dataset / "meta/info.json").is_file() and not cfg.output.exists():
        raise DatasetError(f"no LeRobot dataset at {cfg.dataset}; record one with `make record DATASET={cfg.dataset}`")


def collect_round(
    store: EpisodeStore,
    policy_dir: Path,
    round_index: int,
    episodes: int,
    progress: bool,
    committed: list[CommittedEpisode] | None = None,
    expert_name: str = LQRExpert.name,
) -> RoundReport:
    """Roll the policy out, label its states with the expert named, append the episodes to `store` (and to
    `committed`)."""
    env = make_env()
    policy = PolicyController.load(policy_dir, env)
    expert = make_controller(expert_name, env)
    buffer = EpisodeBuffer(env, env.spec.max_episode_steps)
    first_seed = store.next_seed()
    returns, frames, survived = [], 0, 0
    for seed in tqdm(
        range(first_seed, first_seed + episodes),
        desc=f"round {round_index}",
        unit="ep",
        disable=not progress,
        file=sys.stderr,
        dynamic_ncols=True,
    ):
        episode = run_episode(env, policy, seed, buffer=buffer, labeller=expert)
        episode.dagger_round = round_index
        added = store.append(episode)
        if committed is not None:
            committed.append(added)
        returns.append(episode.episode_return)
        frames += episode.length
        survived += not episode.fell
    env.close()
    return RoundReport(round_index, episodes, frames, float(np.mean(returns)), survived)


def main(cfg: DaggerConfig) -> DaggerResult:
    """Run `cfg.rounds` DAgger rounds on `cfg.output` and save the final policy at `cfg.policy`."""
    validate(cfg)
    checkpoint.check_replaceable(cfg.policy, cfg.overwrite)
    if not cfg.output.exists():
        shutil.copytree(cfg.dataset, cfg.output)
    store = EpisodeStore(cfg.output, DatasetSpec.from_env(make_env()))
    result = DaggerResult()
    context = {"dagger": config_dict(cfg)}
    added: list[CommittedEpisode] = []
    complete = False
    try:
        done = max(read_episodes(cfg.output, [keys.EPISODE_DAGGER_ROUND])[keys.EPISODE_DAGGER_ROUND].to_pylist())
        training = {
            "epochs": cfg.epochs,
            "min_updates": cfg.min_updates,
            "patience": cfg.patience,
            "inputs": cfg.inputs,
        }
        quiet = {**training, "eval_episodes": 0, "progress": False, "tensorboard": False}
        with tempfile.TemporaryDirectory(prefix=".dagger-", dir=cfg.policy.parent) as scratch:
            policy_dir = Path(scratch) / f"round{done}"
            train(TrainConfig(dataset=cfg.output, policy=policy_dir, **quiet), MADE_BY, context)
            for round_index in range(done + 1, done + cfg.rounds + 1):
                result.rounds.append(
                    collect_round(store, policy_dir, round_index, cfg.episodes, cfg.progress, added, cfg.expert)
                )
                if round_index < done + cfg.rounds:
                    policy_dir = Path(scratch) / f"round{round_index}"
                    train(TrainConfig(dataset=cfg.output, policy=policy_dir, **quiet), MADE_BY, context)
        complete = True
    finally:
        store.close()
        recordings.append(cfg.output, MADE_BY, config_dict(cfg), added, complete)
    result.final = train(
        TrainConfig(
            dataset=cfg.output,
            policy=cfg.policy,
            overwrite=cfg.overwrite,
            **training,
            eval_episodes=cfg.eval_episodes,
            progress=cfg.progress,
        ),
        MADE_BY,
        context,
    )
    return result


def _main_and_print(cfg: DaggerConfig) -> None:
    print(main(cfg).describe())


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, DaggerConfig, argv, description=__doc__, prog="python -m bc.dagger")


if __name__ == "__main__":
    sys.exit(cli())
