"""PPO fine-tuning throughput, one environment against WORKERS in worker processes, side by side.

    .venv/bin/python -m bench.ppo_throughput [--bc-policy bench/results/policies/bc_dart_0.05] [--timesteps 20480]
        [--workers 1 2] [--repeats 3]

Environment steps per second of `model.learn` (rollouts and updates, no evaluations), the
settings of `make finetune-rl` otherwise; the contenders alternate within each repeat and the
median ratio to one worker is reported.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from bc.finetune import FinetuneConfig, build_model, make_vec_env


def steps_per_s(bc_policy: Path, workers: int, timesteps: int) -> float:
    config = FinetuneConfig(bc_policy=bc_policy, workers=workers, timesteps=timesteps)
    torch.set_num_threads(config.threads)
    env = make_vec_env(config)
    try:
        model = build_model(config, env, term=None)
        start = time.perf_counter()
        model.learn(total_timesteps=timesteps)
        return timesteps / (time.perf_counter() - start)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    # The policy bench.bc_benchmark trains (make bench runs it first) on the default recipe.
    parser.add_argument("--bc-policy", type=Path, default=Path("bench/results/policies/bc_dart_0.05"))
    parser.add_argument("--timesteps", type=int, default=20_480)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    runs = {w: [] for w in args.workers}
    for _ in range(args.repeats):
        for workers in args.workers:
            runs[workers].append(steps_per_s(args.bc_policy, workers, args.timesteps))
    base = args.workers[0]
    print(f"PPO fine-tuning, {args.timesteps} environment steps per run, {args.repeats} repeats:\n")
    print("| workers | steps/s (each repeat) | median | vs " + f"{base} worker |")
    print("|---|---|---|---|")
    for workers, values in runs.items():
        ratios = [v / b for v, b in zip(values, runs[base], strict=True)]
        print(f"| {workers} | {', '.join(f'{v:,.0f}' for v in values)} | {statistics.median(values):,.0f} | "
              f"{statistics.median(ratios):.2f}x |")


if __name__ == "__main__":
    main()
