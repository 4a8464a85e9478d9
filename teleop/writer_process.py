"""Runs an `EpisodeStore` in a child process, so that writing overlaps with simulation.

Encoding an episode into parquet and MCAP costs about a sixth of simulating it, and a writer
thread would fight the simulation for the GIL, so the writer is a process of its own. Episodes
go to it through a pipe, one at a time: the recorder is never more than one episode ahead, and
memory stays flat.

Crash behaviour: the child ignores Ctrl-C and stops only when the pipe closes, so every episode
that reached it is committed even if the recorder is interrupted or killed. It holds the dataset
lock until then, so a new recorder cannot interleave with it.

The child is a `common.workers.Worker` with `outlives_parent` (a forkserver child, as the
recording workers are; it used to be a `python -m` interpreter of its own, and reaches "ready" as
fast as that did: docs/concepts/processes.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from common.workers import Channel, Worker

if TYPE_CHECKING:
    from humanoid.cameras import Camera
    from rollout.episode import Episode
    from teleop.store import CommittedEpisode

WRITER_MODULES = ("humanoid.env", "teleop.store")  # what `_serve` imports


class WriterProcess:
    """The `EpisodeSink` that appends episodes to `root` from a child process (a `common.workers.Worker`)."""

    def __init__(self, root: Path, parameters: tuple[str, ...] = (), cameras: tuple[Camera, ...] = ()) -> None:
        """`parameters`: what every episode's domain randomisation draws (`teleop.store.DatasetSpec.parameters`);
        `cameras`: what each records (`DatasetSpec.cameras`)."""
        # outlives_parent: the writer commits what it received even if the recorder is killed.
        self._worker = Worker(
            _serve,
            root,
            parameters,
            cameras,
            name=f"the writer process of {root}",
            preload=WRITER_MODULES,
            outlives_parent=True,
        )
        self.num_episodes = -1
        self._seeds: list[int] = []
        self._ready = False

    def wait_ready(self) -> None:
        """Block until the child has opened the dataset; DatasetError (or WorkerError) if it could not."""
        self.num_episodes, self._seeds = self._worker.recv()
        self._ready = True

    def seeds(self) -> list[int]:
        """The seeds of the dataset's episodes when it opened (`wait_ready`)."""
        return self._seeds

    def submit(self, episode: Episode) -> list[CommittedEpisode]:
        """Hand `episode` over (blocks while the child is still writing the previous one)."""
        self._worker.send(episode)  # if the child stopped, raises its reason
        committed = []
        while self._worker.poll():
            committed.append(self._worker.recv())
        self.num_episodes += len(committed)
        return committed

    def close(self) -> list[CommittedEpisode]:
        """Signal the end of the recording and wait until every episode sent is committed."""
        if self._worker.exitcode is not None or self._worker.failed:
            self._worker.close()
            committed, self._worker.unread = self._worker.unread, []  # what it committed before it failed
            self.num_episodes += len(committed)
            return committed
        try:
            self._worker.stop_sending()
            rest = self._worker.rest()  # the child has closed the dataset when its channel ends
            if not self._ready:  # interrupted before `wait_ready`: its message comes first
                next(rest, None)
            committed = list(rest)
            self.num_episodes += len(committed)
            return committed
        finally:
            self._worker.close()


def _serve(channel: Channel, root: Path, parameters: tuple[str, ...], cameras: tuple[Camera, ...]) -> None:
    """The writer (`common.workers`): open the dataset, report it ready, commit each episode received, report it."""
    from humanoid.env import make_env  # noqa: PLC0415 - heavy imports happen in the child only
    from teleop.store import DatasetSpec, EpisodeStore  # noqa: PLC0415 - heavy imports happen in the child only

    store = EpisodeStore(root, DatasetSpec.from_env(make_env(), parameters, cameras))
    try:
        channel.send((store.num_episodes, store.seeds()))
        store.prepare()  # while the recorder simulates the first episode
        for episode in channel:  # until the recorder closes the channel, finished or killed (mid-send too)
            channel.send(store.append(episode))
    finally:
        store.close()  # releases the dataset before the recorder hears that the channel ended
