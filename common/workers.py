"""Worker processes: one way to start a child, talk to it, hear that it failed, and stop it.

The recorder's simulation workers (`teleop.parallel`), its writer process (`teleop.writer_process`)
and PPO's environment workers (`rl.vec_env`) all run on this; docs/concepts/processes.md says why
each property is the one it is, with the measurements.

Start: multiprocessing's forkserver, always. The server is a fresh interpreter (it inherits no
lock, thread or open file of the parent), started once per parent process; it imports the preload
list once and every child is a fork of it, so a child starts in milliseconds instead of paying for
its imports again (docs/concepts/processes.md), and it imports from this process's `sys.path`
(`start_server`). Preload policy: `__main__`, which CPython 3.12.1's server never takes from the
parent (it looks for a key the parent no longer sends, gh-98552: each child re-runs the main module,
cheap once its imports are preloaded), and every module the workers of this process declared
(`preload=`) before the server started; a later declaration does not change a running server, it
only costs that child its imports.

Channel: two one-way pipes, so that the parent can end the child's input (`stop_sending`: its
`for message in channel` ends) and still read what the child sends until it ends (`rest`).

Failure protocol, one for every worker: an exception that ends the child's target is printed with
its traceback on the child's stderr (not a `UserError`: that one is the user's message already) and
sent to the parent, whose next `recv` raises it as one line: a `UserError` as itself, anything else
as `WorkerError("<name> failed: <exception>")`. A child that exits without a word (killed, crashed)
is a `WorkerError("<name> died (exit code N)")`. A request that fails in `Channel.serve` (a
request/answer child that goes on serving) is raised in the parent as the exception itself, with
the child's traceback as a note, so that a caller can catch it as it would in-process.

Shutdown, one path: `close` ends the child's input and stops reading its output, so a child waiting
for a message or blocked on sending one returns, then waits `timeout` seconds (`CLOSE_TIMEOUT`) for it to exit
and kills it after that (or at once with `kill=True`); it reaps the child and is idempotent, and
`with Worker(...)` closes on exit. A child ignores Ctrl-C by default (it reaches the whole process
group; the parent decides what stops). With `outlives_parent` a child is not a daemon, keeps doing
what it was sent when the parent is gone (a message it cannot deliver is dropped) and is never
killed by a timeout: the writer commits every episode it received even after a kill -9 of the
recorder.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import socket
import sys
import traceback
from collections.abc import Callable, Iterable, Iterator
from multiprocessing import forkserver
from multiprocessing.connection import Connection
from typing import Any

from common.cli import UserError
from common.threads import one_blas_thread

START_METHOD = "forkserver"
CLOSE_TIMEOUT = 10.0  # seconds a closing child gets to finish before it is killed
INTERRUPTED = 130  # exit code of a child stopped by Ctrl-C (when it does not ignore it), as a shell reports it

_preload: list[str] = []  # the modules this process's workers declared, in order


class WorkerError(UserError):
    """A worker process failed or died: one line (the traceback, if there is one, is on the worker's stderr)."""


class InputEnded(EOFError):
    """Raised by `Channel.recv` once the parent stopped sending: it closed its end, or it is gone."""


class _ParentGone(Exception):
    """The parent stopped reading (it closed the channel or died): nothing the child sends arrives."""


class _Failure:
    """An exception raised in a worker, on its way to the parent. `fatal`: the worker's target ended with it."""

    def __init__(self, error: BaseException, fatal: bool) -> None:
        self.error = error if _pickles(error) else RuntimeError(repr(error))
        self.fatal = fatal


def _pickles(error: BaseException) -> bool:
    try:
        pickle.loads(pickle.dumps(error))
    except Exception:
        return False
    return True


class Channel:
    """The worker's end of its channel: `recv` (or iterate) what the parent sends, `send` to it."""

    def __init__(self, incoming: Connection, outgoing: Connection, outlives_parent: bool) -> None:
        self._incoming = incoming
        self._outgoing = outgoing
        self._outlives_parent = outlives_parent
        self.parent_gone = False

    def recv(self) -> Any:
        """The parent's next message; InputEnded once it stopped sending."""
        try:
            return self._incoming.recv()
        except (EOFError, OSError):  # closed, or the parent died in the middle of a message
            raise InputEnded from None

    def __iter__(self) -> Iterator[Any]:
        """The parent's messages until it stops sending."""
        while True:
            try:
                yield self.recv()
            except InputEnded:
                return

    def send(self, message: Any) -> None:
        """Send `message` to the parent. If it is gone, the child stops here, or with `outlives_parent` goes on."""
        if self.parent_gone:
            return
        try:
            self._outgoing.send(message)
        except (BrokenPipeError, ConnectionResetError):
            self.parent_gone = True
            if not self._outlives_parent:
                raise _ParentGone from None

    def serve(self, handler: Callable[[Any], Any]) -> None:
        """Answer each message with `handler(message)` until the parent stops sending.

        An exception in `handler` is the answer: the parent's `recv` raises it, and the child goes on serving.
        """
        for message in self:
            try:
                self.send(handler(message))
            except _ParentGone:
                raise
            except Exception as error:
                error.add_note(f"(in a worker process:)\n{traceback.format_exc().rstrip()}")
                self.send(_Failure(error, fatal=False))


def _report(channel: Channel, error: BaseException) -> None:
    try:
        channel.send(_Failure(error, fatal=True))
    except _ParentGone:
        pass


def _child(
    target: Callable[..., None],
    channel: Channel,
    args: tuple,
    cpu: int | None,
    ignore_interrupt: bool,
) -> None:
    """The child's entry point: signal and CPU settings, then `target(channel, *args)` under the failure protocol."""
    if ignore_interrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_blas_thread()
    try:
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        target(channel, *args)
    except (InputEnded, _ParentGone):  # the parent stopped sending or is gone: nothing left to do
        pass
    except KeyboardInterrupt:
        sys.exit(INTERRUPTED)
    except UserError as error:  # already one line for the user
        _report(channel, error)
        sys.exit(1)
    except Exception as error:  # one line for the parent; the traceback on stderr for debugging
        traceback.print_exc()
        sys.stderr.flush()
        _report(channel, error)
        sys.exit(1)


def declare_preload(modules: Iterable[str]) -> Any:
    """Add `modules` to the forkserver's preload list (it counts until the server starts); the context."""
    _preload.extend(module for module in modules if module not in _preload)
    context = mp.get_context(START_METHOD)
    context.set_forkserver_preload(["__main__", *_preload])
    return context


def forkserver_context(preload: Iterable[str] = ()) -> Any:
    """The forkserver context, `preload` declared and the server started on this process's import path
    (`start_server`): every worker and process pool of the project starts from here."""
    context = declare_preload(preload)
    start_server()
    return context


def start_server() -> None:
    """Start the forkserver (if it is not running) importing from this process's `sys.path`, not from the current
    directory. CPython before 3.12.8 and 3.13.1 drops the path it hands the server (gh-117378), whose `python -c`
    then looks in the current directory first: a parent started from another checkout's folder gave its children
    that checkout's modules. The path goes in the environment the server starts with (`PYTHONPATH`, and
    `PYTHONSAFEPATH` to leave the current directory out), which its children inherit; this process's own is
    restored."""
    names = ("PYTHONPATH", "PYTHONSAFEPATH")
    saved = {name: os.environ.get(name) for name in names}
    os.environ["PYTHONPATH"] = os.pathsep.join(path or os.getcwd() for path in sys.path)
    os.environ["PYTHONSAFEPATH"] = "1"
    try:
        forkserver.ensure_running()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def process_owner() -> str:
    """This process as "host-pid": who holds a folder or a dataset's mark, so that another process can tell whether
    it still runs (`owner_gone`)."""
    return f"{socket.gethostname()}-{os.getpid()}"


def owner_gone(owner: str) -> bool:
    """Whether `owner` (`process_owner`) is a process of this machine that no longer runs; another machine's, or one
    that still runs, is not known to be gone."""
    host, _, pid = owner.rpartition("-")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's process
        return False
    return False


def available_cores() -> int:
    """The cores this process may run on: its CPU affinity, which a container or `taskset` narrows (`os.cpu_count`
    counts the machine's). What "0 = one per core" means for a thread count."""
    return len(os.sched_getaffinity(0))


def torch_threads() -> int:
    """The threads torch's own operations get (BC's fit, PPO's updates): one per core this process may run on, or
    fewer where `OMP_NUM_THREADS` says so, as torch itself reads it. Two fits of two threads each on two cores took 90
    s each, one alone 12 s: torch's threads wait for cores by spinning (docs/decisions/test-workers.md)."""
    cores = available_cores()
    told = os.environ.get("OMP_NUM_THREADS", "")
    return max(1, min(cores, int(told))) if told.isdigit() else cores


def default_workers(most: int) -> int:
    """The worker count of recording, PPO and the robustness suite unless told: one per core this process may run on
    (`available_cores`), at most `most`, past which more do not help (each command says why its `most`:
    docs/decisions/worker-counts.md)."""
    return max(1, min(most, available_cores()))


def describe_exit(code: int | None) -> str:
    """`exit code 1`, `exit code -9, SIGKILL` for a child killed by a signal, or `still running`."""
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"exit code {code}, {signal.Signals(-code).name}"
        except ValueError:
            pass
    return f"exit code {code}"


class Worker:
    """A child process running `target(channel, *args)`, and the parent's end of its channel.

    `name` is how messages call it (`recording worker 0`). `preload`: the modules `target` imports
    (see the module's preload policy). `cpu`: pin the child to this core. `ignore_interrupt`: the
    child ignores Ctrl-C (else it exits with code 130). `outlives_parent`: see the module.
    `target` and `args` are pickled: a module-level function, and arguments that pickle (wrap
    closures in SB3's CloudpickleWrapper).
    """

    def __init__(
        self,
        target: Callable[..., None],
        *args: Any,
        name: str,
        preload: Iterable[str] = (),
        cpu: int | None = None,
        ignore_interrupt: bool = True,
        outlives_parent: bool = False,
    ) -> None:
        context = forkserver_context(preload)
        self.name = name
        self.failed = False  # a fatal failure or the child's death was raised: nothing more will come
        self.unread: list[Any] = []
        """The child's messages that `send` read on its way to the child's failure: answers its caller has not had."""
        self.exitcode: int | None = None
        self._outlives_parent = outlives_parent
        self._closed = False
        child_in, self._outgoing = context.Pipe(duplex=False)
        self._incoming, child_out = context.Pipe(duplex=False)
        channel = Channel(child_in, child_out, outlives_parent)
        # daemon: a parent that exits without closing its workers leaves no orphan (one that outlives it is no daemon)
        self.process = context.Process(
            target=_child,
            args=(target, channel, args, cpu, ignore_interrupt),
            name=name,
            daemon=not outlives_parent,
        )
        try:
            self.process.start()
        finally:
            child_in.close()  # the child alone holds its ends: each side sees end-of-file when the other closes
            child_out.close()

    def send(self, message: Any) -> None:
        """Send `message` to the child; if it stopped, raise why (its failure, or that it died), keeping what it
        said before in `unread`."""
        try:
            self._outgoing.send(message)
        except (BrokenPipeError, ConnectionResetError):
            while True:
                self.unread.append(self.recv())  # raises once the child's failure or end is reached

    def recv(self) -> Any:
        """The child's next message (blocks); raises its failure, or WorkerError if it ended or died."""
        message = self._next()
        if message is _END:
            raise self._ended()
        return message

    def rest(self) -> Iterator[Any]:
        """The child's messages until it ends (after `stop_sending`); raises its failure, or WorkerError if it died."""
        while (message := self._next()) is not _END:
            yield message
        if self.exitcode != 0:
            raise self._ended()

    def poll(self, timeout: float = 0.0) -> bool:
        """Whether `recv` would return or raise at once (a message, or the child's end)."""
        return self._incoming.poll(timeout)

    def fileno(self) -> int:
        """The channel's readable end, for `multiprocessing.connection.wait` over several workers."""
        return self._incoming.fileno()

    def stop_sending(self) -> None:
        """End the child's input: its `recv` raises InputEnded, its `for message in channel` ends. Idempotent."""
        self._outgoing.close()

    def close(self, kill: bool = False, timeout: float = CLOSE_TIMEOUT) -> int | None:
        """Stop the child and reap it; returns its exit code. Idempotent: the first call decides.

        The child's input ends and its output is no longer read; it gets `timeout` seconds to exit
        (forever with `outlives_parent`), then it is killed. `kill`: at once, whatever it was doing.
        """
        if self._closed:
            return self.exitcode
        self._closed = True
        self._outgoing.close()
        self._incoming.close()
        if kill:
            self.process.kill()
        self.process.join(None if self._outlives_parent and not kill else timeout)
        if self.process.exitcode is None:
            self.process.kill()
            self.process.join()
        self.exitcode = self.process.exitcode
        self.process.close()
        return self.exitcode

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def _next(self) -> Any:
        """The next message, `_END` once the child has exited (reaped), or the child's failure raised."""
        if self._closed:
            return _END
        try:
            message = self._incoming.recv()
        except (EOFError, OSError):  # the child's end closed: it exited
            self.process.join(CLOSE_TIMEOUT)
            self.exitcode = self.process.exitcode
            return _END
        if isinstance(message, _Failure):
            if not message.fatal:
                raise message.error
            self.failed = True
            if isinstance(message.error, UserError):
                raise message.error
            raise WorkerError(f"{self.name} failed: {message.error!r}") from message.error
        return message

    def _ended(self) -> WorkerError:
        self.failed = True
        if self.exitcode == 0:
            return WorkerError(f"{self.name} ended without answering")
        return WorkerError(f"{self.name} died ({describe_exit(self.exitcode)})")


_END = object()  # `Worker._next`: the child has exited


def close_all(workers: Iterable[Worker], kill: bool = False) -> None:
    """Close several workers: all their inputs end first, so that they finish at the same time."""
    workers = list(workers)
    for worker in workers:
        worker.stop_sending()
    for worker in workers:
        worker.close(kill)
