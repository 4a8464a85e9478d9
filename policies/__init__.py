"""Learned policies and their checkpoint folders.

A checkpoint folder holds `model.safetensors` (weights and normalisation buffers), `config.json`
(the architecture and the training settings) and `dataset.json` (what it was trained on);
`load(path)` rebuilds the policy from it. This module imports no torch: the recorder checks a
controller name with `is_checkpoint` without paying for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from policies.mlp import MLPPolicy

WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
DATASET_FILE = "dataset.json"
EVAL_FILE = "eval.json"


def checkpoint_problem(path: Path) -> str | None:
    """Why `path` is not a checkpoint folder, in one line; None if it has a checkpoint's files.

    Their content is checked by `load`.
    """
    if not path.exists():
        return f"no policy checkpoint at {path}"
    if not ((path / CONFIG_FILE).is_file() and (path / WEIGHTS_FILE).is_file()):
        return f"{path} is not a policy checkpoint (it needs {CONFIG_FILE} and {WEIGHTS_FILE})"
    return None


def is_checkpoint(path: Path) -> bool:
    """Whether `path` is a folder with a checkpoint's files."""
    return checkpoint_problem(path) is None


def load(path: Path | str) -> MLPPolicy:
    """The policy saved in checkpoint folder `path`, in eval mode; CheckpointError if it is not one."""
    from policies.checkpoint import load as load_checkpoint  # noqa: PLC0415 - imports torch

    return load_checkpoint(Path(path))
