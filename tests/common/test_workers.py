"""The worker-process mechanism (`common.workers`) with real processes: failures, deaths, shutdown."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.cli import DatasetError
from common.workers import Channel, Worker, WorkerError, torch_threads

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (processes)

HERE = Path(__file__).resolve().parent

# The children's targets: module-level, so that a forkserver child can unpickle them.


def echo(channel: Channel) -> None:
    for message in channel:
        channel.send(message)


def raise_value_error(channel: Channel) -> None:
    channel.recv()
    raise ValueError("bad value")


def raise_user_error(channel: Channel) -> None:
    raise DatasetError("the dataset is locked")


def answer_once_then_fail(channel: Channel) -> None:
    channel.send(("answered", channel.recv()))
    raise ValueError("bad value")


def report_pid_then_wait(channel: Channel) -> None:
    channel.send(os.getpid())
    channel.recv()


def never_stop(channel: Channel) -> None:
    channel.send(os.getpid())
    while True:
        time.sleep(1)


def look_up(channel: Channel) -> None:
    channel.serve(lambda key: {"a": 1}[key])


def write_slowly(channel: Channel, path: Path) -> None:
    """Each message is appended to `path` after a while, and acknowledged (to a parent that may be gone)."""
    for message in channel:
        time.sleep(0.2)
        with path.open("a") as file:
            file.write(f"{message}\n")
        channel.send(message)


def fail_in_a_child() -> None:
    """For the subprocess test below: prints the one line the parent gets."""
    with Worker(raise_value_error, name="test worker") as worker:
        worker.send("go")
        try:
            worker.recv()
        except WorkerError as error:
            print(error)


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_messages_go_both_ways_and_the_rest_comes_after_the_input_ends() -> None:
    with Worker(echo, name="echo") as worker:
        worker.send({"seed": 3})
        assert worker.recv() == {"seed": 3}
        worker.send(4)
        worker.send(5)
        worker.stop_sending()
        assert list(worker.rest()) == [4, 5]
        assert worker.exitcode == 0


def test_a_child_exception_is_one_line_in_the_parent_with_the_traceback_on_stderr() -> None:
    """The parent raises `<name> failed: ValueError('bad value')`; the child's stderr has the traceback."""
    code = f"import sys; sys.path.insert(0, {str(HERE)!r}); import test_workers; test_workers.fail_in_a_child()"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert result.stdout == "test worker failed: ValueError('bad value')\n"
    assert "Traceback (most recent call last)" in result.stderr
    assert 'raise ValueError("bad value")' in result.stderr


PROBE = """
WHERE = {where!r}


def where(channel):
    channel.send(WHERE)
"""


def test_children_import_from_the_parents_path_not_from_the_current_directory(tmp_path: Path) -> None:
    """A parent whose current directory holds another copy of a module its workers preload (another checkout's
    folder, say) gives them its own copy: the forkserver imports from the parent's `sys.path` (CPython gh-117378)."""
    for folder, where in (("ours", "the parent's"), ("cwd", "another checkout's")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "probe.py").write_text(PROBE.format(where=where))
    code = (
        f"import sys; sys.path.insert(0, {str(tmp_path / 'ours')!r})\n"
        "import probe\n"
        "from common.workers import Worker\n"
        "with Worker(probe.where, name='probe', preload=['probe']) as worker:\n"
        "    print(worker.recv())\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path / "cwd", capture_output=True, text=True, timeout=60, check=True
    )
    assert result.stdout == "the parent's\n"


def test_a_child_exception_ends_it_with_exit_code_1_and_a_user_error_stays_itself() -> None:
    worker = Worker(raise_value_error, name="test worker")
    worker.send("go")
    with pytest.raises(WorkerError, match=r"^test worker failed: ValueError\('bad value'\)$") as raised:
        worker.recv()
    assert isinstance(raised.value.__cause__, ValueError)
    assert worker.close() == 1
    with Worker(raise_user_error, name="writer") as worker:
        with pytest.raises(DatasetError, match="^the dataset is locked$"):
            worker.recv()
        assert worker.close() == 1


def test_a_child_killed_by_sigkill_is_reported_with_its_exit_code() -> None:
    worker = Worker(report_pid_then_wait, name="recording worker 1")
    pid = worker.recv()
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(WorkerError, match=r"^recording worker 1 died \(exit code -9, SIGKILL\)$"):
        worker.recv()
    assert worker.exitcode == -9
    with pytest.raises(WorkerError, match="died"):  # sending to it says the same
        worker.send("more")
    assert worker.close() == -9


def test_close_is_idempotent_and_reaps_the_child() -> None:
    worker = Worker(report_pid_then_wait, name="waiting")
    pid = worker.recv()
    assert worker.close() == 0  # its input ended: it returned
    assert worker.close() == 0
    assert gone(pid)


def test_close_kills_a_child_that_does_not_stop_after_the_timeout() -> None:
    worker = Worker(never_stop, name="stubborn")
    pid = worker.recv()
    start = time.monotonic()
    assert worker.close(timeout=0.5) == -signal.SIGKILL
    assert time.monotonic() - start >= 0.5  # it waited out the timeout first (a bound load cannot break)
    assert gone(pid)
    assert worker.close() == -signal.SIGKILL


def test_a_failed_request_is_raised_as_itself_and_the_child_goes_on() -> None:
    """`Channel.serve`: the handler's exception is the answer (with the child's traceback as a note)."""
    with Worker(look_up, name="server") as worker:
        worker.send("b")
        with pytest.raises(KeyError) as raised:
            worker.recv()
        assert "in a worker process" in raised.value.__notes__[0]
        worker.send("a")
        assert worker.recv() == 1


def test_a_child_that_outlives_its_parent_finishes_what_it_was_sent(tmp_path: Path) -> None:
    """`outlives_parent`: the parent closes at once (it reads nothing more); the child still does all three."""
    out = tmp_path / "out.txt"
    worker = Worker(write_slowly, out, name="writer", outlives_parent=True)
    for message in ("a", "b", "c"):
        worker.send(message)
    assert worker.close() == 0
    assert out.read_text() == "a\nb\nc\n"


DEFAULTS = """
import os, sys
counts = [int(cores) for cores in sys.argv[1:]]
os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[: counts[0]])
from rl import finetune
from evaluation import robustness
from common.workers import default_workers
from teleop import record
for cores in counts:
    os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:cores])
    print(cores, default_workers(14), default_workers(1), end=" ")
    print(finetune.workers(finetune.FinetuneConfig()), finetune.workers(finetune.FinetuneConfig(envs=8)), end=" ")
    print(robustness.RobustnessConfig().workers is None and default_workers(robustness.MOST_WORKERS), end=" ")
    print(record.workers(record.RecordConfig()), record.workers(record.RecordConfig(live=True)), end=" ")
    print(record.workers(record.RecordConfig(writer="inline")), record.workers(record.RecordConfig(workers=3)))
"""
CORE_COUNTS = (2, 1)


@pytest.fixture(scope="module")
def defaults_by_cores() -> dict[int, list[str]]:
    """What DEFAULTS prints for each core count this machine has, from the most to the fewest, in one process (one
    set of imports): narrowed before its imports, then again, so that a default frozen at import fails too."""
    counts = [cores for cores in CORE_COUNTS if cores <= len(os.sched_getaffinity(0))]
    run = subprocess.run(
        [sys.executable, "-c", DEFAULTS, *map(str, counts)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    return {int(line.split()[0]): line.split()[1:] for line in run.stdout.splitlines()}


@pytest.mark.parametrize("cores", CORE_COUNTS)
def test_worker_counts_default_to_the_cores_this_process_may_use(cores: int, defaults_by_cores: dict) -> None:
    """On 1 and 2 cores (this process's affinity narrowed): one worker per core, as PPO and the suite used on 2 before;
    recording in one process where it must (live view, keyboard, inline writer), and an explicit count as given."""
    if len(os.sched_getaffinity(0)) < cores:
        pytest.skip(f"needs {cores} cores")
    assert defaults_by_cores[cores] == [str(cores), "1", str(cores), str(cores), str(cores), str(cores), "1", "1", "3"]


@pytest.mark.parametrize(("told", "most"), [(None, 99), ("1", 1), ("64", 99), ("", 99), ("two", 99)])
def test_torch_threads_are_the_cores_or_fewer_where_omp_num_threads_says(
    told: str | None, most: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One per core this process may use; `OMP_NUM_THREADS` lowers it (a share of the cores) but never raises it, and
    a value that is no count is ignored."""
    if told is None:
        monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OMP_NUM_THREADS", told)
    assert torch_threads() == min(most, len(os.sched_getaffinity(0)))


def test_a_send_to_a_child_that_failed_keeps_its_last_answers() -> None:
    """What the child said before it failed (a writer's committed episodes) is in `unread` when `send` raises why."""
    with Worker(answer_once_then_fail, name="test worker") as worker:
        worker.send(1)
        worker.process.join(10)  # failed and gone: the next send finds the pipe broken
        with pytest.raises(WorkerError, match="bad value"):
            worker.send(2)
        assert worker.unread == [("answered", 1)]
