"""Command lines built from a stage's config dataclass: one flag per field, its help from the field.

Every stage declares its settings once, as a dataclass whose fields carry `help` metadata; the
flags, their defaults in `--help`, and the Makefile variables all follow from it. A flag or value that
an earlier version had and this one removed is refused here, for every stage, in one line that says what
to use instead (`REMOVED_FLAGS`, `REMOVED_VALUES`), before anything is read or written.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import json
import math
import sys
import types
import typing
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from common.files import write_atomically
from common.seed_ranges import RUN_SEED_LIMIT
from common.threads import PINNED, one_blas_thread, unpinned

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
_OPERATOR = Removed(
    "controller 'operator'",
    "every stage follows the operator's schedules by default (TASK=posture); the expert told the simulator's state "
    "under them: expert",
    "pipeline-task",
)

REMOVED_FLAGS: dict[str, Removed] = {
    removed.what[2:].replace("-", "_"): removed
    for removed in (
        Removed(
            "--ppo-from",
            "the PPO stages start from the DAgger student; for a PPO run from another: make finetune-rl BC_POLICY=...",
            "ppo-start",
        ),
        Removed(
            "--deployable",
            "the pipeline's students read only what a robot senses (PPO starts from one of them)",
            "ppo-start",
        ),
        Removed(
            "--odometry-inputs",
            "the pipeline's students read INPUTS=pending+ramp; for another: make train-bc INPUTS=...",
            "pipeline-task",
        ),
        Removed("--tutorial", "the seed tutorial's learners run apart: make tutorial-rl", "pipeline-task"),
        Removed(
            "--proprio-policy",
            "the pipeline records the operator's demonstrations only; BC on the privileged expert's sensed features: "
            "make record CONTROLLER=expert, then make train-bc INPUTS=proprio",
            "pipeline-task",
        ),
        Removed(
            "--sensed-dataset",
            "the pipeline records one dataset, RECORD.DATASET (the expert on leg odometry)",
            "pipeline-task",
        ),
        Removed("--sensed-noise", "RECORD.NOISE is the pipeline's one recording's DART noise", "pipeline-task"),
        Removed("--sensed-latency", "RECORD.LATENCY is the pipeline's one recording's delayed share", "pipeline-task"),
        Removed("--odometry-policy", "BC.POLICY is the pipeline's student on what a robot senses", "pipeline-task"),
        Removed("--schedules", "give --task (TASK=stand|posture|walk; SCHEDULES=0 is TASK=stand)", "task-setting"),
        Removed("--walking", "give --task (TASK=stand|posture|walk; WALKING=1 is TASK=walk)", "task-setting"),
    )
}
"""Flags and Make variables an earlier version had (the Makefile's REMOVED.<target> still passes them, which Make would
otherwise ignore): refused in one line naming what to use instead, by every stage that no longer has them. Other flags
that went are refused by argparse itself, in one line too."""

REMOVED_VALUES: dict[tuple[str, str], Removed] = {
    ("controller", "expert-adaptive"): _ADAPTIVE,  # make record
    ("policy", "expert-adaptive"): _ADAPTIVE,  # make eval, make robustness
    ("expert", "expert-adaptive"): _ADAPTIVE,  # make dagger
    ("controller", "operator"): _OPERATOR,  # make record
    ("policy", "operator"): _OPERATOR,  # make eval, make robustness
    # make train-bc, make dagger; students.inputs.removed_inputs refuses it from a checkpoint too
    ("inputs", "odometry"): Removed(
        "inputs 'odometry'", "use pending: the same inputs, then the command in flight and the delay", "pending-inputs"
    ),
    ("inputs", "proprio+command"): Removed(
        "inputs 'proprio+command'",
        "use pending+command (with the leg odometry, which standing needs) or pending+ramp, the students' default",
        "command-features",
    ),
}
"""Values removed from a flag that stays, by (config field name, value)."""


def check_removed(config_class: type, argv: Sequence[str]) -> None:
    """UserError in one line for a removed flag or value in `argv` (`--name value` or `--name=value`), naming what
    to use instead: argparse's own "unrecognized arguments" would not say it. For a config that nests stages'
    configs, also for a stage's flag given without its stage (`--epochs`, `--dagger-epochs`): which to use."""
    fields = {name for name, _ in flat_fields(config_class)}
    suggested = fields - getattr(config_class, "TIED", frozenset())  # a nesting config's settings it sets itself
    for index, word in enumerate(argv):
        if not word.startswith("--"):
            continue
        text, equals, value = word[2:].partition("=")
        name = text.replace("-", "_")
        if name not in fields:
            if name in REMOVED_FLAGS:
                raise UserError(REMOVED_FLAGS[name].message())
            nested = [field for field in suggested if name in (field.rpartition(".")[2], field.replace(".", "_"))]
            if nested:
                flags = [flag(field) for field in sorted(nested)]
                listed = " or ".join([", ".join(flags[:-1]), flags[-1]] if len(flags) > 2 else flags)
                raise UserError(f"{flag(name)} is a stage's setting here: {listed} (`make help` lists Make's names)")
            continue
        if not equals:
            value = argv[index + 1] if index + 1 < len(argv) else ""
        own_name = name.rpartition(".")[2]  # a nested stage's `--record.controller` is its stage's `--controller`
        if (own_name, value) in REMOVED_VALUES:
            raise UserError(REMOVED_VALUES[own_name, value].message())


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
    """The command-line flag of config field `name` (`stage.field` for a nested stage's), for messages that tell the
    user what to type."""
    return "--" + name.replace("_", "-")


def flat_fields(config_class: type, prefix: str = "") -> list[tuple[str, dataclasses.Field[Any]]]:
    """(name, field) of every setting of `config_class`, a nested stage's as `stage.field`, in order."""
    out = []
    hints = typing.get_type_hints(config_class)
    for field in dataclasses.fields(config_class):
        if dataclasses.is_dataclass(hints[field.name]):
            out += flat_fields(hints[field.name], f"{prefix}{field.name}.")
        else:
            out.append((prefix + field.name, field))
    return out


def field_default(config_class: type, name: str) -> Any:
    """The default of setting `name` of `config_class` (`stage.field` for a nested stage's: that stage's default as the
    config nests it)."""
    stage, _, rest = name.partition(".")
    field = next(f for f in dataclasses.fields(config_class) if f.name == stage)
    default = field.default_factory() if field.default is dataclasses.MISSING else field.default
    return getattr(default, rest) if rest else default


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


def check_seed(config: Any, *names: str) -> None:
    """UserError in one line unless each setting `names` of `config` is a seed: an integer in [0, 2**32)."""
    for name in names:
        value = getattr(config, name)
        if not 0 <= value < RUN_SEED_LIMIT:
            raise UserError(f"{flag(name)} must be a seed, at least 0 and below 2**32, got {value}")


def check_file(config: Any, name: str, suffix: str) -> None:
    """UserError in one line unless setting `name` of `config` (a path; None passes) names a `suffix` file: a path
    ending so that is not a folder (an output's: a video, a figure)."""
    path = getattr(config, name)
    if path is not None and (path.suffix.lower() != suffix or path.is_dir()):
        raise UserError(f"{flag(name)} must be a {suffix} file's path, got {path}")


def check_share(config: Any, name: str) -> None:
    """UserError in one line unless setting `name` of `config` is a share of episodes, in [0, 1] (NaN is not)."""
    value = getattr(config, name)
    if not 0 <= value <= 1:
        raise UserError(f"{flag(name)} must be a share in [0, 1], got {value}")


Range = tuple[float, float]
"""A parameter's (low, high)."""


def assignments(text: str, where: str) -> Iterator[tuple[str, str, str, str]]:
    """The items of `text`, a list NAME=VALUE,...: (the item, NAME, "=" or "" where it has none, VALUE), each stripped;
    what each NAME and VALUE may be is the caller's to check. ValueError, one line starting with `where` (the flag and
    its text), for a NAME given twice."""
    seen: set[str] = set()
    for item in (part.strip() for part in text.strip().split(",")):
        name, equals, value = (part.strip() for part in item.partition("="))
        if name in seen:
            raise ValueError(f"{where}: {name} is given twice")
        seen.add(name)
        yield item, name, equals, value


def parse_ranges(
    text: str, names: Sequence[str], where: str, example: str, check: Callable[[str, Range], None]
) -> dict[str, Range]:
    """`text`, a list NAME=LOW:HIGH,... of some of `names`, as {NAME: (LOW, HIGH)}, each range passed by `check`
    (which raises ValueError saying which rule it breaks). ValueError, one line starting with `where` (the flag and
    its text), for a malformed item, an unknown or repeated NAME, or a broken rule; `example` shows the form."""
    ranges: dict[str, Range] = {}
    for item, name, _, bounds in assignments(text, where):
        low_text, colon, high_text = bounds.partition(":")
        if not name or not colon:
            raise ValueError(f"{where}: {item!r} is not NAME=LOW:HIGH (e.g. {example})")
        if name not in names:
            raise ValueError(f"{where}: unknown parameter {name!r}; parameters: {', '.join(names)}")
        try:
            low, high = float(low_text), float(high_text)
        except ValueError:
            raise ValueError(f"{where}: {item!r} is not NAME=LOW:HIGH with numbers LOW and HIGH") from None
        try:
            check(name, (low, high))
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
        ranges[name] = (low, high)
    return ranges


def config_dict(config: Any) -> dict[str, Any]:
    """Every field of a config dataclass as a JSON value (paths as strings, a nested stage's config as its own dict):
    what a run saves as its config."""
    return {field.name: _json_value(getattr(config, field.name)) for field in dataclasses.fields(config)}


def _json_value(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return config_dict(value)
    return str(value) if isinstance(value, Path) else value


def json_text(content: Any, indent: int | None = None) -> str:
    """`content` as strict JSON, what a run prints and saves: a number that is not finite (NaN: the error of a field no
    settled command asked for, `task.tracking.tracking_summary`) written as null, since the JSON standard has no NaN
    and strict readers (JavaScript's `JSON.parse`, for one) refuse Python's `NaN`; what JSON cannot hold, by its str."""
    return json.dumps(_finite(content), indent=indent, default=str, allow_nan=False)


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    return value


def write_json(path: Path, content: Any, indent: int = 2) -> None:
    """Write `content` as strict JSON (`json_text`) to `path` through a file beside it, renamed: a kill leaves the old
    file or the new one, never half of it (a checkpoint's eval.json, the walker's gait: what a later run trusts)."""
    write_atomically(path, lambda partial: partial.write_text(json_text(content, indent) + "\n"))


def counted(count: int, noun: str) -> str:
    """`count` and `noun`, plural unless it is one: "1 episode", "3 episodes"."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


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
    for name, field in flat_fields(config_class):
        stage, _, own = name.rpartition(".")
        owner = typing.get_type_hints(config_class)[stage] if stage else config_class
        default = field_default(config_class, name)
        parser.add_argument(
            flag(name),
            dest=name,
            type=_parser_type(typing.get_type_hints(owner)[own]),
            default=default,
            choices=field.metadata.get("choices"),
            metavar=field.metadata.get("metavar"),
            help=f"{field.metadata.get('help', '')} (default: {default})",
        )
    return _build(config_class, vars(parser.parse_args(argv)))


def _build(config_class: type[Config], values: dict[str, Any]) -> Config:
    """`config_class` from flat `values` (`stage.field` for a nested stage's), each stage built on its default."""
    hints = typing.get_type_hints(config_class)
    settings: dict[str, Any] = {}
    for field in dataclasses.fields(config_class):
        if dataclasses.is_dataclass(hints[field.name]):
            own = {name.partition(".")[2]: value for name, value in values.items() if name.startswith(field.name + ".")}
            settings[field.name] = dataclasses.replace(field_default(config_class, field.name), **own)
        else:
            settings[field.name] = values[field.name]
    return config_class(**settings)


PLACE_ERRORS = frozenset(
    {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EISDIR, errno.ENOTDIR, errno.EEXIST}
)
"""What the disk says of a place given (unwritable, read-only, full, a file for a folder): one line naming the path,
not a traceback; other OS errors are a defect's and keep theirs."""


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
    why = unpinned()
    if why:
        print(
            f"note: {why}: results may differ from the README's (`make` sets "
            f"{' '.join(f'{name}={value}' for name, value in PINNED.items())}: docs/decisions/cpu-kernels.md)",
            file=sys.stderr,
        )
    try:
        main(parse_config(config_class, argv, description, prog))
    except UserError as error:
        print(f"error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except OSError as error:
        if error.errno not in PLACE_ERRORS:
            raise
        print(f"error: {error.filename}: {error.strerror}" if error.filename else f"error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0
