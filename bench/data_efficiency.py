"""Behaviour cloning's data efficiency: how many demonstrations it takes to stand, full or sensed inputs.

    .venv/bin/python -m bench.data_efficiency [--demos 5 10 20 50] [--first-seeds 0 10000 20000]
        [--inputs full proprio pending] [--work FOLDER] [--json bench/results/data_efficiency.json]

Why: the DART table (`bench/bc_benchmark.py`) trains on 50 demonstrations only, from one seed
range; it does not say whether 5 would do, nor how much that depends on which seeds were
recorded, nor whether a policy that reads only what a robot senses (`--inputs proprio`, the 48
features of observation.state, humanoid/sensors.py) stands at all.

What: for each first seed (disjoint seed ranges) and each N, record N episodes of each input's
teacher (TEACHERS: the expert with the recorder's DART noise 0.05 for full and proprio, the expert on
leg odometry with the same noise for pending, whose inputs it alone explains) on seeds FIRST..FIRST+N-1 into
their own dataset folder, so N=5 is the first 5 seeds of the range, N=10 the first 10, and so on;
train `bc.train` with its defaults once per INPUTS setting; evaluate the policy on the
unseen seeds 1000..1019, which no recording or selection uses. The expert on the same seeds is the
reference row. Prints the table in Markdown and writes every cell to a JSON file. Datasets and
policies go to a temporary folder, or to --work (where a complete dataset from an earlier run is
reused, and policies are retrained).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

from bc.train import TrainConfig
from bc.train import main as train
from bench.bc_benchmark import RESULTS
from common import columns
from common.cli import counted, write_json
from common.seed_ranges import EVAL_SEED
from evaluation.evaluate import evaluate
from students.learned import PolicyController
from task.command_fields import STAND
from teleop.dataset_reader import read_episodes
from teleop.lerobot_io.format import INFO_PATH
from teleop.record import STANDING_NOISE, RecordConfig
from teleop.record import main as record

DEMOS = (5, 10, 20, 50)
FIRST_SEEDS = (0, 10_000, 20_000)
TEACHERS = {
    "full": ("expert", STANDING_NOISE),
    "proprio": ("expert", STANDING_NOISE),
    "pending": ("expert-sensed", STANDING_NOISE),
}
"""Who records each input's demonstrations, and with what DART noise. The expert on leg odometry records with the
expert's noise here, not the pipeline's lower DART_NOISE: from 5 and 10 demonstrations without latency, the
recoveries from its falls at 0.05 are what made students stand (docs/decisions/dart-noise.md, "σ 0.03 for the
sensed expert")."""
INPUTS = tuple(TEACHERS)
EVAL_EPISODES = 20


@dataclass
class Cell:
    """One trained policy: its data, and how it did on the evaluation seeds."""

    first_seed: int
    demos: int
    inputs: str
    demos_fallen: int  # recorded episodes in which the noisy expert itself fell (kept in the data, as always)
    train_episodes: int
    val_episodes: int
    train_frames: int
    survived: int
    episodes: int
    mean_return: float
    train_seconds: float
    teacher: str = "expert"


def check_seeds(first_seeds: Sequence[int], demos: Sequence[int], eval_seed: int, eval_episodes: int) -> None:
    """ValueError unless the recording ranges are disjoint from each other and from the evaluation seeds."""
    ranges = sorted((first, first + max(demos)) for first in first_seeds)
    ranges_and_eval = sorted([*ranges, (eval_seed, eval_seed + eval_episodes)])
    # Sorted by start, two ranges overlap only if some neighbouring pair does.
    for (_, end), (start, _) in pairwise(ranges_and_eval):
        if start < end:
            raise ValueError(
                f"seed ranges overlap: recordings {[f'{a}..{b - 1}' for a, b in ranges]}, "
                f"evaluation {eval_seed}..{eval_seed + eval_episodes - 1}"
            )


def dataset_dir(work: Path, teacher: str, first_seed: int, demos: int) -> Path:
    return work / "data" / f"{teacher}_seeds_{first_seed}_n{demos}"


def recorded(
    root: Path, first_seed: int, demos: int, workers: int, teacher: str, noise: float, latency: float = 0.0
) -> int:
    """Record seeds first_seed..first_seed+demos-1 into `root` unless it holds exactly them; episodes that fell.
    `latency`: the recorder's share of episodes delayed by one step (`make record LATENCY=`).

    Anything else in `root` (an interrupted run, other seeds) is removed first: the recorder would append to it.
    """
    wanted = list(range(first_seed, first_seed + demos))
    if (root / INFO_PATH).exists():
        try:
            episodes = read_episodes(root, [columns.EPISODE_SEED, columns.EPISODE_TERMINATED]).to_pydict()
        except FileNotFoundError:  # created, nothing committed yet
            episodes = {columns.EPISODE_SEED: []}
        if episodes[columns.EPISODE_SEED] == wanted:
            return sum(episodes[columns.EPISODE_TERMINATED])
    shutil.rmtree(root, ignore_errors=True)
    cfg = RecordConfig(
        dataset=root,
        episodes=demos,
        seed=first_seed,
        controller=teacher,
        noise=noise,
        latency=latency,
        task=STAND,
        workers=workers,
        progress=False,
    )
    summary = record(cfg)
    return sum(episode.fell for episode in summary.episodes)


def train_and_evaluate(root: Path, policy: Path, inputs: str, eval_seed: int, eval_episodes: int) -> dict[str, Any]:
    """Train with the default recipe on `root`, then evaluate the trained policy in this process."""
    result = train(
        TrainConfig(
            dataset=root,
            policy=policy,
            inputs=inputs,
            overwrite=True,  # a --work folder from an earlier run: the policy is always retrained
            eval_episodes=0,  # bc.train's own evaluation would use the same seeds: evaluated once, below
            progress=False,
        )
    )
    evaluation = evaluate(PolicyController(result.policy, str(policy)), episodes=eval_episodes, seed=eval_seed)
    return {
        "train_episodes": len(result.train_episodes),
        "val_episodes": len(result.val_episodes),
        "train_frames": result.train_frames,
        "survived": evaluation["survived"],
        "episodes": evaluation["episodes"],
        "mean_return": evaluation["mean_return"],
        "train_seconds": result.train_seconds,
    }


def run(
    work: Path,
    demos: Sequence[int],
    first_seeds: Sequence[int],
    inputs: Sequence[str],
    eval_seed: int = EVAL_SEED,
    eval_episodes: int = EVAL_EPISODES,
    workers: int = 2,
) -> list[Cell]:
    """Every (first seed, N, inputs) cell, in that order; one recording per (teacher, first seed, N), shared by the
    inputs it teaches."""
    check_seeds(first_seeds, demos, eval_seed, eval_episodes)
    cells = []
    for first_seed in first_seeds:
        for n in demos:
            for kind in inputs:
                teacher, noise = TEACHERS[kind]
                root = dataset_dir(work, teacher, first_seed, n)
                fallen = recorded(root, first_seed, n, workers, teacher, noise)
                policy = work / "policies" / f"{root.name}_{kind}"
                measured = train_and_evaluate(root, policy, kind, eval_seed, eval_episodes)
                cell = Cell(
                    first_seed=first_seed, demos=n, inputs=kind, demos_fallen=fallen, teacher=teacher, **measured
                )
                cells.append(cell)
                print(f"{root.name} {kind}: {cells[-1].survived}/{cells[-1].episodes}, {cells[-1].mean_return:,.0f}")
    return cells


def cell_text(survived: int, episodes: int, mean_return: float) -> str:
    return f"{survived}/{episodes}, {mean_return:,.0f}"


def table(cells: Sequence[Cell], expert: dict[str, Any]) -> str:
    """The Markdown table: one row per N, one column per inputs setting and seed range, the expert's row last."""
    # Grouped by inputs, so that the seed ranges of one setting sit side by side.
    columns = [
        (kind, first)
        for kind in dict.fromkeys(c.inputs for c in cells)
        for first in dict.fromkeys(c.first_seed for c in cells)
    ]
    demos = sorted({c.demos for c in cells})
    by_key = {(c.inputs, c.first_seed, c.demos): c for c in cells}
    max_demos = max(demos)
    header = [f"{kind}, seeds {first}..{first + max_demos - 1}" for kind, first in columns]
    lines = ["| demonstrations (train + validation) | " + " | ".join(header) + " |", "|---" * (len(columns) + 1) + "|"]
    for n in demos:
        # The split depends only on N (TrainConfig's seed), so any cell of the row gives it.
        some = next(c for c in cells if c.demos == n)
        label = f"N = {n} ({some.train_episodes} + {some.val_episodes})"
        row = [by_key.get((kind, first, n)) for kind, first in columns]
        lines.append(
            f"| {label} | "
            + " | ".join("" if c is None else cell_text(c.survived, c.episodes, c.mean_return) for c in row)
            + " |"
        )
    reference = cell_text(expert["survived"], expert["episodes"], expert["mean_return"])
    lines.append("| the expert (reference) | " + " | ".join([reference] + [""] * (len(columns) - 1)) + " |")
    return "\n".join(lines)


def notes(cells: Sequence[Cell], eval_seed: int, eval_episodes: int) -> str:
    """What the table leaves implicit: the seeds, the split, the recipe and the expert's falls in the data."""
    fewest = min(cells, key=lambda c: c.demos)
    defaults = TrainConfig()
    falls = []
    for teacher in dict.fromkeys(c.teacher for c in cells):
        fallen = {(c.first_seed, c.demos): c.demos_fallen for c in cells if c.teacher == teacher}
        ranges = "; ".join(
            f"seeds from {first}: "
            + ", ".join(f"{fallen[first, n]} of {n}" for n in sorted({n for f, n in fallen if f == first}))
            for first in dict.fromkeys(f for f, _ in fallen)
        )
        falls.append(f"{teacher} ({', '.join(sorted({c.inputs for c in cells if c.teacher == teacher}))}): {ranges}")
    return (
        f"Survived / {eval_episodes} unseen seeds ({eval_seed}..{eval_seed + eval_episodes - 1}), mean return. "
        "Each N-episode dataset is the first N seeds of its range, recorded by the input's teacher (the expert "
        f"with DART noise {TEACHERS['full'][1]}, the expert on leg odometry with {TEACHERS['pending'][1]}); "
        f"`bc.train` defaults (at least {defaults.epochs} epochs and {defaults.min_updates:,} Adam steps, learning "
        f"rate {defaults.lr:g} on a cosine schedule, the last kept), split by "
        "episode with 10 % held out for "
        f"validation and at least one, so N = {fewest.demos} trains on {counted(fewest.train_episodes, 'episode')}. "
        f"Recorded episodes in which the noisy teacher fell (kept in the data): {'. '.join(falls)}."
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demos", type=int, nargs="+", default=list(DEMOS), help="numbers of demonstrations N")
    parser.add_argument("--first-seeds", type=int, nargs="+", default=list(FIRST_SEEDS), help="one per seed range")
    parser.add_argument("--inputs", nargs="+", default=list(INPUTS), choices=INPUTS)
    parser.add_argument("--work", type=Path, default=None, help="datasets and policies (default: a temporary folder)")
    parser.add_argument("--json", type=Path, default=RESULTS / "data_efficiency.json", help="every cell, written here")
    parser.add_argument("--workers", type=int, default=2, help="the recorder's simulation processes")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        work = args.work or Path(scratch)
        cells = run(work, args.demos, args.first_seeds, args.inputs, workers=args.workers)
    expert = evaluate("expert", episodes=EVAL_EPISODES, seed=EVAL_SEED)
    seconds = time.perf_counter() - start
    print()
    print(table(cells, expert))
    print()
    print(notes(cells, EVAL_SEED, EVAL_EPISODES))
    print(f"\n{seconds / 60:.1f} minutes in all.")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    summary = {
        "cells": [asdict(c) for c in cells],
        "expert": {key: expert[key] for key in ("survived", "episodes", "mean_return", "seeds")},
        "seconds": seconds,
    }
    write_json(args.json, summary)


if __name__ == "__main__":
    main()
