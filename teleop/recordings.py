"""DATASET/recordings.jsonl: one line per run that added episodes to a dataset, with the run's full config.

`make record` (and `make pipeline` when it records, `make dagger` on its aggregate, `make merge`) append a line
when the run ends, also when it is interrupted: who ran (`made_by`), when, the resolved config, and
which episodes (indices and seeds) the run committed; a randomised recording adds the ranges its
`randomize` setting stands for (`"randomization": {"mass": [0.8, 1.2], ...}`), a merge its shards'
own lines (`SESSIONS_KEY`; `expanded` gives the recordings behind a line). A run that committed
nothing writes nothing.
LeRobot reads only meta/ and data/ and ignores the file; `make inspect` lists the sessions.

A kill -9 leaves no time for the line, so a run marks the dataset while it writes (`RUN_FILE`: who,
its config, the episode count it started from; `mark`), and the next run, under the dataset's lock,
writes the killed run's line for the episodes it left (complete false) before marking the dataset as
its own (`take_over`). A run that ends removes its mark (`unmark`) after writing its line.

    {"made_by": "teleop.record", "time": "2026-01-01T12:00:00+00:00", "complete": true,
     "config": {"dataset": "datasets/humanoid_stand", "episodes": 50, ...},
     "episodes": [0, 49], "seeds": [0, 49], "count": 50}
"""

from __future__ import annotations

import datetime
import json
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from common.cli import json_text, write_json
from common.workers import owner_gone, process_owner

log = logging.getLogger(__name__)

RECORDINGS_FILE = "recordings.jsonl"
SESSIONS_KEY = "sessions"
"""A merge's line holds under it each shard's own lines, by shard (`teleop.merge`)."""
RUN_FILE = ".run.json"
"""The mark of a run writing episodes into the dataset (`mark`); a dataset copied for another run leaves it out
(and its staging file, `RUN_FILE` + `common.files.PARTIAL_SUFFIX`)."""
MARK_WAIT = 5.0
"""Seconds a run starting on a dataset waits for the line of a run that let the dataset go but still runs."""


class Committed(Protocol):
    """What a run reports of each episode it committed (`teleop.store.CommittedEpisode`)."""

    index: int
    seed: int


def append(
    root: Path,
    made_by: str,
    config: dict[str, Any],
    committed: Sequence[Committed],
    complete: bool,
    extra: dict[str, Any] | None = None,
) -> None:
    """Add the line of a run that committed `committed` (in commit order) to `root`'s recordings.jsonl.

    `extra` adds keys to the line (the recorder's "randomization": the ranges its --randomize stands for).
    """
    if committed:
        _write(root, _line(made_by, _now(), config, committed, complete, extra))


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _line(
    made_by: str,
    time: str,
    config: dict[str, Any],
    committed: Sequence[Committed],
    complete: bool,
    extra: dict[str, Any] | None,
) -> dict[str, Any]:
    return {
        "made_by": made_by,
        "time": time,
        "complete": complete,
        "config": config,
        "episodes": [committed[0].index, committed[-1].index],
        "seeds": [committed[0].seed, committed[-1].seed],
        "count": len(committed),
        **(extra or {}),
    }


def _cut_short(path: Path) -> bool:
    """Whether the file at `path` ends inside a line (a write a full disk or a kill cut short)."""
    try:
        with path.open("rb") as stream:
            stream.seek(-1, os.SEEK_END)
            return stream.read(1) != b"\n"
    except OSError:  # no file yet, or an empty one
        return False


def _write(root: Path, line: dict[str, Any]) -> None:
    path = root / RECORDINGS_FILE
    try:
        start = "\n" if _cut_short(path) else ""  # a line cut short stays alone, unreadable; this one starts anew
        with path.open("a") as stream:
            stream.write(start + json_text(line) + "\n")
    except OSError as error:  # the episodes are committed: a missing line costs only their history
        log.warning("cannot add the run to %s: %s", path, error.strerror or error)


def read(root: Path) -> list[dict[str, Any]]:
    """The lines of `root`'s recordings.jsonl, oldest first; [] if it has none. A line cut short (a full disk, a kill
    mid-write) is left out: each write starts on a line of its own (`_write`), so the lines after it are whole."""
    path = root / RECORDINGS_FILE
    if not path.is_file():
        return []
    lines = []
    for text in path.read_text().splitlines():
        try:
            lines.append(json.loads(text))
        except ValueError:
            log.warning("%s holds a line cut short: left out", path)
    return lines


def mark(root: Path, made_by: str, config: dict[str, Any], episodes: int, extra: dict[str, Any] | None = None) -> None:
    """Mark `root` as written by this run, which found `episodes` episodes there; atomic, so a kill leaves the old
    mark or the new one."""
    mark = {
        "made_by": made_by,
        "time": _now(),
        "config": config,
        "episodes": episodes,
        "extra": extra or {},
        "owner": process_owner(),
    }
    write_json(root / RUN_FILE, mark)


def marked(root: Path) -> dict[str, Any] | None:
    """The mark of the run that last wrote into `root` and did not end (a kill -9), or None."""
    path = root / RUN_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def killed_line(killed: dict[str, Any], seeds: Sequence[int]) -> dict[str, Any] | None:
    """The line the `killed` run (its mark) gets for the episodes it added, those past the count it started from,
    with the time it started; None if it added none. `seeds`: every episode's seed in the dataset, by index."""
    episodes = [Episode(index, seed) for index, seed in enumerate(seeds) if index >= killed["episodes"]]
    if not episodes:
        return None
    return _line(killed["made_by"], killed["time"], killed["config"], episodes, False, killed["extra"])


def sessions(root: Path, seeds: Callable[[], Sequence[int]]) -> list[dict[str, Any]]:
    """`read(root)`, then the line a run killed there with -9 will get from the next run (`killed_line`), if any:
    what recorded each episode. `seeds()` gives every episode's seed in `root`, by index; it is called only if a
    killed run left its mark, so that a dataset without one is read no further than before."""
    lines = read(root)
    killed = marked(root)
    line = None if killed is None else killed_line(killed, seeds())
    return lines if line is None else [*lines, line]


def log_killed(root: Path, killed: dict[str, Any], seeds: Sequence[int]) -> None:
    """Add the `killed` run's line (`killed_line`), if it added episodes, to `root`'s recordings.jsonl."""
    line = killed_line(killed, seeds)
    if line is not None:
        _write(root, line)


def take_over(
    root: Path,
    made_by: str,
    config: dict[str, Any],
    episodes: int,
    seeds: Callable[[], Sequence[int]],
    extra: dict[str, Any] | None = None,
) -> None:
    """Under `root`'s lock, as a run starts on its `episodes` episodes: the line of a run killed there, if it added
    any (`seeds()` as for `sessions`), then this run's mark. A mark whose run still runs here is that of a run that
    let the dataset go and is writing its line (`teleop.record` does after closing it): waited for, up to
    MARK_WAIT seconds, rather than logged as killed."""
    killed = marked(root)
    deadline = time.monotonic() + MARK_WAIT
    while killed is not None and _finishing(killed) and time.monotonic() < deadline:
        time.sleep(0.02)
        killed = marked(root)
    if killed is not None and episodes > killed["episodes"]:
        log_killed(root, killed, seeds())
    mark(root, made_by, config, episodes, extra)


def _finishing(mark: dict[str, Any]) -> bool:
    """Whether the run that left `mark` may still be writing its line: another process that runs (a mark from before
    marks named their owner, or this process's own, is a killed run's)."""
    owner = mark.get("owner")
    return owner is not None and owner != process_owner() and not owner_gone(owner)


@contextmanager
def logged(
    root: Path,
    made_by: str,
    config: dict[str, Any],
    episodes: int,
    seeds: Callable[[], Sequence[int]],
    extra: dict[str, Any] | None = None,
) -> Iterator[list[Committed]]:
    """A run writing into `root`, under its lock, from `episodes` episodes on: `take_over`, then the list the run
    adds what it commits to; on leaving, the run's line (complete unless an exception left the block) and no mark."""
    take_over(root, made_by, config, episodes, seeds, extra)
    committed: list[Committed] = []
    complete = False
    try:
        yield committed
        complete = True
    finally:
        append(root, made_by, config, committed, complete, extra)
        unmark(root)


def expanded(lines: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """`lines` with each merge's line replaced by the lines of the shards it merged (`SESSIONS_KEY`), recursively:
    the recording sessions behind a dataset's episodes, whose configs say how they were recorded."""
    out: list[dict[str, Any]] = []
    for line in lines:
        shards = line.get(SESSIONS_KEY)
        out += [line] if shards is None else expanded([run for runs in shards.values() for run in runs])
    return out


def unmark(root: Path) -> None:
    """The run has written its line: nothing is left for a later run to log."""
    (root / RUN_FILE).unlink(missing_ok=True)


@dataclass(frozen=True)
class Episode:
    """An episode's index and seed: what a line records of it (a `Committed`)."""

    index: int
    seed: int
