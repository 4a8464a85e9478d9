"""The Makefile's folders and the stages' own defaults agree, so `make X` and `python -m X` do the same."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

from bc.baseline import BaselineConfig
from bc.finetune import FinetuneConfig
from bc.train import TrainConfig
from teleop.record import RecordConfig

MAKEFILE = Path(__file__).resolve().parent.parent / "Makefile"


def make_default(variable: str) -> str:
    """The `VARIABLE ?= value` (or `:=`) default in the Makefile."""
    match = re.search(rf"^{variable} [?:]= *(\S*)$", MAKEFILE.read_text(), flags=re.MULTILINE)
    assert match, f"{variable} has no default in the Makefile"
    return match.group(1)


def test_dataset_and_policy_defaults_match_the_stages() -> None:
    """The Makefile's dataset and checkpoint folders are those the stages use when called directly."""
    assert Path(make_default("DATASET")) == RecordConfig().dataset == TrainConfig().dataset
    assert Path(make_default("BC_DEFAULT")) == TrainConfig().policy == FinetuneConfig().bc_policy
    assert Path(make_default("PPO_DEFAULT")) == FinetuneConfig().policy
    assert Path(make_default("SCRATCH_DEFAULT")) == BaselineConfig().policy


@pytest.mark.parametrize(
    "module", ["teleop.record", "teleop.inspect_dataset", "bc.train", "bc.evaluate", "bc.dagger", "bc.finetune"]
)
def test_every_stage_prints_its_help(module: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`python -m <stage> --help` exits 0 and lists the stage's flags (help texts are %-formatted by argparse)."""
    with pytest.raises(SystemExit) as exit_info:
        importlib.import_module(module).cli(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage:") and "--help" in out
