"""Demonstrations for behaviour cloning: a recorded dataset read in bulk into tensors, split by episode.

Frames come from the parquet files through Arrow (`teleop.dataset_reader.iter_frames`), never
through LeRobot's per-item `__getitem__`. Decoding parquet is the slow part (every row holds a few
hundred list elements, which Arrow's parquet reader decodes slowly, and every episode's metadata
file is read to find the data files). So the decoded float32 arrays are cached as .npy files under
the project's cache folder (`common.paths.cache_dir`), keyed by the dataset's path, its info.json
and the size and modification time of every data file: recording more episodes changes the key.
Later loads copy them out of a memory map, an order of magnitude faster. Measured load speeds:
docs/benchmarks.md, "Behaviour cloning".
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pyarrow as pa
import torch

from common import columns
from common.cli import DatasetError, UserError
from common.paths import cache_dir
from humanoid.conditions import LATENCY_PARAMETER
from humanoid.env import ENV_ID
from rollout.episode import Episode
from students.inputs import INPUT_SETS, computation_digest, episode_inputs, input_set_named
from task.command_fields import VELOCITY_NAMES
from teleop.dataset_reader import fingerprint, iter_frames, read_episodes, read_info, read_parameters
from teleop.lerobot_io.format import CODEBASE_VERSION, INFO_PATH

# The policy's input is computed by its input set (`students.inputs.INPUT_SETS`) along each recorded episode
# (`episode_inputs`), as a rollout runs it: each frame the entries of its `observed_columns`, placed by name in
# `observed_names` order (the gymnasium observation's for "full", whichever way a dataset split it), then the
# frame's action sent (its label, or what ran where another controller labelled: `labelled_by_another`); each episode
# told its recorded delay (`episode_delays`).
_CACHE_FORMAT = 4  # bump when what the cache holds changes
MIN_EPISODES = 2  # the split is by episode, and at least one is held out for validation
_ARRAYS = ("inputs", "actions", "episode_index")
_DECODED = {columns.ACTION: "actions", columns.EXECUTED_ACTION: "executed"}


@dataclass
class Demonstrations:
    """Every committed frame of a dataset as tensors, in index order."""

    root: Path
    inputs: torch.Tensor  # (N, input_dim) float32: what the policy reads (see `input_set_name`)
    actions: torch.Tensor  # (N, action_dim) float32: the label actions
    episode_index: np.ndarray  # (N,) int64
    info: dict[str, Any]
    seconds: float  # time to load, from files to tensors
    from_cache: bool
    fingerprint: str = ""  # `teleop.dataset_reader.fingerprint` of the dataset, taken before reading it
    input_set_name: str = "full"  # students.inputs.INPUT_SETS: which input set `inputs` holds

    @property
    def frames(self) -> int:
        return len(self.actions)

    @property
    def episodes(self) -> list[int]:
        return np.unique(self.episode_index).tolist()

    def identity(self) -> dict[str, Any]:
        """What the checkpoint records about its training data."""
        return {
            "path": str(self.root.resolve()),
            "episodes": len(self.episodes),
            "frames": self.frames,
            "codebase_version": self.info.get("codebase_version"),
            "robot_type": self.info.get("robot_type"),
            "fps": self.info.get("fps"),
            "fingerprint": self.fingerprint,
        }

    def only(self, episodes: list[int]) -> Demonstrations:
        """The frames of `episodes` alone, in the same order."""
        keep = np.isin(self.episode_index, episodes)
        if keep.all():
            return self
        rows = torch.from_numpy(keep)
        return replace(
            self, inputs=self.inputs[rows], actions=self.actions[rows], episode_index=self.episode_index[keep]
        )

    def with_episodes(self, episodes: Sequence[tuple[np.ndarray, np.ndarray, int]]) -> Demonstrations:
        """These frames, then more episodes' (inputs, actions, index), each numbered after every one before it: rows
        in memory, as `load_demonstrations` would read them once the episodes are recorded (`episode_rows`). One
        copy of the aggregate for all of them, not one per episode."""
        if not episodes:
            return self
        last = self.episode_index[-1] if len(self.episode_index) else -1
        for _, _, index in episodes:
            if index <= last:
                raise ValueError(f"episode {index} does not come after episode {last}")
            last = index
        return replace(
            self,
            inputs=torch.cat([self.inputs, *(torch.from_numpy(inputs) for inputs, _, _ in episodes)]),
            actions=torch.cat([self.actions, *(torch.from_numpy(actions) for _, actions, _ in episodes)]),
            episode_index=np.concatenate(
                [self.episode_index, *(np.full(len(actions), index, np.int64) for _, actions, index in episodes)]
            ),
        )


def no_walks(inputs: str, root: Path) -> UserError:
    """The refusal of a walking input set on the dataset at `root`, which commands no walk: it names the recording
    that teaches the set."""
    return UserError(
        f"--inputs {inputs} learns to walk on velocity commands, and {root} commands no walk: record walks "
        f"({input_set_named(inputs).recording}; docs/how-to/walk.md)"
    )


def check_compatible(root: Path, env: gym.Env, inputs: str = "full") -> tuple[dict[str, Any], np.ndarray]:
    """(meta/info.json, where each frame entry sits among the observed columns' entries) of the dataset at
    `root`; DatasetError says in one line why it cannot train a policy on `inputs` for `env`."""
    input_set = input_set_named(inputs)
    if not (root / INFO_PATH).is_file():
        reason = "no such folder" if not root.exists() else f"no {INFO_PATH}"
        raise DatasetError(f"no LeRobot dataset at {root} ({reason}); record one with `make record DATASET={root}`")
    info = read_info(root)
    try:
        features = info["features"]
    except KeyError:
        raise DatasetError(f"{root / INFO_PATH} has no features") from None
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise DatasetError(f"{root} is a LeRobot {info.get('codebase_version')} dataset; this reads {CODEBASE_VERSION}")
    missing = [key for key in (*input_set.columns, columns.ACTION) if key not in features]
    if missing:
        needed = ", ".join((*input_set.columns, columns.ACTION))
        raise DatasetError(f"{root} has no {', '.join(missing)} feature (it needs {needed})")
    recorded_action_dim = features[columns.ACTION]["shape"][0]
    if recorded_action_dim != env.action_space.shape[0]:
        raise DatasetError(
            f"{root} records {recorded_action_dim} action dimensions; {ENV_ID} has {env.action_space.shape[0]}"
        )
    recorded = [name for key in input_set.observed_columns for name in features[key].get("names") or []]
    position = {name: i for i, name in enumerate(recorded)}
    wanted = input_set.observed_names(env.unwrapped.model)
    missing = set(wanted) - position.keys()
    if missing and missing <= set(VELOCITY_NAMES):  # recorded before the velocity fields: it holds no walk
        raise no_walks(inputs, root)
    if missing:
        raise DatasetError(
            f"{root}: its {' + '.join(input_set.observed_columns)} do not name every entry INPUTS={inputs} is computed "
            f"from (recorded before this version? its {columns.OBS_STATE} has "
            f"{features[columns.OBS_STATE]['shape'][0]} "
            f"entries); record a new dataset, or train on it with INPUTS=full if it holds the whole observation"
        )
    index = np.array([position[name] for name in wanted])
    if info.get("total_episodes", 0) < MIN_EPISODES:
        raise DatasetError(
            f"{root} has {info.get('total_episodes', 0)} episodes; training needs at least {MIN_EPISODES} "
            f"(one is held out for validation)"
        )
    return info, index


def _cache_folder(root: Path, info_text: str, inputs: str) -> Path:
    """Where the decoded arrays of this version of the dataset, as `inputs`, live: <path and inputs hash>-<content
    hash>. Each input set keeps its own: PPO's critic reads two sets of the same dataset in turn."""
    files = sorted((root / "data").glob("*/*.parquet"))
    content = json.dumps(
        [
            _CACHE_FORMAT,
            inputs,
            computation_digest(),
            info_text,
            [(str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns) for p in files],
        ]
    )
    path_hash = hashlib.sha256(f"{root.resolve()}\n{inputs}".encode()).hexdigest()[:16]
    return cache_dir() / "bc-frames" / f"{path_hash}-{hashlib.sha256(content.encode()).hexdigest()[:16]}"


def _decode(
    root: Path, info: dict[str, Any], input_columns: tuple[str, ...], index: np.ndarray, ran: bool = False
) -> dict[str, np.ndarray]:
    """The arrays read from the parquet files in float32, rows placed by frame index: the `input_columns`
    side by side, entries ordered by `index`; with `ran`, what ran too ("executed")."""
    features = info["features"]
    rows = info["total_frames"]
    actions = [columns.ACTION, columns.EXECUTED_ACTION] if ran else [columns.ACTION]
    arrays = {
        "inputs": np.empty((rows, len(index)), np.float32),
        **{_DECODED[key]: np.empty((rows, features[key]["shape"][0]), np.float32) for key in actions},
        "episode_index": np.empty(rows, np.int64),
    }
    filled = 0
    for batch in iter_frames(root, [*input_columns, *actions, "episode_index"]):
        frame = batch["index"]
        # Recorded files hold consecutive frames: a slice assigns faster than an index array.
        at = slice(frame[0], frame[-1] + 1) if len(frame) and frame[-1] - frame[0] + 1 == len(frame) else frame
        arrays["inputs"][at] = np.concatenate([batch[key] for key in input_columns], axis=1)[:, index]
        for key in actions:
            arrays[_DECODED[key]][at] = batch[key]
        arrays["episode_index"][at] = batch["episode_index"]
        filled += len(frame)
    if filled != rows:
        raise DatasetError(f"{root} holds {filled} committed frames; its {INFO_PATH} counts {rows}")
    return arrays


def _store(folder: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write the cache folder atomically, and drop older versions of the same dataset's cache of the same inputs."""
    staging: Path | None = None
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=folder.parent, prefix=".partial-"))
        for name in _ARRAYS:
            np.save(staging / f"{name}.npy", arrays[name])
        os.rename(staging, folder)
    except OSError:  # no space, read-only home, or another process wrote it first: the cache is optional
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        return
    path_hash = folder.name.split("-")[0]
    for old in folder.parent.glob(f"{path_hash}-*"):
        if old != folder:
            shutil.rmtree(old, ignore_errors=True)


def cache_demonstrations(demos: Demonstrations) -> None:
    """Put `demos` (every committed frame of its dataset as `load_demonstrations` reads them, rows made elsewhere)
    into the decoded-frames cache, so that the next load of the dataset as these inputs reads them back: DAgger's
    aggregate, whose rows it holds in memory, for PPO's critic."""
    folder = _cache_folder(demos.root, (demos.root / INFO_PATH).read_text(), demos.input_set_name)
    arrays = {"inputs": demos.inputs.numpy(), "actions": demos.actions.numpy(), "episode_index": demos.episode_index}
    _store(folder, arrays)


def load_demonstrations(root: Path, env: gym.Env, cache: bool = True, inputs: str = "full") -> Demonstrations:
    """Every committed frame of the dataset at `root`, checked against `env`, as float32 tensors of `inputs`."""
    start = time.perf_counter()
    info, index = check_compatible(root, env, inputs)
    try:
        digest = fingerprint(root)
    except (OSError, KeyError, ValueError, pa.ArrowException) as error:  # damaged episode metadata
        raise DatasetError(f"cannot read the episode metadata of {root}: {error}") from None
    folder = _cache_folder(root, (root / INFO_PATH).read_text(), inputs)
    from_cache = cache and all((folder / f"{name}.npy").is_file() for name in _ARRAYS)
    if from_cache:
        # Copying out of a memory map is faster than np.load's buffered read, and gives owned, writable arrays.
        arrays = {name: np.array(np.load(folder / f"{name}.npy", mmap_mode="r")) for name in _ARRAYS}
    else:
        try:
            another = labelled_by_another(root)
            arrays = _decode(root, info, INPUT_SETS[inputs].observed_columns, index, ran=bool(another.any()))
            delays = episode_delays(root)[arrays["episode_index"]]
        except (OSError, KeyError, ValueError, pa.ArrowException) as error:  # a damaged or half-copied file
            raise DatasetError(f"cannot read the frames of {root}: {error}") from None
        # The action in flight: the label, or what ran where another controller labelled (DAgger's rounds).
        ran = arrays.pop("executed", arrays["actions"])
        sent = np.where(another[arrays["episode_index"]][:, None], ran, arrays["actions"])
        try:
            arrays["inputs"] = episode_inputs(
                inputs, arrays["inputs"], sent, arrays["episode_index"], delays, env.unwrapped.model
            )
        except UserError as error:  # a delay the input set cannot carry
            raise DatasetError(f"{root}: {error}") from None
        if not (np.isfinite(arrays["inputs"]).all() and np.isfinite(arrays["actions"]).all()):
            raise DatasetError(f"{root} holds non-finite observations or actions")
        if cache:
            _store(folder, arrays)
    return Demonstrations(
        root=root,
        inputs=torch.from_numpy(arrays["inputs"]),
        actions=torch.from_numpy(arrays["actions"]),
        episode_index=arrays["episode_index"],
        info=info,
        seconds=time.perf_counter() - start,
        from_cache=from_cache,
        fingerprint=digest,
        input_set_name=inputs,
    )


def episode_rows(episode: Episode, inputs: str, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(inputs, label actions) of a rolled-out episode, float32, equal bit for bit to the rows `load_demonstrations`
    reads once `teleop.store` has recorded it: DAgger trains on its rounds without reading them back."""
    # The frames as the store records them: split from the whole episode's observations, in float32.
    frames = INPUT_SETS[inputs](model).observe(episode.observation, episode.command).astype(np.float32)
    actions = episode.action.astype(np.float32)
    sent = episode.executed_action.astype(np.float32) if episode.labeller != episode.controller else actions
    delays = np.full(episode.length, episode.parameters.get(LATENCY_PARAMETER, 0), np.int64)
    return episode_inputs(inputs, frames, sent, np.zeros(episode.length, np.int64), delays, model), actions


def labelled_by_another(root: Path) -> np.ndarray:
    """Per committed episode, whether its labels are another controller's than the one that ran (DAgger's rounds):
    the action in flight under latency was then what ran (`executed_action`), not the label."""
    table = read_episodes(root, [columns.EPISODE_CONTROLLER, columns.EPISODE_LABELLER])
    return np.array(
        [row[columns.EPISODE_CONTROLLER] != row[columns.EPISODE_LABELLER] for row in table.to_pylist()], dtype=bool
    )


def episode_delays(root: Path) -> np.ndarray:
    """Each episode's recorded action latency in steps (`make record LATENCY=`; 0 where none was recorded)."""
    return np.array([drawn.get(LATENCY_PARAMETER, 0) for drawn in read_parameters(root)], np.int64)


def split_by_episode(episodes: list[int], val_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """(train, validation) episode indices: a seeded draw of `val_fraction` of them, at least one, for validation."""
    count = min(len(episodes) - 1, max(1, round(val_fraction * len(episodes))))
    validation = np.random.default_rng(seed).choice(episodes, size=count, replace=False)
    return sorted(set(episodes) - set(validation.tolist())), sorted(validation.tolist())
