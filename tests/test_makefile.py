"""`make <stage> VAR=value` is `python -m <stage> --var value`, as pipeline/targets.py's table says, and nothing else.

Every check runs the real `make -n` (which prints the command without running it) with the venv's
install stamp satisfied, so the stage's command line is what `make` would run.
"""

from __future__ import annotations

import importlib
import operator
import os
import re
import shlex
import subprocess
import types
import typing
from pathlib import Path

import pytest

from common.cli import UserError, flag, flat_fields, parse_config
from pipeline.targets import ARGS, TARGETS, Target, help_text

ROOT = Path(__file__).resolve().parent.parent
MAKEFILE = ROOT / "Makefile"


def removed_variables(target: Target) -> dict[str, str]:
    """Removed Make variable -> the removed flag's field name."""
    return {name.upper(): name for name in target.removed}


EVERY_VARIABLE = sorted(
    {var for target in TARGETS.values() for var in (*target.variables, *removed_variables(target))} | {ARGS}
)
PPO_ARGS = "--target-kl 0.01 --learning-rate 1e-4"


@pytest.fixture(scope="module")
def stamp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh file standing in for .venv's install stamp: newer than the lock, so make installs nothing."""
    path = tmp_path_factory.mktemp("make") / "installed"
    path.touch()
    return path


def make_env() -> dict[str, str]:
    """The environment without any stage variable (nor a calling make's), so only the command line sets them."""
    drop = {*EVERY_VARIABLE, "MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES"}
    return {name: value for name, value in os.environ.items() if name not in drop}


def make(*args: str) -> list[str]:
    """Lines printed by `make ARGS` in the project folder."""
    result = subprocess.run(
        ["make", "--no-print-directory", *args], cwd=ROOT, env=make_env(), capture_output=True, text=True, check=True
    )
    return result.stdout.splitlines()


def stage_command(target: str, stamp: Path, **variables: str) -> list[str]:
    """The words after `python -m <module>` and the target's preset flags in what `make -n <target> VAR=value ...`
    would run (they come first)."""
    return full_command(target, stamp, **variables)[len(TARGETS[target].preset) :]


def full_command(target: str, stamp: Path, **variables: str) -> list[str]:
    """The words after `python -m <module>` in what `make -n <target> VAR=value ...` would run: the preset flags
    first."""
    module = TARGETS[target].module
    lines = make("-n", target, f"STAMP={stamp}", *(f"{name}={value}" for name, value in variables.items()))
    commands = [shlex.split(line) for line in lines if f" -m {module}" in line]
    assert len(commands) == 1, lines
    words = commands[0]
    assert words[0].endswith("/bin/python") and words[1:3] == ["-m", module], words
    preset = TARGETS[target].preset_flags
    assert words[3 : 3 + len(preset)] == preset, words
    return words[3:]


def flags_given(words: list[str]) -> dict[str, str]:
    """`--name=value` words as {--name: value}."""
    given = {}
    for word in words:
        name, equals, value = word.partition("=")
        assert name.startswith("--") and equals, f"{word!r} is not --name=value"
        given[name] = value
    return given


def field_type(config: type, field_name: str) -> type:
    """The type of setting `field_name` of `config` (`stage.field`: of a nested stage's config)."""
    stage, _, own = field_name.rpartition(".")
    owner = typing.get_type_hints(config)[stage] if stage else config
    return typing.get_type_hints(owner)[own]


def typed_value(target: Target, field_name: str) -> str:
    """A value of the field's type that differs from its default, as typed on a command line."""
    kind = field_type(target.config, field_name)
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        kind = next(arg for arg in typing.get_args(kind) if arg is not type(None))
    if field_name == "video":
        return "out dir/run.mp4"
    if field_name.endswith("controller"):
        return "random"
    choices = target.field(field_name).metadata.get("choices")
    if choices:  # a value the stage accepts, other than its default if there is one
        return next((choice for choice in choices if choice != target.field(field_name).default), choices[0])
    if kind is bool:
        return "false" if target.field(field_name).default else "true"
    return {int: "7", float: "0.25", Path: f"some dir/{field_name}", str: f"text-{field_name}"}[kind]


def makefile_variables(target: str, kind: str = "VARS") -> set[str]:
    """The variables the Makefile passes to `target`'s stage (its VARS.<target> list, or with `kind` REMOVED its
    REMOVED.<target> list), as make expands it."""
    query = f"print-target-variables: ; @echo $({kind}.{target})"
    (line,) = make("-s", "--eval", query, "print-target-variables")
    return set(line.split())


@pytest.mark.parametrize("target", TARGETS)
def test_the_table_lists_the_variables_the_makefile_passes(target: str) -> None:
    """The Makefile's variable list of each target is the table's: no variable passed that the table does not map."""
    assert makefile_variables(target) == set(TARGETS[target].variables)
    assert makefile_variables(target, "REMOVED") == set(removed_variables(TARGETS[target]))


@pytest.mark.parametrize("target", [name for name, target in TARGETS.items() if target.removed])
def test_a_removed_variable_is_refused_by_its_stage_in_one_line(target: str, stamp: Path) -> None:
    """`make pipeline PPO_FROM=full` reaches the stage, which refuses it naming what to do instead (not make
    ignoring it, nor argparse's "unrecognized arguments")."""
    spec = TARGETS[target]
    for var, field in removed_variables(spec).items():
        assert field not in {name for name, _ in flat_fields(spec.config)}
        words = stage_command(target, stamp, **{var: "value"})
        assert words == [f"{flag(field)}=value"]
        # What an earlier version removed says what replaced it; a setting the pipeline's stages took over names them.
        removed = rf"{flag(field)} was removed; .+ \(docs/decisions/[a-z-]+\.md\)"
        refusal = rf"{removed}|{flag(field)} is a stage's setting here"
        with pytest.raises(UserError, match=rf"^({refusal})"):
            parse_config(spec.config, words, description="")


@pytest.mark.parametrize("target", TARGETS)
def test_the_recipe_passes_only_its_variables(target: str) -> None:
    """Each target's recipe runs its stage with `$(flags)` (its listed variables), plus ARGS for the PPO stages."""
    recipe = re.search(rf"^{re.escape(target)}: .*\n\t(.*)$", MAKEFILE.read_text(), flags=re.MULTILINE)
    assert recipe, f"no recipe for {target}"
    extra = " $(ARGS)" if TARGETS[target].passes_args else ""
    preset = "".join(f"{word} " for word in TARGETS[target].preset_flags)
    assert recipe.group(1) == f"$(PY) -m {TARGETS[target].module} {preset}$(flags){extra}"


@pytest.mark.parametrize("target", TARGETS)
def test_each_variable_becomes_its_flag(target: str, stamp: Path) -> None:
    """With each of its variables set (and ARGS), a target passes each as its flag and value."""
    spec = TARGETS[target]
    own = [*spec.variables, *removed_variables(spec), *([ARGS] if spec.passes_args else [])]
    values = {var: f"value of {var}" for var in own}
    words = stage_command(target, stamp, **values)
    if spec.passes_args:
        assert words[-len(shlex.split(values[ARGS])) :] == shlex.split(values[ARGS])
        words = words[: -len(shlex.split(values[ARGS]))]
    passed = {**spec.variables, **removed_variables(spec)}
    assert flags_given(words) == {flag(field): values[var] for var, field in passed.items()}


@pytest.mark.parametrize("target", TARGETS)
def test_a_variable_the_target_does_not_take_is_refused_in_one_line(target: str, stamp: Path) -> None:
    """Another target's variable, or a typo (EPOCH for EPOCHS): make stops in one line naming it, and runs nothing."""
    spec = TARGETS[target]
    own = {*spec.variables, *removed_variables(spec), *([ARGS] if spec.passes_args else [])}
    for var in [next(var for var in EVERY_VARIABLE if var not in own), "EPOCH", *([] if spec.passes_args else [ARGS])]:
        result = subprocess.run(
            ["make", "--no-print-directory", "-n", target, f"STAMP={stamp}", f"{var}=1"],
            cwd=ROOT,
            env=make_env(),
            capture_output=True,
            text=True,
        )
        assert result.returncode == 2 and result.stdout == "", result
        (line,) = result.stderr.splitlines()
        refusal = rf"Makefile:\d+: \*\*\* make {target} takes no {var}; its variables: make help\.  Stop\."
        assert re.fullmatch(refusal, line), line


def test_a_make_run_by_another_passes_on_the_variables_it_does_not_take(stamp: Path) -> None:
    """A wrapper Makefile's command-line variables reach every target it makes (MAKELEVEL 1): not refused there."""
    result = subprocess.run(
        ["make", "--no-print-directory", "-n", "train-bc", f"STAMP={stamp}", "EPOCH=1"],
        cwd=ROOT,
        env={**make_env(), "MAKELEVEL": "1"},
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0 and result.stdout.strip().endswith("-m bc.train"), result


@pytest.mark.parametrize("target", TARGETS)
def test_unset_variables_pass_nothing(target: str, stamp: Path) -> None:
    """With no variable set the stage runs bare, so every setting is its config's default."""
    assert stage_command(target, stamp) == []


@pytest.mark.parametrize("target", TARGETS)
def test_one_variable_passes_one_flag(target: str, stamp: Path) -> None:
    """Setting one variable passes that flag alone: the others stay unset, at the stage's defaults."""
    for var, field in TARGETS[target].variables.items():
        value = typed_value(TARGETS[target], field)
        assert stage_command(target, stamp, **{var: value}) == [f"{flag(field)}={value}"]


@pytest.mark.parametrize("target", TARGETS)
def test_make_command_parses_into_the_stage_config(target: str, stamp: Path) -> None:
    """The flags make passes are fields of the stage's config, and parse into it with the values given."""
    spec = TARGETS[target]
    module = importlib.import_module(spec.module)
    assert getattr(module, spec.config.__name__) is spec.config
    values = {var: typed_value(spec, field) for var, field in spec.variables.items()}
    config = parse_config(spec.config, stage_command(target, stamp, **values), description="")
    expected = parse_config(spec.config, [f"{flag(field)}={values[var]}" for var, field in spec.variables.items()], "")
    for field in spec.fields:
        value = operator.attrgetter(field)  # `stage.field` reads a nested stage's setting
        assert value(config) == value(expected), field
        if len(spec.field(field).metadata.get("choices") or "..") > 1:  # else no other value exists
            assert value(config) != value(spec.config()), field


@pytest.mark.parametrize("target", [name for name, target in TARGETS.items() if target.preset])
def test_a_preset_is_the_default_and_a_variable_overrides_it(target: str, stamp: Path) -> None:
    """`make play` is the recorder with its preset (the keyboard, datasets/play, no noise); DATASET=x still wins."""
    spec = TARGETS[target]
    bare = parse_config(spec.config, full_command(target, stamp), description="")
    preset = parse_config(spec.config, spec.preset_flags, description="")
    for field, _ in spec.preset:
        assert getattr(bare, field) == getattr(preset, field) != spec.field(field).default, field
    for var, field in spec.variables.items():
        if field in dict(spec.preset):
            value = typed_value(spec, field)
            given = parse_config(spec.config, full_command(target, stamp, **{var: value}), description="")
            assert getattr(given, field) == getattr(parse_config(spec.config, [f"{flag(field)}={value}"], ""), field)


@pytest.mark.parametrize("target", ["finetune-rl", "scratch-rl"])
def test_args_reach_the_ppo_stages_as_typed(target: str, stamp: Path) -> None:
    """ARGS are appended word for word: any other flag of the PPO stage."""
    assert stage_command(target, stamp, ARGS=PPO_ARGS, TIMESTEPS="5") == ["--timesteps=5", *shlex.split(PPO_ARGS)]


def test_the_makefile_types_no_default() -> None:
    """No stage variable gets a value in the Makefile: the defaults are the stage configs' alone."""
    assigned = re.findall(r"^(?:export +)?([A-Z_][A-Z0-9_]*) *[:?+!]?=", MAKEFILE.read_text(), flags=re.MULTILINE)
    assert set(assigned) & set(EVERY_VARIABLE) == set()


def test_help_lists_each_targets_variables_with_flag_help_and_default() -> None:
    """`make help`'s table names, for every target, each variable's flag, its help and the config's default."""
    text = help_text(width=1000)  # unwrapped: one line per variable
    for name, target in TARGETS.items():
        command = " ".join([f"python -m {target.module}", *target.preset_flags])
        section = text.split(f"  make {name} ({command}):\n")[1].split("\n  make ")[0]
        for var, field_name in target.variables.items():
            field = target.field(field_name)
            line = next(line for line in section.splitlines() if line.split()[0] == var)
            assert line.split()[1] == flag(field_name) and field.metadata["help"] in line
            assert f"(default: {target.default(field_name)})" in line or "default:" in field.metadata["help"]


def test_make_help_prints_the_table(stamp: Path) -> None:
    """`make help` lists the targets, then the table (from .venv)."""
    lines = make("help")
    assert any(line.startswith("  make pipeline ") for line in lines)
    assert "    DATASET" in "\n".join(lines) and "--scratch-policy" in "\n".join(lines)


@pytest.mark.parametrize("target", TARGETS)
def test_every_stage_prints_its_help(target: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`python -m <stage> --help` exits 0 and lists the stage's flags (help texts are %-formatted by argparse)."""
    with pytest.raises(SystemExit) as exit_info:
        importlib.import_module(TARGETS[target].module).cli(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage:") and all(flag(field) in out for field in TARGETS[target].fields)
