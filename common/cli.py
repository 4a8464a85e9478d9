"""Command lines built from a stage's config dataclass: one flag per field, its help from the field.

Every stage declares its settings once, as a dataclass whose fields carry `help` metadata; the
flags, their defaults in `--help`, and the Makefile variables all follow from it. A flag or value that
an earlier version had and this one removed is refused here, for every stage, in one line that says what
to use instead (`REMOVED_FLAGS`, `REMOVED_VALUES`), before anything is read or written.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import types
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from common.threads import one_blas_thread

Config = TypeVar("Config")

EXIT_FAILURE = 1


class UserError(Exception):
    """A mistake in the user's input or environment: reported as one line, without a traceback."""


class DatasetError(UserError):
    """A dataset folder that cannot be used as asked (missing, incompatible, locked, unwritable)."""


@dataclass(frozen=True)
class Removed:
    """A flag or value an earlier version had: what it was, what to do instead, the decision record saying why."""

    what: str
    instead: str
    record: str
    """The decision record's name: docs/decisions/<record>.md."""

    def message(self) -> str:
        return f"{self.what} was removed; {self.instead} (docs/decisions/{self.record}.md)"


_ADAPTIVE = Removed("controller 'expert-adaptive'", "use expert-sensed", "identification")
_FIXED = "it is fixed at the value every run used"
_FIXED_RECORD = "fixed-settings"

REMOVED_FLAGS: dict[str, Removed] = {
    removed.what[2:].replace("-", "_"): removed
    for removed in (
        Removed("--bc-weight", "PPO fine-tuning runs without a BC term (as every default run did)", "bc-regulariser"),
        Removed("--bc-decay", "PPO fine-tuning runs without a BC term (as every default run did)", "bc-regulariser"),
        Removed("--keep", "the run keeps the guarded actor, as the default did", "keep-policy"),
        Removed(
            "--ppo-from",
            "the PPO stages start from BC_POLICY, the command-conditioned student; for a PPO run from another BC "
            "policy: make finetune-rl BC_POLICY=...",
            "ppo-start",
        ),
        Removed(
            "--deployable",
            "the pipeline's students read only what a robot senses (PPO starts from one of them)",
            "ppo-start",
        ),
        Removed(
            "--init", "make scratch-rl trains from fresh weights, make finetune-rl from the BC policy's", _FIXED_RECORD
        ),
        Removed("--reward-scale", f"{_FIXED}: 0.01 for make finetune-rl, 1 for make scratch-rl", _FIXED_RECORD),
        Removed("--log-std-init", f"{_FIXED}: log(0.05), the DART noise of the demonstrations", _FIXED_RECORD),
        Removed("--eval-conditions", f"{_FIXED}: clean, push20, mass", _FIXED_RECORD),
        Removed("--validation-seed", f"{_FIXED}: 2000", _FIXED_RECORD),
        *(
            Removed(f"--{name}", f"{_FIXED}: the tutorial's ({value}; make tutorial-rl)", _FIXED_RECORD)
            for name, value in (("step-size", 0.01), ("noise-start", 0.2), ("noise-end", 0.01), ("ent-coef", 0.005))
        ),
        Removed(
            "--odometry-inputs",
            "the pipeline's student reads INPUTS=pending+command; for another: make train-bc INPUTS=... "
            "DATASET=datasets/operator_sensed",
            "pipeline-task",
        ),
        Removed("--tutorial", "the seed tutorial's learners run apart: make tutorial-rl", "pipeline-task"),
        Removed(
            "--proprio-policy",
            "the pipeline records the operator's demonstrations only; BC on the privileged expert's sensed features: "
            "make record, then make train-bc INPUTS=proprio",
            "pipeline-task",
        ),
        Removed(
            "--sensed-dataset",
            "the pipeline records one dataset, DATASET (the expert on leg odometry)",
            "pipeline-task",
        ),
        Removed("--sensed-noise", "NOISE is the pipeline's one recording's DART noise", "pipeline-task"),
        Removed("--sensed-latency", "LATENCY is the pipeline's one recording's delayed share", "pipeline-task"),
        Removed("--odometry-policy", "BC_POLICY is the pipeline's student on what a robot senses", "pipeline-task"),
    )
}
"""Flags removed from every stage that had them, by config field name. A stage that still has a field of the
name (none does today) parses it as its own."""

REMOVED_VALUES: dict[tuple[str, str], Removed] = {
    ("controller", "expert-adaptive"): _ADAPTIVE,  # make record, make pipeline
    ("policy", "expert-adaptive"): _ADAPTIVE,  # make eval, make robustness
    ("expert", "expert-adaptive"): _ADAPTIVE,  # make dagger
    # make train-bc, make dagger; humanoid.inputs.removed_inputs refuses it from a checkpoint too
    ("inputs", "odometry"): Removed(
        "inputs 'odometry'", "use pending: the same inputs, then the command in flight and the delay", "pending-inputs"
    ),
}
"""Values removed from a flag that stays, by (config field name, value)."""


def check_removed(config_class: type, argv: Sequence[str]) -> None:
    """UserError in one line for a removed flag or value in `argv` (`--name value` or `--name=value`), naming what
    to use instead: argparse's own "unrecognized arguments" would not say it."""
    fields = {field.name for field in dataclasses.fields(config_class)}
    for index, word in enumerate(argv):
        if not word.startswith("--"):
            continue
        text, equals, value = word[2:].partition("=")
        name = text.replace("-", "_")
        if name not in fields:
            if name in REMOVED_FLAGS:
                raise UserError(REMOVED_FLAGS[name].message())
            continue
        if not equals:
            value = argv[index + 1] if index + 1 < len(argv) else ""
        if (name, value) in REMOVED_VALUES:
            raise UserError(REMOVED_VALUES[name, value].message())


def first_line(error: BaseException) -> str:
    """The first line of an exception's text (a library's message may span many), or its type if it has none."""
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


def one_line(error: BaseException) -> str:
    """An exception as one line of a message: its type and the first line of its text."""
    return f"{type(error).__name__}: {first_line(error)}" if str(error).strip() else type(error).__name__


def setting(default: Any, help: str, **kwargs: Any) -> Any:
    """A config field with its `--help` text."""
    return dataclasses.field(default=default, metadata={"help": help, **kwargs})


def flag(name: str) -> str:
    """The command-line flag of config field `name`, for messages that tell the user what to type."""
    return "--" + name.replace("_", "-")


def check_positive(config: Any, *names: str) -> None:
    """UserError in one line unless each setting `names` of `config` is finite and above 0 (None, unset, passes)."""
    for name in names:
        value = getattr(config, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"{flag(name)} must be positive, got {value}")


def check_non_negative(config: Any, *names: str) -> None:
    """UserError in one line unless each setting `names` of `config` is finite and at least 0 (None passes)."""
    for name in names:
        value = getattr(config, name)
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise UserError(f"{flag(name)} must be >= 0, got {value}")


def check_share(config: Any, name: str) -> None:
    """UserError in one line unless setting `name` of `config` is a share of episodes, in [0, 1] (NaN is not)."""
    value = getattr(config, name)
    if not 0 <= value <= 1:
        raise UserError(f"{flag(name)} must be a share in [0, 1], got {value}")


def config_dict(config: Any) -> dict[str, Any]:
    """Every field of a config dataclass as a JSON value (paths as strings): what a run saves as its config."""
    values = {field.name: getattr(config, field.name) for field in dataclasses.fields(config)}
    return {name: str(value) if isinstance(value, Path) else value for name, value in values.items()}


def config_text(settings: dict[str, Any]) -> str:
    """`settings` as TensorBoard text (Markdown): a code block of indented JSON, which `json.loads` reads back."""
    return "\n".join("    " + line for line in json.dumps(settings, indent=2, default=str).splitlines())


def _parser_type(annotation: Any) -> Callable[[str], Any]:
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):  # `int | None`
        annotation = next(arg for arg in typing.get_args(annotation) if arg is not type(None))
    return {"int": int, "float": float, "str": str, "Path": Path, "bool": _boolean}.get(
        getattr(annotation, "__name__", str(annotation)), str
    )


def _boolean(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected a boolean, got {text!r}")


class _OneLineParser(argparse.ArgumentParser):
    """Bad flags or values get one line (`--help` still prints the usage): the project's rule for bad input."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def parse_config(
    config_class: type[Config], argv: Sequence[str] | None, description: str, prog: str | None = None
) -> Config:
    """Parse `argv` into `config_class`; `--help` lists each field with its default. UserError for a removed flag
    or value (`check_removed`)."""
    check_removed(config_class, sys.argv[1:] if argv is None else argv)
    parser = _OneLineParser(prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    hints = typing.get_type_hints(config_class)
    for field in dataclasses.fields(config_class):
        choices = field.metadata.get("choices")
        parser.add_argument(
            flag(field.name),
            dest=field.name,
            type=_parser_type(hints[field.name]),
            default=field.default,
            choices=choices,
            metavar=field.metadata.get("metavar"),
            help=f"{field.metadata.get('help', '')} (default: {field.default})",
        )
    return config_class(**vars(parser.parse_args(argv)))


def run_cli(
    main: Callable[[Config], Any],
    config_class: type[Config],
    argv: Sequence[str] | None,
    description: str,
    prog: str | None = None,
) -> int:
    """Parse, run `main` (on one BLAS thread: `common.threads`), and turn user errors into one line on stderr and a
    non-zero exit code."""
    one_blas_thread()
    try:
        main(parse_config(config_class, argv, description, prog))
    except UserError as error:
        print(f"error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0
