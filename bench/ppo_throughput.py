"""PPO fine-tuning throughput: the same environments in 1 worker (the learner's process) and in 2, side by side.

    .venv/bin/python -m bench.ppo_throughput [--bc-policy bench/results/policies/bc_dart_0.05] [--timesteps 32768]
        [--workers 1 2] [--envs 64] [--repeats 3]

Environment steps per second of `model.learn` (rollouts and updates, no evaluations), the
settings of `make finetune-rl` otherwise (so the same number of environments, `--envs`, for
every worker count: only where they are simulated differs); the contenders alternate within each
repeat and the median of the per-repeat ratios to the first worker count is reported.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from bc.finetune import FinetuneConfig, build_model, make_vec_env


def steps_per_s(bc_policy: Path, workers: int, envs: int, timesteps: int) -> float:
    config = FinetuneConfig(bc_policy=bc_policy, workers=workers, envs=envs, timesteps=timesteps)
    torch.set_num_threads(1)  # as bc.finetune.main: PPOWithUpdateThreads raises it for its updates
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
    parser.add_argument("--timesteps", type=int, default=32_768)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--envs", type=int, default=FinetuneConfig.envs)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    runs = {w: [] for w in args.workers}
    for _ in range(args.repeats):
        for workers in args.workers:
            runs[workers].append(steps_per_s(args.bc_policy, workers, args.envs, args.timesteps))
    base = args.workers[0]
    print(f"PPO fine-tuning, {args.envs} environments, {args.timesteps} environment steps per run, "
          f"{args.repeats} repeats:\n")
    print("| workers | steps/s (each repeat) | median | vs " + f"{base} worker |")
    print("|---|---|---|---|")
    for workers, values in runs.items():
        ratios = [v / b for v, b in zip(values, runs[base], strict=True)]
        print(f"| {workers} | {', '.join(f'{v:,.0f}' for v in values)} | {statistics.median(values):,.0f} | "
              f"{statistics.median(ratios):.2f}x |")


if __name__ == "__main__":
    main()
