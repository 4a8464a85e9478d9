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

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path
from typing import TYPE_CHECKING

from common.workers import Channel, Worker, close_all
from humanoid.cameras import Camera
from humanoid.conditions import Condition
from rollout.episode import ControllerFailure, Episode, EpisodeBuffer, EpisodeFailure, run_episode
from task.command_fields import STAND
from teleop.spool import SPOOL_DIR, Spool

if TYPE_CHECKING:
    from policies.mlp import MLPPolicy
    from teachers.base import Teacher

SEEDS_AHEAD = 2  # seeds a worker holds: the one it simulates and the next one
# What `_work` imports.
WORKER_MODULES = ("humanoid.conditions", "rollout.controllers", "humanoid.env", "rollout.episode", "teleop.spool")


@dataclass(frozen=True)
class RolloutSettings:
    """What a worker needs to reproduce the recorder's rollout of a seed."""

    controller: str | type[Teacher]  # a teacher (its class: `rollout.controllers.built`), or a name or policy folder
    noise: float
    max_steps: int
    condition: Condition = Condition()  # what the environment changes (`humanoid.conditions.recording_condition`)
    task: str = STAND  # what the operator commands (`task.schedules.task_commands`)
    labeller: type[Teacher] | None = None  # the teacher that labels every state (DAgger's expert), or none
    policy: MLPPolicy | None = None  # the controller's weights, held in memory (DAgger's round policy, `controller`
    # naming it), instead of a registered controller or checkpoint folder by that name
    cameras: tuple[Camera, ...] = ()  # the cameras each episode records (`humanoid.cameras`)


class Simulator:
    """One worker's environment and controller: `run(seed)` is the episode the recorder records for that seed."""

    def __init__(self, settings: RolloutSettings) -> None:
        from humanoid.env import make_env  # noqa: PLC0415 - heavy imports in the worker only
        from rollout.controllers import make_controller  # noqa: PLC0415 - heavy imports in the worker only

        self.settings = settings
        self.env = settings.condition.wrap(make_env(settings.max_steps))
        if settings.policy is None:
            self.controller = make_controller(settings.controller, self.env)
        else:
            self.act_with(settings.policy, settings.controller)
        self.labeller = None if settings.labeller is None else make_controller(settings.labeller, self.env)
        self.buffer = EpisodeBuffer(self.env, settings.max_steps, settings.cameras)

    def run(self, seed: int) -> Episode | EpisodeFailure:
        """The episode of `seed`, or, where a controller fails in it, why (`rollout.episode.ControllerFailure`)."""
        settings = self.settings
        try:
            return run_episode(
                self.env, self.controller, seed, settings.noise, self.buffer, labeller=self.labeller, task=settings.task
            )
        except ControllerFailure as failure:
            return EpisodeFailure(seed, str(failure))

    def act_with(self, policy: MLPPolicy, name: str) -> None:
        """From the next seed on, `policy` (in memory, called `name`) acts: DAgger's next round."""
        from students.learned import PolicyController  # noqa: PLC0415 - torch, for a policy's worker only

        self.controller = PolicyController(policy, name, self.env)


@dataclass(frozen=True)
class NextPolicy:
    """A message to the workers: the policy that acts from the next seed on (`Simulator.act_with`)."""

    policy: MLPPolicy
    name: str


def _work(channel: Channel, settings: RolloutSettings, dataset: Path, spool_name: str) -> None:
    """A worker (`common.workers`): simulate each seed received, spool the episode, report the seed (or the
    `EpisodeFailure` of one a controller failed in); a `NextPolicy` changes who acts."""
    simulator = Simulator(settings)
    spool = Spool(dataset, spool_name)
    for message in channel:
        if isinstance(message, NextPolicy):
            simulator.act_with(message.policy, message.name)
            continue
        outcome = simulator.run(message)
        if isinstance(outcome, EpisodeFailure):
            channel.send(outcome)
            continue
        spool.put(outcome)
        channel.send(message)


class ParallelRollouts:
    """`workers` simulation processes for one recording; a context manager that stops them on exit."""

    def __init__(self, settings: RolloutSettings, dataset: Path, workers: int, spool: str = SPOOL_DIR) -> None:
        """Spooled into DATASET/`spool`: the recorder's spool, or another whose episodes the caller commits."""
        self._spool = Spool(dataset, spool)
        self._workers: list[Worker] = []
        self._closed = False
        try:
            for index in range(workers):
                # The forkserver imports WORKER_MODULES once: a worker then starts in milliseconds instead of 0.2 s.
                self._workers.append(
                    Worker(_work, settings, dataset, spool, name=f"recording worker {index}", preload=WORKER_MODULES)
                )
        except BaseException:
            self.close(interrupted=True)
            raise

    def in_seed_order(
        self, seeds: Sequence[int], meanwhile: Callable[[], None] = lambda: None
    ) -> Iterator[Path | EpisodeFailure]:
        """The spool file of each seed's episode (or its `EpisodeFailure`), in the order of `seeds`, as soon as all
        before it are done.

        `meanwhile` runs once the workers have their first seeds, before waiting for them.
        """
        handed = 0
        holding = dict.fromkeys(self._workers, 0)
        done: dict[int, EpisodeFailure | None] = {}

        def hand_out(worker: Worker) -> None:
            nonlocal handed
            while holding[worker] < SEEDS_AHEAD and handed < len(seeds):
                worker.send(seeds[handed])
                holding[worker] += 1
                handed += 1

        for worker in self._workers:
            hand_out(worker)
        meanwhile()
        for seed in seeds:
            while seed not in done:
                for worker in wait(self._workers):
                    # A worker's failure is raised here as one line (a UserError), as is a worker that died.
                    finished = worker.recv()
                    failed = isinstance(finished, EpisodeFailure)
                    done[finished.seed if failed else finished] = finished if failed else None
                    holding[worker] -= 1
                    hand_out(worker)
            failure = done.pop(seed)
            yield self._spool.path_of(seed) if failure is None else failure

    def act_with(self, policy: MLPPolicy, name: str) -> None:
        """Every worker rolls out `policy` (called `name`) from the next seed handed out on (DAgger's next round)."""
        for worker in self._workers:
            worker.send(NextPolicy(policy, name))

    def close(self, interrupted: bool = False) -> None:
        """Stop the workers once their seeds are done, or at once if `interrupted` (spooled episodes stay).

        Idempotent: the first call decides.
        """
        if self._closed:
            return
        self._closed = True
        # Interrupted: an unfinished episode is worth nothing, and the finished ones are spooled.
        close_all(self._workers, kill=interrupted)

    def __enter__(self) -> ParallelRollouts:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        self.close(interrupted=exc_type is not None)
