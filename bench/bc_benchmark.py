"""The DART table: behaviour cloning from clean and noise-injected demonstrations, beside the expert.

    .venv/bin/python -m bench.bc_benchmark [--noise 0 0.02 0.05 0.1] [--episodes 50] [--repeats 3]
        [--dagger-rounds 6] [--dagger-episodes 10]

For each recording noise σ: record EPISODES expert episodes (seeds 0..EPISODES-1) into
bench/results/data/dart_<σ> unless it exists, measure loading into tensors (a fresh process, from
the parquet files, then from the decoded cache; median of REPEATS), train `bc.train` with its
defaults (timed from the start to a saved policy), and evaluate the policy on 20 unseen seeds
(1000..1019) clean, with action noise 0.05, and with 10 N pushes; the expert on the same seeds
and conditions gives the last row. DAgger (`bc.dagger`) starts from the first noise level's
demonstrations (the clean ones by default) and adds its row. Prints the table in Markdown.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bc.dagger import DaggerConfig
from bc.dagger import main as dagger
from bc.train import TrainConfig
from bc.train import main as train
from evaluation.evaluate import evaluate
from teleop.lerobot_io.format import INFO_PATH
from teleop.record import STANDING, RecordConfig
from teleop.record import main as record

CONDITIONS = {"clean": {}, "NOISE=0.05": {"noise": 0.05}, "PUSH=10": {"push": 10.0}}
RESULTS = Path("bench/results")
"""Where the benchmarks keep what they record and train (git-ignored)."""


def dart_policy(noise: float) -> Path:
    """The BC policy this benchmark trains on demonstrations at DART `noise`: the PPO benchmarks' start."""
    return RESULTS / "policies" / f"bc_dart_{noise:g}"


# One load in a fresh process, as `bc.train` does it: no memory or imports left warm by an earlier load.
_LOAD_ONCE = (
    "import sys; from pathlib import Path; from bc.data import load_demonstrations; "
    "from humanoid.env import make_env; "
    "d = load_demonstrations(Path(sys.argv[1]), make_env(), cache=sys.argv[2] == 'cache'); "
    "print(d.frames, d.seconds)"
)


def loading_rows_per_s(root: Path, repeats: int) -> dict[str, float]:
    """Median rows/s from the parquet files (a dataset's first load) and from the cache (every later one)."""

    def load_once(source: str) -> float:
        rows, seconds = subprocess.run(
            [sys.executable, "-c", _LOAD_ONCE, str(root), source], check=True, capture_output=True, text=True
        ).stdout.split()
        return int(rows) / float(seconds)

    load_once("cache")  # writes the cache if this version of the dataset has none yet
    return {source: statistics.median(load_once(source) for _ in range(repeats)) for source in ("parquet", "cache")}


def cell(evaluation: dict[str, Any]) -> str:
    return f"{evaluation['survived']}/{evaluation['episodes']}, {evaluation['mean_return']:,.0f}"


def bench_noise(noise: float, episodes: int, repeats: int) -> tuple[str, str]:
    """The DART-table row and the timing row of BC trained on demonstrations recorded at `noise`."""
    root = RESULTS / "data" / f"dart_{noise:g}"
    if not (root / INFO_PATH).exists():
        record(RecordConfig(dataset=root, episodes=episodes, seed=0, noise=noise, progress=False, **STANDING))
    policy = dart_policy(noise)
    loading = loading_rows_per_s(root, repeats)
    start = time.perf_counter()
    trained = train(
        TrainConfig(dataset=root, policy=policy, inputs="full", overwrite=True, eval_episodes=0, progress=False)
    )
    to_policy = time.perf_counter() - start
    results = [cell(evaluate(str(policy), **settings)) for settings in CONDITIONS.values()]
    label = "clean demonstrations" if noise == 0 else f"DART σ = {noise:g}"
    frames = trained.train_frames + trained.val_frames
    row = f"| BC, {label} ({frames:,} frames) | " + " | ".join(results) + " |"
    timing = (
        f"| {label} | {loading['parquet']:,.0f} | {loading['cache']:,.0f} | {trained.train_seconds:.1f} "
        f"({len(trained.curves.val_loss)} epochs) | {to_policy:.1f} |"
    )
    return row, timing


def bench_dagger(noise: float, rounds: int, episodes: int) -> str:
    """The DART-table row of DAgger started from the demonstrations recorded at `noise`."""
    output = RESULTS / "data" / f"dagger_from_{noise:g}"
    shutil.rmtree(output, ignore_errors=True)  # a fresh aggregate: the row is about exactly ROUNDS rounds
    policy = RESULTS / "policies" / f"dagger_from_{noise:g}"
    result = dagger(
        DaggerConfig(
            dataset=RESULTS / "data" / f"dart_{noise:g}",
            output=output,
            policy=policy,
            inputs="full",
            expert="expert",
            noise=0.0,
            epochs=30,
            rounds=rounds,
            episodes=episodes,
            overwrite=True,
            eval_episodes=0,
            progress=False,
        )
    )
    frames = result.final.train_frames + result.final.val_frames
    label = "clean demonstrations" if noise == 0 else f"σ = {noise:g} demonstrations"
    results = [cell(evaluate(str(policy), **settings)) for settings in CONDITIONS.values()]
    return (
        f"| DAgger, {rounds} rounds x {episodes} episodes from {label} ({frames:,} frames) | "
        + " | ".join(results)
        + " |"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.02, 0.05, 0.1])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dagger-rounds", type=int, default=6, help="0 = no DAgger row")
    parser.add_argument("--dagger-episodes", type=int, default=10)
    args = parser.parse_args(argv)

    rows, timings = zip(*(bench_noise(noise, args.episodes, args.repeats) for noise in args.noise), strict=True)
    if args.dagger_rounds:
        rows = (*rows, bench_dagger(args.noise[0], args.dagger_rounds, args.dagger_episodes))
    expert = [cell(evaluate("expert", **settings)) for settings in CONDITIONS.values()]
    print("Survived / 20 unseen seeds (1000..1019), mean return:\n")
    print("| policy | " + " | ".join(CONDITIONS) + " |")
    print("|---" * (len(CONDITIONS) + 1) + "|")
    print("\n".join(rows))
    print("| the expert | " + " | ".join(expert) + " |")
    print("\nLoading into tensors (rows/s) and training, 2 CPU cores:\n")
    print("| training data | load from parquet | load from cache | training s | start to saved policy s |")
    print("|---|---|---|---|---|")
    print("\n".join(timings))


if __name__ == "__main__":
    main()
