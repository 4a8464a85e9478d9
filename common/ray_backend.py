"""`BACKEND=ray`: the recorder's and PPO's workers as Ray actors, anywhere in a Ray cluster.

    RaySession(address, workers)     ray.init: joins the cluster at `address`, or starts a local Ray
        .spawn(factories, name)      one actor per factory, one CPU each, spread over the nodes, pinned
            -> [RayWorker]           send/recv like common.workers.Worker; .submit/.get for many calls
    close()                          the actors go, then ray.shutdown (a local Ray stops with it)

The workers' code is this project's, imported on every node (the nodes need it installed, as the
driver does: docs/concepts/ray.md). Each actor holds one CPU of the cluster's resources and a session
refuses more workers than the cluster has CPUs: actors that wait for a CPU never start, and two
actors that held a 2-CPU node's CPUs starved everything else there (docs/concepts/ray.md). Ray does not
pin processes to cores; each actor pins itself to a core of its node, in the order the actors
landed there, as `common.workers` does (unpinned, two PPO workers queued on one core: docs/concepts/ray.md).

Failures: an exception raised by a worker's method is raised by `get` as itself (a `UserError` is
the user's one line); a worker whose process or node is gone raises `WorkerLost`, one line.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable, Sequence
from typing import Any

from common.cli import UserError, first_line
from common.threads import PINNED
from common.workers import WorkerError

log = logging.getLogger(__name__)

BACKENDS = ("local", "ray")
CONNECT_TIMEOUT = 3.0  # seconds to reach RAY_ADDRESS: ray.init itself retries for about a minute
START_TIMEOUT = 120.0  # seconds for the actors to start: past that the cluster has no room for them


class WorkerLost(WorkerError):
    """A Ray worker's process or node is gone: what it held is lost, nothing it finished is."""


def check_backend(backend: str, address: str | None) -> None:
    """Refuse an unknown backend or a malformed address in one line (before anything is written)."""
    if backend not in BACKENDS:
        raise UserError(f"unknown --backend {backend!r}; known: {', '.join(BACKENDS)}")
    if address and backend != "ray":
        # Not refused: Ray's own convention exports RAY_ADDRESS, which make passes on to every target.
        log.warning("--ray-address %s is not used: --backend is %s", address, backend)
    elif address:
        _host_and_port(address)


def _host_and_port(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UserError(f"--ray-address must be HOST:PORT (the head node's GCS port, 6379 by default), got {address!r}")
    return host, int(port)


def _check_reachable(address: str) -> None:
    """One line within CONNECT_TIMEOUT when nothing answers at `address`, instead of ray.init's minute of retries."""
    host, port = _host_and_port(address)
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except OSError as error:
        raise UserError(
            f"no Ray cluster answers at {address} ({error.strerror or error}): start one with "
            "`ray start --head --port PORT`, or leave RAY_ADDRESS unset for a local Ray"
        ) from None


class _Host:
    """A Ray actor holding one object built by a factory; it calls the object's methods by name."""

    def __init__(self, factory: Callable[[], Any]) -> None:
        self.target = factory()

    def where(self) -> tuple[str, list[int]]:
        """The node this actor runs on and the cores it may use there."""
        import ray  # noqa: PLC0415 - in the actor's process, where ray is already imported

        return ray.get_runtime_context().get_node_id(), sorted(os.sched_getaffinity(0))

    def pin(self, cpu: int) -> None:
        os.sched_setaffinity(0, {cpu})

    def call(self, method: str, *args: Any) -> Any:
        return getattr(self.target, method)(*args)


class RayWorker:
    """One actor: `send`/`recv` as `common.workers.Worker` (a request, then its answer), or `submit`/`get`."""

    def __init__(self, actor: Any, name: str) -> None:
        self.actor, self.name = actor, name
        self._pending: Any = None

    def submit(self, method: str, *args: Any) -> Any:
        """Start `target.method(*args)` in the actor; returns its ObjectRef. Calls run in the order submitted."""
        return self.actor.call.remote(method, *args)

    def get(self, ref: Any) -> Any:
        """The result of a submitted call: its exception raised as itself, or WorkerLost."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as error:
            raise error.cause from None
        except (ray.exceptions.RayActorError, ray.exceptions.ObjectLostError) as error:
            # ObjectLostError: the call finished, but its result was in the object store of a node now gone.
            raise WorkerLost(f"{self.name} was lost: {first_line(error)}") from None

    def send(self, message: tuple[str, tuple]) -> None:
        """`common.workers.Worker` protocol: the command (`target.handle(command, *data)`) starts at once."""
        command, data = message
        self._pending = self.submit("handle", command, *data)

    def recv(self) -> Any:
        ref, self._pending = self._pending, None
        return self.get(ref)


class RaySession:
    """A connection to a Ray cluster for `workers` workers: `spawn` them, `close` to let go of everything.

    `address` None starts a local Ray for this session (stopped by `close`); HOST:PORT joins a running
    cluster (its head's `ray start --head --port PORT`), which `close` leaves running.
    """

    def __init__(self, address: str | None, workers: int) -> None:
        import ray  # noqa: PLC0415 - imported only with the Ray backend (0.5 s)

        if address:
            _check_reachable(address)
        # "local": a new Ray for this session, never one found on the machine (RAY_ADDRESS, the last `ray start`).
        # Every node's workers load their BLAS libraries as this process did (common.threads.PINNED).
        pinned = {name: os.environ[name] for name in PINNED if name in os.environ}
        ray.init(
            address=address or "local",
            include_dashboard=False,
            logging_level=logging.WARNING,
            runtime_env={"env_vars": pinned} if pinned else None,
        )
        self._actors: list[Any] = []
        try:
            cpus = int(ray.cluster_resources().get("CPU", 0))
            if workers > cpus:
                raise UserError(
                    f"--workers {workers} needs {workers} CPUs in the Ray cluster, it has {cpus}: "
                    "each worker holds one (docs/concepts/ray.md)"
                )
        except BaseException:
            ray.shutdown()
            raise

    def spawn(self, factories: Sequence[Callable[[], Any]], name: str) -> list[RayWorker]:
        """One actor per factory (`name i`), each holding `factory()`, one CPU and one core."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        host = ray.remote(num_cpus=1, max_restarts=0, scheduling_strategy="SPREAD")(_Host)
        actors = [host.remote(factory) for factory in factories]
        self._actors += actors
        workers = [RayWorker(actor, f"{name} {index}") for index, actor in enumerate(actors)]
        try:
            places = ray.get([actor.where.remote() for actor in actors], timeout=START_TIMEOUT)
        except ray.exceptions.GetTimeoutError:
            raise UserError(
                f"the Ray cluster did not start {len(actors)} workers within {START_TIMEOUT:.0f} s: "
                f"its free CPUs are {ray.available_resources().get('CPU', 0):g}"
            ) from None
        except ray.exceptions.RayTaskError as error:  # a factory failed: its exception, as in one process
            raise error.cause from None
        landed: dict[str, int] = {}
        pins = []
        for actor, (node, cores) in zip(actors, places, strict=True):
            order = landed[node] = landed.get(node, -1) + 1
            pins.append(actor.pin.remote(cores[order % len(cores)]))
        ray.get(pins)
        return workers

    def put(self, value: Any) -> Any:
        """`value` in the object store once, for many workers' calls (each resolves the reference)."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        return ray.put(value)

    def wait(self, refs: list[Any]) -> list[Any]:
        """The references among `refs` whose calls have finished (at least one; blocks until then)."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        ready, _ = ray.wait(refs, num_returns=1)
        return ready

    def kill_actors(self) -> None:
        """Stop every worker spawned, whatever it was doing."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        for actor in self._actors:
            ray.kill(actor, no_restart=True)
        self._actors = []

    def close(self) -> None:
        """Kill the actors and disconnect (a local Ray stops). Idempotent."""
        import ray  # noqa: PLC0415 - imported only with the Ray backend

        if ray.is_initialized():
            self.kill_actors()
            ray.shutdown()
