"""DATASET/recordings.jsonl: one line per run that added episodes to a dataset, with the run's full config.

`make record` (and `make pipeline` when it records, and `make dagger` on its aggregate) append a line
when the run ends, also when it is interrupted: who ran (`made_by`), when, the resolved config, and
which episodes (indices and seeds) the run committed; a randomised recording adds the ranges its
`randomize` setting stands for (`"randomization": {"mass": [0.8, 1.2], ...}`). A run that committed
nothing writes nothing.
LeRobot reads only meta/ and data/ and ignores the file; `make inspect` lists the sessions.

    {"made_by": "teleop.record", "time": "2026-01-01T12:00:00+00:00", "complete": true,
     "config": {"dataset": "datasets/humanoid_stand", "episodes": 50, ...},
     "episodes": [0, 49], "seeds": [0, 49], "count": 50}
"""

from __future__ import annotations

import datetime
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

log = logging.getLogger(__name__)

RECORDINGS_FILE = "recordings.jsonl"


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
    if not committed:
        return
    line = {
        "made_by": made_by,
        "time": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "complete": complete,
        "config": config,
        "episodes": [committed[0].index, committed[-1].index],
        "seeds": [committed[0].seed, committed[-1].seed],
        "count": len(committed),
        **(extra or {}),
    }
    try:
        with (root / RECORDINGS_FILE).open("a") as stream:
            stream.write(json.dumps(line, default=str) + "\n")
    except OSError as error:  # the episodes are committed: a missing line costs only their history
        log.warning("cannot add the run to %s: %s", root / RECORDINGS_FILE, error.strerror or error)


def read(root: Path) -> list[dict[str, Any]]:
    """The lines of `root`'s recordings.jsonl, oldest first; [] if it has none (or an unreadable line ends it)."""
    path = root / RECORDINGS_FILE
    if not path.is_file():
        return []
    lines = []
    for text in path.read_text().splitlines():
        try:
            lines.append(json.loads(text))
        except ValueError:  # a line cut short by a full disk: what follows cannot be trusted either
            break
    return lines
