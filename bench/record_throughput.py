"""Recording throughput: 1 worker against 2 and against the rollout alone, side by side; memory of a long run.

    .venv/bin/python -m bench.record_throughput [--episodes 50] [--repeats 3] [--memory-episodes 50] [--cpu-episodes 20]

Each repeat runs, back to back on the same machine: the expert rollout alone (no writing), two
rollouts at once in two processes (what the two cores give at that moment), the recorder with one
worker (simulation in its process, writing in a writer process: the default), and the recorder
with two simulation workers. Throughputs are end to end (start-up included) and
their ratios are taken within a repeat, then the median is reported: the machines are shared and
noisy, so only side-by-side ratios mean something.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import EpisodeBuffer, run_episode
from teleop.lerobot_io.format import INFO_PATH, read_info
from teleop.record import STANDING, STANDING_NOISE, RecordConfig, main


def rollout_frames(seeds: range) -> int:
    """Frames of the expert rollout of `seeds`, with no writing (set-up included in the caller's timing)."""
    env = make_env()
    controller = make_controller("expert", env)
    buffer = EpisodeBuffer(env, env.spec.max_episode_steps)
    return sum(run_episode(env, controller, seed, STANDING_NOISE, buffer).length for seed in seeds)


def rollout_only(episodes: int, first_seed: int) -> float:
    """Frames/s of the expert rollout in this process, set-up included."""
    start = time.perf_counter()
    frames = rollout_frames(range(first_seed, first_seed + episodes))
    return frames / (time.perf_counter() - start)


def two_rollouts(episodes: int, first_seed: int) -> float:
    """Frames/s of two rollout processes sharing the seeds, no writing: what the two cores give right now.

    On these virtual machines two busy processes do not always run twice as fast as one (the host
    may place both virtual cores on one physical core); this is the ceiling 2 workers are held to.
    """
    start = time.perf_counter()
    halves = [range(first_seed + half, first_seed + episodes, 2) for half in (0, 1)]
    # spawn, not the forkserver: the recorder's workers set up the forkserver as they need it.
    with ProcessPoolExecutor(2, mp_context=mp.get_context("spawn")) as pool:
        frames = sum(pool.map(rollout_frames, halves))
    return frames / (time.perf_counter() - start)


def recording(episodes: int, first_seed: int, workers: int, root: Path) -> float:
    """Frames/s of `main` recording the same episodes into a new dataset, start-up included."""
    start = time.perf_counter()
    summary = main(
        RecordConfig(
            dataset=root,
            episodes=episodes,
            seed=first_seed,
            workers=workers,
            progress=False,
            noise=STANDING_NOISE,
            **STANDING,
        )
    )
    return summary.frames / (time.perf_counter() - start)


def cpu_per_episode(episodes: int, root: Path) -> dict[str, float]:
    """Median CPU ms per 1000-frame episode of each stage of a parallel recording, run one after another.

    A parallel recording spends, per episode: the simulation and the spool write (in a worker),
    then the spool read and the append to both formats (in the recorder). With all of them on two
    cores, 2 workers can run at most 2 / (1 + (everything but the simulation) / simulation) times
    as fast as the simulation alone.
    """
    from teleop.mcap_io.writer import write_episode_mcap  # noqa: PLC0415 - the writing stack, for this measure only
    from teleop.spool import Spool  # noqa: PLC0415 - the writing stack, for this measure only
    from teleop.store import DatasetSpec, EpisodeStore  # noqa: PLC0415 - the writing stack, for this measure only

    env = make_env()
    controller = make_controller("expert", env)
    buffer = EpisodeBuffer(env, env.spec.max_episode_steps)
    store = EpisodeStore(root, DatasetSpec.from_env(env))
    store.prepare()
    costs: dict[str, list[float]] = {
        "simulate": [],
        "spool write": [],
        "spool read": [],
        "append (both formats)": [],
        "of which MCAP": [],
    }

    def timed(stage: str, work: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        result = work(*args, **kwargs)
        costs[stage].append((time.process_time() - start) * 1000)
        return result

    seed = 50_000
    while len(costs["append (both formats)"]) < episodes:
        episode = timed("simulate", run_episode, env, controller, seed, STANDING_NOISE, buffer)
        seed += 1
        if episode.length < env.spec.max_episode_steps:  # compare whole episodes only
            costs["simulate"].pop()
            continue
        path = timed("spool write", store.spool.put, episode)
        loaded = timed("spool read", Spool.load, path)
        spec = store.spec
        mcap_args = (  # as EpisodeStore.append calls it
            root / "scratch.mcap",
            loaded,
            spec.split(loaded.observation)[0],
            spec.split(loaded.final_observation)[0],
            0,
            spec.scene,
            spec.body_frames,
            spec.step_ns,
            {},
            spec.mjcf,
        )
        timed("of which MCAP", write_episode_mcap, *mcap_args)
        timed("append (both formats)", store.append, loaded, spooled=path)
    store.close()
    return {stage: statistics.median(values) for stage, values in costs.items()}


def rss_mib(pid: int) -> float:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:  # the process ended between listing and reading
        return 0.0
    for line in status.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def children(pid: int) -> list[int]:
    try:
        return [int(c) for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()]
    except OSError:
        return []


class MemorySampler(threading.Thread):
    """Resident memory of this process and of its writer, sampled while a one-worker recording runs. The writer is
    a child of the forkserver (common.workers), itself this process's child beside the resource tracker: the
    grandchildren are the writer."""

    def __init__(self, root: Path) -> None:
        super().__init__(daemon=True)
        self.root, self.samples, self.stop = root, [], threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.1):
            # info.json is written by a rename: whole whenever it is there
            committed = read_info(self.root)["total_episodes"] if (self.root / INFO_PATH).exists() else 0
            writers = [grandchild for child in children(os.getpid()) for grandchild in children(child)]
            self.samples.append((committed, rss_mib(os.getpid()), sum(rss_mib(k) for k in writers)))


def memory_profile(episodes: int, root: Path) -> tuple[tuple[float, float], tuple[float, float]]:
    """Peak (recorder, writer) RSS in MiB over the first 20 % of the episodes and over the last 20 %."""
    sampler = MemorySampler(root)
    sampler.start()
    main(RecordConfig(dataset=root, episodes=episodes, workers=1, progress=False, noise=STANDING_NOISE, **STANDING))
    sampler.stop.set()
    sampler.join()
    early = [s for s in sampler.samples if 1 <= s[0] <= episodes // 5]
    late = [s for s in sampler.samples if s[0] >= episodes - episodes // 5]

    def peak(samples: list) -> tuple[float, float]:
        return max(s[1] for s in samples), max(s[2] for s in samples)

    return peak(early), peak(late)


def run(episodes: int, repeats: int, memory_episodes: int, cpu_episodes: int) -> str:
    rows, one_vs_rollout, two_vs_one, two_vs_two_rollouts = [], [], [], []
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(repeats):
            seed = 10_000 + repeat * episodes  # fresh seeds, the same ones for every contender
            alone = rollout_only(episodes, seed)
            both = two_rollouts(episodes, seed)
            one = recording(episodes, seed, 1, Path(scratch) / f"one{repeat}")
            two = recording(episodes, seed, 2, Path(scratch) / f"two{repeat}")
            one_vs_rollout.append(one / alone)
            two_vs_one.append(two / one)
            two_vs_two_rollouts.append(two / both)
            rows.append(
                f"| {repeat + 1} | {alone:,.0f} | {both:,.0f} ({both / alone:.2f}x) | "
                f"{one:,.0f} ({one / alone:.2f}x rollout) | "
                f"{two:,.0f} ({two / one:.2f}x 1 worker, {two / both:.2f}x 2 rollouts) |"
            )
        (early, late) = memory_profile(memory_episodes, Path(scratch) / "memory")
        cpu = cpu_per_episode(cpu_episodes, Path(scratch) / "cpu")
    overhead = sum(ms for stage, ms in cpu.items() if stage not in ("simulate", "of which MCAP"))
    table = [
        f"Recording throughput, frames/s end to end ({episodes} expert episodes of 1000 steps, "
        f"NOISE={STANDING_NOISE}):",
        "",
        "| repeat | rollout, no writing | 2 rollouts at once | record, 1 worker | record, 2 workers (default) |",
        "|---|---|---|---|---|",
        *rows,
        f"| median | | | {statistics.median(one_vs_rollout):.2f}x rollout | "
        f"{statistics.median(two_vs_one):.2f}x 1 worker, {statistics.median(two_vs_two_rollouts):.2f}x 2 rollouts |",
        "",
        f"Peak resident memory of a {memory_episodes}-episode recording, MiB (recorder / writer process):",
        f"first {memory_episodes // 5} episodes {early[0]:.0f} / {early[1]:.0f}; "
        f"last {memory_episodes // 5} episodes {late[0]:.0f} / {late[1]:.0f}",
        "",
        f"CPU per 1000-frame episode, ms (median of {cpu_episodes}, one stage after another in one process):",
        "",
        "| " + " | ".join(cpu) + " |",
        "|" + "---|" * len(cpu),
        "| " + " | ".join(f"{ms:.1f}" for ms in cpu.values()) + " |",
        "",
        f"Ceiling for 2 workers on 2 cores: 2 / (1 + {overhead:.1f} / {cpu['simulate']:.1f}) = "
        f"{2 / (1 + overhead / cpu['simulate']):.2f}x the rollout alone",
    ]
    return "\n".join(table)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--episodes", type=int, default=50, help="episodes per contender and repeat (a default recording)"
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--memory-episodes", type=int, default=50)
    parser.add_argument("--cpu-episodes", type=int, default=20, help="whole episodes timed stage by stage")
    args = parser.parse_args()
    print(run(args.episodes, args.repeats, args.memory_episodes, args.cpu_episodes))
