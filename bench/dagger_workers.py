"""DAgger's rollouts on 1 process against 2, side by side, and the same aggregate either way.

    .venv/bin/python -m bench.dagger_workers [--demonstrations 50] [--rounds 2] [--episodes 20] [--repeats 3]

A recording in the pipeline's recipe, then the pipeline's DAgger stage on it (`pipeline.run.stages`: its student's
inputs, its labelling expert, its noise and conditions) for ROUNDS rounds of EPISODES rollouts, once with WORKERS=1
and once with WORKERS=2 in each repeat: labelled frames per second of the rounds' rollouts (the worker processes'
start-up included, the fits not: `RoundReport.seconds`), and the median of the per-repeat ratios. Each repeat also
checks that both runs wrote the same aggregate (`teleop.dataset_reader.fingerprint`) and the same final weights.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
from pathlib import Path

from bc.dagger import main
from pipeline.run import PipelineConfig, stages
from rl.finetune import weights_digest
from teleop.dataset_reader import fingerprint
from teleop.record import record


def dagger(demonstrations: Path, folder: Path, rounds: int, episodes: int, workers: int) -> tuple[float, str, str]:
    """(labelled frames per second, the aggregate's fingerprint, the final weights' digest) of one DAgger run: the
    pipeline's stage on `demonstrations`, with `workers`."""
    config = dataclasses.replace(
        stages(PipelineConfig()).dagger,
        dataset=demonstrations,
        output=folder / "aggregate",
        policy=folder / "policy",
        rounds=rounds,
        episodes=episodes,
        workers=workers,
        min_updates=0,  # the fits are not what is measured
        progress=False,
    )
    rounds_run = main(config).rounds
    rate = sum(report.frames for report in rounds_run) / sum(report.seconds for report in rounds_run)
    weights = weights_digest(config.policy)
    return rate, fingerprint(config.output), weights


def run(demonstrations: int, rounds: int, episodes: int, repeats: int) -> str:
    with tempfile.TemporaryDirectory() as scratch:
        recorded = Path(scratch) / "demonstrations"
        recording = stages(PipelineConfig()).record  # the pipeline's recipe
        record(dataclasses.replace(recording, dataset=recorded, episodes=demonstrations, progress=False))
        rows, ratios = [], []
        for repeat in range(repeats):
            one = dagger(recorded, Path(scratch) / f"one{repeat}", rounds, episodes, 1)
            two = dagger(recorded, Path(scratch) / f"two{repeat}", rounds, episodes, 2)
            if one[1:] != two[1:]:
                raise RuntimeError(f"repeat {repeat}: 1 and 2 workers wrote different aggregates or weights")
            ratios.append(two[0] / one[0])
            rows.append(f"| {repeat} | {one[0]:,.0f} | {two[0]:,.0f} | {ratios[-1]:.2f}× |")
    return "\n".join(
        [
            f"DAgger, {rounds} rounds × {episodes} rollouts from {demonstrations} operator demonstrations, "
            "labelled frames/s of the rounds (with the workers' start-up); the same aggregate and weights each time",
            "",
            "| repeat | 1 worker | 2 workers | 2 against 1 |",
            "|---|---|---|---|",
            *rows,
            "",
            f"median ratio: {statistics.median(ratios):.2f}×",
        ]
    )


def cli() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demonstrations", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(run(args.demonstrations, args.rounds, args.episodes, args.repeats))


if __name__ == "__main__":
    cli()
