"""One run is one sample: `make pipeline`'s learned rows trained again with other training seeds on the same
dataset, each measured as the pipeline's table measures it, and the spread over the seeds.

    .venv/bin/python -m bench.training_seeds [--seeds 0 1 2] [--root policies/seeds] [--episodes 20]

Seed 0 is the pipeline's own run (its folders, reused when `make pipeline` made them with these settings); seed
N > 0 trains both BC students (`train-bc --seed N`), the DAgger student (`dagger --seed N`, into its own aggregate)
and both PPO stages (`--seed N`, from that seed's DAgger student) into ROOT/seed_N/. The dataset is the pipeline's,
so what varies is training alone: the students' validation split, initial weights and minibatches (and so where
DAgger's rollouts go), PPO's environments and sampling. Prints each seed's table, then per learned row
and condition the lowest and highest survivors and tracking score over the seeds, and the mean return's range.
Takes about the pipeline's length per new seed on 2 cores (docs/benchmarks.md, "Training seeds").
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

from humanoid.conditions import SUITE
from pipeline import report
from pipeline import run as pipeline
from pipeline.run import PipelineConfig, stages
from task.tracking import tracking_score

ROLES = ("blind", "student", "dagger", "fine-tuned", "scratch")
"""The learned rows of the pipeline's table, in its order (`pipeline.run_stages`)."""


def seed_config(seed: int, root: Path) -> PipelineConfig:
    """The pipeline's settings for training seed `seed`: its own folders for seed 0, ROOT/seed_N/ otherwise."""
    default = PipelineConfig()
    if seed == 0:
        return default
    folder = root / f"seed_{seed}"
    return dataclasses.replace(
        default,
        bc=dataclasses.replace(default.bc, policy=folder / "bc_operator", seed=seed),
        blind_policy=folder / "bc_operator_blind",
        dagger=dataclasses.replace(
            default.dagger, output=folder / "operator_dagger", policy=folder / "dagger_operator", seed=seed
        ),
        ppo=dataclasses.replace(default.ppo, policy=folder / "ppo_operator", seed=seed),
        scratch_policy=folder / "ppo_scratch_operator",
    )


def run_seed(seed: int, root: Path, episodes: int) -> tuple[dict[str, dict], dict[str, dict]]:
    """Train (or reuse) seed `seed`'s learned rows and measure them: (zero-command, schedules) results by role."""
    run_stages = stages(seed_config(seed, root))
    policies = list(map(str, pipeline.run_stages(run_stages, overwrite=False)))
    standing, tracked = pipeline.measure(policies, episodes, list(SUITE), run_stages.finetune.workers)
    return (
        {role: standing[policy] for role, policy in zip(ROLES, policies, strict=True)},
        {role: tracked[policy] for role, policy in zip(ROLES, policies, strict=True)},
    )


def _range(values: list[float], digits: int) -> str:
    low, high = (f"{value:.{digits}f}" for value in (min(values), max(values)))
    return low if low == high else f"{low}–{high}"


def spread_table(seeds: list[int], runs: list[tuple[dict[str, dict], dict[str, dict]]]) -> str:
    """Per learned row: the range over the seeds of the survivors with the command zero and, per condition on held-out
    schedules, of the survivors and the tracking score; and of the mean return over the conditions."""
    names = list(SUITE)
    lines = [
        f"training seeds {', '.join(map(str, seeds))}: lowest–highest over the seeds (survivors · tracking score)",
        "",
        "| row | standing | " + " | ".join(names) + " | mean return |",
        "|---|---|" + "---|" * len(names) + "---|",
    ]
    for role in ROLES:
        standing = [report.survivors(run[0][role]) for run in runs]
        cells = []
        for name in names:
            rows = [run[1][role]["conditions"][name] for run in runs]
            scores = [tracking_score(row["tracking"]) for row in rows]
            cells.append(f"{_range([report.survivors(row) for row in rows], 0)} · {_range(scores, 2)}")
        returns = [report.mean_return(run[1][role]) for run in runs]
        lines.append(f"| {role} | {_range(standing, 0)} | " + " | ".join(cells) + f" | {_range(returns, 0)} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.training_seeds", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds (default 0 1 2)")
    parser.add_argument("--root", type=Path, default=Path("policies/seeds"), help="folder of the seeds past 0")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per condition (the pipeline's 20)")
    args = parser.parse_args(argv)
    runs = []
    for seed in args.seeds:
        standing, tracked = run_seed(seed, args.root, args.episodes)
        runs.append((standing, tracked))
        print(f"\nseed {seed}:\n" + report.command_table(standing, tracked).split("\n\n")[0], flush=True)
    print("\n" + spread_table(args.seeds, runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
