"""Students under one step of action latency: told the delay and their command in flight, or not.

    .venv/bin/python -m bench.latency_students [--demos 20 50] [--first-seeds 0 100 200] [--share 0.5]
        [--work FOLDER] [--json bench/results/latency_students.json]

Why: one step of latency topples a student on the leg odometry alone, which acts as if its command ran at
once; the "pending" inputs add that command and the delay (students/inputs.py). Whether that is
enough, and from how many demonstrations, is measured here, not assumed (the student on the odometry
alone, `INPUTS=odometry`, was removed once this measured it: docs/decisions/pending-inputs.md).

What: for each first seed (disjoint seed ranges) and each N, the expert on leg odometry records N
episodes (DART noise DART_NOISE, as `make pipeline` records them), a share of them with one step of
latency, drawn per episode and told to it (`make record LATENCY=SHARE`). A student trains on it with
`bc.train`'s defaults and INPUTS=pending. It is evaluated on the
unseen seeds 1000..1019 under the suite's clean, latency and noise conditions, the expert on leg
odometry beside them. Prints a Markdown table and writes every cell to a JSON file.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from bc.train import TrainConfig
from bc.train import main as train
from bench.data_efficiency import EVAL_EPISODES, RESULTS, check_seeds, dataset_dir, recorded
from common.cli import write_json
from common.seed_ranges import EVAL_SEED
from evaluation.evaluate import evaluate
from humanoid.conditions import LATENCY_PARAMETER
from students.learned import PolicyController
from teleop.dataset_reader import read_parameters
from teleop.record import DART_NOISE

DEMOS = (20, 50)
FIRST_SEEDS = (0, 100, 200)
SHARE = 0.5
TEACHER = "expert-sensed"
STUDENTS = ("pending",)
CONDITIONS = ("clean", "latency", "noise")


@dataclass
class Cell:
    first_seed: int
    demos: int
    inputs: str
    demos_delayed: int  # recorded episodes drawn with the delay
    demos_fallen: int  # recorded episodes in which the teacher fell (kept in the data)
    survived: dict[str, int]  # per condition, of EVAL_EPISODES
    mean_return: dict[str, float]


def conditions_of(controller: PolicyController | str) -> tuple[dict[str, int], dict[str, float]]:
    """Survivors and mean return of `controller` under each of CONDITIONS, on the evaluation seeds."""
    runs = {name: evaluate(controller, episodes=EVAL_EPISODES, seed=EVAL_SEED, condition=name) for name in CONDITIONS}
    return {n: r["survived"] for n, r in runs.items()}, {n: r["mean_return"] for n, r in runs.items()}


def run(work: Path, demos: list[int], first_seeds: list[int], share: float) -> list[Cell]:
    check_seeds(first_seeds, demos, EVAL_SEED, EVAL_EPISODES)
    cells = []
    for first_seed in first_seeds:
        for n in demos:
            root = dataset_dir(work, f"{TEACHER}_latency{share:g}", first_seed, n)
            fallen = recorded(root, first_seed, n, 2, TEACHER, DART_NOISE, latency=share)
            delayed = sum(d.get(LATENCY_PARAMETER, 0) for d in read_parameters(root))
            for kind in STUDENTS:
                policy = work / "policies" / f"{root.name}_{kind}"
                result = train(
                    TrainConfig(
                        dataset=root,
                        policy=policy,
                        inputs=kind,
                        overwrite=True,
                        eval_episodes=0,
                        progress=False,
                    )
                )
                survived, returns = conditions_of(PolicyController(result.policy, str(policy)))
                cells.append(Cell(first_seed, n, kind, delayed, fallen, survived, returns))
                print(f"{root.name} {kind}: {survived}", flush=True)
    return cells


def table(cells: list[Cell], teacher: tuple[dict[str, int], dict[str, float]]) -> str:
    """Rows: N and inputs; columns: each seed range's survivors under each condition."""
    firsts = sorted({c.first_seed for c in cells})
    header = "| N | inputs | " + " | ".join(f"seeds {f}.. ({', '.join(CONDITIONS)})" for f in firsts) + " |"
    lines = [header, "|" + "---|" * (2 + len(firsts))]
    by_key = {(c.demos, c.inputs, c.first_seed): c for c in cells}
    for n in sorted({c.demos for c in cells}):
        for kind in STUDENTS:
            row = [", ".join(str(by_key[n, kind, f].survived[name]) for name in CONDITIONS) for f in firsts]
            lines.append(f"| {n} | {kind} | " + " | ".join(row) + " |")
    teacher_row = ", ".join(str(teacher[0][name]) for name in CONDITIONS)
    lines.append(f"| teacher | {TEACHER} | {teacher_row} (the same seeds 1000..1019 for every column) |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demos", type=int, nargs="+", default=list(DEMOS), help="numbers of demonstrations N")
    parser.add_argument("--first-seeds", type=int, nargs="+", default=list(FIRST_SEEDS), help="one per seed range")
    parser.add_argument("--share", type=float, default=SHARE, help="share of the recorded episodes delayed")
    parser.add_argument("--work", type=Path, default=None, help="datasets and policies (default: a temporary folder)")
    parser.add_argument("--json", type=Path, default=RESULTS / "latency_students.json", help="every cell, written here")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        cells = run(args.work or Path(scratch), args.demos, args.first_seeds, args.share)
    teacher = conditions_of(TEACHER)
    seconds = time.perf_counter() - start
    print()
    print(table(cells, teacher))
    print(
        f"\nEach cell: survivors of {EVAL_EPISODES} under {', '.join(CONDITIONS)}; {seconds / 60:.1f} minutes in all."
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    summary = {
        "share": args.share,
        "cells": [asdict(c) for c in cells],
        "teacher": {"survived": teacher[0], "mean_return": teacher[1]},
        "seconds": seconds,
    }
    write_json(args.json, summary)


if __name__ == "__main__":
    main()
