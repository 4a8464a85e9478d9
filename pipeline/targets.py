"""Which Make variable sets which flag of which stage: the one table, printed by `make help`.

A Make variable is the name of its stage's config field in capitals (MAX_STEPS is --max-steps; a nested stage's
field, as the pipeline's, keeps its stage: RECORD.EPISODES is --record.episodes), and
the Makefile passes it only when it is set, so an unset one leaves the default of the stage's
config. The same name can belong to several targets, each time as that stage's own setting (SEED
is the first recorded seed for `make record`, the first evaluation seed for `make eval`): `make
help` lists every target's variables with their flags, help and defaults.

    python -m pipeline.targets          # what `make help` prints after the targets
    python -m pipeline.targets --markdown   # every flag of every stage: docs/reference/flags.md (`make docs`)

tests/test_makefile.py holds the Makefile to this table: every variable of a target becomes its
flag with its value, an unset one passes nothing, and the Makefile passes no variable the table
does not list. A target's removed variables (`Target.removed`) are still passed, so that the stage
refuses them in one line naming what to use instead (`common.cli.REMOVED_FLAGS`) rather than make
ignoring them. A target that is a special case of another's stage (`make play`: the recorder with the
keyboard) passes its `Target.preset` flags first; a variable of the same field comes after, and wins.
"""

from __future__ import annotations

import dataclasses
import importlib
import shutil
import sys
import textwrap
from dataclasses import dataclass
from typing import Any

from bc.dagger import DaggerConfig
from bc.train import TrainConfig
from common.cli import field_default, flag, flat_fields
from common.paths import NEWEST
from evaluation.evaluate import EvalConfig
from evaluation.robustness import RobustnessConfig
from evaluation.tune_walker import TuneConfig
from pipeline.run import SHARED_WORKERS, TIES, PipelineConfig
from rl.finetune import FinetuneConfig
from rl.scratch import ScratchConfig
from rl.tutorial import TutorialConfig
from teleop.export import ExportConfig
from teleop.inspect_dataset import InspectConfig
from teleop.merge import MergeConfig
from teleop.record import RecordConfig

ARGS = "ARGS"
"""The PPO targets' pass-through variable: any other flag of the stage, as typed."""


@dataclass(frozen=True)
class Target:
    """A Make target that runs a stage: `python -m <module>`, its config, the fields Make variables set."""

    module: str
    config: type
    fields: tuple[str, ...]
    passes_args: bool = False  # ARGS is appended as it is (further flags)
    removed: tuple[str, ...] = ()
    """Fields an earlier version had (keys of `common.cli.REMOVED_FLAGS`): passed when set, for the stage to refuse."""
    preset: tuple[tuple[str, str], ...] = ()
    """(field, value) pairs the recipe passes before the variables, as `--field=value`: what makes the target a
    special case of its stage, its own defaults (a variable of the same field overrides it)."""

    @property
    def variables(self) -> dict[str, str]:
        """Make variable -> config field."""
        return {name.upper(): name for name in self.fields}

    @property
    def preset_flags(self) -> list[str]:
        """The words the recipe passes before `$(flags)`."""
        return [f"{flag(name)}={value}" for name, value in self.preset]

    def field(self, name: str) -> dataclasses.Field[Any]:
        return dict(flat_fields(self.config))[name]

    def default(self, name: str) -> object:
        """The value field `name` has when its variable is unset: the preset's, else the stage config's default."""
        return dict(self.preset).get(name, field_default(self.config, name))


_LIVE = ("live", "live_port", "live_host")
_BACKEND = ("workers", "backend", "ray_address")
_PPO = ("bc_policy", "policy", "timesteps", *_BACKEND, "envs", "push", "kick", "curriculum", "randomize", "overwrite")

TARGETS: dict[str, Target] = {
    "record": Target(
        "teleop.record",
        RecordConfig,
        (
            "dataset",
            "episodes",
            "seed",
            "controller",
            "task",
            "kick",
            "noise",
            "randomize",
            "latency",
            "max_steps",
            *_BACKEND,
            "front_end",
            "pace",
            *_LIVE,
            "cameras",
        ),
        removed=("schedules", "walking"),
    ),
    # `make record CONTROLLER=keyboard` with a learned policy instead of the expert, into its own dataset, and no DART
    # noise: the keys drive the policy as it is (noise is for demonstrations a student learns from).
    "play": Target(
        "teleop.record",
        RecordConfig,
        ("policy", "dataset", "episodes", "noise", "front_end", "pace", *_LIVE, "cameras"),
        preset=(("controller", "keyboard"), ("policy", NEWEST), ("dataset", "datasets/play"), ("noise", "0")),
    ),
    "merge": Target("teleop.merge", MergeConfig, ("shards", "dataset")),
    "inspect": Target("teleop.inspect_dataset", InspectConfig, ("dataset", "plot", "plot_path")),
    "export": Target("teleop.export", ExportConfig, ("format", "dataset", "out", "reference_episodes")),
    "train-bc": Target(
        "bc.train",
        TrainConfig,
        ("dataset", "policy", "inputs", "epochs", "min_updates", "seed", "eval_episodes", "overwrite"),
    ),
    "eval": Target(
        "evaluation.evaluate",
        EvalConfig,
        (
            "policy",
            "episodes",
            "seed",
            "task",
            "push",
            "kick",
            "noise",
            "condition",
            "video",
            "plot",
            "hold",
            *_LIVE,
        ),
        removed=("schedules", "walking"),
    ),
    "robustness": Target(
        "evaluation.robustness",
        RobustnessConfig,
        ("policy", "episodes", "seed", "conditions", "task", "workers"),
        removed=("schedules", "walking"),
    ),
    "tune-walker": Target(
        "evaluation.tune_walker",
        TuneConfig,
        (
            "generations",
            "population",
            "walks",
            "kicks",
            "kick",
            "noise",
            "seed",
            "cma_seed",
            "sigma",
            "bounds",
            "turn_weight",
            "sensed",
            "workers",
            "start",
            "run",
            "out",
        ),
    ),
    "dagger": Target(
        "bc.dagger",
        DaggerConfig,
        (
            "dataset",
            "output",
            "policy",
            "inputs",
            "expert",
            "randomize",
            "latency",
            "kick",
            "noise",
            "rounds",
            "episodes",
            "epochs",
            "min_updates",
            "eval_episodes",
            "workers",
            "seed",
            "overwrite",
        ),
    ),
    "finetune-rl": Target("rl.finetune", FinetuneConfig, _PPO, passes_args=True),
    "scratch-rl": Target("rl.scratch", ScratchConfig, _PPO, passes_args=True),
    "tutorial-rl": Target("rl.tutorial", TutorialConfig, ("learners", "timesteps", "overwrite")),
    "pipeline": Target(
        "pipeline.run",
        PipelineConfig,
        (
            *(
                f"record.{name}"
                for name in ("dataset", "episodes", "seed", "controller", "noise", "latency", "max_steps")
            ),
            "bc.policy",
            "bc.epochs",
            "blind_policy",
            *(f"dagger.{name}" for name in ("output", "policy", "rounds", "episodes", "epochs")),
            *(f"ppo.{name}" for name in ("policy", "timesteps", "envs", "push", "curriculum", "randomize")),
            "scratch_policy",
            *_BACKEND,
            "overwrite",
            "robustness_episodes",
            "conditions",
        ),
        passes_args=True,
        # This version's stage settings were the pipeline's own before (EPISODES is RECORD.EPISODES now): passed, they
        # are refused naming the new one (`common.cli.check_removed`); the rest were removed earlier.
        removed=(
            *("dataset", "episodes", "seed", "controller", "noise", "latency", "max_steps", "bc_policy", "epochs"),
            *("dagger_output", "dagger_policy", "rounds", "dagger_episodes", "dagger_epochs", "ppo_policy"),
            *("timesteps", "envs", "push", "curriculum", "randomize"),
            "deployable",
            "ppo_from",
            "odometry_inputs",
            "tutorial",
            "proprio_policy",
            "sensed_dataset",
            "sensed_noise",
            "sensed_latency",
            "odometry_policy",
        ),
    ),
}


TIED_FROM = {
    **{f"{stage}.{name}": f"{source}.{source_name}".lstrip(".") for stage, name, source, source_name in TIES},
    **{f"{stage}.workers": "workers" for stage in SHARED_WORKERS},
}
"""The pipeline's nested settings it sets itself (`pipeline.run.TIES`; `workers` when WORKERS is given) -> from
which: given otherwise, the pipeline refuses them, so the flag reference says so."""


def help_text(width: int = 120) -> str:
    """Every target's variables: flag, help and the stage's default, wrapped to `width` columns."""
    lines = [
        "Variables of each target (VAR=value is the stage's --var value; unset, the stage's default applies):",
    ]
    name_width = max(len(var) for target in TARGETS.values() for var in target.variables) + 2
    flag_width = max(len(flag(field)) for target in TARGETS.values() for field in target.fields) + 2
    indent = " " * (4 + name_width + flag_width)
    for name, target in TARGETS.items():
        lines.append(f"  make {name} ({' '.join([f'python -m {target.module}', *target.preset_flags])}):")
        for var, field_name in target.variables.items():
            text = target.field(field_name).metadata.get("help", "")
            if "default:" not in text or field_name in dict(target.preset):  # else the help says it itself
                text += f" (default: {target.default(field_name)})"
            head = f"    {var:<{name_width}}{flag(field_name):<{flag_width}}"
            lines += textwrap.wrap(
                text, width=max(width, len(indent) + 40), initial_indent=head, subsequent_indent=indent
            )
        if target.passes_args:
            extra = f"any other flag, as typed (`python -m {target.module} --help`)"
            lines.append(f"    {ARGS:<{name_width}}{'...':<{flag_width}}{extra}")
    return "\n".join(lines)


MARKDOWN_COMMAND = "python -m pipeline.targets --markdown"
"""What writes docs/reference/flags.md (`make docs`); tests/test_docs.py checks the committed file is its output."""


def _cell(text: object) -> str:
    """`text` as one Markdown table cell: one line, its pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def markdown_text() -> str:
    """Every flag of every stage target as Markdown tables: its Make variable (if any), default and help."""
    lines = [
        "# Flag reference",
        "",
        f"Generated from each stage's config by `make docs` (`{MARKDOWN_COMMAND}`); do not edit by hand:",
        "tests/test_docs.py fails when this page and the configs differ. `make help` prints the Make variables",
        "of the same table. A Make variable is its flag in capitals (`MAX_STEPS=500` is `--max-steps 500`), passed",
        "only when set; a flag without one is set with `python -m <module> --flag value`, or for the PPO targets",
        f'with `{ARGS}="--flag value"`.',
    ]
    for name, target in TARGETS.items():
        summary = (importlib.import_module(target.module).__doc__ or "").strip().split("\n\n")[0]
        command = " ".join([f"python -m {target.module}", *target.preset_flags])
        lines += ["", f"## make {name}", "", f"`{command}`: {_cell(summary)}", ""]
        lines += ["| Make variable | flag | default | what it sets |", "|---|---|---|---|"]
        variables = {field_name: var for var, field_name in target.variables.items()}
        for field_name, field in flat_fields(target.config):
            var = f"`{variables[field_name]}`" if field_name in variables else ""
            text = field.metadata.get("help", "")
            default = f"`{target.default(field_name)}`" if target.default(field_name) != "" else '`""`'
            if "default:" in text and field_name not in dict(target.preset):  # the help says it itself
                default = "(in the help)"
            if field_name in TIED_FROM and target.config is PipelineConfig:
                default, text = "(tied)", f"{text}; the pipeline sets it from `{flag(TIED_FROM[field_name])}`"
            lines.append(f"| {var} | `{flag(field_name)}` | {_cell(default)} | {_cell(text)} |")
        if target.passes_args:
            lines.append(f"| `{ARGS}` | ... | | any other flag above, as typed |")
    return "\n".join(lines) + "\n"


def main() -> int:
    try:
        if sys.argv[1:] == ["--markdown"]:
            print(markdown_text(), end="", flush=True)
            return 0
        print(help_text(min(shutil.get_terminal_size((120, 24)).columns, 120)), flush=True)
    except BrokenPipeError:  # `make help | head`
        sys.stdout = None
    return 0


if __name__ == "__main__":
    sys.exit(main())
