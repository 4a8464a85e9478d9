"""A checkpoint folder's file names, the torch-free check that a folder is one, and what a run recorded there.

The recorder checks a controller name with `is_checkpoint` without paying for torch; the weights are read by
`policies.checkpoint`, the settings a run recorded by `training_settings`, which every stage that reuses a finished
run reads (`finished_with`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

from common.cli import UserError
from common.paths import NEWEST

WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
DATASET_FILE = "dataset.json"
EVAL_FILE = "eval.json"
SB3_FILE = "sb3_model.zip"
"""A stable-baselines3 policy saved by SB3 itself (`model.save`): the tutorial's PPO baseline (`rl.tutorial`)."""
LEARNING_CURVE_FILE = "learning_curve.png"
"""The training stage's learning curve as a figure (BC's losses, PPO's validation returns), in the checkpoint folder."""
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


def damage(path: Path) -> str | None:
    """Why checkpoint folder `path`'s files cannot load, in one line, read without torch (a process that only records
    checks a policy before its workers load it); None if they look whole."""
    if not json_object(path / CONFIG_FILE):
        return f"{path / CONFIG_FILE} is empty or no JSON object: the checkpoint is damaged, train it again"
    if not weights_whole(path / WEIGHTS_FILE):
        return f"{path / WEIGHTS_FILE} is cut short or not safetensors: the checkpoint is damaged, train it again"
    return None


def weights_whole(path: Path) -> bool:
    """Whether `path` is a whole safetensors file, read without torch: an 8-byte header length, the JSON header, and
    exactly the bytes its tensors' offsets end at (a copy cut short, or another file, is not)."""
    try:
        size = path.stat().st_size
        with path.open("rb") as stream:
            length = int.from_bytes(stream.read(8), "little")
            if size < 8 + length:
                return False
            header = json.loads(stream.read(length))
        ends = [entry["data_offsets"][1] for name, entry in header.items() if name != "__metadata__"]
        return size == 8 + length + max(ends, default=0)
    except (OSError, ValueError, TypeError, KeyError, IndexError, AttributeError):
        return False


def is_checkpoint(path: Path) -> bool:
    """Whether `path` is a folder with a checkpoint's files."""
    return checkpoint_problem(path) is None


def json_object(path: Path) -> dict[str, Any]:
    """The JSON object in `path`; {} if it is missing, unreadable or not an object (an older version's, a kill's)."""
    try:
        content = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return content if isinstance(content, dict) else {}


def training_settings(path: Path) -> dict[str, Any]:
    """The settings the run that made checkpoint folder `path` recorded (config.json's "training"); {} if none."""
    training = json_object(path / CONFIG_FILE).get("training")
    return training if isinstance(training, dict) else {}


def finished_with(path: Path, settings: dict[str, Any], ignored: Collection[str] = ()) -> bool:
    """Whether `path` holds a finished run (its eval.json written) that recorded `settings`, those named in
    `ignored` aside: what a stage asked for the same run again reuses rather than runs."""
    if not (path / EVAL_FILE).is_file():
        return False
    saved = training_settings(path)
    return all(saved.get(name) == value for name, value in settings.items() if name not in ignored)


def newest(candidates: Sequence[Path]) -> Path | None:
    """The candidate checkpoint folder whose weights were written last; None where none is a checkpoint."""
    found = [path for path in candidates if is_checkpoint(path)]
    return max(found, key=lambda path: (path / WEIGHTS_FILE).stat().st_mtime_ns, default=None)


def chosen_policy(policy: str, candidates: Sequence[Path], maker: str) -> str:
    """`policy` as given, or where it is `common.paths.NEWEST` the newest checkpoint among `candidates`, which a line on
    stderr names; UserError in one line where none of them is there yet (`maker`: the command that makes one)."""
    if policy != NEWEST:
        return policy
    found = newest(candidates)
    listed = ", ".join(map(str, candidates))
    if found is None:
        raise UserError(f"no policy checkpoint yet at {listed}: {maker} makes one")
    print(f"policy: {found}, the newest of {listed}", file=sys.stderr, flush=True)
    return str(found)
