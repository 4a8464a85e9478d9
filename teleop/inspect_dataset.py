"""`make inspect`: what a dataset folder holds, and whether its LeRobot and MCAP halves agree.

Prints a summary (episodes, frames, tasks, controllers, seeds, the range of each randomised physical
parameter, the sessions of recordings.jsonl, return and length per episode, features, disk size, the
MCAP files' message counts), then verifies
the dataset and exits with `error: <the first problem found>` if anything is wrong:

- LeRobot metadata: info.json (v3.0), the episode rows, the frame indices, the tasks and stats.json
  agree with each other and with the frames; every declared feature is a column of that shape;
  and LeRobot's own `LeRobotDatasetMetadata` loads the folder (in a child process, overlapped
  with the other checks: importing it takes torch, several seconds).
- Frames: every floating-point value is finite.
- MCAP: each committed episode's file ends properly and has a summary; every per-step topic (all
  but `/scene`) holds one message per frame; its `/step` messages equal the parquet frames exactly
  (both are written from the same arrays).
- Cameras (`observation.images.*`): each episode's video holds one frame per data frame, 1/fps apart
  from the episode's `from_timestamp`, at the declared size (read from the packets, not decoded).

With `--plot true` it also draws returns per episode, torso height over time and the action
histograms to a PNG, and for a dataset with cameras a contact sheet beside it (`*_cameras.png`: a
few frames of a few episodes per camera). Nothing in the dataset is changed; the PNGs are the only
files written.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.reader import make_reader

from common import columns, paths
from common.cli import DatasetError, UserError, check_file, counted, one_line, run_cli, setting
from common.figures import save_figure
from common.files import PARTIAL_SUFFIX
from humanoid.sensors import observation_index
from teleop import recordings
from teleop.dataset_reader import read_episodes, read_frames, read_info, read_mcap_final, read_steps
from teleop.lerobot_io.format import (
    CODEBASE_VERSION,
    EPISODES_DIR,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_DIR,
    data_file,
    data_files,
    episode_files,
    read_footer,
    video_file,
    video_files,
    video_keys,
)
from teleop.mcap_io.writer import FINAL_TOPIC, SCENE_TOPIC, STEP_TOPIC
from teleop.spool import SPOOLS, Spool
from teleop.store import MCAP_DIR, mcap_name


@dataclass
class InspectConfig:
    """Settings of one inspection."""

    dataset: Path = setting(
        paths.DATASET, "dataset folder to summarise and verify (its files never modified; PLOT's PNG goes into it)"
    )
    plot: bool = setting(False, "also draw returns per episode, torso height over time and action histograms to a PNG")
    plot_path: Path | None = setting(None, "where the PNG goes; default: DATASET/inspect.png")
    lerobot: bool = setting(
        True,
        "also let LeRobot itself load the metadata, in a child process overlapped with "
        "the other checks (it imports torch: about 5 s)",
    )


PLOT_NAME = "inspect.png"
TORSO_HEIGHT = "root.z"  # the name of the torso height in the observation features' `names`
PLOTTED_EPISODES = 5
TIMESTAMP_TOLERANCE_S = 1e-4
MCAP_MAGIC = b"\x89MCAP0\r\n"  # opens and closes every finished MCAP file
ONCE_TOPICS = (SCENE_TOPIC, FINAL_TOPIC)  # one message per file; every other topic has one per frame

# The /step fields and the parquet columns they were written from (the observation: joined by name).
OBSERVATION_COLUMNS = (columns.OBS_STATE, columns.OBS_ENV_STATE)
STEP_COLUMNS: dict[str, tuple[str, ...]] = {
    "episode_index": ("episode_index",),
    "frame_index": ("frame_index",),
    "observation": OBSERVATION_COLUMNS,
    "state": (columns.OBS_STATE,),
    "action": (columns.ACTION,),
    "executed_action": (columns.EXECUTED_ACTION,),
    "reward": (columns.REWARD,),
    "terminated": (columns.TERMINATED,),
    "truncated": (columns.TRUNCATED,),
}

# Run by the child process that lets LeRobot itself load the metadata. LeRobot's errors span several
# lines (advice, links): the child prints the exception's type and first line, on stdout, and exits 1.
_LEROBOT_LOAD = """\
import sys
try:
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    LeRobotDatasetMetadata(repo_id="local/inspect", root=sys.argv[1])
except Exception as error:
    first = next((line.strip() for line in str(error).splitlines() if line.strip()), "")
    print(f"{type(error).__name__}: {first}")
    sys.exit(1)
"""


@dataclass(frozen=True)
class McapFile:
    """One episode's MCAP file as its summary section describes it, without decoding a message."""

    path: Path
    problem: str | None  # why it cannot be read (missing, truncated, no summary, ...); None if readable
    counts: dict[str, int]  # messages per topic, from the summary's statistics


@dataclass
class Dataset:
    """Everything read from the folder: what the summary shows and the checks compare."""

    root: Path
    info: dict
    episodes: dict[str, list]  # meta/episodes columns (without stats/), one entry per committed episode
    frames: dict[str, np.ndarray]  # every data column, in index order
    data_rows: int  # rows of the referenced data files, before read_frames keeps the committed ones
    data_paths: list[Path]  # the data file of each episode
    tasks: list[str]  # by task_index, the ones info.json counts
    mcap: list[McapFile]  # one per episode
    leftovers: list[str]

    @property
    def num_episodes(self) -> int:
        return len(self.episodes["episode_index"])

    @cached_property
    def observation_order(self) -> np.ndarray | None:
        """Where each gymnasium observation entry sits in observation.state + environment_state (by name)."""
        features = self.info["features"]
        names = [name for key in OBSERVATION_COLUMNS for name in features.get(key, {}).get("names") or []]
        return observation_index(names)

    def rows(self, episode: int) -> slice:
        return slice(self.episodes["dataset_from_index"][episode], self.episodes["dataset_to_index"][episode])

    def where(self, episode: int) -> str:
        return str(self.data_paths[episode].relative_to(self.root))

    def returns(self) -> np.ndarray:
        """The sum of each episode's rewards (NaN for a dataset without the reward column)."""
        rewards = self.frames.get(columns.REWARD)
        return np.array(
            [rewards[self.rows(e)].sum() if rewards is not None else math.nan for e in range(self.num_episodes)]
        )


@dataclass
class Report:
    """The summary of a dataset, and how the verification went."""

    root: Path
    info: dict
    episodes: int
    frames: int
    tasks: dict[str, int]  # task -> frames
    controllers: dict[str, int] | None  # "controller (noise σ)" -> episodes; None for datasets without the column
    randomized: dict[str, str]  # drawn parameter -> the range of its values over the episodes (randomised datasets)
    seeds: list[int]
    lengths: np.ndarray
    returns: np.ndarray
    fell: int | None
    sizes: dict[str, int]  # bytes: data, meta, mcap, other, total
    mcap_readable: int
    mcap_counts: dict[str, int]  # messages per topic over the readable files
    mcap_counts_match: int  # episodes whose every per-step topic has one message per frame
    leftovers: list[str] = field(default_factory=list)
    runs: list[dict] = field(default_factory=list)  # the sessions that added the episodes (`recordings.sessions`)
    verified: list[str] = field(default_factory=list)  # what passed, once everything has
    plot: Path | None = None
    contact_sheet: Path | None = None
    seconds: float = 0.0

    def summary(self) -> str:
        """What the dataset holds: known before any verification."""
        info = self.info
        lines = [
            f"{self.root}: LeRobot {info.get('codebase_version')}, fps {info.get('fps')}, "
            f"robot_type {info.get('robot_type')}"
        ]
        seeds = ""
        if self.seeds:
            distinct = len(set(self.seeds))
            seeds = (
                f" (seeds {min(self.seeds)}..{max(self.seeds)}"
                + ("" if distinct == len(self.seeds) else f", only {distinct} distinct")
                + ")"
            )
        lines.append(_row("episodes", f"{self.episodes:,}{seeds}"))
        lines.append(_row("frames", f"{self.frames:,}"))
        lines += _listing("tasks", [f"{task!r}: {frames:,} frames" for task, frames in self.tasks.items()])
        if self.controllers is not None:
            lines += _listing("controllers", [f"{name}: {count} episodes" for name, count in self.controllers.items()])
        if self.randomized:
            lines += _listing("randomised", [f"{name}: {drawn}" for name, drawn in self.randomized.items()])
        if self.runs:
            lines += _listing("sessions", [_run(run) for run in self.runs])
        lines.append(_row("length", _min_mean_max(self.lengths, "{:,.0f}", "{:,.1f}") + " steps"))
        lines.append(_row("return", _min_mean_max(self.returns, "{:,.1f}", "{:,.1f}")))
        if self.fell is not None:
            lines.append(_row("fell", f"{self.fell} of {self.episodes} episodes end terminated"))
        features = info.get("features", {})
        width = max((len(name) for name in features), default=0)
        lines += _listing(
            "features",
            [
                f"{name:<{width}}  {ft.get('dtype', '?'):<8} {tuple(ft.get('shape', ()))}"
                for name, ft in features.items()
            ],
        )
        sizes = self.sizes
        lines.append(
            _row(
                "disk",
                f"{_mb(sizes['total'])} (parquet: data {_mb(sizes['data'])}, meta "
                f"{_mb(sizes['meta'])}; MCAP {_mb(sizes['mcap'])}; "
                + (f"videos {_mb(sizes['videos'])}; " if sizes.get("videos") else "")
                + f"other {_mb(sizes['other'])})",
            )
        )
        topics = ", ".join(f"{topic} {count:,}" for topic, count in sorted(self.mcap_counts.items()))
        lines.append(_row("MCAP", f"{self.mcap_readable}/{self.episodes} files readable; messages: {topics or 'none'}"))
        lines.append(
            _row(
                "",
                f"{self.mcap_counts_match}/{self.episodes} episodes have one message per frame on "
                f"every per-step topic (all but {', '.join(ONCE_TOPICS)}, one each)",
            )
        )
        lines += [_row("note", leftover) for leftover in self.leftovers]
        return "\n".join(lines)

    def outcome(self) -> str:
        """What was verified, the plot and the time taken; empty until the verification passed."""
        lines = []
        if self.verified:
            lines += _listing("verified", self.verified)
        if self.plot:
            lines.append(_row("plot", str(self.plot)))
        if self.contact_sheet:
            lines.append(_row("cameras", str(self.contact_sheet)))
        if self.seconds:
            lines.append(_row("time", f"{self.seconds:.1f} s"))
        return "\n".join(lines)


def _run(run: dict) -> str:
    """One line of recordings.jsonl: who recorded, when, which episodes (its settings are in the file)."""
    first, last = (run.get("episodes") or ["?", "?"])[:2]
    interrupted = "" if run.get("complete", True) else ", interrupted"
    return f"{run.get('made_by', '?')} at {run.get('time', '?')}: episodes {first}..{last}{interrupted}"


def _row(label: str, text: str) -> str:
    return f"{label:<12}{text}"


def _listing(label: str, items: list[str]) -> list[str]:
    return [_row(label if i == 0 else "", item) for i, item in enumerate(items)] or [_row(label, "none")]


def _min_mean_max(values: np.ndarray, extreme: str, mean: str) -> str:
    if not len(values):
        return "-"
    return (
        f"min {extreme.format(values.min())} / mean {mean.format(values.mean())} / max {extreme.format(values.max())}"
    )


def _mb(size: int) -> str:
    return f"{size / 1e6:,.1f} MB"


def _quiet(text: str) -> None:
    """Shows nothing: `main` called from code returns the report instead."""


def check_plot_path(cfg: InspectConfig) -> None:
    """UserError in one line for a PLOT_PATH the plot cannot take: without PLOT, not a .png, or a folder."""
    if cfg.plot_path is None:
        return
    if not cfg.plot:
        raise UserError(f"--plot-path names where --plot true draws: give --plot true too, got {cfg.plot_path}")
    check_file(cfg, "plot_path", ".png")


def main(cfg: InspectConfig, show: Callable[[str], None] = _quiet) -> Report:
    """Summarise and verify `cfg.dataset`; a DatasetError names the first problem.

    `show` gets the summary as soon as it is known, before the verification (which waits on
    LeRobot's loader), and then the outcome: a user reads the summary even when a problem follows.
    """
    start = time.perf_counter()
    check_plot_path(cfg)
    root = cfg.dataset
    info = _open(root)
    # Started now, so that its torch import overlaps with the reading below.
    lerobot = _LeRobotLoad(root) if cfg.lerobot else None
    try:
        dataset = _read(root, info)
        report = _summarise(dataset)
        show(report.summary())
        report.verified = _verify(dataset, lerobot)
    finally:
        if lerobot:
            lerobot.close()
    if cfg.plot:
        report.plot = cfg.plot_path or root / PLOT_NAME
        plot(dataset, report.plot)
        if video_keys(info["features"]):
            report.contact_sheet = report.plot.with_name(f"{report.plot.stem}_cameras.png")
            contact_sheet(dataset, report.contact_sheet)
    report.seconds = time.perf_counter() - start
    show(report.outcome())
    return report


# Reading ---------------------------------------------------------------------------------------


def _open(root: Path) -> dict:
    """info.json of the dataset at `root`, once it is known to be a v3.0 dataset with episodes."""
    if not root.exists():
        raise DatasetError(f"{root} does not exist")
    if not root.is_dir():
        raise DatasetError(f"{root} is a file, not a dataset folder")
    if not (root / INFO_PATH).is_file():
        raise DatasetError(f"{root} holds no LeRobot dataset (no {INFO_PATH})")
    info = read_info(root)
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise DatasetError(
            f"{root / INFO_PATH}: codebase_version is {info.get('codebase_version')!r}, not {CODEBASE_VERSION!r}"
        )
    for key, kind in (
        ("fps", int),
        ("total_episodes", int),
        ("total_frames", int),
        ("total_tasks", int),
        ("data_path", str),
        ("features", dict),
    ):
        if not isinstance(info.get(key), kind) or isinstance(info.get(key), bool):
            raise DatasetError(f"{root / INFO_PATH}: {key} is {info.get(key)!r}, not {kind.__name__}")
    for name, feature in info["features"].items():
        if not isinstance(feature, dict) or not isinstance(feature.get("shape"), list) or "dtype" not in feature:
            raise DatasetError(f"{root / INFO_PATH}: feature {name!r} has no dtype and shape list")
    if info["total_episodes"] <= 0:
        raise DatasetError(f"{root} holds no committed episode (info.json total_episodes is {info['total_episodes']})")
    # LeRobot turns a missing metadata file into a download from the Hub: make sure it has nothing to fetch.
    for path in (root / TASKS_PATH, root / STATS_PATH):
        if not path.is_file():
            raise DatasetError(f"{root} has no {path.relative_to(root)}")
    if not episode_files(root):
        raise DatasetError(f"{root} has no episode metadata ({EPISODES_DIR}/*/*.parquet)")
    return info


def _read(root: Path, info: dict) -> Dataset:
    """Read the metadata, the frames and the MCAP summaries; what makes reading impossible is a DatasetError."""
    try:
        table = read_episodes(root)
    except (OSError, pa.ArrowException, KeyError) as error:
        raise DatasetError(f"cannot read the episode metadata in {root / EPISODES_DIR}: {one_line(error)}") from None
    for column in ("length", "dataset_from_index", "dataset_to_index", "data/chunk_index", "data/file_index"):
        if column not in table.column_names:
            raise DatasetError(f"{root / EPISODES_DIR}: no {column!r} column")
        if table[column].null_count:
            raise DatasetError(f"{root / EPISODES_DIR}: {table[column].null_count} episodes have no {column!r}")
    episodes = table.to_pydict()
    data_paths = [
        data_file(root, info, chunk, file)
        for chunk, file in zip(episodes["data/chunk_index"], episodes["data/file_index"], strict=True)
    ]
    data_rows = _check_data_files(root, info, data_paths)
    try:
        frames = read_frames(root)
    except (OSError, pa.ArrowException, KeyError, ValueError) as error:
        raise DatasetError(f"cannot read the frames in {root / 'data'}: {one_line(error)}") from None
    tasks = _read_tasks(root, info)
    mcap_paths = [
        root / path if path else root / MCAP_DIR / mcap_name(index)
        for index, path in zip(
            episodes["episode_index"],
            episodes.get(columns.EPISODE_MCAP, [None] * len(episodes["episode_index"])),
            strict=True,
        )
    ]
    return Dataset(
        root,
        info,
        episodes,
        frames,
        data_rows,
        data_paths,
        tasks,
        [_mcap_file(path) for path in mcap_paths],
        _leftovers(root, info, set(data_paths), set(mcap_paths)),
    )


def _check_data_files(root: Path, info: dict, paths: list[Path]) -> int:
    """Every declared feature is a column of each data file, with its shape and dtype; the files' total rows."""
    rows = 0
    for path in sorted(set(paths)):
        where = path.relative_to(root)
        if not path.is_file():
            raise DatasetError(f"{where} is missing (meta/episodes points to it)")
        metadata = read_footer(path)
        try:
            schema = metadata.schema.to_arrow_schema()
        except (OSError, pa.ArrowException) as error:
            raise DatasetError(f"{where} is not a readable parquet file ({one_line(error)})") from None
        rows += metadata.num_rows
        for name, feature in info["features"].items():
            if feature["dtype"] == "video":  # LeRobot keeps videos in mp4 files, not in the frames table
                continue
            if name not in schema.names:
                raise DatasetError(f"{where}: no column {name!r}, which info.json declares")
            problem = _column_problem(schema.field(name).type, feature)
            if problem:
                raise DatasetError(f"{where}: column {name!r} {problem}")
    return rows


def _column_problem(arrow_type: pa.DataType, feature: dict) -> str | None:
    """Why a column of this Arrow type cannot hold the feature, as LeRobot writes it; None if it can."""
    shape = feature["shape"]
    flat_vector = pa.types.is_fixed_size_list(arrow_type) and not pa.types.is_nested(arrow_type.value_type)
    if len(shape) != 1:
        # Images and arrays: LeRobot's encodings vary; a flat vector, though, is no multi-dimensional array.
        return f"holds flat vectors ({arrow_type}), but info.json declares shape {shape}" if flat_vector else None
    is_list = pa.types.is_fixed_size_list(arrow_type) or pa.types.is_list(arrow_type)
    if shape == [1] and is_list:
        return f"is a list ({arrow_type}), but info.json declares shape [1]"
    if shape != [1]:
        if not pa.types.is_fixed_size_list(arrow_type):
            return f"has type {arrow_type}, not a fixed-size list of {shape[0]}"
        if arrow_type.list_size != shape[0]:
            return f"holds vectors of {arrow_type.list_size}, but info.json declares shape {shape}"
    value_type = arrow_type.value_type if is_list else arrow_type
    try:
        expected = pa.string() if feature["dtype"] == "string" else pa.from_numpy_dtype(np.dtype(feature["dtype"]))
    except TypeError:
        return None  # a dtype NumPy does not know (image, ...): nothing to compare with
    if value_type != expected:
        return f"holds {value_type}, but info.json declares {feature['dtype']}"
    return None


def _read_tasks(root: Path, info: dict) -> list[str]:
    """The task strings by task_index, limited to the ones info.json counts (a kill may leave one more)."""
    try:
        table = pq.read_table(root / TASKS_PATH)
    except (OSError, pa.ArrowException) as error:
        raise DatasetError(f"{TASKS_PATH} is not readable ({one_line(error)})") from None
    if "task_index" not in table.column_names or columns.TASK not in table.column_names:
        raise DatasetError(f"{TASKS_PATH} has no 'task' and 'task_index' columns")
    indices, names = table["task_index"].to_pylist(), table[columns.TASK].to_pylist()
    counted = sorted((index, name) for index, name in zip(indices, names, strict=True) if index < info["total_tasks"])
    if [index for index, _ in counted] != list(range(info["total_tasks"])):
        raise DatasetError(
            f"{TASKS_PATH} holds task indices {sorted(indices)}, but info.json total_tasks is "
            f"{info['total_tasks']} (expected 0..{info['total_tasks'] - 1} once each)"
        )
    return [name for _, name in counted]


def _mcap_file(path: Path) -> McapFile:
    """The MCAP file's message counts from its summary, or why it has none."""
    if not path.is_file():
        return McapFile(path, "is missing", {})
    try:
        with path.open("rb") as stream:
            stream.seek(max(path.stat().st_size - len(MCAP_MAGIC), 0))
            if stream.read() != MCAP_MAGIC:
                return McapFile(path, "does not end with the MCAP magic: truncated, or never finished", {})
            stream.seek(0)
            summary = make_reader(stream).get_summary()
    except Exception as error:
        return McapFile(path, f"is unreadable ({one_line(error)})", {})
    if summary is None or summary.statistics is None:
        return McapFile(path, "has no summary statistics (written without an index?)", {})
    counts: Counter[str] = Counter()
    for channel_id, channel in summary.channels.items():
        counts[channel.topic] += summary.statistics.channel_message_counts.get(channel_id, 0)
    return McapFile(path, None, dict(counts))


def _leftovers(root: Path, info: dict, data_paths: set[Path], mcap_paths: set[Path]) -> list[str]:
    """What an interrupted recording left behind: harmless, and removed or committed by the next `make record`."""
    notes = []
    extra_rows = sum(pq.read_metadata(path).num_rows for path in episode_files(root)) - info["total_episodes"]
    stray_data = [path for path in data_files(root) if path not in data_paths]
    stray_mcap = [path for path in (root / MCAP_DIR).glob("*.mcap") if path not in mcap_paths]
    stray_videos = len(video_files(root)) - info["total_episodes"] * len(video_keys(info["features"]))
    partial = [path for path in root.rglob(f"*{PARTIAL_SUFFIX}") if path.parent.name not in SPOOLS]  # a spool's: below
    if extra_rows > 0 or stray_data or stray_mcap or partial or stray_videos > 0:
        notes.append(
            f"uncommitted files of an interrupted recording: {max(extra_rows, 0)} episode rows, "
            f"{len(stray_data)} data files, {len(stray_mcap)} MCAP files, {max(stray_videos, 0)} video files, "
            f"{len(partial)} partial files "
            "(the next `make record` removes them)"
        )
    for name, fate in SPOOLS.items():
        finished, cut_short = Spool(root, name).contents(info["total_episodes"])
        if finished or cut_short:
            notes.append(f"{name} holds {finished} finished episodes and {cut_short} partial files ({fate})")
    return notes


# Summary ---------------------------------------------------------------------------------------


def _summarise(dataset: Dataset) -> Report:
    episodes, frames, n = dataset.episodes, dataset.frames, dataset.num_episodes
    if columns.TERMINATED in frames:
        fell: int | None = sum(bool(frames[columns.TERMINATED][dataset.rows(e)].any()) for e in range(n))
    elif columns.EPISODE_TERMINATED in episodes:
        fell = sum(bool(value) for value in episodes[columns.EPISODE_TERMINATED])
    else:
        fell = None
    task_frames = (
        np.bincount(frames["task_index"].clip(0), minlength=len(dataset.tasks))
        if "task_index" in frames
        else np.zeros(0, np.int64)
    )
    tasks = {task: int(task_frames[i]) for i, task in enumerate(dataset.tasks)}
    controllers = None
    if columns.EPISODE_CONTROLLER in episodes:
        noise = episodes.get(columns.EPISODE_NOISE_STD, [None] * n)
        controllers = dict(
            Counter(
                f"{name} (noise {sigma:g})" if sigma is not None else str(name)
                for name, sigma in zip(episodes[columns.EPISODE_CONTROLLER], noise, strict=True)
            )
        )
    randomized = {name: _drawn_range(values) for name, values in columns.drawn_parameters(episodes).items()}
    readable = [m for m in dataset.mcap if m.problem is None]
    topics: Counter[str] = Counter()
    for m in readable:
        topics.update(m.counts)
    return Report(
        root=dataset.root,
        info=dataset.info,
        episodes=n,
        frames=len(frames["index"]) if "index" in frames else 0,
        tasks=tasks,
        controllers=controllers,
        randomized=randomized,
        seeds=[seed for seed in episodes.get(columns.EPISODE_SEED, []) if seed is not None],
        lengths=np.array(episodes["length"]),
        returns=dataset.returns(),
        fell=fell,
        sizes=_disk_sizes(dataset.root),
        mcap_readable=len(readable),
        mcap_counts=dict(topics),
        mcap_counts_match=sum(
            m.problem is None and _count_problem(m, length) is None
            for m, length in zip(dataset.mcap, episodes["length"], strict=True)
        ),
        leftovers=dataset.leftovers,
        runs=recordings.sessions(dataset.root, lambda: episodes.get(columns.EPISODE_SEED, [])),
    )


def _drawn_range(values: list) -> str:
    """The values a randomised parameter took over the episodes: "0.803..1.197 (13 per episode)", or for a count
    drawn per episode (the delay in steps) how many episodes drew each: "0 in 9 episodes, 1 in 11 episodes"."""
    drawn_values = [value for value in values if value is not None]
    if drawn_values and np.issubdtype(np.asarray(drawn_values).dtype, np.integer):
        counts = Counter(int(value) for value in drawn_values)
        return ", ".join(f"{value} in {counted(n, 'episode')}" for value, n in sorted(counts.items()))
    per_episode = [np.atleast_1d(np.array(value, dtype=float)) for value in drawn_values]
    if not per_episode:
        return "no value"
    drawn = np.concatenate(per_episode)
    counts = sorted({len(value) for value in per_episode})
    each = "" if counts == [1] else f" ({'/'.join(map(str, counts))} per episode)"
    return f"{drawn.min():.3f}..{drawn.max():.3f}{each}"


def _disk_sizes(root: Path) -> dict[str, int]:
    sizes = dict.fromkeys(("data", "meta", "mcap", "videos", "other"), 0)
    for path in root.rglob("*"):
        if path.is_file():
            top = path.relative_to(root).parts[0]
            kind = (
                top
                if top in ("data", "meta") and path.suffix == ".parquet"
                else ("mcap" if top == MCAP_DIR and path.suffix == ".mcap" else "other")
            )
            kind = "videos" if top == VIDEO_DIR and path.suffix == ".mp4" else kind
            sizes[kind] += path.stat().st_size
    return {**sizes, "total": sum(sizes.values())}


# Verification ----------------------------------------------------------------------------------


def _verify(dataset: Dataset, lerobot: _LeRobotLoad | None) -> list[str]:
    """Every check, in order; the first problem is raised as a DatasetError. What passed, for the summary."""
    _verify_episode_rows(dataset)
    _verify_frame_indices(dataset)
    _verify_tasks(dataset)
    _verify_stats(dataset)
    _verify_finite(dataset)
    _verify_episode_facts(dataset)
    _verify_mcap(dataset)
    cameras = _verify_videos(dataset)
    problem = lerobot.result() if lerobot else None
    if problem:
        raise DatasetError(f"LeRobot cannot load {dataset.root}: {problem}")
    compared = ", ".join(
        field for field, columns in STEP_COLUMNS.items() if all(column in dataset.frames for column in columns)
    )
    return [
        "LeRobot metadata: info.json, episodes, frame indices, tasks and stats.json consistent; "
        + ("LeRobot loads it" if lerobot else "LeRobot's own loader not run"),
        f"frames: every declared feature present with its shape; all {len(dataset.frames['index']):,} finite",
        f"MCAP: one message per frame on each per-step topic; {STEP_TOPIC} equals parquet ({compared}, task)",
        *(
            [f"cameras: {cameras}: one video frame per data frame, 1/fps apart, of the declared size"]
            if cameras
            else []
        ),
    ]


def _verify_episode_rows(dataset: Dataset) -> None:
    info, episodes, n = dataset.info, dataset.episodes, dataset.num_episodes
    if n != info["total_episodes"]:
        raise DatasetError(
            f"{EPISODES_DIR} holds {n} episodes, but info.json total_episodes is {info['total_episodes']}"
        )
    if episodes["episode_index"] != list(range(n)):
        missing = sorted(set(range(n)) - set(episodes["episode_index"]))
        raise DatasetError(f"{EPISODES_DIR}: episode_index is not 0..{n - 1} once each (missing {missing[:5]})")
    lengths = episodes["length"]
    if sum(lengths) != info["total_frames"]:
        raise DatasetError(
            f"info.json total_frames is {info['total_frames']}, but the episodes' lengths in "
            f"{EPISODES_DIR} sum to {sum(lengths)}"
        )
    start = 0
    for e in range(n):
        first, end = episodes["dataset_from_index"][e], episodes["dataset_to_index"][e]
        if first != start or end - first != lengths[e]:
            raise DatasetError(
                f"episode {e}: dataset_from_index..to_index is {first}..{end}, expected {start}.."
                f"{start + lengths[e]} (contiguous from 0, length {lengths[e]})"
            )
        start = end
    if dataset.data_rows != info["total_frames"]:
        raise DatasetError(
            f"the data files hold {dataset.data_rows} rows, but info.json total_frames is {info['total_frames']}"
        )


def _verify_frame_indices(dataset: Dataset) -> None:
    frames = dataset.frames
    for column in ("index", "episode_index", "frame_index", "task_index"):
        if column not in frames:
            raise DatasetError(f"the data files have no {column!r} column")
    index = frames["index"]
    if len(index) != dataset.info["total_frames"] or not np.array_equal(index, np.arange(len(index))):
        raise DatasetError(f"the frames' index column is not 0..{dataset.info['total_frames'] - 1} once each")
    for e in range(dataset.num_episodes):
        rows = dataset.rows(e)
        for column, expected in (
            ("episode_index", np.full(rows.stop - rows.start, e)),
            ("frame_index", np.arange(rows.stop - rows.start)),
        ):
            bad = np.flatnonzero(frames[column][rows] != expected)
            if len(bad):
                raise DatasetError(
                    f"episode {e}, frame {bad[0]}: {column} is {frames[column][rows][bad[0]]}, "
                    f"expected {expected[bad[0]]} ({dataset.where(e)})"
                )
    if "timestamp" in frames:
        # LeRobot's own tolerance (LeRobotDataset's tolerance_s) when it checks timestamps against fps.
        late = np.abs(frames["timestamp"] - frames["frame_index"] / dataset.info["fps"]) > TIMESTAMP_TOLERANCE_S
        if late.any():
            row = int(np.argmax(late))
            e = int(frames["episode_index"][row])
            raise DatasetError(
                f"episode {e}, frame {frames['frame_index'][row]}: timestamp {frames['timestamp'][row]} "
                f"is not frame_index / fps ({dataset.where(e)})"
            )


def _verify_tasks(dataset: Dataset) -> None:
    task_index, tasks = dataset.frames["task_index"], dataset.tasks
    bad = np.flatnonzero((task_index < 0) | (task_index >= len(tasks)))
    if len(bad):
        e = int(dataset.frames["episode_index"][bad[0]])
        raise DatasetError(
            f"episode {e}, frame {dataset.frames['frame_index'][bad[0]]}: task_index "
            f"{task_index[bad[0]]} is not in {TASKS_PATH} ({len(tasks)} tasks; {dataset.where(e)})"
        )
    used = set(np.unique(task_index).tolist())
    if used != set(range(len(tasks))):
        raise DatasetError(
            f"{TASKS_PATH} lists {len(tasks)} tasks but the frames use {len(used)} "
            f"(unused: {sorted(set(range(len(tasks))) - used)})"
        )
    if "tasks" in dataset.episodes:
        for e, listed in enumerate(dataset.episodes["tasks"]):
            own = {tasks[i] for i in np.unique(task_index[dataset.rows(e)]).tolist()}
            if set(listed or []) != own:
                raise DatasetError(
                    f"episode {e}: {EPISODES_DIR} lists tasks {sorted(listed or [])}, but its frames have {sorted(own)}"
                )


def _verify_stats(dataset: Dataset) -> None:
    path = dataset.root / STATS_PATH
    try:
        stats = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise DatasetError(f"{STATS_PATH} is not readable JSON ({one_line(error)})") from None
    for name, feature in dataset.info["features"].items():
        if feature["dtype"] in ("video", "image", "string"):
            continue  # LeRobot keeps no statistics, or per-channel image ones computed otherwise
        if name not in stats:
            raise DatasetError(f"{STATS_PATH} has no statistics for {name!r}")
        count = stats[name].get("count")
        if count is not None and np.atleast_1d(count).tolist() != [dataset.info["total_frames"]]:
            # The recorder writes stats.json just before info.json: a kill between the two leaves this.
            hint = (
                "; a recording killed before its commit? the next `make record` rebuilds it"
                if np.atleast_1d(count)[0] > dataset.info["total_frames"]
                else ""
            )
            raise DatasetError(
                f"{STATS_PATH}: {name!r} counts {count} frames, but info.json total_frames is "
                f"{dataset.info['total_frames']}{hint}"
            )


def _verify_finite(dataset: Dataset) -> None:
    for name, values in dataset.frames.items():
        if not np.issubdtype(values.dtype, np.floating):
            continue  # integers and flags cannot be NaN
        finite = np.isfinite(values.reshape(len(values), -1))
        if finite.all():
            continue
        row, dimension = np.argwhere(~finite)[0]
        e = int(dataset.frames["episode_index"][row])
        names = dataset.info["features"].get(name, {}).get("names") or []
        label = (
            f"{name}[{dimension}]" + (f" ({names[dimension]})" if dimension < len(names) else "")
            if values.ndim > 1
            else name
        )
        raise DatasetError(
            f"episode {e}, frame {dataset.frames['frame_index'][row]}: {label} is "
            f"{values.reshape(len(values), -1)[row, dimension]} ({dataset.where(e)})"
        )


def _verify_episode_facts(dataset: Dataset) -> None:
    """The project's episode columns (return, terminated, truncated) agree with the frames, where present."""
    frames, episodes = dataset.frames, dataset.episodes
    for e in range(dataset.num_episodes):
        rows = dataset.rows(e)
        if columns.EPISODE_RETURN in episodes and columns.REWARD in frames:
            stated, summed = episodes[columns.EPISODE_RETURN][e], float(frames[columns.REWARD][rows].sum())
            # Summed from the same float64 rewards, in the same order: only the last bits may differ.
            if stated is None or not math.isclose(stated, summed, rel_tol=1e-9, abs_tol=1e-9):
                raise DatasetError(
                    f"episode {e}: {EPISODES_DIR} return is {stated}, but its {columns.REWARD} "
                    f"sums to {summed} ({dataset.where(e)})"
                )
        for column, flag in (
            (columns.EPISODE_TERMINATED, columns.TERMINATED),
            (columns.EPISODE_TRUNCATED, columns.TRUNCATED),
        ):
            if column in episodes and flag in frames:
                last = bool(frames[flag][rows][-1])
                if episodes[column][e] != last:
                    raise DatasetError(
                        f"episode {e}: {EPISODES_DIR} {column} is {episodes[column][e]}, but its "
                        f"last frame's {flag} is {last} ({dataset.where(e)})"
                    )


def video_path(dataset: Dataset, key: str, episode: int) -> Path:
    """Where episode `episode`'s frames of the video feature `key` are."""
    row = {name: values[episode] for name, values in dataset.episodes.items() if name.startswith(f"videos/{key}/")}
    chunk, file = row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"]
    return video_file(dataset.root, dataset.info, key, chunk, file)


def _video_times(path: Path) -> tuple[np.ndarray, tuple[int, int]]:
    """The presentation times (s, sorted) of every frame of the video file at `path` and its (height, width), from
    its packets (nothing decoded); DatasetError if it cannot be read."""
    import av  # noqa: PLC0415 - only for datasets with cameras

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            times = [float(p.pts * p.time_base) for p in container.demux(stream) if p.pts is not None]
            return np.sort(times), (stream.codec_context.height, stream.codec_context.width)
    except (av.FFmpegError, IndexError) as error:
        raise DatasetError(f"{path} is not a readable video ({one_line(error)})") from None


def _verify_videos(dataset: Dataset) -> str:
    """Each camera's frames of each episode: in its file, between the row's from and to timestamps, one per data frame,
    1/fps apart, of the declared size. The cameras checked, named."""
    info, fps = dataset.info, dataset.info["fps"]
    keys = video_keys(info["features"])
    read: dict[Path, tuple[np.ndarray, tuple[int, int]]] = {}
    for key in keys:
        size = tuple(info["features"][key]["shape"][:2])
        for e, length in enumerate(dataset.episodes["length"]):
            path = video_path(dataset, key, e)
            where = path.relative_to(dataset.root)
            if not path.is_file():
                raise DatasetError(f"episode {e}: {where} is missing (meta/episodes points to it)")
            if path not in read:
                read[path] = _video_times(path)
            times, shape = read[path]
            if shape != size:
                raise DatasetError(f"episode {e}: {where} is {shape[0]}x{shape[1]}, info.json declares {key} {size}")
            start = dataset.episodes[f"videos/{key}/from_timestamp"][e]
            end = dataset.episodes[f"videos/{key}/to_timestamp"][e]
            inside = times[(times >= start - TIMESTAMP_TOLERANCE_S) & (times < end - TIMESTAMP_TOLERANCE_S)]
            if len(inside) != length:
                raise DatasetError(f"episode {e}: {where} holds {len(inside)} frames of {key} for {length} data frames")
            if not np.allclose(inside - start, np.arange(length) / fps, atol=TIMESTAMP_TOLERANCE_S, rtol=0):
                raise DatasetError(f"episode {e}: {where}'s frames of {key} are not 1/{fps} s apart from {start} s")
    return ", ".join(key.removeprefix(columns.OBS_IMAGES + ".") for key in keys)


def _count_problem(mcap: McapFile, length: int) -> str | None:
    if STEP_TOPIC not in mcap.counts:
        return f"has no {STEP_TOPIC} topic"
    for topic, count in sorted(mcap.counts.items()):
        if topic not in ONCE_TOPICS and count != length:
            return f"has {count} {topic} messages for {length} frames"
        if topic in ONCE_TOPICS and count != 1:
            return f"has {count} {topic} messages, not one"
    return None


def _verify_mcap(dataset: Dataset) -> None:
    """Counts first for every file (from the summaries, cheap), then /step contents file by file."""
    lengths = dataset.episodes["length"]
    for e, mcap in enumerate(dataset.mcap):
        problem = mcap.problem or _count_problem(mcap, lengths[e])
        if problem:
            raise DatasetError(f"episode {e}: {mcap.path.relative_to(dataset.root)} {problem}")
    for e, mcap in enumerate(dataset.mcap):
        problem = _step_problem(dataset, e, mcap.path)
        if problem:
            raise DatasetError(f"episode {e}: {mcap.path.relative_to(dataset.root)} {problem}")


def _step_problem(dataset: Dataset, episode: int, path: Path) -> str | None:
    """How the /step messages of `path` differ from the episode's parquet frames; None if they are equal."""
    try:
        steps = read_steps(path)
    except Exception as error:
        return f"has unreadable {STEP_TOPIC} messages ({one_line(error)})"
    frames, rows = dataset.frames, dataset.rows(episode)
    length = rows.stop - rows.start
    if len(steps["task"]) != length:
        return f"holds {len(steps['task'])} {STEP_TOPIC} messages, but the episode has {length} frames"
    expected = {
        name: np.concatenate([frames[c][rows].reshape(length, -1) for c in names], axis=1)
        for name, names in STEP_COLUMNS.items()
        if all(c in frames for c in names)
    }
    if "observation" in expected:
        order = dataset.observation_order
        if order is None:
            return f"cannot be compared: {' + '.join(OBSERVATION_COLUMNS)} do not name every observation entry"
        expected["observation"] = expected["observation"][:, order]
    if "state" in expected and not steps["state"].size:  # recorded before /step carried the state
        del expected["state"]
    for name, values in expected.items():
        got = steps[name].reshape(length, -1)
        what = f"{STEP_TOPIC}.{name} differs from parquet {' + '.join(STEP_COLUMNS[name])}"
        if got.shape != values.shape:
            return f"{what}: {got.shape[1]} values per step, not {values.shape[1]}"
        differs = np.flatnonzero((got != values).any(axis=1))
        if len(differs):
            return f"{what} at frame {differs[0]}"
    final_state = dataset.episodes.get(columns.EPISODE_FINAL_STATE)
    if final_state is not None:  # recorded with the final observation: /final_observation holds the same
        try:
            final = read_mcap_final(path)
        except Exception as error:
            return f"has no readable {FINAL_TOPIC} message ({one_line(error)})"
        if final["frame_index"] != length or not np.array_equal(final["state"], final_state[episode]):
            return f"{FINAL_TOPIC} differs from the episode's {columns.EPISODE_FINAL_STATE}"
    task_names = [dataset.tasks[i] for i in frames["task_index"][rows].tolist()]
    differs = [t for t, (got, want) in enumerate(zip(steps["task"], task_names, strict=True)) if got != want]
    if differs:
        return f"{STEP_TOPIC}.task differs from parquet task_index at frame {differs[0]}"
    return None


class _LeRobotLoad:
    """LeRobot's own metadata loader run on the dataset in a child process, started on construction."""

    def __init__(self, root: Path) -> None:
        # Offline whatever the caller's environment: a local dataset must never send LeRobot to the Hub.
        env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
        # stderr is dropped: LeRobot logs warnings there that say nothing about this dataset.
        self.process = subprocess.Popen(
            [sys.executable, "-c", _LEROBOT_LOAD, str(root.resolve())],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )

    def result(self) -> str | None:
        """None if LeRobot loaded the metadata, else its error in one line."""
        stdout, _ = self.process.communicate()
        if self.process.returncode == 0:
            return None
        lines = [line.strip() for line in stdout.splitlines() if line.strip()]
        return lines[-1] if lines else f"its loader exited with code {self.process.returncode}"

    def close(self) -> None:
        """Stop the child if the result was not needed (an earlier problem)."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate()


# Plot ------------------------------------------------------------------------------------------


def plot(dataset: Dataset, path: Path) -> None:
    """Returns per episode, torso height over time for a few episodes, and one histogram per action dimension."""
    from matplotlib.figure import Figure  # noqa: PLC0415 - the object API draws to files without a GUI backend

    frames, info, n = dataset.frames, dataset.info, dataset.num_episodes
    actions = frames.get(columns.ACTION)
    action_names = info["features"].get(columns.ACTION, {}).get("names") or []
    per_row = 6
    hist_rows = 0 if actions is None else math.ceil(actions.shape[1] / per_row)
    figure = Figure(figsize=(3 * per_row, 4 + 2 * hist_rows))
    grid = figure.add_gridspec(1 + hist_rows, per_row, height_ratios=[2] + [1] * hist_rows)

    returns = np.nan_to_num(dataset.returns())
    axes = figure.add_subplot(grid[0, : per_row // 2])
    axes.bar(np.arange(n), returns, color="tab:blue")
    axes.set_xlabel("episode")
    axes.set_ylabel("return")
    axes.set_title(f"return per episode ({n} episodes)")

    axes = figure.add_subplot(grid[0, per_row // 2 :])
    holder = next(
        (key for key in OBSERVATION_COLUMNS if TORSO_HEIGHT in (info["features"].get(key, {}).get("names") or [])),
        None,
    )
    if holder is not None and holder in frames:
        column = info["features"][holder]["names"].index(TORSO_HEIGHT)
        for e in _plotted_episodes(returns):
            height = frames[holder][dataset.rows(e), column]
            axes.plot(np.arange(len(height)), height, label=f"episode {e} (return {returns[e]:,.0f})")
        axes.legend(fontsize="small")
        axes.set_title("torso height")
    else:
        axes.set_title(f"no {TORSO_HEIGHT} in {' or '.join(OBSERVATION_COLUMNS)}")
    axes.set_xlabel("step")
    axes.set_ylabel(f"{TORSO_HEIGHT} (m)")

    if actions is not None:
        executed = frames.get(columns.EXECUTED_ACTION)
        both = executed is not None and executed.shape == actions.shape
        for d in range(actions.shape[1]):
            axes = figure.add_subplot(grid[1 + d // per_row, d % per_row])
            # Shared bins: the executed action's wider spread is the injected noise, to be compared by eye.
            values = np.concatenate([actions[:, d], executed[:, d]]) if both else actions[:, d]
            bins = np.histogram_bin_edges(values, bins=50)
            axes.hist(actions[:, d], bins=bins, color="tab:blue", label=columns.ACTION)
            if both:
                axes.hist(executed[:, d], bins=bins, histtype="step", color="tab:orange", label=columns.EXECUTED_ACTION)
            axes.set_title(action_names[d] if d < len(action_names) else f"{columns.ACTION}[{d}]", fontsize="small")
            axes.tick_params(labelsize="x-small")
            if d == 0:
                axes.legend(fontsize="x-small")
    figure.suptitle(f"{dataset.root}: {n} episodes, {len(frames['index']):,} frames")
    figure.tight_layout()
    save_figure(figure, path, dpi=80)


SHEET_FRAMES = 6
"""Frames per episode on the contact sheet, evenly spread from its first to its last."""


def contact_sheet(dataset: Dataset, path: Path) -> None:
    """A few episodes' frames per camera (`SHEET_FRAMES` each, for the episodes `plot` draws), one row per episode and
    camera, each frame titled with its time: a recording checked by eye."""
    import av  # noqa: PLC0415 - only for datasets with cameras
    from matplotlib.figure import Figure  # noqa: PLC0415 - as in `plot`

    fps, keys = dataset.info["fps"], video_keys(dataset.info["features"])
    episodes = _plotted_episodes(np.nan_to_num(dataset.returns()))
    figure = Figure(figsize=(2.2 * SHEET_FRAMES, 1.9 * len(episodes) * len(keys)))
    grid = figure.add_gridspec(len(episodes) * len(keys), SHEET_FRAMES)
    for r, (e, key) in enumerate((e, key) for e in episodes for key in keys):
        length, start = dataset.episodes["length"][e], dataset.episodes[f"videos/{key}/from_timestamp"][e]
        wanted = np.linspace(0, length - 1, SHEET_FRAMES).round().astype(int)
        frames: dict[int, np.ndarray] = {}
        with av.open(str(video_path(dataset, key, e))) as container:
            for frame in container.decode(video=0):
                row = round((float(frame.pts * frame.time_base) - start) * fps)
                if row in wanted:
                    frames[row] = frame.to_ndarray(format="rgb24")
                if row >= wanted[-1]:
                    break
        for c, row in enumerate(wanted):
            axes = figure.add_subplot(grid[r, c])
            if row in frames:
                axes.imshow(frames[row])
            axes.set_axis_off()
            axes.set_title(
                f"{row / fps:.1f} s" if c else f"ep {e} {key.removeprefix(columns.OBS_IMAGES + '.')}, 0 s",
                fontsize="small",
            )
    figure.suptitle(f"{dataset.root}: cameras, {len(episodes)} of {dataset.num_episodes} episodes")
    figure.tight_layout()
    save_figure(figure, path, dpi=80)


def _plotted_episodes(returns: np.ndarray) -> list[int]:
    """Up to PLOTTED_EPISODES episodes spread over the dataset, always with the lowest return (a fall shows)."""
    n = len(returns)
    chosen = {int(i) for i in np.linspace(0, n - 1, min(n, PLOTTED_EPISODES - 1)).round()}
    chosen.add(int(np.argmin(returns)))
    return sorted(chosen)[:PLOTTED_EPISODES]


# Command line ----------------------------------------------------------------------------------


def _print(text: str) -> None:
    print(text, flush=True)  # the summary must show while the verification runs, piped or not


def _main_and_print(cfg: InspectConfig) -> None:
    main(cfg, show=_print)


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, InspectConfig, argv, description=__doc__, prog="python -m teleop.inspect_dataset")


if __name__ == "__main__":
    sys.exit(cli())
