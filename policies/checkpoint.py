"""Saving a policy to a checkpoint folder and rebuilding it from one (robomimic style: one call).

    POLICY/
      model.safetensors   weights and buffers: input mean/std, action bounds
      config.json         format, the policy's spec, the training settings
      dataset.json        the dataset's identity: path, episodes, frames, the split

A checkpoint is written into a hidden sibling folder and renamed into place only once complete,
so an interrupted or failed run never leaves a half-written checkpoint nor destroys the old one; the
folder a killed run leaves is removed by the next run for the same checkpoint.
"""

from __future__ import annotations

import dataclasses
import fcntl
import glob
import json
import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from safetensors import SafetensorError
from safetensors.torch import load_file
from safetensors.torch import save as save_weights

from common.cli import UserError, first_line, write_json
from common.files import PARTIAL_SUFFIX
from common.workers import owner_gone, process_owner
from policies.folder import CONFIG_FILE, DATASET_FILE, WEIGHTS_FILE, checkpoint_problem, is_checkpoint, is_sb3_policy
from policies.mlp import MLPPolicy, MLPSpec

FORMAT = "humanoid-bc/policy"
FORMAT_VERSION = 1
POLICY_CLASSES = {"MLPPolicy": (MLPPolicy, MLPSpec)}


class CheckpointError(UserError):
    """A folder that is not a usable checkpoint, or a checkpoint that may not be replaced."""


def save(policy: MLPPolicy, folder: Path, training: dict[str, Any], dataset: dict[str, Any]) -> None:
    """Write the checkpoint files of `policy` into `folder` (see `staged` for putting it in place)."""
    policy_config = {"class": type(policy).__name__, **dataclasses.asdict(policy.spec)}
    try:
        folder.mkdir(parents=True, exist_ok=True)
        # Bytes written here rather than by save_file, which creates the file with mode 0600.
        weights = {name: t.contiguous() for name, t in policy.state_dict().items()}
        (folder / WEIGHTS_FILE).write_bytes(save_weights(weights, metadata={"format": FORMAT}))
        write_json(
            folder / CONFIG_FILE,
            {"format": FORMAT, "version": FORMAT_VERSION, "policy": policy_config, "training": training},
        )
        write_json(folder / DATASET_FILE, dataset)
    except OSError as error:  # disk full, permissions
        raise CheckpointError(f"cannot write the checkpoint to {folder}: {error.strerror or error}") from None


def read_config(path: Path) -> dict[str, Any]:
    """config.json of checkpoint folder `path`, checked to be this project's format."""
    problem = checkpoint_problem(path)
    if problem:
        raise CheckpointError(problem)
    try:
        config = json.loads((path / CONFIG_FILE).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise CheckpointError(f"{path / CONFIG_FILE} is unreadable: {error}") from None
    if not isinstance(config, dict) or config.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} checkpoint (its {CONFIG_FILE} has another format)")
    if config.get("version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path} has checkpoint version {config.get('version')}; this code reads {FORMAT_VERSION}"
        )
    return config


def load(path: Path) -> MLPPolicy:
    """The policy in checkpoint folder `path`, in eval mode, with its saved weights and buffers."""
    config = read_config(path)
    try:
        policy_config = dict(config["policy"])
        policy_class, spec_class = POLICY_CLASSES[policy_config.pop("class")]
        policy = policy_class(spec_class.from_dict(policy_config))
        policy.load_state_dict(load_file(path / WEIGHTS_FILE))
    except (KeyError, TypeError, ValueError, RuntimeError, SafetensorError, OSError) as error:
        # load_state_dict's message spans many lines; the first says what is wrong.
        raise CheckpointError(f"{path} is not a loadable checkpoint: {first_line(error)}") from None
    return policy.eval()


def check_replaceable(path: Path, overwrite: bool) -> None:
    """Refuse, before any work, to write a checkpoint where one may not go."""
    if not path.exists():
        return
    if not (is_checkpoint(path) or is_sb3_policy(path)):
        raise CheckpointError(f"{path} exists and is not a policy checkpoint: refusing to replace it")
    if not overwrite:
        raise CheckpointError(
            f"{path} already holds a checkpoint; pass --overwrite true (OVERWRITE=1 with make) to replace it"
        )


def running_folder(path: Path) -> Path:
    """Where a resumable run that will become `path` keeps its work until it finishes (`running`)."""
    return path.parent / f".{path.name}.running"


@contextmanager
def running(path: Path, overwrite: bool) -> Iterator[Path]:
    """Like `staged`, but the folder is always the same one and survives a failure or a kill, so that the run
    can resume from what it holds (`rl.resume`); it becomes `path` when the block succeeds. One run at a time holds
    it (a lock the kernel drops with the process, kill -9 too): another, started while it runs, is refused in one
    line rather than resuming from files being written."""
    folder = running_folder(path)
    created = not folder.exists()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = os.open(folder, os.O_RDONLY)
    except OSError as error:
        raise CheckpointError(f"cannot write a checkpoint in {path.parent}: {error.strerror or error}") from None
    try:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise CheckpointError(
                f"another run is writing {path} now (in {folder}): wait for it to end, or give another folder"
            ) from None
        try:
            _recover(path)
            check_replaceable(path, overwrite)
        except CheckpointError:
            if created:
                folder.rmdir()  # this refusal made it: it leaves nothing behind
            raise
        yield folder
        _publish(folder, path, overwrite)
    finally:
        os.close(lock)


def _replaced(path: Path) -> Path:
    """Where `_publish` moves the checkpoint it replaces until the new one is in place."""
    return path.parent / f".{path.name}.replaced"


def _recover(path: Path) -> None:
    """Undo what a kill inside `_publish` left: the replaced checkpoint back at `path` if nothing took its place, else
    removed (the new one was in place)."""
    replaced = _replaced(path)
    if replaced.is_dir():
        if path.exists():
            shutil.rmtree(replaced)
        else:
            replaced.rename(path)


def _publish(folder: Path, path: Path, overwrite: bool) -> None:
    """Rename the finished `folder` to `path`, replacing what is there only if that may be replaced."""
    _recover(path)
    check_replaceable(path, overwrite)  # something may have appeared there in the meantime
    if path.exists():
        replaced = _replaced(path)
        path.rename(replaced)
        folder.rename(path)
        shutil.rmtree(replaced)
    else:
        folder.rename(path)


def _remove_abandoned(path: Path) -> None:
    """Remove the staging folders of `path` (`staged`) whose run is gone (killed before it could clean up): those of
    a process of this machine that no longer runs. Another machine's, a live run's, or an unnamed one stays."""
    prefix = f".{path.name}."
    for folder in path.parent.glob(f"{glob.escape(prefix)}*{PARTIAL_SUFFIX}"):
        if owner_gone(folder.name.removeprefix(prefix).removesuffix(PARTIAL_SUFFIX).rpartition(".")[0]):
            shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def staged(path: Path, overwrite: bool) -> Iterator[Path]:
    """A fresh hidden folder beside `path` to write into (named after its owner: `_remove_abandoned`); it becomes
    `path` when the block succeeds."""
    _recover(path)
    check_replaceable(path, overwrite)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _remove_abandoned(path)
        # Not tempfile.mkdtemp: its 0700 mode would stay on the published checkpoint.
        staging = path.parent / f".{path.name}.{process_owner()}.{uuid.uuid4().hex[:8]}{PARTIAL_SUFFIX}"
        staging.mkdir()
    except OSError as error:
        raise CheckpointError(f"cannot write a checkpoint in {path.parent}: {error.strerror or error}") from None
    try:
        yield staging
        _publish(staging, path, overwrite)
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # still there only if the block failed
