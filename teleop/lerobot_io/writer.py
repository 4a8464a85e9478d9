"""Appends episodes to a LeRobot dataset (format v3.0) so that a kill -9 never costs a committed one.

LeRobot's own writer keeps a parquet file open across episodes: killed before `finalize()`, that
file has no footer and the whole dataset is unreadable. This writer keeps the v3.0 layout (see
`teleop.lerobot_io.format`) but gives every episode its own finished parquet file, for its frames and
for its metadata row, and makes `meta/info.json` the commit point:

1. `stage`: data/chunk-C/file-F.parquet and meta/episodes/chunk-C/file-F.parquet (each written to a
   `.partial` file, then renamed), and tasks.parquet if the task is new;
2. `commit`: meta/stats.json, then meta/info.json, whose episode count makes the episode exist.

The files of an uncommitted episode sort after every committed one, and LeRobot serves only the
frames info.json counts, so the dataset stays loadable after a kill; `open` deletes them.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from common import columns
from common.cli import DatasetError
from common.files import PARTIAL_SUFFIX, write_atomically
from teleop.lerobot_io.format import (
    DEFAULT_FEATURES,
    EPISODES_PATH,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    Stats,
    aggregate_stats,
    cameras_spec,
    check_destination,
    data_file,
    data_files,
    episode_files,
    episode_stats,
    flatten_stats,
    hf_features,
    new_info,
    next_chunk_file,
    read_info,
    stats_from_json,
    stats_to_json,
    unflatten_stats,
    video_file,
    video_files,
    video_keys,
)

log = logging.getLogger(__name__)

_DATA_PAGE_SIZE = 64 * 1024 * 1024


def _write_json(data: dict, path: Path, indent: int | None = 4) -> None:
    write_atomically(path, lambda p: p.write_text(json.dumps(data, indent=indent)))


def _write_stats(stats: Stats, path: Path) -> None:
    # Rewritten at every commit; indenting would make Python's JSON encoder 3x slower (no C encoder).
    _write_json(stats_to_json(stats), path, indent=None)


@dataclass(frozen=True)
class StagedEpisode:
    """An episode whose files are on disk but not yet counted by info.json."""

    index: int
    length: int
    stats: Stats
    total_tasks: int


class LeRobotWriter:
    """Appends episodes to one LeRobot v3.0 dataset; `open` creates it or checks it is compatible."""

    def __init__(
        self, root: Path, info: dict, tasks: pd.DataFrame, stats: Stats | None, last_file: tuple[int, int] | None
    ) -> None:
        self.root = root
        self.info = info
        self.tasks = tasks
        self.stats = stats
        self._last_file = last_file
        self._schema: pa.Schema | None = None  # built by `prepare` or on first use: it imports `datasets`

    @property
    def total_episodes(self) -> int:
        return self.info["total_episodes"]

    @classmethod
    def open(cls, root: Path, features: dict, fps: int, robot_type: str) -> LeRobotWriter:
        """The writer for `root`: a new dataset if the folder is empty, else the existing one, recovered."""
        info = new_info(fps, {**features, **DEFAULT_FEATURES}, robot_type)
        info_path = root / INFO_PATH
        if not info_path.exists():
            check_destination(root)
            _write_json(info, info_path)
            return cls(root, info, _empty_tasks(), None, None)

        existing = read_info(root)
        problems = [
            f"{key} {existing.get(key)!r}, not {info[key]!r}"
            for key in ("codebase_version", "fps", "robot_type")
            if existing.get(key) != info[key]
        ]
        if existing.get("features") != info["features"]:
            theirs, ours = existing.get("features", {}), info["features"]
            cameras = [cameras_spec(features) or "none" for features in (theirs, ours)]
            if cameras[0] != cameras[1]:  # a dataset keeps one set of cameras (LeRobot's features are per dataset)
                problems.append(f"recorded with cameras {cameras[0]}, this session records {cameras[1]}")
            elif set(theirs) != set(ours):
                problems.append(f"other features (keys {sorted(set(theirs) ^ set(ours))} differ)")
            else:
                problems.append("other features (shapes, dtypes or names differ)")
        if problems:
            raise DatasetError(f"{root} holds a dataset this recorder cannot append to: {'; '.join(problems)}")
        return cls._recovered(root, existing)

    @classmethod
    def _recovered(cls, root: Path, info: dict) -> LeRobotWriter:
        """The writer for an existing dataset, after deleting what a killed writer left uncommitted."""
        episodes = _remove_uncommitted(root, info)
        stored_tasks = pd.read_parquet(root / TASKS_PATH) if info["total_tasks"] else _empty_tasks()
        tasks = stored_tasks[stored_tasks["task_index"] < info["total_tasks"]]
        stats_path = root / STATS_PATH
        stats = stats_from_json(json.loads(stats_path.read_text())) if stats_path.exists() else None
        last_file = None
        if episodes:
            last = episodes[-1]
            last_file = (last["meta/episodes/chunk_index"], last["meta/episodes/file_index"])
        writer = cls(root, info, tasks, stats, last_file)
        if len(tasks) < len(stored_tasks):
            writer._write_tasks()
        # stats.json is written just before info.json: a kill between the two leaves it counting an episode that
        # was never committed, so rebuild it from the committed episodes' own statistics (none: no stats).
        if not episodes and stats is not None:
            writer.stats = None
            stats_path.unlink()
        elif episodes and (stats is None or int(stats["index"]["count"][0]) != info["total_frames"]):
            writer.stats = aggregate_stats([unflatten_stats(row) for row in episodes])
            _write_stats(writer.stats, stats_path)
        return writer

    def prepare(self) -> None:
        """Build the Arrow schema now (importing `datasets` takes about a second), not at the first episode."""
        if self._schema is None:
            self._schema = hf_features(self.info["features"]).arrow_schema

    def stage(
        self,
        arrays: dict[str, np.ndarray],
        tasks: np.ndarray,
        extra: dict[str, Any],
        videos: dict[str, tuple[bytes, dict[str, np.ndarray]]] | None = None,
    ) -> StagedEpisode:
        """Write the frames, videos and metadata row of the next episode, uncommitted.

        `arrays` holds every non-default feature but the videos and `tasks` the task string, one row per frame;
        `extra` adds episode-level columns (seed, controller, ...) to the metadata row; `videos` holds each video
        feature's MP4 file (one frame per row, frame i at i / fps) and its statistics
        (`common.lerobot_stats.image_stats`). An episode's video is a file of its own, numbered as its frames' file.
        """
        videos = videos or {}
        if set(videos) != set(video_keys(self.info["features"])):
            raise ValueError(f"videos {sorted(videos)} for a dataset of {video_keys(self.info['features'])}")
        index, start = self.info["total_episodes"], self.info["total_frames"]
        length = len(next(iter(arrays.values())))
        frame_index = np.arange(length, dtype=np.int64)
        episode_tasks = list(dict.fromkeys(tasks.tolist()))  # in order of first use, as LeRobot lists them
        task_index = {task: self._task_index(task) for task in episode_tasks}
        frames = {
            **arrays,
            "timestamp": (frame_index / self.info["fps"]).astype(np.float32),
            "frame_index": frame_index,
            "episode_index": np.full(length, index, dtype=np.int64),
            "index": start + frame_index,
            "task_index": np.array([task_index[task] for task in tasks.tolist()], dtype=np.int64),
        }
        chunk, file = (0, 0) if self._last_file is None else next_chunk_file(*self._last_file)
        data_path = data_file(self.root, self.info, chunk, file)
        # Dictionary encoding, parquet's default, makes writing float frames 40 times slower; one page
        # per column (an episode's column is at most a few MB) instead of 1 MB pages saves a third more.
        write_atomically(
            data_path,
            lambda p: pq.write_table(
                self._frames_table(frames),
                p,
                compression="snappy",
                use_dictionary=False,
                data_page_size=_DATA_PAGE_SIZE,
            ),
        )
        stats = episode_stats(frames)
        located: dict[str, Any] = {}
        for key, (video, video_stats) in videos.items():
            path = video_file(self.root, self.info, key, chunk, file)
            write_atomically(path, lambda p, video=video: p.write_bytes(video))
            stats[key] = video_stats
            located |= {
                f"videos/{key}/chunk_index": chunk,
                f"videos/{key}/file_index": file,
                f"videos/{key}/from_timestamp": 0.0,
                f"videos/{key}/to_timestamp": length / self.info["fps"],
            }
        row = {
            "episode_index": index,
            "tasks": episode_tasks,
            "length": length,
            "data/chunk_index": chunk,
            "data/file_index": file,
            "dataset_from_index": start,
            "dataset_to_index": start + length,
            **flatten_stats(stats),
            "meta/episodes/chunk_index": chunk,
            "meta/episodes/file_index": file,
            **located,
            **extra,
        }
        table = pa.Table.from_pylist([row])
        write_atomically(
            self.root / EPISODES_PATH.format(chunk_index=chunk, file_index=file),
            lambda p: pq.write_table(table, p, compression="snappy"),
        )
        self._last_file = (chunk, file)
        return StagedEpisode(index, length, stats, total_tasks=len(self.tasks))

    def commit(self, staged: StagedEpisode) -> None:
        """Count the staged episode in stats.json and then info.json: from now on it exists."""
        self.stats = staged.stats if self.stats is None else aggregate_stats([self.stats, staged.stats])
        _write_stats(self.stats, self.root / STATS_PATH)
        self.info["total_episodes"] = staged.index + 1
        self.info["total_frames"] += staged.length
        self.info["total_tasks"] = staged.total_tasks
        self.info["splits"] = {"train": f"0:{self.info['total_episodes']}"}
        _write_json(self.info, self.root / INFO_PATH)

    def episode_column(self, name: str) -> list[Any]:
        """Values of an episode-level column (e.g. `seed`) over the committed episodes that have it."""
        values = []
        for path in episode_files(self.root):
            if name in pq.read_schema(path).names:
                table = pq.read_table(path, columns=["episode_index", name])
                values += [
                    value
                    for index, value in zip(table["episode_index"].to_pylist(), table[name].to_pylist(), strict=True)
                    if index < self.total_episodes
                ]
        return values

    def last_episode_columns(self) -> list[str]:
        """The columns of the last staged episode's metadata row: the last committed one's right after `open`."""
        if self._last_file is None:
            return []
        chunk, file = self._last_file
        return pq.read_schema(self.root / EPISODES_PATH.format(chunk_index=chunk, file_index=file)).names

    def _task_index(self, task: str) -> int:
        if task not in self.tasks.index:
            self.tasks.loc[task] = len(self.tasks)
            self._write_tasks()
        return int(self.tasks.loc[task, "task_index"])

    def _write_tasks(self) -> None:
        write_atomically(self.root / TASKS_PATH, lambda p: self.tasks.to_parquet(p))

    def _frames_table(self, frames: dict[str, np.ndarray]) -> pa.Table:
        """The episode as an Arrow table with the schema LeRobot's writer gives the same features."""
        self.prepare()
        arrays = []
        for field in self._schema:
            values = np.ascontiguousarray(frames[field.name])
            if pa.types.is_fixed_size_list(field.type):
                flat = pa.array(values.reshape(-1), type=field.type.value_type)
                arrays.append(pa.FixedSizeListArray.from_arrays(flat, field.type.list_size))
            else:
                arrays.append(pa.array(values.reshape(-1), type=field.type))
        return pa.Table.from_arrays(arrays, schema=self._schema)


def _empty_tasks() -> pd.DataFrame:
    return pd.DataFrame({"task_index": pd.Series(dtype="int64")}, index=pd.Index([], name=columns.TASK, dtype="object"))


def _remove_uncommitted(root: Path, info: dict) -> list[dict[str, Any]]:
    """Delete partial files and every file of an episode >= total_episodes; the committed episode rows."""
    committed = info["total_episodes"]
    for partial in root.rglob(f"*{PARTIAL_SUFFIX}"):
        partial.unlink()
    rows: list[dict[str, Any]] = []
    for path in episode_files(root):
        file_rows = pq.read_table(path).to_pylist()
        indices = [row["episode_index"] for row in file_rows]
        if min(indices) >= committed:
            _remove(root, path)
        elif max(indices) >= committed:
            raise DatasetError(
                f"{path} mixes committed episodes with some beyond the {committed} that "
                "info.json counts; repair the dataset by hand"
            )
        else:
            rows += file_rows
    rows.sort(key=lambda row: row["episode_index"])
    referenced = {data_file(root, info, row["data/chunk_index"], row["data/file_index"]) for row in rows}
    for key in video_keys(info["features"]):
        referenced |= {
            video_file(root, info, key, row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"])
            for row in rows
        }
    for path in [*data_files(root), *video_files(root)]:
        if path not in referenced:
            _remove(root, path)
    return rows


def _remove(root: Path, path: Path) -> None:
    log.warning("removing %s: its episode was never committed", path.relative_to(root))
    path.unlink()
