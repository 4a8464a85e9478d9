"""`make merge SHARDS="a b" DATASET=out`: datasets recorded apart (one per node) as one, in seed order.

    each shard's episodes (parquet frames and episode columns, MCAP /step, /tf, /final_observation, the cameras'
    videos, JPEGs and statistics)
      -> the Episode the recorder had in memory (read_episode)
      -> teleop.store.EpisodeStore.append, in seed order, as the recorder commits them

Past one writer's throughput each node records its own dataset on its own seed range
(docs/concepts/ray.md). Merging re-commits every episode through the recorder's own store, so the
result is the dataset one recorder would have written for the same seeds, file for file (a test;
recordings.jsonl holds the merge's line, with the shards' own lines in it), with its guarantees:
one data and MCAP file per episode, an episode committed whole or not at all.
Killed, the same command continues: the seeds already in DATASET are skipped. LeRobot's
`aggregate_datasets` merges the LeRobot part only (no MCAP); the measurements are in
docs/concepts/ray.md.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from tqdm import tqdm

from common import columns, paths
from common.cli import UserError, config_dict, counted, run_cli, setting
from humanoid.cameras import CameraTrack, parse_cameras
from humanoid.env import make_env
from rollout.episode import Episode
from teleop import recordings
from teleop.dataset_reader import (
    read_commanded_frames,
    read_episodes,
    read_info,
    read_mcap_final,
    read_steps,
    read_videos,
)
from teleop.lerobot_io.format import INFO_PATH, cameras_spec
from teleop.mcap_io.writer import IMAGE_TOPIC, TF_TOPIC, camera_frame
from teleop.seeds import seed_clash
from teleop.spool import SPOOLS
from teleop.store import DatasetSpec, EpisodeStore


@dataclass
class MergeConfig:
    """Settings of one merge."""

    shards: str = setting(
        "", "the datasets to merge, separated by spaces or commas; their seeds must not overlap (teleop/seeds.py)"
    )
    dataset: Path = setting(paths.DATASET, "the merged dataset: created if missing, else continued (same seeds)")
    progress: bool = setting(True, "show a progress bar")


MADE_BY = "teleop.merge"


def read_body_poses(path: Path, body_frames: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Every step's positions (T, B, 3) and orientations (T, B, 4, w-x-y-z) of `body_frames` (bodies, cameras) from an
    MCAP file's /tf."""
    positions, orientations = [], []
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, decoded in reader.iter_decoded_messages(topics=[TF_TOPIC]):
            poses = {t.child_frame_id: t for t in decoded.transforms}
            frames = [poses[name] for name in body_frames]
            positions.append([(f.translation.x, f.translation.y, f.translation.z) for f in frames])
            orientations.append([(f.rotation.w, f.rotation.x, f.rotation.y, f.rotation.z) for f in frames])
    return np.array(positions, np.float64), np.array(orientations, np.float64)


FRAME_COLUMNS = (columns.OBS_COMMAND, columns.SETPOINT, columns.PUSH)
"""The per-frame columns that only the dataset holds (the MCAP files hold the rest of an episode)."""


def read_cameras(
    path: Path,
    videos: dict[str, tuple[Path, dict[str, np.ndarray]]],
    positions: np.ndarray,
    orientations: np.ndarray,
) -> dict[str, CameraTrack]:
    """The camera tracks of the episode whose MCAP file is `path`, as the recorder had them: `videos` (the video files
    and statistics, `teleop.dataset_reader.read_videos`), the MCAP's JPEGs (read in one pass), and each camera's /tf
    poses, (T, cameras, 3) `positions` and (T, cameras, 4) `orientations` in `videos`' order."""
    names = [key.removeprefix(columns.OBS_IMAGES + ".") for key in videos]
    topics = {IMAGE_TOPIC.format(name=name): name for name in names}
    images: dict[str, list[bytes]] = {name: [] for name in names}
    if topics:
        with path.open("rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, _, message in reader.iter_decoded_messages(topics=list(topics)):
                images[topics[channel.topic]].append(message.data)
    return {
        name: CameraTrack(video.read_bytes(), images[name], positions[:, i], orientations[:, i], stats)
        for i, (name, (video, stats)) in enumerate(zip(names, videos.values(), strict=True))
    }


def read_episode(
    root: Path,
    row: dict,
    arrays: dict[str, np.ndarray],
    body_frames: list[str],
    videos: dict[str, tuple[Path, dict[str, np.ndarray]]] | None = None,
) -> Episode:
    """The episode of `row` (its episode columns) as the recorder had it; `arrays` holds its frames' commands,
    setpoints and pushes (`FRAME_COLUMNS`), `videos` its cameras' (`read_cameras`)."""
    path = root / row[columns.EPISODE_MCAP]
    steps = read_steps(path)
    videos = videos or {}
    cameras = [camera_frame(key.removeprefix(columns.OBS_IMAGES + ".")) for key in videos]
    positions, orientations = read_body_poses(path, [*body_frames, *cameras])  # one pass over /tf
    bodies = len(body_frames)
    body_position, body_orientation = positions[:, :bodies], orientations[:, :bodies]
    return Episode(
        seed=row[columns.EPISODE_SEED],
        controller=row[columns.EPISODE_CONTROLLER],
        labeller=row[columns.EPISODE_LABELLER],
        noise_std=row[columns.EPISODE_NOISE_STD],
        observation=steps["observation"],
        action=steps["action"],
        executed_action=steps["executed_action"],
        reward=steps["reward"],
        terminated=steps["terminated"],
        truncated=steps["truncated"],
        body_position=body_position,
        body_orientation=body_orientation,
        command=arrays[columns.OBS_COMMAND],
        setpoint=arrays[columns.SETPOINT],
        push=arrays[columns.PUSH],
        tasks=steps["task"],
        final_observation=read_mcap_final(path)["observation"],
        dagger_round=row[columns.EPISODE_DAGGER_ROUND],
        parameters=columns.drawn_parameters(row),
        cameras=read_cameras(path, videos, positions[:, bodies:], orientations[:, bodies:]),
    )


def shard_list(text: str) -> list[Path]:
    return [Path(name) for name in text.replace(",", " ").split()]


def check_finished(shard: Path) -> None:
    """UserError in one line if a run killed in `shard` left work there (its mark, episodes waiting in a spool): the
    next run there finishes it, and its episodes would come after those merged, out of seed order."""
    left = ["its mark"] if recordings.marked(shard) is not None else []
    left += [name for name in SPOOLS if any((shard / name).glob("*.npz"))]
    if left:
        raise UserError(
            f"{shard} holds what a killed run left ({', '.join(left)}): the next run on it "
            f"(`make record DATASET={shard}`, `make dagger` on an aggregate) finishes it; merge after"
        )


def _plan(shards: list[Path]) -> tuple[list[tuple[int, Path, dict]], tuple[str, ...], dict]:
    """Every shard episode as (seed, shard, episode columns) in seed order; the drawn parameters; the features."""
    if not shards:
        raise UserError("--shards names no dataset")
    episodes, features, parameters = [], None, None
    for number, shard in enumerate(shards):
        if not (shard / INFO_PATH).is_file():
            raise UserError(f"{shard} is not a dataset (no {INFO_PATH})")
        check_finished(shard)
        info = read_info(shard)
        if features is not None and info["features"] != features:
            raise UserError(f"{shard} was recorded with other features than {shards[0]}: they cannot be one dataset")
        features = info["features"]
        rows = read_episodes(shard).to_pylist()
        missing = [row[columns.EPISODE_MCAP] for row in rows if not (shard / row[columns.EPISODE_MCAP]).is_file()]
        if missing:
            raise UserError(f"{shard} lacks {missing[0]}, one of its episodes' MCAP files: copy the shard again")
        drawn = tuple(columns.drawn_parameters(rows[0])) if rows else None
        if drawn is not None and parameters is not None and set(drawn) != set(parameters):
            raise UserError(f"{shard} draws other physical parameters than {shards[0]}")
        parameters = parameters if drawn is None else drawn
        earlier = ", ".join(map(str, shards[:number])) or str(shard)
        clash = seed_clash([row[columns.EPISODE_SEED] for row in rows], [seed for seed, _, _ in episodes], earlier)
        if clash:
            raise UserError(f"shard {shard}: {clash}; record it again from there")
        episodes += [(row[columns.EPISODE_SEED], shard, row) for row in rows]
    episodes.sort(key=lambda episode: episode[0])
    return episodes, parameters or (), features or {}


def main(cfg: MergeConfig) -> int:
    """Commit every shard episode not yet in DATASET, in seed order; returns how many were added. The run's line in
    DATASET/recordings.jsonl holds each shard's own lines (`recordings.SESSIONS_KEY`): how its episodes were
    recorded travels with them."""
    shards = shard_list(cfg.shards)
    if any(shard.resolve() == cfg.dataset.resolve() for shard in shards):
        raise UserError(f"--shards names {cfg.dataset}, the DATASET merged into: a shard cannot be merged into itself")
    resolved = [shard.resolve() for shard in shards]
    twice = next((shard for n, shard in enumerate(shards) if resolved[n] in resolved[:n]), None)
    if twice is not None:
        raise UserError(f"--shards names {twice} twice: give each shard once")
    episodes, parameters, features = _plan(shards)
    sessions = {recordings.SESSIONS_KEY: {str(shard): recordings.read(shard) for shard in shards}}
    cameras = parse_cameras(cameras_spec(features))
    store = EpisodeStore(cfg.dataset, DatasetSpec.from_env(make_env(), parameters, cameras))
    try:
        have = read_episodes(cfg.dataset)[columns.EPISODE_SEED].to_pylist() if store.num_episodes else []
        if have != [seed for seed, _, _ in episodes[: len(have)]]:
            raise UserError(
                f"{cfg.dataset} holds other episodes than the first {len(have)} of these shards' seeds: merge into a "
                "new DATASET (a merge goes on only where an earlier merge of the same shards stopped)"
            )
        commands: dict[Path, dict[str, np.ndarray]] = {}  # each shard's FRAME_COLUMNS, read once
        videos: dict[Path, list] = {}  # and its cameras' videos
        with recordings.logged(cfg.dataset, MADE_BY, config_dict(cfg), len(have), lambda: have, sessions) as added:
            for _, shard, row in tqdm(episodes[len(have) :], unit="ep", disable=not cfg.progress, file=sys.stderr):
                if shard not in commands:
                    commands[shard] = read_commanded_frames(shard, [*FRAME_COLUMNS, "episode_index"])
                    videos[shard] = read_videos(shard)
                frames = commands[shard]
                mine = frames["episode_index"] == row["episode_index"]
                arrays = {key: frames[key][mine] for key in FRAME_COLUMNS}
                added.append(
                    store.append(
                        read_episode(shard, row, arrays, store.spec.body_frames, videos[shard][row["episode_index"]])
                    )
                )
    finally:
        store.close()
    return len(added)


def _main_and_print(cfg: MergeConfig) -> None:
    added = main(cfg)
    print(f"{cfg.dataset}: added {counted(added, 'episode')} from {counted(len(shard_list(cfg.shards)), 'shard')}")


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, MergeConfig, argv, description=__doc__, prog="python -m teleop.merge")


if __name__ == "__main__":
    sys.exit(cli())
