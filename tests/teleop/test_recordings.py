"""recordings.jsonl and the mark a run leaves while it writes: known answers, on files in tmp_path."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from teleop import recordings


def test_a_killed_runs_line_covers_the_episodes_past_its_start(tmp_path: Path) -> None:
    """Started on 2 episodes, the killed run added the next ones: their indices and seeds, its time and config."""
    recordings.mark(tmp_path, "teleop.record", {"episodes": 10}, episodes=2, extra={"randomization": {}})
    killed = recordings.marked(tmp_path)
    line = recordings.killed_line(killed, [5, 6, 7, 9])
    assert {key: line[key] for key in ("made_by", "complete", "config", "episodes", "seeds", "count", "time")} == {
        "made_by": "teleop.record",
        "complete": False,
        "config": {"episodes": 10},
        "episodes": [2, 3],
        "seeds": [7, 9],
        "count": 2,
        "time": killed["time"],
    }


def test_a_killed_run_that_added_nothing_gets_no_line(tmp_path: Path) -> None:
    recordings.mark(tmp_path, "teleop.record", {}, episodes=2)
    recordings.log_killed(tmp_path, recordings.marked(tmp_path), [0, 1])
    assert recordings.killed_line(recordings.marked(tmp_path), [0, 1]) is None
    assert recordings.read(tmp_path) == []


def test_sessions_end_with_the_killed_runs_line_until_it_is_written(tmp_path: Path) -> None:
    """Before the next run writes it, `sessions` shows the killed run's line; after, that line once, and no mark."""
    recordings.append(tmp_path, "teleop.record", {}, [recordings.Episode(0, 0)], complete=True)
    recordings.mark(tmp_path, "teleop.record", {"episodes": 5}, episodes=1)
    pending = recordings.sessions(tmp_path, lambda: [0, 1, 2])
    recordings.log_killed(tmp_path, recordings.marked(tmp_path), [0, 1, 2])
    recordings.unmark(tmp_path)
    assert [line["episodes"] for line in pending] == [[0, 0], [1, 2]]
    assert recordings.sessions(tmp_path, lambda: [0, 1, 2]) == recordings.read(tmp_path) == pending
    assert recordings.marked(tmp_path) is None


def test_a_run_that_fails_is_logged_incomplete_and_leaves_no_mark(tmp_path: Path) -> None:
    """`logged`: what the run committed before the error gets its line, complete false; the mark goes."""
    with pytest.raises(RuntimeError), recordings.logged(tmp_path, "teleop.merge", {}, 0, list) as added:
        added.append(recordings.Episode(0, 7))
        raise RuntimeError("interrupted")
    (line,) = recordings.read(tmp_path)
    assert (line["complete"], line["episodes"], line["seeds"]) == (False, [0, 0], [7, 7])
    assert recordings.marked(tmp_path) is None


def test_a_line_cut_short_hides_no_later_session(tmp_path: Path) -> None:
    """A write cut short (a full disk, a kill) leaves half a line: the next session's line starts a line of its own,
    and reading leaves out the broken one only."""
    recordings.append(tmp_path, "teleop.record", {"n": 1}, [recordings.Episode(0, 0)], complete=True)
    with (tmp_path / recordings.RECORDINGS_FILE).open("a") as stream:
        stream.write('{"made_by": "teleop.rec')
    recordings.append(tmp_path, "teleop.record", {"n": 3}, [recordings.Episode(2, 2)], complete=True)
    assert [line["config"] for line in recordings.read(tmp_path)] == [{"n": 1}, {"n": 3}]


def mark_of(root: Path, process: subprocess.Popen, episodes: int) -> None:
    """`root` marked by `process`'s run, which started on `episodes` episodes."""
    recordings.mark(root, "teleop.record", {}, episodes=episodes)
    path = root / recordings.RUN_FILE
    path.write_text(json.dumps({**json.loads(path.read_text()), "owner": f"{socket.gethostname()}-{process.pid}"}))


def test_a_run_still_writing_its_line_is_waited_for_not_logged_as_killed(tmp_path: Path) -> None:
    """The run before let the dataset go and still runs (writing its line): the next run waits for its mark to go
    rather than logging it as killed, and marks the dataset as its own."""
    finishing = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        mark_of(tmp_path, finishing, episodes=0)
        start = time.monotonic()  # before the timer starts: its 0.3 s count from there
        threading.Timer(0.3, recordings.unmark, [tmp_path]).start()  # its line written, its mark gone
        recordings.take_over(tmp_path, "teleop.record", {"n": 2}, 1, lambda: [0])
        assert 0.3 <= time.monotonic() - start < recordings.MARK_WAIT
        assert recordings.read(tmp_path) == [] and recordings.marked(tmp_path)["config"] == {"n": 2}
    finally:
        finishing.kill()
        finishing.wait()


def test_a_run_whose_process_is_gone_is_logged_as_killed_at_once(tmp_path: Path) -> None:
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    mark_of(tmp_path, gone, episodes=0)
    start = time.monotonic()
    recordings.take_over(tmp_path, "teleop.record", {}, 1, lambda: [0])
    assert time.monotonic() - start < 1.0
    assert [line["episodes"] for line in recordings.read(tmp_path)] == [[0, 0]]
