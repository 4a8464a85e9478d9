"""`make pipeline`: the chained stages on the operator's task, then the comparisons and one table.

    make record      -> RECORD.DATASET: the teacher on what a robot senses follows the operator's schedules
    make train-bc    -> BC.POLICY: the deployable student (INPUTS pending+ramp); and BLIND_POLICY: the same
                        without the command (pending), what the command buys
    make dagger      -> DAGGER.OUTPUT, DAGGER.POLICY: the teacher labels where the student goes
    make finetune-rl -> PPO.POLICY: PPO refines the DAgger student; and SCRATCH_POLICY: PPO from scratch, same
                        task and budget (make scratch-rl)
    then the table: survival and tracking per command field on held-out schedules, clean and under every condition of
    the robustness suite, and survival with the command zero (standing), for the teacher and every policy.

`PipelineConfig` nests each stage's own config as that stage's target has it, LeRobot's way: `--dagger.rounds 6`
on the command line, `make pipeline DAGGER.ROUNDS=6`, a stage's default is its target's. The pipeline adds only the
ties between them (the student trains on the dataset recorded, PPO starts from the DAgger student: `TIES`), the
two comparisons, the shared worker settings and the table's. Why this task and these students:
docs/decisions/pipeline-task.md, docs/decisions/pipeline-student.md; the seed tutorial's learners are apart
(`make tutorial-rl`). Every stage's checks run before the first one starts, each stage runs in this process
through its own `main`.

A stage is skipped only if its output exists and was made from the same inputs:

- the dataset: its recordings.jsonl (`teleop.recordings`) accounts for every episode in it, and
  those runs recorded with the pipeline's settings, seeds from RECORD.SEED (0 when unset), RECORD.EPISODES in all;
- a checkpoint: its config.json holds the same settings and its eval.json exists (BC and DAgger here skip
  their evaluation and write none, PPO its final one: STAGE_EVALUATION), and it was made
  from the input the pipeline has now: the dataset's fingerprint (BC: dataset.json; DAgger: `demonstrations`
  in config.json) or the BC weights' digest (PPO: `bc_policy_sha256` in config.json);
- DAgger's aggregate, when its checkpoint is made again: it is a copy of the dataset as it is now (its
  `bc.dagger.SOURCE_FILE`) and its rounds were rolled out with the same settings, else it is made again;
- the table's evaluations: a policy's robustness_schedules.json, if written after its weights with the same
  seeds and conditions (a registered controller's always).

Settings that change only speed, display or permissions are not compared (NOT_COMPARED; the worker
counts among them, since tests/teleop/test_parallel_record.py and tests/rl/test_finetune.py show
they change nothing else). An output whose saved settings lack one of this version's was made by an
older version: it differs (docs/decisions/added-since.md). Otherwise the pipeline says in one line why
the stage runs, and what happens to an output that differs depends on who made it:

- the pipeline (`made_by` "pipeline.run" in config.json, or on every line of recordings.jsonl): made
  again. A checkpoint is replaced once the new one is complete (the stage's --overwrite). A dataset
  recorded with other settings is deleted and recorded again; one that holds only the first
  episodes asked for (an interrupted pipeline) gets the others appended, which gives the dataset a
  single recording would (each episode depends only on its seed).
- anyone else (`make record`, `make train-bc`, a version before recordings.jsonl and `made_by`):
  refused in one line and left as it is; before any stage runs when the refusal can be foreseen
  (an output downstream of one that will be made again). OVERWRITE=1 lets the pipeline replace
  such a checkpoint. A dataset the pipeline did not record is never deleted nor appended to.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, ClassVar

from bc import dagger as bc_dagger
from bc import train as bc_train
from bc.dagger import DaggerConfig
from bc.data import MIN_EPISODES
from bc.train import TrainConfig
from common import columns, paths
from common.cli import DatasetError, UserError, config_dict, field_default, flag, run_cli, setting
from common.ray_backend import BACKENDS
from common.seed_ranges import EVAL_SEED
from evaluation import robustness
from evaluation.robustness import RobustnessConfig
from humanoid.conditions import SUITE
from humanoid.env import nominal_model
from humanoid.sensors import proprioception_names
from pipeline import report
from policies.folder import (
    DATASET_FILE,
    EVAL_FILE,
    SB3_FILE,
    WEIGHTS_FILE,
    checkpoint_problem,
    is_checkpoint,
    is_sb3_policy,
    json_object,
    training_settings,
)
from rl.finetune import FinetuneConfig, print_summary, weights_digest
from rl.finetune import main as ppo_main
from rl.finetune import validate as validate_ppo
from rl.scratch import ScratchConfig
from rollout.controllers import INTERACTIVE, registered
from students.inputs import BLIND_INPUTS
from task.command_fields import POSTURE_TASK, STAND
from task.tracking import ERROR_KINDS
from teachers.registry import TEACHER
from teleop import recordings
from teleop.dataset_reader import fingerprint, read_episodes, read_info
from teleop.lerobot_io.format import INFO_PATH
from teleop.record import RecordConfig, effective, record
from teleop.record import validate as validate_record

MADE_BY = "pipeline.run"
OWN = (MADE_BY, "bc.pipeline")
"""The `made_by` of outputs the pipeline made: this version's, and the name it had before (docs/concepts/layout.md)."""

NOT_COMPARED = frozenset(
    {
        *("progress", "overwrite", "cache", "writer", "front_end", "workers", "backend", "ray_address"),
        *("update_threads", "live", "live_port", "live_host", "final_eval_episodes"),
    }
)
"""Settings that change only speed, display, permissions or the final evaluation a stage reports: never a reason to
make an output again (so what `make record` and the other stage targets made with their defaults, the pipeline
reuses). BC's and DAgger's `eval_episodes` are of that kind too (`STUDENT_NOT_COMPARED`); PPO's are its validation
episodes, which choose the actor kept."""
STUDENT_NOT_COMPARED = NOT_COMPARED | {"eval_episodes"}
"""For BC and DAgger checkpoints: also how many episodes their evaluation after training ran."""

REUSE, RUN, REMAKE, RESUME = "reuse", "run", "remake", "resume"

STAGE_EVALUATION = 0
"""Episodes of each stage's own evaluation after training (BC's, DAgger's, PPO's final one): none, since the table
evaluates every controller on the same held-out seeds (its clean column is that evaluation;
docs/decisions/pipeline-task.md)."""
EXPERTS = (TEACHER,)
"""The registered controllers the table measures beside the policies: the expert on leg odometry that records the
demonstrations, the students' reference. The expert told the simulator's state is left to `make robustness
POLICY=expert`: it teaches no row of the table (docs/decisions/pipeline-task.md)."""


def _stage(default: Callable[[], Any], help: str) -> Any:
    """A nested stage's config (`--stage.field` flags): `default` builds it as the pipeline runs it."""
    return dataclasses.field(default_factory=default, metadata={"help": help})


TIES = (
    ("bc", "dataset", "record", "dataset"),
    ("dagger", "dataset", "record", "dataset"),
    ("dagger", "noise", "record", "noise"),
    ("dagger", "randomize", "record", "randomize"),
    ("dagger", "latency", "record", "latency"),
    ("ppo", "bc_policy", "dagger", "policy"),
    ("ppo", "scratch_policy", "", "scratch_policy"),
    *((stage, name, "", name) for stage in ("record", "ppo") for name in ("backend", "ray_address")),
)
"""(stage, setting, from stage or "" for the pipeline's own, its setting): each stage's input is the output of the
stage before it, DAgger's rounds run under the recording's noise, bodies and latency (as given, so that the settings
its checkpoint saves are the ones the next run compares), and PPO's figure shows the pipeline's scratch run."""


@dataclass
class PipelineConfig:
    """Settings of the pipeline: the chained stages' own configs, nested as LeRobot's `TrainPipelineConfig` nests its
    parts (`--record.episodes 50`, `make pipeline RECORD.EPISODES=50`), and what only the pipeline has. A stage's
    input is the output of the stage before it (`stages` ties them: giving a tied setting otherwise is refused)."""

    TIED: ClassVar[frozenset[str]] = frozenset(f"{stage}.{name}" for stage, name, _, _ in TIES)
    """The nested settings the pipeline sets itself (`TIES`): `common.cli.check_removed` never suggests them."""

    record: RecordConfig = _stage(RecordConfig, "the recording of the operator's demonstrations (make record)")
    bc: TrainConfig = _stage(
        lambda: TrainConfig(eval_episodes=STAGE_EVALUATION), "the deployable student's cloning (make train-bc)"
    )
    dagger: DaggerConfig = _stage(
        lambda: DaggerConfig(eval_episodes=STAGE_EVALUATION), "DAgger on that student's inputs (make dagger)"
    )
    ppo: FinetuneConfig = _stage(
        lambda: FinetuneConfig(final_eval_episodes=STAGE_EVALUATION),
        "PPO from the DAgger student (make finetune-rl); PPO from scratch runs with the same settings",
    )
    blind_policy: Path = setting(
        paths.BLIND_POLICY,
        f"checkpoint folder of the student without the command (the bc stage's settings, --inputs {BLIND_INPUTS}): "
        "what the command buys",
    )
    scratch_policy: Path = setting(
        paths.SCRATCH_POLICY, "checkpoint folder of PPO from scratch (make scratch-rl), on the ppo stage's settings"
    )
    workers: int | None = setting(
        None,
        "simulation processes of the recording, DAgger's rounds, both PPO stages and the table's evaluations; "
        "default: each stage's (the machine's cores)",
    )
    backend: str = setting(
        "local", "where the recording's and both PPO stages' workers run (local, or ray)", choices=BACKENDS
    )
    ray_address: str | None = setting(None, "HOST:PORT of a running Ray cluster's head (--backend ray)")
    overwrite: bool = setting(
        False, "also replace checkpoints the pipeline did not make when they differ (never a dataset it did not record)"
    )
    robustness_episodes: int = setting(
        20,
        "episodes per condition of the closing table, on held-out schedules (seeds 1000..) and with the command zero",
    )
    conditions: str = setting(
        "all", "the closing table's conditions (docs/concepts/robustness-suite.md), comma-separated, or 'all'"
    )


@dataclass
class Stages:
    """The config of every stage, as the pipeline runs them."""

    record: RecordConfig
    student: TrainConfig
    blind: TrainConfig
    dagger: DaggerConfig
    scratch: ScratchConfig
    finetune: FinetuneConfig

    def outputs(self) -> dict[str, Path]:
        """Each output folder, by the pipeline's option that names it."""
        return {
            "--record.dataset": self.record.dataset,
            "--bc.policy": self.student.policy,
            "--blind-policy": self.blind.policy,
            "--dagger.output": self.dagger.output,
            "--dagger.policy": self.dagger.policy,
            "--scratch-policy": self.scratch.policy,
            "--ppo.policy": self.finetune.policy,
        }


def check(cfg: PipelineConfig) -> list[str]:
    """The pipeline's own settings, refused in one line that names them before any stage starts (the stages' own
    checks name the stages' flags); the table's conditions."""
    if cfg.record.episodes < MIN_EPISODES:
        raise UserError(
            f"--record.episodes must be at least {MIN_EPISODES} (BC holds whole episodes out for validation), "
            f"got {cfg.record.episodes}"
        )
    if cfg.robustness_episodes < 1:
        raise UserError(f"--robustness-episodes must be at least 1, got {cfg.robustness_episodes}")
    if cfg.record.task == STAND or cfg.record.controller in INTERACTIVE:  # what `bc.train.check_taught` would refuse
        given = f"--record.task {STAND}" if cfg.record.task == STAND else f"--record.controller {cfg.record.controller}"
        raise UserError(
            f"{given}: the students learn to follow the operator's command, which the pipeline's recording changes "
            "only by the scripted schedules"
        )
    if cfg.record.latency == 0:  # what `bc.train.check_taught` would refuse after the recording
        raise UserError(
            f"--record.latency 0: the students read {BLIND_INPUTS}'s inputs, which learn to act through action "
            "latency, and a recording without it never shows it: give a share above 0"
        )
    return robustness.selected(RobustnessConfig(conditions=cfg.conditions))


SHARED_WORKERS = ("record", "dagger", "ppo")
"""The stages whose `workers` the pipeline's WORKERS sets, when given (unset, each stage's own applies)."""


def tied(cfg: PipelineConfig) -> PipelineConfig:
    """`cfg` with each tied setting (`TIES`, and WORKERS where given) set from its source; UserError in one line for
    one given otherwise."""
    replaced = {}
    workers = [(stage, "workers", "", "workers") for stage in SHARED_WORKERS] if cfg.workers is not None else []
    for stage, name, source, source_name in (*TIES, *workers):
        config = replaced.get(stage, getattr(cfg, stage))
        value, wanted = getattr(config, name), getattr(getattr(cfg, source) if source else cfg, source_name)
        if value != wanted and value != field_default(PipelineConfig, f"{stage}.{name}"):
            tie = flag(f"{source}.{source_name}" if source else source_name)
            raise UserError(
                f"{flag(f'{stage}.{name}')} {value}: the pipeline ties it to {tie} ({wanted}); set that instead"
            )
        replaced[stage] = dataclasses.replace(config, **{name: wanted})
    return dataclasses.replace(cfg, **replaced)


def stages(cfg: PipelineConfig) -> Stages:
    """The stages' configs for `cfg`: its nested stages tied together (`tied`: the shared worker settings too), the
    blind student and PPO from scratch made from the bc and ppo stages."""
    check(cfg)
    cfg = tied(cfg)
    finetune = cfg.ppo
    scratch_settings = {
        field.name: getattr(finetune, field.name)
        for field in dataclasses.fields(FinetuneConfig)
        if field.name not in ScratchConfig.OWN
    }
    return Stages(
        record=cfg.record,
        student=cfg.bc,
        blind=dataclasses.replace(cfg.bc, policy=cfg.blind_policy, inputs=BLIND_INPUTS),
        dagger=cfg.dagger,
        scratch=ScratchConfig(**{**scratch_settings, "policy": cfg.scratch_policy}),
        finetune=finetune,
    )


@dataclass(frozen=True)
class Decision:
    """What the pipeline does about a stage, the config it runs it with, and the line that says why."""

    action: str  # REUSE, RUN (nothing there yet), REMAKE (differs: made again), RESUME (append what is missing)
    line: str
    config: Any = None


def first_difference(saved: dict[str, Any], config: Any, skip: frozenset[str] | set[str]) -> str | None:
    """The first setting of `config` that `saved` (a saved config) holds otherwise: "--epochs 30, not 5"."""
    for name, wanted in config_dict(config).items():
        if name in skip:
            continue
        if name not in saved:
            return f"no {flag(name)} (an older version)"
        have = saved[name]
        if isinstance(getattr(config, name), Path) and isinstance(have, str):
            same = Path(have).resolve() == getattr(config, name).resolve()
        else:
            same = have == wanted
        if not same:
            return f"{flag(name)} {have}, not {wanted}"
    return None


def _committed_episodes(root: Path) -> int | None:
    """info.json's total_episodes, or None without a readable one."""
    try:
        return int(read_info(root)["total_episodes"])
    except (OSError, DatasetError, ValueError, KeyError, TypeError):
        return None


def _dataset_problem(cfg: RecordConfig, total: int, runs: list[dict[str, Any]]) -> str | None:
    """Why the dataset's `total` episodes are not the first ones of a recording `cfg` asks for; None if they are."""
    if not runs:
        return "has no recordings.jsonl saying how it was recorded"
    next_index, next_seed = 0, 0 if cfg.seed is None else cfg.seed
    for run in runs:
        try:
            (first, last), (first_seed, last_seed), count = run["episodes"], run["seeds"], run["count"]
            settings = run["config"]
        except (KeyError, TypeError, ValueError):
            return "has a recordings.jsonl line this version cannot read"
        if (first, last - first + 1) != (next_index, count):
            return f"holds episodes {next_index}.. that recordings.jsonl does not account for (a run killed?)"
        difference = first_difference(settings, cfg, NOT_COMPARED | {"dataset", "episodes", "seed"})
        if difference:
            return f"was recorded with {difference}"
        if (first_seed, last_seed - first_seed + 1) != (next_seed, count):
            return f"holds seeds {first_seed}..{last_seed} where {next_seed}.. were asked for"
        next_index, next_seed = next_index + count, next_seed + count
    if next_index != total:
        return f"holds {total - next_index} episodes that recordings.jsonl does not account for (a run killed?)"
    if total > cfg.episodes:
        return f"holds {total} episodes, not {cfg.episodes}"
    return None


def _layout_problem(root: Path) -> str | None:
    """Why the dataset's sensed features are not the ones this version records (`humanoid.sensors`); None if
    they are, or if meta/info.json cannot say (the checks that read it report that)."""
    try:
        names = read_info(root)["features"][columns.OBS_STATE]["names"]
    except (OSError, DatasetError, KeyError, TypeError):
        return None
    wanted = proprioception_names(nominal_model())
    if names == wanted:
        return None
    return f"records {len(names)} sensed features as {columns.OBS_STATE}, not this version's {len(wanted)}"


def dataset_decision(cfg: RecordConfig) -> Decision:
    """Whether the recording stage reuses, records, records again or completes `cfg.dataset`, `cfg` as it records
    (`teleop.record.effective`: an unset teacher or latency share is its task's, as recordings.jsonl saves it)."""
    cfg = effective(cfg)
    root = cfg.dataset
    total = _committed_episodes(root)
    if not total:
        return Decision(RUN, f"recording {root}: {'no dataset there yet' if total is None else 'no episode yet'}", cfg)
    runs = recordings.sessions(
        root, lambda: read_episodes(root, [columns.EPISODE_SEED])[columns.EPISODE_SEED].to_pylist()
    )
    problem = _dataset_problem(cfg, total, runs) or _layout_problem(root)
    ours = all(run.get("made_by") in OWN for run in runs) and bool(runs)
    if problem is None and total == cfg.episodes:
        return Decision(REUSE, f"{root} holds the {total} episodes asked for, recorded so: not recording")
    if problem is None:
        if ours:
            rest = dataclasses.replace(cfg, episodes=cfg.episodes - total, seed=(cfg.seed or 0) + total)
            line = f"{root} holds {total} of the {cfg.episodes} episodes asked for: recording the other {rest.episodes}"
            return Decision(RESUME, line, rest)
        problem = f"holds {total} of the {cfg.episodes} episodes asked for"
    if ours:
        return Decision(REMAKE, f"recording {root} again: it {problem}", cfg)
    raise UserError(
        f"{root} {problem}, and the pipeline did not record it: it is left as it is "
        "(ask for what it holds, or choose another --record.dataset)"
    )


def evaluates(cfg: TrainConfig | FinetuneConfig | DaggerConfig) -> bool:
    """Whether the stage writes an eval.json: PPO always (its training's figures), BC and DAgger unless told no
    episodes."""
    return not isinstance(cfg, TrainConfig | DaggerConfig) or cfg.eval_episodes > 0


def checkpoint_decision(
    cfg: TrainConfig | FinetuneConfig | DaggerConfig,
    verb: str,
    option: str,
    source: str,
    saved_source: str | None,
    current_source: Callable[[], str | None],
    overwrite: bool,
    source_remade: bool = False,
    settings_key: str | None = None,
) -> Decision:
    """Whether a training stage reuses its checkpoint `cfg.policy`, makes it, or makes it again.

    `source` names its input ("dataset", "BC policy"); `saved_source` is the input's identity the
    checkpoint records, `current_source` gives the one there now; `source_remade` foresees an input
    the pipeline will make again. `option` is the pipeline's flag of the folder, for the refusal.
    `settings_key`: where in config.json's "training" the stage's settings are ("dagger"), if not there itself.
    """
    folder = cfg.policy
    if not folder.exists():
        return Decision(RUN, f"{verb} {folder}: no checkpoint there yet", cfg)
    problem = checkpoint_problem(folder)
    if problem:
        raise UserError(f"{problem}: it is left as it is (choose another {option})")
    training = training_settings(folder)
    saved = training.get(settings_key, {}) if settings_key else training
    skip = NOT_COMPARED if isinstance(cfg, FinetuneConfig) else STUDENT_NOT_COMPARED
    difference = first_difference(saved if isinstance(saved, dict) else {}, cfg, skip | {"policy"})
    if source_remade:
        problem = f"was made from the {source} the pipeline makes again"
    elif difference:
        problem = f"was made with {difference}"
    elif saved_source is None:
        problem = f"does not record which {source} it was made from (an older version)"
    elif saved_source != current_source():
        problem = f"was made from another {source}"
    elif evaluates(cfg) and not (folder / EVAL_FILE).is_file():
        problem = f"has no {EVAL_FILE} (its evaluation did not finish)"
    if problem is None:
        return Decision(REUSE, f"{folder} was made from this {source} with these settings: not {verb}")
    if training.get("made_by") in OWN or overwrite:
        return Decision(REMAKE, f"{verb} {folder} again: it {problem}", dataclasses.replace(cfg, overwrite=True))
    raise UserError(
        f"{folder} {problem}, and the pipeline did not make it: it is left as it is "
        f"(--overwrite true, OVERWRITE=1 with make, replaces it; or choose another {option})"
    )


def dataset_fingerprint(root: Path) -> str | None:
    """The fingerprint of the dataset at `root` (`teleop.dataset_reader.fingerprint`), or None where there is none."""
    return fingerprint(root) if (root / INFO_PATH).is_file() else None


def bc_decision(
    cfg: TrainConfig, overwrite: bool, dataset_remade: bool = False, option: str = "--bc.policy"
) -> Decision:
    """A train-bc stage's decision: its input is the dataset, identified by its fingerprint."""
    saved = json_object(cfg.policy / DATASET_FILE).get("fingerprint")
    current = partial(dataset_fingerprint, cfg.dataset)
    return checkpoint_decision(cfg, "training", option, "dataset", saved, current, overwrite, dataset_remade)


def as_run(cfg: DaggerConfig) -> DaggerConfig:
    """`cfg` as `make dagger` runs it (`bc.dagger.resolved`: the expert and the rounds its student's inputs default to,
    the recording's conditions where none is given), which is what its checkpoint and its aggregate record: a run made
    on the defaults then compares equal to them. As given where no dataset holds the conditions yet, or they cannot be
    read (DAgger itself then says why in one line)."""
    try:
        return bc_dagger.resolved(cfg) if cfg.output.exists() or cfg.dataset.exists() else cfg
    except UserError:
        return cfg


def dagger_decision(cfg: DaggerConfig, overwrite: bool, dataset_remade: bool = False) -> Decision:
    """The DAgger stage's decision: its input is the dataset, identified by the fingerprint the checkpoint records
    (`demonstrations`: of the copy its aggregate began as), and its settings as it runs them (`as_run`)."""
    cfg = cfg if dataset_remade else as_run(cfg)
    saved = training_settings(cfg.policy).get("demonstrations")
    current = partial(dataset_fingerprint, cfg.dataset)
    return checkpoint_decision(
        cfg, "DAgger", "--dagger.policy", "dataset", saved, current, overwrite, dataset_remade, settings_key="dagger"
    )


def aggregate_problem(cfg: DaggerConfig) -> str | None:
    """Why DAgger's aggregate OUTPUT cannot go on to the checkpoint `cfg` asks for: a copy of another dataset than
    DATASET now, or rounds rolled out with other settings (a run killed too); None if it can, or is not there."""
    if not cfg.output.exists():
        return None
    cfg = as_run(cfg)
    source = bc_dagger.copied_from(cfg.output)
    if not source:
        return f"has no {bc_dagger.SOURCE_FILE} saying which demonstrations it copied"
    now = dataset_fingerprint(cfg.dataset)
    if now is None or source.get("fingerprint") != now:
        return f"is a copy of another dataset than {cfg.dataset} now"
    killed = recordings.marked(cfg.output)
    runs = [line for line in recordings.read(cfg.output) if bc_dagger.is_dagger_run(line)]
    for run in [*runs, *([killed] if killed and bc_dagger.is_dagger_run(killed) else [])]:
        changed = bc_dagger.changed_settings(run["config"], cfg, (*bc_dagger.SHAPING, "rounds"))
        if changed:
            return f"holds rounds rolled out with {flag(changed[0])} {run['config'].get(changed[0])}"
    return None


def ppo_decision(cfg: FinetuneConfig, option: str, overwrite: bool, bc_remade: bool = False) -> Decision:
    """A PPO stage's decision: its input is the BC checkpoint, identified by its weights' digest."""

    def current() -> str | None:
        return weights_digest(cfg.bc_policy) if is_checkpoint(cfg.bc_policy) else None

    saved = training_settings(cfg.policy).get("bc_policy_sha256")
    verb = "training from scratch" if cfg.fresh else "fine-tuning"
    return checkpoint_decision(cfg, verb, option, "BC policy", saved, current, overwrite, bc_remade)


def validate(run: Stages) -> None:
    """Every stage's own checks, and that no two stages write one folder, before the first one starts."""
    validate_record(run.record)
    bc_train.validate(run.student)
    bc_train.validate(run.blind)
    bc_dagger.check_settings(run.dagger)
    validate_ppo(run.scratch)
    validate_ppo(run.finetune)
    seen: dict[Path, str] = {}
    for option, folder in run.outputs().items():
        other = seen.setdefault(folder.resolve(), option)
        if other != option:
            raise UserError(f"{other} and {option} both name {folder}: each output needs its own folder")


def foresee(run: Stages, overwrite: bool) -> None:
    """Refuse now what the run would refuse later: a checkpoint downstream of an output made again."""
    dataset_remade = dataset_decision(run.record).action != REUSE
    remade = {
        config.policy.resolve(): bc_decision(config, overwrite, dataset_remade, option).action != REUSE
        for config, option in ((run.student, "--bc.policy"), (run.blind, "--blind-policy"))
    }
    remade[run.dagger.policy.resolve()] = dagger_decision(run.dagger, overwrite, dataset_remade).action != REUSE
    if remade[run.dagger.policy.resolve()]:
        if dataset_remade and run.dagger.output.exists():
            problem = "is a copy of the dataset the pipeline records again"
        else:
            problem = aggregate_problem(run.dagger)
        check_aggregate(run.dagger, problem)
    for config, option in ((run.scratch, "--scratch-policy"), (run.finetune, "--ppo.policy")):
        # A PPO stage is downstream of whichever BC checkpoint it starts from.
        ppo_decision(config, option, overwrite, remade.get(config.bc_policy.resolve(), False))


def run(stages: Stages, overwrite: bool = False, episodes: int = 20, conditions: Sequence[str] = tuple(SUITE)) -> str:
    """Run what has to run, say why in one line each, then evaluate the experts and every policy (`episodes` per
    condition) and print and return the table (`pipeline.report.command_table`)."""
    validate(stages)
    foresee(stages, overwrite)
    policies = run_stages(stages, overwrite)
    names = [*EXPERTS, *map(str, policies)]
    table = report.command_table(*measure(names, episodes, list(conditions), stages.finetune.workers))
    print(table)
    return table


def run_stages(stages: Stages, overwrite: bool) -> list[Path]:
    """Record, clone, DAgger and run both PPO stages, each unless reused; the policies' folders, in the table's
    order."""
    record_stage(stages.record)
    bc_stage(stages.blind, overwrite, "--blind-policy")
    bc_stage(stages.student, overwrite, "--bc.policy")
    dagger_stage(stages.dagger, overwrite)
    for config, option in ((stages.scratch, "--scratch-policy"), (stages.finetune, "--ppo.policy")):
        decision = ppo_decision(config, option, overwrite)
        print(f"pipeline: {decision.line}", flush=True)
        if decision.action != REUSE:
            print_summary(decision.config, ppo_main(decision.config, made_by=MADE_BY))
    return [
        stages.blind.policy,
        stages.student.policy,
        stages.dagger.policy,
        stages.finetune.policy,
        stages.scratch.policy,
    ]


def record_stage(cfg: RecordConfig) -> None:
    """Record the dataset of `cfg`, complete it, or reuse it (`dataset_decision`), saying which."""
    decision = dataset_decision(cfg)
    print(f"pipeline: {decision.line}", flush=True)
    if decision.action == REMAKE:
        shutil.rmtree(cfg.dataset)
    if decision.action != REUSE:
        print(record(decision.config, made_by=MADE_BY).describe(), flush=True)


def bc_stage(cfg: TrainConfig, overwrite: bool, option: str) -> None:
    """Train the BC checkpoint of `cfg` or reuse it (`bc_decision`), saying which."""
    decision = bc_decision(cfg, overwrite, option=option)
    print(f"pipeline: {decision.line}", flush=True)
    if decision.action != REUSE:
        print(bc_train.main(decision.config, made_by=MADE_BY).describe(), flush=True)


def check_aggregate(cfg: DaggerConfig, problem: str | None) -> None:
    """Refuse in one line to make again an aggregate with `problem` that the pipeline did not copy."""
    if problem and bc_dagger.copied_from(cfg.output).get("made_by") != MADE_BY:
        raise UserError(
            f"{cfg.output} {problem}, and the pipeline did not make it: it is left as it is "
            "(choose another --dagger.output)"
        )


def dagger_stage(cfg: DaggerConfig, overwrite: bool) -> None:
    """Run DAgger for the checkpoint of `cfg` or reuse it (`dagger_decision`), saying which; an aggregate that cannot
    go on to it (`aggregate_problem`) is made again if the pipeline copied it, refused otherwise."""
    decision = dagger_decision(cfg, overwrite)
    print(f"pipeline: {decision.line}", flush=True)
    if decision.action == REUSE:
        return
    problem = aggregate_problem(cfg)
    check_aggregate(cfg, problem)
    if problem:
        print(f"pipeline: making {cfg.output} again: it {problem}", flush=True)
        shutil.rmtree(cfg.output)
    print(bc_dagger.main(decision.config, made_by=MADE_BY).describe(), flush=True)


def measure(
    names: list[str], episodes: int, conditions: list[str], workers: int | None = None
) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, Any]]]:
    """What the table shows of each controller in `names`: its evaluation with the command zero (the clean condition)
    and its suite on held-out schedules under `conditions` (a suite saved after the policy with the same episodes,
    conditions and errors is reused), by name. Every evaluation goes to one pool at once: no worker waits at a
    controller's end for the next one's."""
    count = robustness.worker_count(workers)
    seeds = range(EVAL_SEED, EVAL_SEED + episodes)
    configs = {name: suite_config(name, episodes, conditions, workers) for name in names}
    saved = {name: saved_suite(config) for name, config in configs.items()}
    fresh = [name for name in names if saved[name] is None]
    for name in names:
        print(f"pipeline: {name} with the command zero: {episodes} episodes", flush=True)
    for name in names:
        saved_at = robustness.result_paths(configs[name])[0]
        how = f"{episodes} episodes x {len(conditions)} conditions" if name in fresh else f"reusing {saved_at}"
        print(f"pipeline: {name} on held-out schedules: {how}", flush=True)
    planned = [
        *(robustness.suite_runs(name, ["clean"], seeds, count) for name in names),
        *(robustness.suite_runs(name, conditions, seeds, count, POSTURE_TASK) for name in fresh),
    ]
    rows = list(robustness.evaluate_suites(planned, count))
    standing = {name: row["clean"] for name, row in zip(names, rows[: len(names)], strict=True)}
    made = {name: robustness.save(configs[name], row) for name, row in zip(fresh, rows[len(names) :], strict=True)}
    return standing, {name: saved[name] or made[name] for name in names}


def suite_config(policy: str, episodes: int, conditions: list[str], workers: int | None = None) -> RobustnessConfig:
    """The robustness run of `policy`'s row in the table: `episodes` on held-out schedules under each condition."""
    return RobustnessConfig(
        policy=policy,
        episodes=episodes,
        conditions=",".join(conditions),
        task=POSTURE_TASK,
        workers=workers,
        progress=False,
    )


def saved_suite(cfg: RobustnessConfig) -> dict[str, Any] | None:
    """The suite `cfg` runs as its robustness_schedules.json holds it, if made after the policy (a registered
    controller's always) with the same episodes, conditions and errors; else None."""
    saved = robustness.result_paths(cfg)[0]
    policy = Path(cfg.policy)
    weights = policy / (SB3_FILE if is_sb3_policy(policy) else WEIGHTS_FILE)
    if not saved.is_file() or not (cfg.policy in registered() or saved.stat().st_mtime_ns > weights.stat().st_mtime_ns):
        return None
    result = json_object(saved)
    if not result:  # unreadable (written before it was written whole): made again
        return None
    current = all(set(ERROR_KINDS) <= set(row["tracking"]) for row in result["conditions"].values())
    seeds = list(range(cfg.seed, cfg.seed + cfg.episodes))
    same = result["seeds"] == seeds and list(result["conditions"]) == cfg.conditions.split(",")
    return result if current and same else None


def main(cfg: PipelineConfig) -> str:
    """The whole pipeline as configured; returns the table(s) it printed."""
    return run(stages(cfg), cfg.overwrite, cfg.robustness_episodes, check(cfg))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(main, PipelineConfig, argv, description=__doc__, prog="python -m pipeline.run")


if __name__ == "__main__":
    sys.exit(cli())
