"""The Makefile's folders and the stages' own defaults agree, so `make X` and `python -m X` do the same."""

from __future__ import annotations

import re
from pathlib import Path

from bc.train import TrainConfig
from teleop.record import RecordConfig

MAKEFILE = Path(__file__).resolve().parent.parent / "Makefile"


def make_default(variable: str) -> str:
    """The `VARIABLE ?= value` default in the Makefile."""
    match = re.search(rf"^{variable} \?= *(\S*)$", MAKEFILE.read_text(), flags=re.MULTILINE)
    assert match, f"{variable} has no default in the Makefile"
    return match.group(1)


def test_dataset_and_policy_defaults_match_the_stages() -> None:
    """DATASET and POLICY default to the folders record and train-bc use when called directly."""
    assert Path(make_default("DATASET")) == RecordConfig().dataset == TrainConfig().dataset
    assert Path(make_default("POLICY")) == TrainConfig().policy
