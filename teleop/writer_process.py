"""Runs an `EpisodeStore` in a child process, so that writing overlaps with simulation.

Encoding an episode into parquet and MCAP costs about a sixth of simulating it, and a writer
thread would fight the simulation for the GIL, so the writer is a process of its own. Episodes
go to it through a pipe, one at a time: the recorder is never more than one episode ahead, and
memory stays flat.

Crash behaviour: the child ignores Ctrl-C and stops only when the pipe closes, so every episode
that reached it is committed even if the recorder is interrupted or killed. It holds the dataset
lock until then, so a new recorder cannot interleave with it.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING

from common.cli import DatasetError

if TYPE_CHECKING:
    from humanoid.episode import Episode
    from teleop.store import CommittedEpisode


class WriterProcess:
    """The `EpisodeSink` that appends episodes to `root` from a child process."""

    def __init__(self, root: Path) -> None:
        # A fresh interpreter started with `-m`: unlike multiprocessing's spawn, it never re-imports
        # the caller's __main__, and it inherits exactly the two pipe ends it needs.
        episodes_in, episodes_out = os.pipe()
        results_in, results_out = os.pipe()
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(root), str(episodes_in), str(results_out)],
            pass_fds=(episodes_in, results_out),
        )
        os.close(episodes_in)  # the child alone reads episodes: it sees end-of-file when ours closes
        os.close(results_out)
        self._episodes = Connection(episodes_out, readable=False)
        self._results = Connection(results_in, writable=False)
        self.num_episodes = -1
        self._next_seed = -1
        self._error: str | None = None

    def wait_ready(self) -> None:
        """Block until the child has opened the dataset; DatasetError if it could not."""
        kind, payload = self._receive()
        if kind != "ready":
            self._fail(payload)
        self.num_episodes, self._next_seed = payload

    def next_seed(self) -> int:
        return self._next_seed

    def submit(self, episode: Episode) -> list[CommittedEpisode]:
        """Hand `episode` over (blocks while the child is still writing the previous one)."""
        try:
            self._episodes.send(episode)
        except (BrokenPipeError, ConnectionResetError):
            self._committed(until_closed=True)  # the child stopped: collect its reason
        return self._committed(until_closed=False)

    def close(self) -> list[CommittedEpisode]:
        """Signal the end of the recording and wait until every episode sent is committed."""
        if self._episodes.closed:
            return []
        self._episodes.close()
        try:
            return [] if self._error else self._committed(until_closed=True)
        finally:
            self._results.close()
            self._process.wait()

    def _receive(self) -> tuple[str, object]:
        try:
            return self._results.recv()
        except (EOFError, ConnectionResetError):
            return "error", f"the writer process died (exit code {self._process.wait()})"

    def _committed(self, until_closed: bool) -> list[CommittedEpisode]:
        committed = []
        while until_closed or self._results.poll():
            kind, payload = self._receive()
            if kind == "closed":
                break
            if kind != "committed":
                self._fail(payload)
            committed.append(payload)
            self.num_episodes += 1
        return committed

    def _fail(self, message: str) -> None:
        """Remember that the child stopped (so `close` just cleans up) and raise its reason."""
        self._error = message
        self._process.wait()
        raise DatasetError(message)


def _send(results: Connection, kind: str, payload: object) -> None:
    """Report to the recorder; if it is gone (killed), keep writing what it already sent."""
    try:
        results.send((kind, payload))
    except (BrokenPipeError, ConnectionResetError):
        pass


def _serve(root: Path, episodes: Connection, results: Connection) -> None:
    from humanoid.env import make_env  # noqa: PLC0415 - heavy imports happen in the child only
    from teleop.store import DatasetSpec, EpisodeStore  # noqa: PLC0415 - heavy imports happen in the child only

    try:
        store = EpisodeStore(root, DatasetSpec.from_env(make_env()))
    except DatasetError as error:
        _send(results, "error", str(error))
        return
    except Exception as error:
        traceback.print_exc()
        _send(results, "error", f"cannot open {root}: {error}")
        return
    try:
        _send(results, "ready", (store.num_episodes, store.next_seed()))
        store.prepare()  # while the recorder simulates the first episode
        while True:
            try:
                episode = episodes.recv()
            except (EOFError, OSError):  # the recorder closed the pipe, finished or killed mid-send
                break
            _send(results, "committed", store.append(episode))
    except Exception as error:  # report it as one line; the traceback goes to stderr for debugging
        traceback.print_exc()
        _send(results, "error", f"writing to {root} failed: {error}")
    else:
        store.close()  # releases the dataset before the recorder hears that it may go on
        _send(results, "closed", None)
    finally:
        store.close()


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group; the recorder decides
    parser = argparse.ArgumentParser(description="internal: the recorder's writer process")
    parser.add_argument("root", type=Path)
    parser.add_argument("episodes_fd", type=int)
    parser.add_argument("results_fd", type=int)
    args = parser.parse_args()
    _serve(args.root, Connection(args.episodes_fd, writable=False), Connection(args.results_fd, readable=False))
    # Every file is closed and renamed: skip the interpreter's teardown (a few hundred ms of module cleanup).
    sys.stderr.flush()
    os._exit(0)
