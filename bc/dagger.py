"""`make dagger`: DAgger with the scripted expert (EXPERT: on the full state, or on leg odometry) as the oracle.

Behaviour cloning only ever sees the states the expert visits; a cloned policy drifts into states
it never saw and its errors compound. DAgger (Ross et al., 2011) collects labels where the policy
itself goes:

1. Copy DATASET to OUTPUT (once; OUTPUT is then a dataset of its own, appended to), read its frames
   into memory and fit a policy to them (`bc.train.fit_demonstrations`).
2. Each round (`DAggerTrainer`): roll the current policy out for EPISODES episodes under the
   conditions the dataset was recorded in (RANDOMIZE, LATENCY: by default what its recordings.jsonl
   says); at every visited state store the expert's action as the label (`action`) and the policy's
   as what ran (`executed_action`). The episodes run over WORKERS processes and are appended to
   OUTPUT in seed order as they end (one finished early waits in OUTPUT/.dagger-spool), with
   `dagger_round` = the round and `labeller` = EXPERT, and to the frames in memory; the next policy
   is fitted to the aggregate in memory: nothing is read back from disk.
3. The last round's aggregate trains the checkpoint at POLICY (`bc.train.train_and_save`), the policy
   `make train-bc` would train on OUTPUT with the same settings, evaluated like any BC policy.

Rounds continue the seeds after the dataset's last one. ROUNDS is how many rounds OUTPUT holds
when the run ends: run again after a kill (-9 included), the same command finishes the round it
was in (its policy fitted again to the same frames, so the same policy and seeds: the same result
as an unbroken run) and the rounds after it, refusing settings that would change them; a larger
ROUNDS adds rounds. The run's settings go with what it writes: a line in OUTPUT/recordings.jsonl
for the episodes it added, and "dagger" in the final checkpoint's config.json (and its TensorBoard
text).
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from bc.data import Demonstrations, cache_demonstrations, episode_rows, load_demonstrations
from bc.train import MIN_UPDATES, TrainConfig, TrainResult, check_taught, fit_demonstrations, train_and_save
from common import columns, paths
from common.cli import (
    DatasetError,
    UserError,
    check_non_negative,
    check_positive,
    check_seed,
    check_share,
    config_dict,
    flag,
    run_cli,
    setting,
    write_json,
)
from common.files import PARTIAL_SUFFIX
from common.workers import default_workers
from humanoid.conditions import (
    NO_RANDOMIZATION,
    Condition,
    parse_randomization,
    recorded_parameters,
    recording_condition,
)
from humanoid.env import make_env, nominal_model
from policies import checkpoint
from policies.folder import json_object
from policies.mlp import MLPPolicy
from rollout.episode import EpisodeFailure
from students.inputs import INPUTS, STUDENT_INPUTS, input_set_named
from teachers.registry import TEACHER, TEACHERS, WALKING_TEACHER, able, teacher_named
from teleop import recordings
from teleop.dataset_reader import fingerprint, read_episodes, read_parameters
from teleop.lerobot_io.format import INFO_PATH
from teleop.parallel import ParallelRollouts, RolloutSettings
from teleop.record import DART_NOISE
from teleop.spool import DAGGER_SPOOL, Spool
from teleop.store import CommittedEpisode, DatasetSpec, EpisodeStore

MADE_BY = "bc.dagger"
SOURCE_FILE = "demonstrations.json"
"""In OUTPUT: which demonstrations it is a copy of (DATASET's path and fingerprint when copied) and who copied them:
what the checkpoint records as its demonstrations, and what `make pipeline` compares before reusing OUTPUT."""
ROUNDS = 6
"""DAgger's rounds by default: 6 of 20 episodes follow every held-out posture schedule
(docs/decisions/pipeline-student.md)."""
WALKING_ROUNDS = 12
"""A walking student's: 12 rounds walked more selection schedules than 6 at each of three training seeds (89 against 69
of 120; docs/decisions/walker-students.md)."""
SHAPING = ("inputs", "expert", "randomize", "latency", "kick", "noise", "episodes", "epochs", "min_updates", "seed")
"""The settings that decide a round's policy and episodes: a resumed run keeps the killed run's."""


@dataclass
class DaggerConfig:
    """Settings of a DAgger run."""

    dataset: Path = setting(paths.DATASET, "demonstrations to start from (left unchanged)")
    output: Path = setting(paths.DAGGER_DATASET, "aggregate dataset: a copy of DATASET, then every round appended")
    policy: Path = setting(paths.DAGGER_POLICY, "checkpoint folder of the final policy")
    inputs: str = setting(
        STUDENT_INPUTS,
        "what the student reads (`make train-bc`'s INPUTS); EXPERT labels from the sensed features or the full state",
        metavar="{" + ",".join(INPUTS) + "}",
    )
    expert: str | None = setting(
        None,
        f"who labels the policy's states, any registered teacher ({', '.join(TEACHERS)}); "
        f"default: the teacher on leg odometry, {TEACHER}, or for a walking student (INPUTS=...+walk or +gait, "
        f"whose rollouts follow walking schedules) {WALKING_TEACHER} (docs/concepts/controllers.md)",
    )
    randomize: str | None = setting(
        None,
        "the physical parameters each rollout draws, as `make record RANDOMIZE=` (a preset or ranges); "
        "default: what DATASET's recordings drew (its recordings.jsonl)",
    )
    latency: float | None = setting(
        None,
        "the share of rollouts run with one step of action latency, as `make record LATENCY=`; default: DATASET's",
    )
    kick: float = setting(
        0.0,
        "one kick of the root's horizontal velocity per rollout, in m/s, as `make record KICK=` gives it (the "
        "suite's kick conditions): the expert labels the states the kick leads to, so give one that steps "
        "(docs/how-to/walk.md); 0 = none",
    )
    noise: float = setting(
        DART_NOISE,
        "std of Gaussian noise on the actions the rollouts execute (DART within DAgger: the expert labels the states "
        "the noise leads to as well), the recording's by default; 0 = none",
    )
    rounds: int | None = setting(
        None,
        "rounds of roll out, label, aggregate, retrain that OUTPUT holds when the run ends (rounds already there, "
        "from an earlier or a killed run, count; a round with fewer than EPISODES episodes is finished first); "
        f"default: {ROUNDS}, or {WALKING_ROUNDS} for a walking student (docs/decisions/walker-students.md)",
    )
    episodes: int = setting(
        20,
        "policy episodes rolled out and labelled per round: 6 rounds of 20 follow every held-out schedule where 10 a "
        "round did less (docs/decisions/pipeline-student.md)",
    )
    workers: int | None = setting(
        None,
        "processes rolling a round's episodes out, each with its labelling expert (committed in seed order: the "
        "aggregate does not depend on it); default: the machine's cores, at most EPISODES",
    )
    epochs: int = setting(
        15,
        "training epochs of every round's policy (more if MIN_UPDATES needs them): a sturdier student than at 30 "
        "over three training seeds, for fewer Adam steps (docs/decisions/pipeline-student.md)",
    )
    min_updates: int = setting(MIN_UPDATES, "at least this many Adam steps in every round's training (bc.train's)")
    seed: int = setting(
        0,
        "training seed of every round's fit and of the final one (initial weights, validation split, minibatches); "
        "the rollouts' episode seeds continue the dataset's whatever it is",
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
    seconds: float  # rolling out, labelling and committing its episodes


@dataclass
class DaggerResult:
    """The rounds and the final training."""

    rounds: list[RoundReport] = field(default_factory=list)
    final: TrainResult | None = None

    def describe(self) -> str:
        lines = [
            f"round {r.round}: the policy stood {r.survived}/{r.episodes} episodes, mean return "
            f"{r.mean_return:.1f}; {r.frames} frames labelled in {r.seconds:.1f} s"
            for r in self.rounds
        ]
        return "\n".join([*lines, self.final.describe()])


def rounds_of(cfg: DaggerConfig) -> int:
    """How many rounds: --rounds, else `ROUNDS`, or `WALKING_ROUNDS` for a walking student."""
    if cfg.rounds is not None:
        return cfg.rounds
    return WALKING_ROUNDS if input_set_named(cfg.inputs).walks else ROUNDS


def expert_of(cfg: DaggerConfig) -> str:
    """Who labels: --expert, else the default teacher for the student's inputs (`WALKING_TEACHER` for a walking one)."""
    if cfg.expert is not None:
        return cfg.expert
    return WALKING_TEACHER if input_set_named(cfg.inputs).walks else TEACHER


def for_student(cfg: DaggerConfig) -> DaggerConfig:
    """`cfg` with EXPERT and ROUNDS its student's defaults where not given (`expert_of`, `rounds_of`)."""
    return dataclasses.replace(cfg, expert=expert_of(cfg), rounds=rounds_of(cfg))


def check_settings(cfg: DaggerConfig) -> None:
    """The settings alone, refused in one line (`validate` also checks the folders)."""
    cfg = for_student(cfg)
    expert = teacher_named(cfg.expert, "--expert")
    if input_set_named(cfg.inputs).walks and not expert.walks:
        walkers = " or ".join(f"--expert {name}" for name in able("walks"))
        raise UserError(f"--inputs {cfg.inputs} learns to walk, and --expert {cfg.expert} does not: give {walkers}")
    check_positive(cfg, "rounds", "episodes", "epochs", "workers")
    check_non_negative(cfg, "min_updates", "eval_episodes", "noise", "kick")
    check_seed(cfg, "seed")
    if cfg.latency is not None:
        check_share(cfg, "latency")
    if cfg.randomize is not None:
        try:
            parse_randomization(cfg.randomize)
        except ValueError as error:
            raise UserError(str(error)) from None
    if cfg.output.resolve() == cfg.dataset.resolve():
        raise UserError("--output must differ from --dataset: DAgger leaves the demonstrations unchanged")


def validate(cfg: DaggerConfig) -> None:
    check_settings(cfg)
    if cfg.output.exists() and not (cfg.output / INFO_PATH).is_file():
        raise DatasetError(
            f"{cfg.output} exists and holds no LeRobot dataset: OUTPUT is DAgger's own copy of DATASET, give another"
        )
    if cfg.output.exists() and not is_aggregate(cfg.output):
        raise DatasetError(
            f"{cfg.output} holds a dataset DAgger did not copy (no {SOURCE_FILE}, no round): OUTPUT is DAgger's own "
            "copy of DATASET, give another"
        )
    if not (cfg.dataset / INFO_PATH).is_file() and not cfg.output.exists():
        raise DatasetError(f"no LeRobot dataset at {cfg.dataset}; record one with `make record DATASET={cfg.dataset}`")


def recorded_conditions(root: Path) -> tuple[str, float]:
    """(RANDOMIZE, LATENCY) that the runs which recorded the dataset at `root` used (its recordings.jsonl: the lines
    whose config has `randomize`, a merge's by its shards' lines; a line from before `latency` existed recorded
    none), ("none", 0.0) if no line says; DatasetError if they differ."""
    conditions = {
        (config["randomize"], float(config.get("latency", 0.0)))
        for line in recordings.expanded(recordings.read(root))
        if (config := line.get("config", {})).get("randomize") is not None
    }
    if len(conditions) > 1:
        listed = "; ".join(f"RANDOMIZE={r} LATENCY={latency}" for r, latency in sorted(conditions))
        raise DatasetError(f"{root} was recorded under several conditions ({listed}): give RANDOMIZE and LATENCY")
    return conditions.pop() if conditions else (NO_RANDOMIZATION, 0.0)


def resolved(cfg: DaggerConfig) -> DaggerConfig:
    """`cfg` with EXPERT and ROUNDS filled in for its student (`for_student`), RANDOMIZE and LATENCY from the
    aggregate's recordings, where not given; DatasetError if its episodes draw other parameters than rollouts under
    them would (the store could not append them)."""
    cfg = for_student(cfg)
    root = cfg.output if cfg.output.exists() else cfg.dataset
    if cfg.randomize is None or cfg.latency is None:  # given, they stand: the drawn parameters are checked below
        randomize, latency = recorded_conditions(root)
        cfg = dataclasses.replace(
            cfg,
            randomize=randomize if cfg.randomize is None else cfg.randomize,
            latency=latency if cfg.latency is None else cfg.latency,
        )
    episodes = read_parameters(root)
    drawn = set(episodes[0]) if episodes else set()
    rolled = set(recorded_parameters(condition(cfg)))
    if drawn != rolled:
        raise DatasetError(
            f"{root}'s episodes draw {sorted(drawn) or 'no parameter'}; rollouts with RANDOMIZE={cfg.randomize} "
            f"LATENCY={cfg.latency} would draw {sorted(rolled) or 'none'}: give the conditions it was recorded in"
        )
    return cfg


def condition(cfg: DaggerConfig) -> Condition:
    """What each rollout's environment changes: the recording's conditions (RANDOMIZE, LATENCY, resolved) and the
    KICK, as `make record` builds them (`humanoid.conditions.recording_condition`)."""
    return recording_condition(cfg.randomize, cfg.latency, cfg.kick)


def is_dagger_run(line: dict[str, Any]) -> bool:
    """Whether a recordings.jsonl line (or a run's mark) is a DAgger run's, whoever ran it (`make dagger`, `make
    pipeline`): its config holds the SHAPING settings."""
    return set(SHAPING) <= set(line.get("config", {}))


def changed_settings(saved: dict[str, Any], cfg: DaggerConfig, names: Sequence[str] = SHAPING) -> list[str]:
    """The settings among `names` that a DAgger run's saved config holds otherwise than `cfg`."""
    settings = config_dict(cfg)
    return [name for name in names if saved.get(name) != settings[name]]


def copy_demonstrations(cfg: DaggerConfig, made_by: str) -> None:
    """Make OUTPUT a copy of DATASET with its SOURCE_FILE; copied aside, then renamed: a copy killed half-way is
    never taken for the aggregate. Without DATASET's mark: a run killed there is not this one."""
    partial = cfg.output.with_name(f".{cfg.output.name}{PARTIAL_SUFFIX}")
    shutil.rmtree(partial, ignore_errors=True)
    source = {"path": str(cfg.dataset), "fingerprint": fingerprint(cfg.dataset), "made_by": made_by}
    shutil.copytree(cfg.dataset, partial, ignore=shutil.ignore_patterns(recordings.RUN_FILE + "*"))
    write_json(partial / SOURCE_FILE, source)
    partial.rename(cfg.output)


def copied_from(output: Path) -> dict[str, Any]:
    """OUTPUT's SOURCE_FILE; {} if it has none (a copy made before it existed, or no DAgger copy)."""
    return json_object(output / SOURCE_FILE)


def is_aggregate(output: Path) -> bool:
    """Whether the dataset at `output` is a DAgger run's aggregate: copied by one (its SOURCE_FILE), or, copied before
    that file existed, holding a round's episodes and no merge (a copy killed before its first round is not told from a
    recording: refused, the demonstrations are copied again elsewhere)."""
    if copied_from(output):
        return True
    if any(recordings.SESSIONS_KEY in line for line in recordings.read(output)):
        return False  # a merge: its rounds may be another aggregate's, copied from no DATASET of this run
    try:
        rounds = read_episodes(output, [columns.EPISODE_DAGGER_ROUND])[columns.EPISODE_DAGGER_ROUND].to_pylist()
    except (OSError, KeyError, ValueError):
        return False
    return any(rounds)


def check_resume(cfg: DaggerConfig) -> None:
    """DatasetError in one line if OUTPUT holds the mark (`recordings.RUN_FILE`) of a DAgger run killed with other
    SHAPING settings than this one's: a resume keeps its rounds. Reads only, so that a refused run leaves OUTPUT as
    it was. (A mark another kind of run left binds nothing: the next take-over logs its episodes.)"""
    killed = recordings.marked(cfg.output)
    if killed is None or not is_dagger_run(killed):
        return
    changed = changed_settings(killed["config"], cfg)
    if changed:
        was = ", ".join(f"{flag(name)} {killed['config'].get(name)}" for name in changed)
        raise DatasetError(
            f"{cfg.output} holds the rounds of a DAgger run killed with {was}: run it again with those "
            f"(or delete {cfg.output / recordings.RUN_FILE} to go on with these)"
        )


class DAggerTrainer:
    """DAgger rounds in memory, as `imitation`'s trainers run them: the aggregate's frames and the current policy
    live here, so a round fits its policy to what the last one rolled out without reading the dataset back.

    A round's episodes are rolled out over `workers` processes (`teleop.parallel`, kept from one round to the next,
    each with its labelling expert) and committed in seed order: the same aggregate whatever the count. A finished
    episode waits for its turn in OUTPUT/`DAGGER_SPOOL` (`teleop.spool`), so a crash costs at most the episodes being
    rolled out, and a later run commits the waiting ones in their turn and continues from the rounds on disk.
    """

    def __init__(
        self,
        demos: Demonstrations,
        training: TrainConfig,
        rollouts: RolloutSettings,
        action_space: gym.spaces.Box,
        workers: int = 1,
        name: str = "dagger",
    ) -> None:
        """`demos`: the aggregate so far, rows as `load_demonstrations` reads them; `training`: how each policy is
        fitted; `rollouts`: how it is rolled out (the conditions, the noise, the labeller: `controller` and `policy`
        are each round's); `workers`: processes rolling out; `name`: the rolled-out policies' controller name, with
        ":roundN" for the round whose aggregate trained it."""
        self.demos = demos
        self.training = training
        self.rollouts = dataclasses.replace(rollouts, task=input_set_named(training.inputs).task)
        self.action_space = action_space
        self.workers = workers
        self.name = name
        self.policy: MLPPolicy | None = None
        self.round_of: dict[int, int] = {}
        """The DAgger round of each aggregate episode the trainer added or was told of; unlisted ones are round 0."""
        self._model = nominal_model()  # nominal, as the training inputs are computed on load: never a drawn body
        self._processes: ParallelRollouts | None = None  # started by the first round with episodes to roll out

    def train(self, round_index: int | None = None) -> MLPPolicy:
        """Fit a new policy to the aggregate (with `round_index`, to its episodes from before that round: the
        policy that round rolls out, also when some of its episodes are already in); the next `collect` rolls it
        out."""
        demos = self.demos
        if round_index is not None:
            demos = demos.only([e for e in demos.episodes if self.round_of.get(e, 0) < round_index])
        self.policy = fit_demonstrations(demos, self.training, self.action_space).policy
        return self.policy

    def _rolled_out(self, root: Path, seeds: list[int], name: str) -> Iterator[Path | EpisodeFailure]:
        """The spool file (in `root`'s DAGGER_SPOOL) of each of `seeds` as the current policy (called `name`) rolls them
        out (or its `EpisodeFailure`, where a controller failed in it), in their order."""
        if not seeds:
            return iter(())
        if self._processes is None:
            settings = dataclasses.replace(self.rollouts, controller=name, policy=self.policy)
            self._processes = ParallelRollouts(settings, root, self.workers, DAGGER_SPOOL)
        else:
            self._processes.act_with(self.policy, name)
        return self._processes.in_seed_order(seeds)

    def collect(
        self, store: EpisodeStore, round_index: int, episodes: int, progress: bool = False
    ) -> tuple[RoundReport, list[CommittedEpisode]]:
        """Roll the current policy out for `episodes` episodes (seeds after `store`'s last; those a killed run left in
        the spool are taken from there), the expert labelling every state; append each episode to `store` and its
        frames to the aggregate."""
        if self.policy is None:
            raise RuntimeError("train() a policy before collecting its rollouts")
        start = time.perf_counter()
        spool = Spool(store.root, DAGGER_SPOOL)
        first_seed = store.next_seed()
        seeds = list(range(first_seed, first_seed + episodes))
        waiting = {seed for seed in seeds if spool.path_of(seed).is_file()}
        fresh = [seed for seed in seeds if seed not in waiting]
        rolled = self._rolled_out(store.root, fresh, f"{self.name}:round{round_index - 1}")
        added, returns, frames, survived, rows = [], [], 0, 0, []
        bar = tqdm(
            seeds, desc=f"round {round_index}", unit="ep", disable=not progress, file=sys.stderr, dynamic_ncols=True
        )
        try:
            for seed in bar:
                path = spool.path_of(seed) if seed in waiting else next(rolled)
                if isinstance(path, EpisodeFailure):  # that episode alone is lost: the round goes on without it
                    tqdm.write(f"warning: round {round_index}: {path.message}", file=sys.stderr)
                    continue
                episode = Spool.load(path)
                episode.dagger_round = round_index
                committed = store.append(episode, spooled=path)
                added.append(committed)
                rows.append((*episode_rows(episode, self.training.inputs, self._model), committed.index))
                self.round_of[committed.index] = round_index
                returns.append(episode.episode_return)
                frames += episode.length
                survived += not episode.fell
        except BaseException:
            self.close(interrupted=True)  # the finished episodes stay spooled
            raise
        finally:  # also when interrupted: the aggregate in memory holds every episode on disk
            self.demos = self.demos.with_episodes(rows)
        spool.remove_if_empty()
        seconds = time.perf_counter() - start
        return RoundReport(round_index, episodes, frames, float(np.mean(returns)), survived, seconds), added

    def close(self, interrupted: bool = False) -> None:
        """Stop the rollout processes (at once if `interrupted`)."""
        if self._processes is not None:
            self._processes.close(interrupted)
            self._processes = None


def workers(cfg: DaggerConfig) -> int:
    """The rollout processes `cfg` asks for: --workers, else one per core, at most EPISODES (`common.workers`)."""
    return default_workers(cfg.episodes) if cfg.workers is None else cfg.workers


def settle_spool(output: Path, committed: int) -> None:
    """What a killed run left in OUTPUT's DAGGER_SPOOL: kept for its round (`teleop.spool`'s recovery) if the run was a
    DAgger run, which `check_resume` let through with these settings; dropped otherwise (no run was killed, or its
    mark was removed to go on with other settings): those episodes are no round of this run."""
    spool = Spool(output, DAGGER_SPOOL)
    killed = recordings.marked(output)
    if killed is not None and is_dagger_run(killed):
        spool.recover(committed)
    else:
        shutil.rmtree(spool.folder, ignore_errors=True)


def main(cfg: DaggerConfig, made_by: str = MADE_BY) -> DaggerResult:
    """Bring `cfg.output` to `cfg.rounds` DAgger rounds of `cfg.episodes` episodes and save the final policy at
    `cfg.policy`. `made_by` (bc.dagger, pipeline.run) goes with what the run writes: OUTPUT's copy, its
    recordings.jsonl line, the checkpoint's config.json."""
    validate(cfg)
    checkpoint.check_replaceable(cfg.policy, cfg.overwrite)
    cfg = resolved(cfg)
    # What train-bc refuses (inputs the data cannot teach), before any copy or rollout rather than at the first fit.
    check_taught(TrainConfig(dataset=cfg.output if cfg.output.exists() else cfg.dataset, inputs=cfg.inputs))
    if not cfg.output.exists():
        copy_demonstrations(cfg, made_by)
    check_resume(cfg)
    rolled = condition(cfg)
    env = rolled.wrap(make_env())
    store = EpisodeStore(cfg.output, DatasetSpec.from_env(env, recorded_parameters(rolled)))
    settle_spool(cfg.output, store.num_episodes)
    result = DaggerResult()
    context = {"dagger": config_dict(cfg), "demonstrations": copied_from(cfg.output).get("fingerprint")}
    training = TrainConfig(
        dataset=cfg.output,
        policy=cfg.policy,
        inputs=cfg.inputs,
        overwrite=cfg.overwrite,
        epochs=cfg.epochs,
        min_updates=cfg.min_updates,
        eval_episodes=cfg.eval_episodes,
        progress=cfg.progress,
        seed=cfg.seed,
    )
    rollouts = RolloutSettings(
        controller=cfg.policy.name,  # each round's policy goes by it (`DAggerTrainer`)
        noise=cfg.noise,
        max_steps=env.spec.max_episode_steps,
        condition=rolled,
        labeller=TEACHERS[cfg.expert],  # the class: a teacher registered here is known in the workers too
    )
    trainer: DAggerTrainer | None = None
    try:
        table = read_episodes(
            cfg.output, ["episode_index", columns.EPISODE_SEED, columns.EPISODE_DAGGER_ROUND]
        ).to_pydict()
        demos = load_demonstrations(cfg.output, env, inputs=cfg.inputs)
        rounds = table[columns.EPISODE_DAGGER_ROUND]
        quiet = dataclasses.replace(training, progress=False)
        trainer = DAggerTrainer(demos, quiet, rollouts, env.action_space, workers(cfg), cfg.policy.name)
        trainer.round_of = dict(zip(table["episode_index"], rounds, strict=True))
        last = max(rounds)
        # A last round with fewer than EPISODES episodes was cut short (a killed run): it is finished first.
        first = last if last and rounds.count(last) < cfg.episodes else last + 1
        seeds = table[columns.EPISODE_SEED]
        # Under the store's lock: one run at a time marks OUTPUT; a killed run's episodes get their line first.
        with recordings.logged(cfg.output, made_by, config_dict(cfg), len(seeds), lambda: seeds) as added:
            for round_index in range(first, cfg.rounds + 1):
                trainer.train(round_index)
                missing = cfg.episodes - rounds.count(round_index)
                report, committed = trainer.collect(store, round_index, missing, cfg.progress)
                result.rounds.append(report)
                added += committed
    finally:
        if trainer is not None:
            trainer.close()
        store.close()
        env.close()
    # The identity of the dataset the policy was trained on: OUTPUT as the rounds left it.
    aggregate = dataclasses.replace(trainer.demos, fingerprint=fingerprint(cfg.output))
    cache_demonstrations(aggregate)  # the rows `load_demonstrations` would compute again (PPO's critic reads them)
    result.final = train_and_save(aggregate, training, env.action_space, made_by, context)
    return result


def _main_and_print(cfg: DaggerConfig) -> None:
    print(main(cfg).describe())


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, DaggerConfig, argv, description=__doc__, prog="python -m bc.dagger")


if __name__ == "__main__":
    sys.exit(cli())
