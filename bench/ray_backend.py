"""BACKEND=ray against local processes, 2 workers each, side by side: recording and PPO sampling.

    .venv/bin/python -m bench.ray_backend [--episodes 40] [--repeats 3]
        [--bc-policy bench/results/policies/bc_dart_0.05] [--timesteps 32768]

Each repeat runs, back to back: `make record WORKERS=2` on the local backend, then on Ray (a local
Ray started by the command, as without RAY_ADDRESS), on the same seeds into new datasets; then
PPO fine-tuning (`make finetune-rl` settings, no evaluations) with 2 local workers and with 2 Ray
actors. Throughput excludes start-up, which is reported on its own: for recording, the frames
committed after the first commit over the time from it to the last; for PPO, environment
steps over the time spent sampling (`WorkerGroupVecEnv.sample`, the only part the backend changes)
and over the whole `learn`. Ratios are taken within a repeat (the machines are shared and noisy)
and their median is reported.
"""

from __future__ import annotations

import argparse
import functools
import pickle
import statistics
import tempfile
import time
from pathlib import Path

import torch

from bench.bc_benchmark import dart_policy
from bench.ppo_throughput import timed
from common.ray_backend import BACKENDS, RaySession
from rl.finetune import FinetuneConfig, learner, vec_env
from teleop.parallel import RolloutSettings, Simulator
from teleop.record import STANDING, STANDING_NOISE, RecordConfig, RecordSummary
from teleop.record import main as record


class CommitTimes(list):
    """`RecordSummary.episodes`, noting when each batch of episodes was committed."""

    def __init__(self) -> None:
        super().__init__()
        self.times: list[tuple[float, int]] = []  # (time, episodes committed so far)

    def __iadd__(self, committed: list) -> CommitTimes:  # type: ignore[override]
        super().__iadd__(committed)
        if committed:
            self.times.append((time.perf_counter(), len(self)))
        return self


def recording(backend: str, episodes: int, root: Path) -> tuple[float, float]:
    """(frames/s from the first commit to the last, the rest of the command's wall time) of a 2-worker recording.

    From the first commit on, both backends are in their steady state: the workers' start (imports, the
    controller's set-up; Ray's start too) and Ray's shut-down fall outside, into the second figure.
    """
    start = time.perf_counter()
    config = RecordConfig(
        dataset=root,
        episodes=episodes,
        seed=0,
        workers=2,
        backend=backend,
        progress=False,
        noise=STANDING_NOISE,
        **STANDING,
    )
    committed = CommitTimes()
    record(config, RecordSummary(root, committed))
    total = time.perf_counter() - start
    (first, first_count), (last, _) = committed.times[0], committed.times[-1]
    frames = sum(episode.length for episode in committed[first_count:])
    return frames / (last - first), total - (last - first)


def ppo(backend: str, bc_policy: Path, timesteps: int) -> tuple[float, float, float]:
    """(steps/s of sampling, steps/s of the whole `learn`, seconds to start the workers) with 2 workers."""
    config = FinetuneConfig(bc_policy=bc_policy, workers=2, backend=backend, timesteps=timesteps)
    torch.set_num_threads(1)  # as rl.finetune.main: WorkerRolloutPPO raises it for its updates
    start = time.perf_counter()
    env = vec_env(config)
    startup = time.perf_counter() - start
    try:
        model = learner(config, env)
        sampling: list[float] = []
        env.sample = timed(env.sample, sampling)
        start = time.perf_counter()
        model.learn(total_timesteps=timesteps)
        return timesteps / sum(sampling), timesteps / (time.perf_counter() - start), startup
    finally:
        env.close()


def receiving(episodes: int) -> tuple[float, float]:
    """(median CPU ms, MB) for the recorder to take one finished 1000-frame episode from a Ray actor (`ray.get`).

    Besides the local backend's writer work (spool write, spool read, append: `bench.record_throughput`),
    this is what a Ray recording's writer spends per episode: the docs' scaling model adds it up.
    """
    session = RaySession(None, 1)
    try:
        (worker,) = session.spawn([functools.partial(Simulator, RolloutSettings("expert", STANDING_NOISE, 1000))], "w")
        costs, sizes = [], []
        for seed in range(50_000, 50_000 + episodes):
            ref = worker.submit("run", seed)
            session.wait([ref])  # the simulation is not the writer's cost
            start = time.process_time()
            episode = worker.get(ref)
            costs.append((time.process_time() - start) * 1000 * 1000 / episode.length)
            sizes.append(len(pickle.dumps(episode)) / 1e6 * 1000 / episode.length)
        return statistics.median(costs), statistics.median(sizes)
    finally:
        session.close()


def table(title: str, unit: str, runs: dict[str, list[float]], startups: dict[str, list[float]], startup: str) -> None:
    print(f"\n{title}\n")
    print(f"| backend | {unit} (each repeat) | median | vs local | {startup}, median |")
    print("|---|---|---|---|---|")
    for backend, values in runs.items():
        ratios = [value / local for value, local in zip(values, runs["local"], strict=True)]
        print(
            f"| {backend} | {', '.join(f'{value:,.0f}' for value in values)} | {statistics.median(values):,.0f} | "
            f"{statistics.median(ratios):.2f}x | {statistics.median(startups[backend]):.1f} s |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=3)
    # The policy bench.bc_benchmark trains (make bench runs it first) on the default recipe.
    parser.add_argument("--bc-policy", type=Path, default=dart_policy(STANDING_NOISE))
    parser.add_argument("--timesteps", type=int, default=32_768)
    args = parser.parse_args()
    frames: dict[str, list[float]] = {b: [] for b in BACKENDS}
    record_startup: dict[str, list[float]] = {b: [] for b in BACKENDS}
    sampling: dict[str, list[float]] = {b: [] for b in BACKENDS}
    learning: dict[str, list[float]] = {b: [] for b in BACKENDS}
    ppo_startup: dict[str, list[float]] = {b: [] for b in BACKENDS}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for backend in BACKENDS:
                rate, startup = recording(backend, args.episodes, Path(scratch) / f"{backend}_{repeat}")
                frames[backend].append(rate)
                record_startup[backend].append(startup)
            for backend in BACKENDS:
                sample_rate, learn_rate, startup = ppo(backend, args.bc_policy, args.timesteps)
                sampling[backend].append(sample_rate)
                learning[backend].append(learn_rate)
                ppo_startup[backend].append(startup)
    receive_ms, megabytes = receiving(10)
    print(f"2 workers on each backend (Ray: a local Ray started by the command), {args.repeats} repeats.")
    title = f"Recording {args.episodes} expert episodes, frames/s from the first commit to the last:"
    table(title, "frames/s", frames, record_startup, "the rest of the wall time")
    print(
        f"\nThe recorder takes a finished 1000-frame episode from a Ray actor in {receive_ms:.1f} ms of CPU "
        f"(`ray.get`, median of 10; {megabytes:.2f} MB pickled)."
    )
    title = f"PPO, {args.timesteps} environment steps, sampling only (what the backend changes):"
    table(title, "steps/s", sampling, ppo_startup, "workers' start-up")
    table(
        "PPO, the same runs, whole `learn` (sampling and updates):",
        "steps/s",
        learning,
        ppo_startup,
        "workers' start-up",
    )


if __name__ == "__main__":
    main()
