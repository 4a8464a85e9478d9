"""Reading a recorded dataset back in bulk: LeRobot frames as NumPy arrays, MCAP steps decoded.

LeRobot's per-item access (`LeRobotDataset[i]`) reads a few thousand rows a second; training and
checks need whole columns, so this reads the parquet files with Arrow directly, limited to the
committed episodes that meta/info.json counts.
"""

from __future__ import annotations

import hashlib
import json
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas  # noqa: F401 - pyarrow imports it on its first conversion to NumPy: pay it at import, not mid-load
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from common import columns
from common.cli import DatasetError
from common.lerobot_stats import QUANTILES, quantile_key
from humanoid.sensors import observation_index
from task.command_fields import COMMAND_NAMES, COMMAND_SIZE, field_positions
from teleop.lerobot_io.format import (
    EPISODES_DIR,
    data_file,
    episode_files,
    read_info,
    unflatten_stats,
    video_file,
    video_keys,
)
from teleop.mcap_io.writer import FINAL_TOPIC, STEP_TOPIC

PARALLEL_FILES = 2  # parquet files decoded at once: Arrow releases the GIL, so one per core


def _read_parquet(path: Path, columns: list[str] | None, skip_prefix: str | None = None) -> pa.Table:
    # pq.ParquetFile, not pq.read_table: the dataset layer of the latter costs more than these small reads.
    file = pq.ParquetFile(path)
    if columns is None and skip_prefix:
        columns = [name for name in file.schema_arrow.names if not name.startswith(skip_prefix)]
    return file.read(columns=columns, use_threads=False)


def _read_in_order(paths: list[Path], columns: list[str] | None, skip_prefix: str | None = None) -> Iterator[pa.Table]:
    """The tables of `paths` in order, the next PARALLEL_FILES ones decoding in threads meanwhile."""
    with ThreadPoolExecutor(PARALLEL_FILES) as pool:
        pending: deque[Future[pa.Table]] = deque()
        for path in paths:
            pending.append(pool.submit(_read_parquet, path, columns, skip_prefix))
            if len(pending) > PARALLEL_FILES:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def _rows_before(table: pa.Table, column: str, limit: int) -> pa.Table:
    """The rows whose `column` is below `limit`."""
    keep = table[column].to_numpy() < limit
    return table if keep.all() else table.filter(pa.array(keep))


def read_episodes(root: Path, columns: list[str] | None = None) -> pa.Table:
    """One row per committed episode: `columns`, or LeRobot's and this project's (seed, return, ...) without stats."""
    committed = read_info(root)["total_episodes"]
    wanted = None if columns is None else list(dict.fromkeys([*columns, "episode_index"]))
    paths = episode_files(root)
    if not paths:
        raise DatasetError(f"{root} has no episode metadata ({EPISODES_DIR}): no episode was committed to it")
    # Hundreds of stats/ columns per file: reading only the wanted ones is most of the speed.
    tables = list(_read_in_order(paths, wanted, skip_prefix="stats/"))
    episodes = _rows_before(pa.concat_tables(tables, promote_options="default"), "episode_index", committed)
    order = np.argsort(episodes["episode_index"].to_numpy(), kind="stable")
    episodes = episodes.take(pa.array(order))
    return episodes if columns is None else episodes.select(columns)


def read_videos(root: Path) -> list[dict[str, tuple[Path, dict[str, np.ndarray]]]]:
    """Per committed episode, in order: each camera's video file and its statistics (`common.lerobot_stats`), by
    dataset key; empty dicts for a dataset without cameras."""
    info = read_info(root)
    keys = video_keys(info["features"])
    stats = ["min", "max", "mean", "std", "count", *map(quantile_key, QUANTILES)]
    located = [f"videos/{key}/{part}" for key in keys for part in ("chunk_index", "file_index")]
    rows = read_episodes(root, [*located, *(f"stats/{key}/{name}" for key in keys for name in stats)]).to_pylist()

    def path(row: dict[str, Any], key: str) -> Path:
        chunk, file = row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"]
        return video_file(root, info, key, chunk, file)

    return [{key: (path(row, key), unflatten_stats(row)[key]) for key in keys} for row in rows]


def read_parameters(root: Path) -> list[dict[str, Any]]:
    """Each committed episode's drawn physical parameters, e.g. {"friction_scale": 1.2}; {} if not randomised.

    From the episode columns `randomization.*` (`columns.RANDOMIZATION_PREFIX`), in episode order.
    """
    table = read_episodes(root)
    drawn = [name for name in table.column_names if name.startswith(columns.RANDOMIZATION_PREFIX)]
    rows = table.select(drawn).to_pylist() if drawn else [{} for _ in range(table.num_rows)]
    return [columns.drawn_parameters(row) for row in rows]


def fingerprint(root: Path) -> str:
    """A digest of what the dataset at `root` holds: its info.json and every committed episode's row.

    The rows carry each episode's seed, length, return, files and per-feature statistics, so any
    episode added, removed or changed changes the digest; the same recording made again (the
    recorder is deterministic, whatever its workers) has the same one. Checkpoints record it
    (dataset.json), and `make pipeline` compares it with the dataset's to decide what to re-make.
    """
    info = read_info(root)
    paths = episode_files(root)
    rows = pa.concat_tables(list(_read_in_order(paths, None)), promote_options="default") if paths else None
    episodes = [] if rows is None else _rows_before(rows, "episode_index", info["total_episodes"]).to_pylist()
    episodes.sort(key=lambda row: row["episode_index"])
    content = json.dumps([info, episodes], sort_keys=True, default=str)
    return hashlib.sha256(content.encode()).hexdigest()


def column_to_numpy(column: pa.ChunkedArray) -> np.ndarray:
    """A parquet column as an array: (rows,) for scalars, (rows, n) for fixed-size lists."""
    array = column.combine_chunks()  # one chunk when read from one file: no copy
    if pa.types.is_fixed_size_list(array.type):
        return array.flatten().to_numpy(zero_copy_only=False).reshape(len(array), array.type.list_size)
    return array.to_numpy(zero_copy_only=False)


def data_files(root: Path) -> list[Path]:
    """The parquet files holding the committed episodes' frames, in (chunk, file) order."""
    info = read_info(root)
    episodes = read_episodes(root, ["data/chunk_index", "data/file_index"])
    return sorted(
        {
            data_file(root, info, chunk, file)
            for chunk, file in zip(
                episodes["data/chunk_index"].to_pylist(), episodes["data/file_index"].to_pylist(), strict=True
            )
        }
    )


def iter_frames(root: Path, columns: list[str] | None = None) -> Iterator[dict[str, np.ndarray]]:
    """The committed frames file by file, each batch with its `index` column (the global frame index).

    For readers that fill preallocated arrays: only a few files' decoded columns are alive at a
    time, so their memory is reused instead of growing with the dataset (page faults dominate
    otherwise).
    """
    committed = read_info(root)["total_frames"]
    wanted = None if columns is None else list(dict.fromkeys([*columns, "index"]))
    for table in _read_in_order(data_files(root), wanted):
        table = _rows_before(table, "index", committed)  # rows of an unfinished episode, if any
        yield {name: column_to_numpy(table[name]) for name in table.column_names}


def read_frames(root: Path, columns: list[str] | None = None) -> dict[str, np.ndarray]:
    """The committed frames of the dataset at `root`, in index order, one array per column."""
    batches = list(iter_frames(root, columns))
    names = (list(batches[0]) if batches else []) if columns is None else columns
    if not batches:
        return {name: np.empty(0) for name in names}
    index = np.concatenate([batch["index"] for batch in batches])
    order = None if np.all(np.diff(index) > 0) else np.argsort(index, kind="stable")
    frames = {name: np.concatenate([batch[name] for batch in batches]) for name in names}
    return frames if order is None else {name: values[order] for name, values in frames.items()}


COMMAND_COLUMNS = (columns.OBS_COMMAND, columns.SETPOINT)
"""The frame columns with one entry per command field."""


def command_columns(info: dict[str, Any], frames: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """`frames` with each of its `COMMAND_COLUMNS` laid out as today's command (`COMMAND_NAMES`), by the names the
    dataset's info gives them: a field recorded before it existed (a velocity, in a dataset of postures) reads 0, the
    zero command. DatasetError for a field this version does not know."""
    out = dict(frames)
    for key in COMMAND_COLUMNS:
        if key not in frames:
            continue
        names = info["features"][key]["names"]
        if list(names) == list(COMMAND_NAMES):
            continue
        unknown = [name for name in names if name not in COMMAND_NAMES]
        if unknown:
            raise DatasetError(f"{key} names fields this version does not know: {', '.join(unknown)}")
        wide = np.zeros((len(frames[key]), COMMAND_SIZE), frames[key].dtype)
        wide[:, field_positions(names)] = frames[key]
        out[key] = wide
    return out


def read_commanded_frames(root: Path, columns: list[str] | None = None) -> dict[str, np.ndarray]:
    """`read_frames` with the command columns laid out as today's command (`command_columns`)."""
    return command_columns(read_info(root), read_frames(root, columns))


# Step fields read back, with the dtype of the matching LeRobot column.
STEP_FIELDS = {
    "frame_index": np.int64,
    "observation": np.float64,
    "state": np.float64,
    "action": np.float32,
    "executed_action": np.float32,
    "reward": np.float64,
    "terminated": bool,
    "truncated": bool,
}
_STEP_DTYPES: dict[str, Any] = {"episode_index": np.int64, **STEP_FIELDS}  # what read_steps returns


def read_steps(path: Path) -> dict[str, np.ndarray]:
    """The /step messages of one MCAP file, field by field; the task strings under "task".

    Decoding /step alone is several times cheaper than every topic (the 13 transforms of /tf
    included), and /step is all that parquet can be compared to.
    """
    values: dict[str, list] = {name: [] for name in [*_STEP_DTYPES, "task"]}
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, decoded in reader.iter_decoded_messages(topics=[STEP_TOPIC]):
            for name, column in values.items():
                column.append(getattr(decoded, name))
    # np.array over the repeated containers converts them in C: a list() of each costs 4 times more.
    return {name: np.array(column, _STEP_DTYPES.get(name, object)) for name, column in values.items()}


@dataclass
class Transitions:
    """One episode as offline RL reads it: T+1 observations for T actions, so (o_t, a_t, r_t, o_t+1) for every t."""

    observations: np.ndarray  # (T+1, 348) float64, the gymnasium observation's order: o_0 .. o_T
    actions: np.ndarray  # (T, 17) float32, the label actions
    rewards: np.ndarray  # (T,) float64
    terminated: np.ndarray  # (T,) bool
    truncated: np.ndarray  # (T,) bool
    commands: np.ndarray  # (T+1, 5) float32, the operator's command in force at each observation (o_T: the last's)


def read_transitions(root: Path) -> list[Transitions]:
    """Every committed episode's transitions, in episode order: the frames' observations joined by name into the
    gymnasium one, then the final observation the episode columns keep (`columns.EPISODE_FINAL_STATE`), each with the
    command in force (the final one under the last frame's: no key acts after the last step)."""
    final_columns = [columns.EPISODE_FINAL_STATE, columns.EPISODE_FINAL_ENV_STATE]
    episodes = read_episodes(root)
    if not set(final_columns) <= set(episodes.column_names):
        raise DatasetError(f"{root} has no final observations (recorded before they were kept); record it again")
    names = [read_info(root)["features"][key]["names"] for key in (columns.OBS_STATE, columns.OBS_ENV_STATE)]
    index = observation_index(names[0] + names[1])
    if index is None:
        raise DatasetError(f"{root}'s observation features do not name every gymnasium observation entry")
    wanted = [
        columns.OBS_STATE,
        columns.OBS_ENV_STATE,
        columns.OBS_COMMAND,
        columns.ACTION,
        columns.REWARD,
        columns.TERMINATED,
        columns.TRUNCATED,
    ]
    frames = read_commanded_frames(root, [*wanted, "episode_index"])
    observations = np.concatenate([frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE]], axis=1)[:, index]
    finals = episodes.select(final_columns).to_pylist()
    result = []
    for episode, final in enumerate(finals):
        rows = frames["episode_index"] == episode
        last = np.concatenate([final[columns.EPISODE_FINAL_STATE], final[columns.EPISODE_FINAL_ENV_STATE]])[index]
        result.append(
            Transitions(
                observations=np.vstack([observations[rows], last]),
                actions=frames[columns.ACTION][rows],
                rewards=frames[columns.REWARD][rows].reshape(-1),
                terminated=frames[columns.TERMINATED][rows].reshape(-1),
                truncated=frames[columns.TRUNCATED][rows].reshape(-1),
                commands=np.vstack([frames[columns.OBS_COMMAND][rows], frames[columns.OBS_COMMAND][rows][-1:]]),
            )
        )
    return result


def read_mcap_final(path: Path) -> dict[str, np.ndarray]:
    """The `/final_observation` message of one MCAP file: {"observation": (348,), "state": (48,), "frame_index": T}."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, decoded in reader.iter_decoded_messages(topics=[FINAL_TOPIC]):
            return {
                "observation": np.array(decoded.observation, np.float64),
                "state": np.array(decoded.state, np.float64),
                "frame_index": np.int64(decoded.frame_index),
            }
    raise DatasetError(f"{path} has no {FINAL_TOPIC} message")
