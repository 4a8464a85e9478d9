"""The LeRobot dataset format v3.0, as far as this project writes and reads it.

Spelled out here rather than imported from `lerobot.datasets`, whose import pulls in torch and
torchvision, seconds the recorder's writer process would pay at every start. The tests hold each
constant and function to LeRobot's own (`tests/teleop/test_lerobot_format.py`): same paths, same
info.json, same parquet schemas, same statistics keys and aggregation.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from common.cli import DatasetError, one_line
from common.columns import OBS_IMAGES
from common.lerobot_stats import QUANTILES, quantile_key
from humanoid.encoding import CODEC, ENCODER

if TYPE_CHECKING:
    import pyarrow.parquet as pq

    import datasets

CODEBASE_VERSION = "v3.0"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_DIR = "meta/episodes"
DATA_DIR = "data"
_CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = f"{DATA_DIR}/{_CHUNK_FILE}.parquet"
VIDEO_DIR = "videos"
VIDEO_PATH = f"{VIDEO_DIR}/{{video_key}}/{_CHUNK_FILE}.mp4"
EPISODES_PATH = f"{EPISODES_DIR}/{_CHUNK_FILE}.parquet"
CHUNKS_SIZE = 1000  # files per chunk folder
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200

# Columns LeRobot adds to every frame.
DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": (1,), "names": None},
    "frame_index": {"dtype": "int64", "shape": (1,), "names": None},
    "episode_index": {"dtype": "int64", "shape": (1,), "names": None},
    "index": {"dtype": "int64", "shape": (1,), "names": None},
    "task_index": {"dtype": "int64", "shape": (1,), "names": None},
}


def read_info(root: Path) -> dict:
    """meta/info.json as a dict (the LeRobot dataset's features, fps and counts); DatasetError in one line if it holds
    no JSON object (a copy cut short); OSError if it cannot be read (missing: callers that ask first say so)."""
    try:
        info = json.loads((root / INFO_PATH).read_text())
    except ValueError as error:
        raise DatasetError(f"{root / INFO_PATH} is not readable JSON ({one_line(error)})") from None
    if not isinstance(info, dict):
        raise DatasetError(f"{root / INFO_PATH} holds {type(info).__name__}, not an object")
    return info


def data_file(root: Path, info: dict, chunk: int, file: int) -> Path:
    """The frames' parquet file (`chunk`, `file`) of the dataset at `root`, as its info.json's `data_path` names it."""
    return root / info["data_path"].format(chunk_index=chunk, file_index=file)


def video_file(root: Path, info: dict, key: str, chunk: int, file: int) -> Path:
    """Camera `key`'s video file (`chunk`, `file`) of the dataset at `root`, as its info.json's `video_path` names
    it."""
    return root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)


def episode_files(root: Path) -> list[Path]:
    """The episode metadata's parquet files on disk (`EPISODES_DIR`), committed or not, in order."""
    return sorted((root / EPISODES_DIR).glob("*/*.parquet"))


def data_files(root: Path) -> list[Path]:
    """The frames' parquet files on disk (`DATA_DIR`), committed or not, in order."""
    return sorted((root / DATA_DIR).glob("*/*.parquet"))


def video_files(root: Path) -> list[Path]:
    """The cameras' video files on disk (`VIDEO_DIR`), committed or not, in order."""
    return sorted((root / VIDEO_DIR).glob("*/*/*.mp4"))


Stats = dict[str, dict[str, np.ndarray]]


def check_destination(root: Path) -> None:
    """DatasetError unless `root` is missing, an empty folder (hidden files aside) or holds a dataset whose parquet
    files are whole: what opening it for writing refuses, found by reading only, before a recording starts (here
    rather than in the writer, so that the recorder's validation of a new dataset imports no pandas or pyarrow)."""
    if root.exists() and not root.is_dir():
        raise DatasetError(f"{root} is a file, not a dataset folder")
    if not root.is_dir():
        return
    if not (root / INFO_PATH).exists():
        if any(not p.name.startswith(".") for p in root.iterdir()):
            raise DatasetError(
                f"{root} is not empty and holds no LeRobot dataset (no {INFO_PATH}); choose an empty or new folder"
            )
        return
    # Appending to a dataset that LeRobot and training cannot read would only add episodes nobody can use.
    for path in sorted([*data_files(root), *(root / INFO_PATH).parent.rglob("*.parquet")]):
        read_footer(path)


def read_footer(path: Path) -> pq.FileMetaData:
    """The footer of parquet file `path` (its schema and row counts, not its data: cheap); DatasetError naming the
    file if it has none a reader accepts (truncated by a copy cut short, or damaged)."""
    import pyarrow as pa  # noqa: PLC0415 - only where a dataset holds parquet files
    import pyarrow.parquet as pq  # noqa: PLC0415

    try:
        return pq.read_metadata(path)
    except (OSError, pa.ArrowException) as error:
        raise DatasetError(
            f"{path} is not a readable parquet file ({one_line(error)}): truncated or damaged; restore it from a copy "
            "or use another dataset folder"
        ) from None


def video_keys(features: dict) -> list[str]:
    """The keys of `features` stored as video files (the cameras'), not in the frames' parquet."""
    return [key for key, ft in features.items() if ft["dtype"] == "video"]


def cameras_spec(features: dict) -> str:
    """The cameras `features` hold as `--cameras` names them, with their sizes ("" for none:
    `humanoid.cameras.parse_cameras` reads it back)."""
    return ",".join(
        f"{key.removeprefix(OBS_IMAGES + '.')}:{features[key]['shape'][0]}x{features[key]['shape'][1]}"
        for key in video_keys(features)
    )


def video_feature(height: int, width: int, fps: int) -> dict[str, Any]:
    """The feature of a camera's frames, as LeRobot declares a video (its `info` what LeRobot reads off the first
    episode's file with `get_video_info` and the encoder's settings, `humanoid.encoding.ENCODER`: a test holds them
    equal)."""
    encoder = {key: value for key, value in ENCODER.items() if key != "vcodec"}
    return {
        "dtype": "video",
        "shape": (height, width, 3),
        "names": ["height", "width", "channels"],
        "info": {
            "video.height": height,
            "video.width": width,
            "video.codec": CODEC,
            "video.pix_fmt": ENCODER["pix_fmt"],
            "video.fps": fps,
            "video.channels": 3,
            "has_audio": False,
            **{f"video.{key}": value for key, value in encoder.items()},
            "video.video_backend": "pyav",
            "video.extra_options": {},
            "is_depth_map": False,
        },
    }


def new_info(fps: int, features: dict, robot_type: str) -> dict[str, Any]:
    """info.json of an empty dataset (`features` includes DEFAULT_FEATURES; videos, if any, in VIDEO_PATH)."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "fps": fps,
        "features": {key: {**ft, "shape": list(ft["shape"])} for key, ft in features.items()},
        "total_episodes": 0,
        "total_frames": 0,
        "total_tasks": 0,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if video_keys(features) else None,
        "robot_type": robot_type,
        "splits": {},
    }


def hf_features(features: dict) -> datasets.Features:
    """The HuggingFace features of the frame table (scalars and 1-D vectors, as LeRobot maps them)."""
    import datasets  # noqa: PLC0415 - half a second: paid at the first write, not at start-up

    mapped = {}
    for key, ft in features.items():
        if ft["dtype"] == "video":  # in video files, not in the frames' table
            continue
        shape = tuple(ft["shape"])
        if len(shape) != 1:
            raise ValueError(f"feature {key!r} has shape {shape}; only scalars and vectors are written here")
        value = datasets.Value(ft["dtype"])
        mapped[key] = value if shape == (1,) else datasets.Sequence(length=shape[0], feature=value)
    return datasets.Features(mapped)


def next_chunk_file(chunk_index: int, file_index: int) -> tuple[int, int]:
    """The file after (chunk, file): CHUNKS_SIZE files per chunk folder."""
    return (chunk_index + 1, 0) if file_index == CHUNKS_SIZE - 1 else (chunk_index, file_index + 1)


def episode_stats(frames: dict[str, np.ndarray]) -> Stats:
    """Per-episode statistics of every column, with the keys and shapes of LeRobot's.

    LeRobot estimates quantiles from 5000-bin histograms, one feature at a time in Python;
    `np.quantile` gives exact ones, vectorised, and about ten times as fast. The
    inverted-CDF definition returns a recorded value, as LeRobot's estimate does for discrete
    columns (flags, indices), where interpolating between values would differ by a whole step.
    """
    stats = {}
    for key, values in frames.items():
        samples = values.reshape(len(values), -1).astype(np.float64)
        quantiles = np.quantile(samples, QUANTILES, axis=0, method="inverted_cdf")
        stats[key] = {
            "min": samples.min(axis=0),
            "max": samples.max(axis=0),
            "mean": samples.mean(axis=0),
            "std": samples.std(axis=0),
            "count": np.array([len(samples)]),
            **{quantile_key(q): quantiles[i] for i, q in enumerate(QUANTILES)},
        }
    return stats


def aggregate_stats(stats_list: list[Stats]) -> Stats:
    """Dataset statistics from per-episode ones: exact min, max, mean and std; count-weighted quantiles."""
    aggregated = {}
    # First-seen order, not a set's hash order: stats.json must come out byte-identical run to run.
    for key in dict.fromkeys(key for stats in stats_list for key in stats):
        parts = [stats[key] for stats in stats_list if key in stats]
        means = np.stack([part["mean"] for part in parts])
        # (episodes, 1, ...): one count per episode against each entry (a camera's stats are (3, 1, 1)).
        counts = np.stack([part["count"] for part in parts]).astype(np.float64).reshape(-1, *[1] * (means.ndim - 1))
        total = counts.sum(axis=0)
        mean = (means * counts).sum(axis=0) / total
        variance = ((np.stack([part["std"] for part in parts]) ** 2 + (means - mean) ** 2) * counts).sum(axis=0) / total
        aggregated[key] = {
            "min": np.min([part["min"] for part in parts], axis=0),
            "max": np.max([part["max"] for part in parts], axis=0),
            "mean": mean,
            "std": np.sqrt(variance),
            "count": total.reshape(-1)[:1].astype(np.int64),
            **{
                name: (np.stack([part[name] for part in parts]) * counts).sum(axis=0) / total
                for name in map(quantile_key, QUANTILES)
                if all(name in part for part in parts)
            },
        }
    return aggregated


def stats_to_json(stats: Stats) -> dict[str, dict[str, list]]:
    return {key: {name: np.asarray(value).tolist() for name, value in ft.items()} for key, ft in stats.items()}


def stats_from_json(data: dict[str, dict[str, list]]) -> Stats:
    return {key: {name: np.atleast_1d(np.array(value)) for name, value in ft.items()} for key, ft in data.items()}


def flatten_stats(stats: Stats) -> dict[str, list]:
    """Episode statistics as the `stats/<feature>/<stat>` columns of an episodes parquet row."""
    return {
        f"stats/{key}/{name}": np.asarray(value).tolist() for key, ft in stats.items() for name, value in ft.items()
    }


def unflatten_stats(row: dict[str, Any]) -> Stats:
    """The inverse of `flatten_stats`, for one row (other columns ignored)."""
    stats: Stats = {}
    for column, value in row.items():
        if column.startswith("stats/"):
            key, name = column.removeprefix("stats/").rsplit("/", 1)
            stats.setdefault(key, {})[name] = np.atleast_1d(np.array(value))
    return stats
