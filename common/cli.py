"""Command lines built from a stage's config dataclass: one flag per field, its help from the field.

Every stage declares its settings once, as a dataclass whose fields carry `help` metadata; the
flags, their defaults in `--help`, and the Makefile variables all follow from it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

Config = TypeVar("Config")

EXIT_FAILURE = 1


class UserError(Exception):
    """A mistake in the user's input or environment: reported as one line, without a traceback."""


class DatasetError(UserError):
    """A dataset folder that cannot be used as asked (missing, incompatible, locked, unwritable)."""


def one_line(error: BaseException) -> str:
    """An exception as one line of a message: its type and the first line of its text."""
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def setting(default: Any, help: str, **kwargs: Any) -> Any:
    """A config field with its `--help` text."""
    return dataclasses.field(default=default, metadata={"help": help, **kwargs})


def flag(name: str) -> str:
    """The command-line flag of config field `name`, for messages that tell the user what to type."""
    return "--" + name.replace("_", "-")


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
    """Parse `argv` into `config_class`; `--help` lists each field with its default."""
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
    """Parse, run `main`, and turn user errors into one line on stderr and a non-zero exit code."""
    config = parse_config(config_class, argv, description, prog)
    try:
        main(config)
    except UserError as error:
        print(f"error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0
