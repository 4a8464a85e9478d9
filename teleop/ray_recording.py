"""Recording with `BACKEND=ray`: the simulation workers are Ray actors, the writer stays here.

    recorder (this machine)                         Ray actors (any node)
      hands out seeds, SEEDS_AHEAD per worker  ->   Simulator.run(seed) -> Episode
      each finished Episode, as it arrives     <-   (through Ray's object store)
        -> DATASET/.spool/<seed>.npz                 spooled here first, as with local workers
      commits the spool in seed order               (teleop.record, teleop.store)

The dataset is the one `WORKERS=1` records (an episode depends only on its seed and the settings;
a test compares every file), because the same `teleop.parallel.Simulator` runs each seed and the
writer commits in seed order. A kill -9 of the recorder loses no finished episode that reached it:
it is committed or spooled, and the next recording commits the spool.

A worker lost mid-recording (its process killed, its node gone) costs only the episodes it was
simulating: their seeds go back to the front of the queue for the other workers, so no seed is
skipped or recorded twice. With no worker left the recording stops with one line; what was
finished is committed, and the next `make record` continues after it.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from common.ray_backend import RaySession, RayWorker, WorkerLost
from rollout.episode import EpisodeFailure
from teleop.parallel import SEEDS_AHEAD, RolloutSettings, Simulator
from teleop.spool import Spool

log = logging.getLogger(__name__)


class RayRollouts:
    """`workers` Ray actors simulating for one recording; the interface of `teleop.parallel.ParallelRollouts`."""

    def __init__(self, settings: RolloutSettings, dataset: Path, workers: int, address: str | None) -> None:
        self._spool = Spool(dataset)
        self._session = RaySession(address, workers)
        self._closed = False
        try:
            self._workers = self._session.spawn(
                [functools.partial(Simulator, settings)] * workers, name="recording worker"
            )
        except BaseException:
            self._session.close()
            raise

    def in_seed_order(
        self, seeds: Sequence[int], meanwhile: Callable[[], None] = lambda: None
    ) -> Iterator[Path | EpisodeFailure]:
        """The spool file of each seed's episode (or its `EpisodeFailure`), in the order of `seeds`, as soon as all
        before it are done.

        `meanwhile` runs once the workers have their first seeds, before waiting for them.
        """
        position = {seed: index for index, seed in enumerate(seeds)}
        queue = list(seeds)  # seeds not handed out, in order
        running: dict[object, tuple[RayWorker, int]] = {}  # a call in flight: its worker and seed
        done: dict[int, EpisodeFailure | None] = {}
        workers = list(self._workers)

        def hand_out(worker: RayWorker) -> None:
            while queue and sum(w is worker for w, _ in running.values()) < SEEDS_AHEAD:
                seed = queue.pop(0)
                running[worker.submit("run", seed)] = (worker, seed)

        def lose(worker: RayWorker, error: WorkerLost) -> None:
            requeued = sorted(running.pop(ref)[1] for ref in [ref for ref, (w, _) in running.items() if w is worker])
            queue[:] = sorted([*requeued, *queue], key=position.__getitem__)  # the oldest seeds first
            workers.remove(worker)
            if not workers:
                raise WorkerLost(f"{error}; no Ray worker is left: run the same `make record` again to continue")
            log.warning("%s; seeds %s go to the other workers", error, requeued)
            for other in workers:
                hand_out(other)

        for worker in workers:
            hand_out(worker)
        meanwhile()
        for seed in seeds:
            while seed not in done:
                for ref in self._session.wait(list(running)):
                    if ref not in running:  # dropped with its lost worker
                        continue
                    worker, finished = running[ref]
                    try:
                        episode = worker.get(ref)
                    except WorkerLost as error:
                        lose(worker, error)
                        continue
                    del running[ref]
                    if isinstance(episode, EpisodeFailure):
                        done[finished] = episode
                    else:
                        self._spool.put(episode)  # before anything else: a kill -9 from here on loses nothing
                        done[finished] = None
                    hand_out(worker)
            failure = done.pop(seed)
            yield self._spool.path_of(seed) if failure is None else failure

    def close(self, interrupted: bool = False) -> None:
        """Stop the workers. Idempotent.

        Unlike processes, actors hold nothing of value once the recording stops: every finished episode
        reached the spool, so `interrupted` changes nothing. Ray itself is let go of on leaving the context.
        """
        if not self._closed:
            self._closed = True
            self._session.kill_actors()

    def __enter__(self) -> RayRollouts:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        self.close(interrupted=exc_type is not None)
        self._session.close()
