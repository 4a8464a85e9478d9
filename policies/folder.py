"""A checkpoint folder's file names and the torch-free check that a folder is one.

The recorder checks a controller name with `is_checkpoint` without paying for torch; the files'
content is read by `policies.checkpoint`.
"""

from __future__ import annotations

from pathlib import Path

WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
DATASET_FILE = "dataset.json"
EVAL_FILE = "eval.json"
SB3_FILE = "sb3_model.zip"
"""A stable-baselines3 policy saved by SB3 itself (`model.save`): the tutorial's PPO baseline (`bc.tutorial`)."""
TENSORBOARD_DIR = "tensorboard"
"""Where a training stage writes its TensorBoard curves, inside the checkpoint folder it makes."""
CONFIG_TAG = "config"
"""The TensorBoard text holding the run's settings (`common.cli.config_text`)."""


def is_sb3_policy(path: Path) -> bool:
    """Whether `path` is a folder holding an SB3-saved policy rather than an `MLPPolicy` checkpoint."""
    return (path / SB3_FILE).is_file()


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
