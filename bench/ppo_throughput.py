"""PPO fine-tuning throughput: the same environments in 1 worker (the learner's process) and in 2, side by side.

    .venv/bin/python -m bench.ppo_throughput [--bc-policy bench/results/policies/bc_dart_0.05] [--timesteps 32768]
        [--workers 1 2] [--envs 64] [--rollout-steps 16384] [--repeats 3]

Environment steps per second of `model.learn` (rollouts and updates, no evaluations), the
settings of `make finetune-rl` otherwise (so the same number of environments, `--envs`, for
every worker count: only where they are simulated differs); the contenders alternate within each
repeat and the median of the per-repeat ratios to the first worker count is reported. Each run's
wall time is also split into its three serial parts: waiting for the environments (the
simulation, the only part more workers speed up), PPO's updates, and the rest of the rollouts
(the learner's forward passes, the rollout buffer, callbacks): Amdahl's law with these figures
says what 2 workers can reach.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bench.bc_benchmark import dart_policy
from common.cli import UserError
from rl.finetune import FinetuneConfig, learner, validate, vec_env
from teleop.record import STANDING_NOISE


@dataclass
class Run:
    """One `model.learn`: its throughput and where its wall time went."""

    steps_per_s: float
    simulation_s: float  # waiting for the environments' step results
    update_s: float  # PPO's updates
    learner_s: float  # the rest: forward passes, rollout buffer, callbacks, start of the run


def timed(method: Callable[..., Any], seconds: list[float]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds.append(time.perf_counter() - start)

    return wrapper


def settings(
    bc_policy: Path, workers: int, envs: int, timesteps: int, rollout_steps: int = FinetuneConfig.rollout_steps
) -> FinetuneConfig:
    """`make finetune-rl`'s settings but these (its minibatch at most the rollout); UserError in one line where the
    stage would refuse them."""
    config = FinetuneConfig(
        bc_policy=bc_policy,
        workers=workers,
        envs=envs,
        timesteps=timesteps,
        rollout_steps=rollout_steps,
        batch_size=min(FinetuneConfig.batch_size, rollout_steps),
    )
    validate(config)
    return config


def learn(config: FinetuneConfig) -> Run:
    """One `model.learn` of `config.timesteps` steps (`settings`), timed; the rate counts the steps PPO ran, whole
    rollouts, which pass `config.timesteps` when it is not a multiple of the rollout's size."""
    torch.set_num_threads(1)  # as rl.finetune.main: WorkerRolloutPPO raises it for its updates
    env = vec_env(config)
    try:
        model = learner(config, env)
        simulation: list[float] = []
        updates: list[float] = []
        env.sample = timed(env.sample, simulation)
        model.train = timed(model.train, updates)
        start = time.perf_counter()
        model.learn(total_timesteps=config.timesteps)
        seconds = time.perf_counter() - start
        simulated, updated = sum(simulation), sum(updates)
        return Run(model.num_timesteps / seconds, simulated, updated, seconds - simulated - updated)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    # The policy bench.bc_benchmark trains (make bench runs it first) on the default recipe.
    parser.add_argument("--bc-policy", type=Path, default=dart_policy(STANDING_NOISE))
    parser.add_argument("--timesteps", type=int, default=32_768)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--envs", type=int, default=FinetuneConfig.envs)
    parser.add_argument("--rollout-steps", type=int, default=FinetuneConfig.rollout_steps)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    try:  # any run's settings refused before the first run starts
        configs = {w: settings(args.bc_policy, w, args.envs, args.timesteps, args.rollout_steps) for w in args.workers}
    except UserError as error:
        sys.exit(f"error: {error}")
    runs: dict[int, list[Run]] = {w: [] for w in args.workers}
    for _ in range(args.repeats):
        for workers in args.workers:
            runs[workers].append(learn(configs[workers]))
    base = args.workers[0]
    print(
        f"PPO fine-tuning, {args.envs} environments, {args.timesteps} environment steps per run "
        f"in rollouts of {args.rollout_steps}, "
        f"{args.repeats} repeats:\n"
    )
    print("| workers | steps/s (each repeat) | median | vs " + f"{base} worker | sampling | updates | rest |")
    print("|---|---|---|---|---|---|---|")
    for workers, values in runs.items():
        ratios = [run.steps_per_s / b.steps_per_s for run, b in zip(values, runs[base], strict=True)]
        print(
            f"| {workers} | {', '.join(f'{run.steps_per_s:,.0f}' for run in values)} | "
            f"{statistics.median(run.steps_per_s for run in values):,.0f} | {statistics.median(ratios):.2f}x | "
            f"{statistics.median(run.simulation_s for run in values):.2f} s | "
            f"{statistics.median(run.update_s for run in values):.2f} s | "
            f"{statistics.median(run.learner_s for run in values):.2f} s |"
        )


if __name__ == "__main__":
    main()
