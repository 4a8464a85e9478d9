"""Merging per-node dataset shards: `make merge` against LeRobot's own `aggregate_datasets`, speed and what survives.

    .venv/bin/python -m bench.shard_merge [--episodes 10]

Past one writer (docs/concepts/ray.md), each node records its own dataset on a disjoint seed range and
the shards are merged afterwards. This records two shards (seeds 0.. and EPISODES..) and the same
seeds in one go, merges the shards with `lerobot.datasets.aggregate.aggregate_datasets`, times it
against copying the shards (a floor: the bytes have to move anyway), and checks the merge against
the one-go recording: LeRobot loads it, the frames are equal, which of our episode columns and
files are kept. `make merge` (`teleop.merge`) is timed on the same shards, and its result compared
with the one-go recording file by file.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from lerobot.datasets.aggregate import aggregate_datasets
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from common import columns
from teleop import recordings
from teleop.dataset_reader import read_episodes, read_frames
from teleop.merge import MergeConfig
from teleop.merge import main as merge
from teleop.record import STANDING, STANDING_NOISE, RecordConfig, main


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file of the dataset at `root` with its bytes, but its history (recordings.jsonl): the merge's says that
    it merged, and the one-go recording here, made by `teleop.record.main` rather than its command line, has none."""
    files = (p for p in sorted(root.rglob("*")) if p.is_file() and p.name != recordings.RECORDINGS_FILE)
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def record(root: Path, episodes: int, seed: int) -> None:
    main(
        RecordConfig(
            dataset=root, episodes=episodes, seed=seed, workers=2, progress=False, noise=STANDING_NOISE, **STANDING
        )
    )


def checks(merged: Path, whole: Path) -> dict[str, bool]:
    """Each property of the one-go recording that the merge has (True) or lost (False)."""
    ours, theirs = read_frames(merged), read_frames(whole)
    compared = [columns.ACTION, columns.OBS_STATE, columns.OBS_ENV_STATE]
    # A merged (multi-episode) parquet file comes back as one array per row: stacked, the values compare.
    ours = {c: np.stack(list(ours[c])) if ours[c].dtype == object else ours[c] for c in compared}
    ours_episodes, whole_episodes = read_episodes(merged), read_episodes(whole)
    extra = [name for name in whole_episodes.column_names if name not in ours_episodes.column_names]
    try:
        loads = len(LeRobotDataset("local/merged", root=merged)) == len(theirs["index"])
    except Exception as error:  # what LeRobot says about it is the finding
        print(f"LeRobot refuses the merge: {error!r}")
        loads = False
    return {
        "LeRobot loads it, every frame": loads,
        "frames equal (action, both observations)": all(np.array_equal(ours[c], theirs[c]) for c in compared),
        f"our episode columns ({len(whole_episodes.column_names)})": not extra,
        "MCAP files copied": (merged / "mcap").is_dir(),
        "MCAP paths unique": len(set(ours_episodes[columns.EPISODE_MCAP].to_pylist())) == len(ours_episodes),
        "one data file per episode (what appending and crash safety assume)": len(
            list((merged / "data").rglob("*.parquet"))
        )
        == len(ours_episodes),
        "meta/info.json identical": (merged / "meta/info.json").read_bytes() == (whole / "meta/info.json").read_bytes(),
    } | ({} if not extra else {f"lost: {', '.join(extra)}": False})


def main_() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=10, help="episodes per shard")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        shards = [root / "shard_0", root / "shard_1"]
        for index, shard in enumerate(shards):
            record(shard, args.episodes, index * args.episodes)
        record(root / "whole", 2 * args.episodes, 0)
        start = time.perf_counter()
        for shard in shards:
            shutil.copytree(shard, root / "copies" / shard.name)
        copy_s = time.perf_counter() - start
        start = time.perf_counter()
        aggregate_datasets(["local/shard_0", "local/shard_1"], "local/merged", roots=shards, aggr_root=root / "merged")
        merge_s = time.perf_counter() - start
        results = checks(root / "merged", root / "whole")
        start = time.perf_counter()
        merge(MergeConfig(shards=" ".join(map(str, shards)), dataset=root / "ours", progress=False))
        ours_s = time.perf_counter() - start
        identical = snapshot(root / "ours") == snapshot(root / "whole")
    episodes = 2 * args.episodes
    print(f"\nTwo shards of {args.episodes} expert episodes (1000 frames each), merged:\n")
    print("| | seconds | ms per episode |\n|---|---|---|")
    print(f"| `make merge` (`teleop.merge`) | {ours_s:.2f} | {ours_s / episodes * 1000:.0f} |")
    print(f"| `aggregate_datasets` | {merge_s:.2f} | {merge_s / episodes * 1000:.0f} |")
    print(f"| copying the shards (floor) | {copy_s:.2f} | {copy_s / episodes * 1000:.0f} |\n")
    same = "yes" if identical else "NO"
    print(f"`make merge`: every file but its history identical to the one-go recording: {same}\n")
    print("`aggregate_datasets`:")
    for check, kept in results.items():
        print(f"- {check}: {'kept' if kept else 'NOT kept'}")


if __name__ == "__main__":
    main_()
