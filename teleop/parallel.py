"""Parallel recording: N simulation processes, one dataset committed in seed order.

Each worker builds its own environment and controller, simulates the seeds it is handed and
writes every finished episode to the dataset's spool (`teleop.spool`). The recorder's process
hands out seeds (each worker holds at most `SEEDS_AHEAD`, so a worker never waits for its next
seed while the recorder writes) and commits the spooled episodes strictly in seed order. Seeds go
to whichever worker is free, so an episode that falls early does not leave a worker idle, and
the values are those a single process would record: an episode depends only on its seed and the
settings (the rollout is deterministic).

A kill -9 of the whole group loses no finished episode: the finished ones are committed or in
the spool, and the next recording commits the spool before it starts.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path

from common.cli import UserError
from teleop.spool import Spool

SEEDS_AHEAD = 2  # seeds a worker holds: the one it simulates and the next one
WORKER_MODULES = ("humanoid.controllers", "humanoid.env", "humanoid.episode", "teleop.spool")  # what `_work` imports


@dataclass(frozen=True)
class RolloutSettings:
    """What a worker needs to reproduce the recorder's rollout of a seed."""

    controller: str
    noise: float
    max_steps: int
    task: str


def _work(settings: RolloutSettings, dataset: Path, seeds: Connection, results: Connection) -> None:
    """A worker's loop: simulate each seed received, spool the episode, report the seed."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group; the recorder stops us
    try:
        from humanoid.controllers import make_controller  # noqa: PLC0415 - heavy imports in the worker only
        from humanoid.env import make_env  # noqa: PLC0415 - heavy imports in the worker only
        from humanoid.episode import EpisodeBuffer, run_episode  # noqa: PLC0415 - heavy imports in the worker only

        env = make_env(settings.max_steps)
        controller = make_controller(settings.controller, env)
        buffer = EpisodeBuffer(env, settings.max_steps)
        spool = Spool(dataset)
        while (seed := seeds.recv()) is not None:
            spool.put(run_episode(env, controller, seed, settings.noise, buffer, settings.task))
            results.send(("done", seed))
    except (EOFError, BrokenPipeError):  # the recorder is gone
        return
    except UserError as error:
        results.send(("error", str(error)))
    except Exception as error:  # one line for the user; the traceback on stderr for debugging
        traceback.print_exc()
        results.send(("error", f"a recording worker failed: {error!r}"))


class ParallelRollouts:
    """`workers` simulation processes for one recording; a context manager that stops them on exit."""

    def __init__(self, settings: RolloutSettings, dataset: Path, workers: int) -> None:
        # forkserver: workers start from a clean interpreter, not a fork of a process holding locks.
        context = mp.get_context("forkserver")
        # Imported once by the server (when this process starts it) instead of by every worker: a
        # worker then starts in milliseconds instead of 0.2 s. Later calls do not change a running server.
        context.set_forkserver_preload(["__main__", *WORKER_MODULES])
        self._spool = Spool(dataset)
        self._seeds: list[Connection] = []
        self._results: list[Connection] = []
        self._processes = []
        self._closed = False
        for _ in range(workers):
            seeds_out, seeds_in = context.Pipe(duplex=False)
            results_out, results_in = context.Pipe(duplex=False)
            process = context.Process(target=_work, args=(settings, dataset, seeds_out, results_in), daemon=True)
            process.start()
            seeds_out.close()
            results_in.close()
            self._seeds.append(seeds_in)
            self._results.append(results_out)
            self._processes.append(process)

    def in_seed_order(self, seeds: Sequence[int], meanwhile: Callable[[], None] = lambda: None) -> Iterator[Path]:
        """The spool file of each seed's episode, in the order of `seeds`, as soon as all before it are done.

        `meanwhile` runs once the workers have their first seeds, before waiting for them.
        """
        handed = 0
        holding = [0] * len(self._processes)
        done: set[int] = set()

        def hand_out(worker: int) -> None:
            nonlocal handed
            while holding[worker] < SEEDS_AHEAD and handed < len(seeds):
                self._seeds[worker].send(seeds[handed])
                holding[worker] += 1
                handed += 1

        for worker in range(len(self._processes)):
            hand_out(worker)
        meanwhile()
        for seed in seeds:
            while seed not in done:
                for connection in wait(self._results):
                    worker = self._results.index(connection)
                    try:
                        kind, payload = connection.recv()
                    except EOFError:
                        raise UserError(
                            f"recording worker {worker} died (exit code {self._processes[worker].exitcode})"
                        ) from None
                    if kind == "error":
                        raise UserError(payload)
                    done.add(payload)
                    holding[worker] -= 1
                    hand_out(worker)
            done.discard(seed)
            yield self._spool.path_of(seed)

    def close(self, interrupted: bool = False) -> None:
        """Stop the workers once their seeds are done, or at once if `interrupted` (spooled episodes stay).

        Idempotent: the first call decides.
        """
        if self._closed:
            return
        self._closed = True
        for connection in self._seeds:
            if not interrupted:
                try:
                    connection.send(None)
                except OSError:  # the worker is already gone
                    pass
            connection.close()
        for process in self._processes:
            if interrupted:
                process.kill()  # an unfinished episode is worth nothing; the finished ones are spooled
            process.join()
        for connection in self._results:
            connection.close()

    def __enter__(self) -> ParallelRollouts:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        self.close(interrupted=exc_type is not None)
