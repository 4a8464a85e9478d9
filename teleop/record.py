"""`make record`: drive Humanoid-v5 with a controller and append every step to a dataset folder.

The folder holds a LeRobot v3.0 dataset and one MCAP file per episode (`teleop.store`). Episodes
are appended, never overwritten: the first new one uses SEED, or one past the largest seed already
recorded, so that running the recorder again adds new episodes; a SEED whose episodes would repeat
seeds the dataset holds is refused (`teleop.seeds`: a dataset's seeds identify its episodes).

Noise-injected demonstrations (DART): with `--noise σ` the environment receives the controller's
action plus Gaussian noise, clipped to the bounds, while the `action` label stays the clean
action. The data then shows how the expert recovers from the small errors a cloned policy makes;
clean demonstrations never leave the expert's own path, and a policy cloned from them falls.
Episodes in which the noisy expert falls are kept, with `terminated` set: their states are the
ones a policy most needs labels for, and dropping them would bias the dataset towards easy seeds.

Domain randomisation (`--randomize`, a preset or a list of ranges: `humanoid.conditions`): each
episode's masses, friction and motor strengths are drawn from its seed at its reset, and the draw
is stored with the episode (columns `randomization.*` of meta/episodes, and the MCAP metadata), so
that a user can filter or condition on it. A dataset holds randomised episodes or plain ones, not both.
Action latency (`--latency SHARE`) is drawn the same way: that share of the episodes executes every
action one step late, the episode's delay is stored beside the other draws, and the controller is
told it (the expert predicts through it); a student on the "pending" inputs learns from both kinds.

Each session adds a line to DATASET/recordings.jsonl (`teleop.recordings`): its full config (and
the randomisation's ranges), and the episodes it added, also when interrupted; a session killed
with -9 gets its line from the next one (the mark it left, `teleop.recordings.mark`).
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from common import columns, paths
from common.cli import (
    DatasetError,
    UserError,
    check_non_negative,
    check_positive,
    check_share,
    config_dict,
    counted,
    run_cli,
    setting,
)
from common.paths import NEWEST
from common.ray_backend import BACKENDS, check_backend
from common.seed_ranges import SEED_LIMIT
from common.workers import default_workers
from humanoid.cameras import CAMERAS, DEFAULT_SIZE, Camera, CameraRig, parse_cameras
from humanoid.conditions import (
    LATENCY_PARAMETER,
    NO_RANDOMIZATION,
    PRESETS,
    RANDOMIZE_EXAMPLE,
    Condition,
    parse_randomization,
    recorded_parameters,
    recording_condition,
)
from humanoid.env import EPISODE_STEPS, make_env, model_and_data
from policies.folder import chosen_policy
from rollout.controllers import INTERACTIVE, built, check_controller, make_controller, registered
from rollout.episode import ControllerFailure, EpisodeBuffer, EpisodeFailure, run_episode
from students.inputs import STUDENT_INPUTS
from task.command_fields import POSTURE_TASK, STAND, TASKS, WALK
from teachers.registry import TEACHER, TEACHERS, WALKING_TEACHER, able
from teleop import recordings
from teleop.lerobot_io.format import check_destination
from teleop.live import DEFAULT_HOST, DEFAULT_PORT, check_port, start_live
from teleop.seeds import next_free, seed_clash

if TYPE_CHECKING:
    from teleop.parallel import ParallelRollouts
    from teleop.ray_recording import RayRollouts
    from teleop.store import CommittedEpisode, EpisodeSink, EpisodeStore


DART_NOISE = 0.03
"""The executed actions' noise (DART): clean demonstrations give a student that falls; at 0.05 the teacher on leg
odometry, half its episodes delayed, falls in most and its students stood under noise far less often
(docs/decisions/dart-noise.md)."""
STANDING_NOISE = 0.05
"""The standing recipe's DART noise, for the expert told the simulator's state (`make record CONTROLLER=expert
TASK=stand NOISE=0.05 LATENCY=0`): at 0.05 it stands on most seeds and its students on every unseen one
(docs/decisions/dart-noise.md)."""
STANDING = {"controller": "expert", "task": STAND, "latency": 0.0}
"""The standing recipe's other recording settings (with NOISE=STANDING_NOISE): the expert told the simulator's state,
the zero command, no episode delayed; the benchmarks' expert episodes and most recording tests use it."""
LATENCY_SHARE = 0.5
"""The share of episodes recorded with one step of action latency, told to the teacher: a student on the "pending"
inputs learns to act through the delay from them, and the undelayed half keeps it standing without
(docs/decisions/latency-share.md)."""
WALKING_LATENCY_SHARE = 0.2
"""The share for walking demonstrations (`--task walk`): delayed, the walker falls in most of them, and no student of
its walks took the delay in (0 of 20 delayed walks at 0.5 or 0.2); plain BC's students walked 97 of 320 selection
walks at 0.2, 67 at 0.5 and 74 at 0.1 (docs/decisions/latency-share.md, "Walking")."""


# Past about 6.6 simulation workers the one writer is the limit (docs/concepts/ray.md, "Throughput against the number
# of nodes"): more only wait for it.
MOST_WORKERS = 7


@dataclass
class RecordConfig:
    """Settings of one recording session."""

    dataset: Path = setting(paths.DATASET, "dataset folder: created if missing, else appended to")
    episodes: int = setting(50, "number of episodes to add")
    seed: int | None = setting(
        None,
        "seed of the first new episode (episode i uses SEED+i); "
        "default: one past the largest seed in the dataset, 0 if new",
    )
    controller: str | None = setting(
        None,
        "who acts: a registered controller or a policy checkpoint folder; default: the teacher on what a robot senses, "
        f"{TEACHER} ({WALKING_TEACHER} with --task walk; expert: the one told the simulator's state)",
        metavar="{" + ",".join([*registered(), *INTERACTIVE]) + "}|PATH",
    )
    noise: float = setting(DART_NOISE, "std of the Gaussian noise added to the executed action (DART); 0 = clean")
    randomize: str = setting(
        NO_RANDOMIZATION,
        "domain randomisation, drawn per episode from its seed and stored with it: "
        f"{NO_RANDOMIZATION} (nothing), a preset ({', '.join(name for name in PRESETS if name != NO_RANDOMIZATION)}: "
        "docs/decisions/randomisation-presets.md) or ranges of the scale factors of mass, friction, strength "
        f"like {RANDOMIZE_EXAMPLE}",
    )
    latency: float | None = setting(
        None,
        "share of the episodes whose actions execute one env step late, drawn per episode from its seed; the delay "
        f"is stored with the episode ({columns.RANDOMIZATION_PREFIX}{LATENCY_PARAMETER}) and told to the controller; "
        f"default: {LATENCY_SHARE} ({WALKING_LATENCY_SHARE} with --task walk)",
    )
    kick: float = setting(
        0.0,
        "one kick of the root's horizontal velocity per episode, in m/s, in a seeded direction 4 to 8 s in (the "
        "suite's kick conditions), recorded in the push column; 0 = none. The teachers that step out of it: "
        + ", ".join(able("walks")),
    )
    max_steps: int = setting(EPISODE_STEPS, "time limit of an episode in steps (1000 is Humanoid-v5's)")
    task: str = setting(
        POSTURE_TASK,
        "what the scripted operator commands, drawn from each episode's seed (task.schedules): stand (the zero "
        "command), posture (schedules of postures) or walk (schedules that mix walks in: for a controller that walks, "
        "docs/how-to/walk.md); the controller is told each command, the dataset records it (with --controller "
        "keyboard the keys set it)",
        choices=TASKS,
    )
    policy: str | None = setting(
        None,
        "with --controller keyboard: the keys command this policy (a checkpoint folder of a policy that takes a "
        f"command, '{NEWEST}': the newest of {', '.join(map(str, paths.LEARNED))}, or a registered controller that "
        f"takes one, such as {WALKING_TEACHER}) instead of the expert (`make play`)",
    )
    workers: int | None = setting(
        None,
        "simulation processes; with 2 or more (or --backend ray) the recorder's own process writes, "
        "committing episodes in seed order (the dataset is the one a single process records); default: the "
        f"machine's cores, at most {MOST_WORKERS}, and 1 with --live, a keyboard controller or --writer inline",
    )
    backend: str = setting(
        "local",
        "where the simulation workers run: 'local' (processes here) or 'ray' (Ray actors, anywhere "
        "in the cluster at --ray-address; the writer stays here: docs/concepts/ray.md)",
        choices=BACKENDS,
    )
    ray_address: str | None = setting(
        None, "HOST:PORT of a running Ray cluster's head (--backend ray); default: a local Ray for this command"
    )
    writer: str = setting(
        "process",
        "with 1 worker: 'process' writes in a child process, overlapped with "
        "simulation; 'inline' writes between episodes",
        choices=("process", "inline"),
    )
    front_end: str = setting(
        "auto",
        "keyboard teleoperation's front end: the MuJoCo viewer window, the terminal "
        "(raw keys and a status line; works over SSH), or auto (viewer if a display exists)",
        choices=("auto", "viewer", "terminal"),
    )
    pace: float = setting(
        1.0,
        "keyboard teleoperation's simulated seconds per second of the wall clock: 1 real time, 0.5 slow motion (to "
        "watch a kick recovery), 2 twice as fast (a machine too slow for it runs as fast as it can)",
    )
    progress: bool = setting(True, "show a progress bar (not with the keyboard: the status line shows progress)")
    cameras: str = setting(
        "",
        "cameras each episode records as video (observation.images.NAME) and in the MCAP, a comma-separated list of "
        f"{', '.join(f'{c.name} ({c.description})' for c in CAMERAS.values())}, each optionally with its size as "
        f":HEIGHTxWIDTH (positive even numbers; default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}); a dataset keeps one set; "
        "'' = none",
        metavar="NAME[:HxW],...",
    )
    live: bool = setting(False, "publish every step to a Foxglove WebSocket server as it happens (one worker)")
    live_port: int = setting(DEFAULT_PORT, "port of the live view's server (0: any free port)")
    live_host: str = setting(DEFAULT_HOST, "address the live view's server binds to (0.0.0.0: every interface)")


@dataclass
class RecordSummary:
    """What a session added."""

    dataset: Path
    episodes: list[CommittedEpisode] = field(default_factory=list)
    total_episodes: int = 0
    seconds: float = 0.0
    marked: bool = False  # the session marked the dataset as its own (`teleop.recordings.mark`)

    @property
    def frames(self) -> int:
        return sum(e.length for e in self.episodes)

    def describe(self) -> str:
        if not self.episodes:
            return f"{self.dataset}: no episode added ({self.total_episodes} in total)"
        returns = np.array([e.episode_return for e in self.episodes])
        falls = sum(e.fell for e in self.episodes)
        first, last = self.episodes[0].seed, self.episodes[-1].seed
        return (
            f"{self.dataset}: added {counted(len(self.episodes), 'episode')} "
            f"({f'seed {first}' if len(self.episodes) == 1 else f'seeds {first}..{last}'}), {self.frames} frames in "
            f"{self.seconds:.1f} s ({self.frames / max(self.seconds, 1e-9):.0f} frames/s); return mean "
            f"{returns.mean():.1f}, min {returns.min():.1f}, max {returns.max():.1f}; {falls} fell; "
            f"{counted(self.total_episodes, 'episode')} in the dataset"
        )


def validate(cfg: RecordConfig) -> None:
    """Reject bad settings before anything touches the disk (of `cfg` as it records: `effective`)."""
    cfg = effective(cfg)
    try:
        check_controller(cfg.controller)
    except ValueError as error:
        raise UserError(str(error)) from None
    check_positive(cfg, "episodes", "max_steps", "workers", "pace")
    check_non_negative(cfg, "noise", "kick")
    if cfg.controller in INTERACTIVE and cfg.kick:
        raise UserError(f"--controller {cfg.controller} kicks with its k key: --kick must be 0")
    check_task(cfg.controller, cfg.task)
    if cfg.seed is not None and not 0 <= cfg.seed <= SEED_LIMIT - cfg.episodes:
        raise UserError(f"--seed must be >= 0 and its episodes' seeds below 2**63 (a dataset's int64), got {cfg.seed}")
    check_backend(cfg.backend, cfg.ray_address)
    if cfg.live and (workers(cfg) != 1 or cfg.backend != "local"):
        raise UserError(
            f"--live shows one simulation here: --workers must be 1 and --backend local, "
            f"got {workers(cfg)} and {cfg.backend}"
        )
    check_port(cfg.live_port)
    if cfg.controller in INTERACTIVE and (workers(cfg) != 1 or cfg.backend != "local"):
        raise UserError(
            f"--controller {cfg.controller} records in one process here: --workers must be 1 and --backend local"
        )
    try:
        randomization = parse_randomization(cfg.randomize)
    except ValueError as error:
        raise UserError(str(error)) from None
    if cfg.controller in INTERACTIVE and randomization.active:
        # Its postures are solved on the live model at each key: under randomisation, on whichever draw is current.
        raise UserError(f"--controller {cfg.controller} records the nominal body: --randomize must be none")
    check_share(cfg, "latency")
    cameras = parse_cameras(cfg.cameras)
    if cfg.policy is not None:
        check_played(cfg)
    if cfg.controller in INTERACTIVE:
        from teleop.keyboard import front_end_here  # noqa: PLC0415 - termios and the keys, for the keyboard only

        front_end_here(cfg.front_end)
    check_destination(cfg.dataset)
    if cameras:
        check_rendering(cameras)


def check_rendering(cameras: tuple[Camera, ...]) -> None:
    """`humanoid.cameras.RenderError` in one line (naming MUJOCO_GL's choices) unless `cameras` render here."""
    env = make_env()
    try:
        CameraRig(model_and_data(env)[0], cameras).close()
    finally:
        env.close()


def check_task(controller: str, task: str) -> None:
    """UserError in one line, before anything is written, where `controller` cannot do `task`: a walking task needs a
    controller that walks (a teacher that declares it, or a policy on a walking input set); the keys command
    themselves."""
    if task != WALK:
        return
    if controller in INTERACTIVE:
        raise UserError(f"--task {WALK} draws the scripted operator's walking schedules: the keys command themselves")
    if controller in TEACHERS:
        walks = TEACHERS[controller].walks
    elif controller in registered():
        walks = False
    else:
        from students.learned import input_set_of  # noqa: PLC0415 - reads the checkpoint (torch), for a policy only

        walks = bool((input_set := input_set_of(Path(controller))) and input_set.walks)
    if not walks:
        walkers = ", ".join(name for name, teacher in TEACHERS.items() if teacher.walks)
        raise UserError(
            f"--task {WALK}: {controller} does not walk, so nobody would follow the walks recorded; give a controller "
            f"that walks ({walkers}, or a policy on a walking input set)"
        )


def effective(cfg: RecordConfig) -> RecordConfig:
    """`cfg` as it records: no --controller is the teacher for its task (`TEACHER`, `WALKING_TEACHER`), no --latency
    its share (`LATENCY_SHARE`, `WALKING_LATENCY_SHARE`); with the keys (`--controller keyboard`) the command is theirs
    (no scripted task) and no episode is delayed, and `--policy newest` is the newest of the chain's policies
    (`common.paths.LEARNED`)."""
    walks = cfg.task == WALK
    if cfg.controller is None:
        cfg = dataclasses.replace(cfg, controller=WALKING_TEACHER if walks else TEACHER)
    if cfg.latency is None:
        cfg = dataclasses.replace(cfg, latency=WALKING_LATENCY_SHARE if walks else LATENCY_SHARE)
    if cfg.controller not in INTERACTIVE:
        return cfg
    policy = None if cfg.policy is None else chosen_policy(cfg.policy, paths.LEARNED, "make train-bc")
    task = cfg.task if cfg.task == WALK else STAND  # a walk is refused in one line by `validate`
    return dataclasses.replace(cfg, task=task, latency=0.0, policy=policy)


def check_played(cfg: RecordConfig) -> None:
    """UserError in one line unless --policy names a policy the keys can command (`make play`)."""
    if cfg.controller not in INTERACTIVE:
        raise UserError(f"--policy is driven by the keys: it needs --controller keyboard, got {cfg.controller}")
    try:
        check_controller(cfg.policy, interactive=False)
    except ValueError as error:
        raise UserError(str(error)) from None
    if cfg.policy in registered():  # a registered controller: the teachers follow the keys (the walkers walk)
        env = make_env()
        try:
            commanded = make_controller(cfg.policy, env)
        finally:
            env.close()
        if not commanded.takes_command:
            raise UserError(f"{cfg.policy} takes no command: the keys would change nothing")
    else:
        from students.learned import input_set_of  # noqa: PLC0415 - reads the checkpoint (torch)

        commanded = input_set_of(Path(cfg.policy))
        if commanded is None or not commanded.takes_command:
            raise UserError(
                f"{cfg.policy} takes no command: the keys would change nothing (train one on inputs that read it, "
                f"such as the default INPUTS={STUDENT_INPUTS})"
            )
    if not commanded.walks:
        print(
            f"{cfg.policy} takes no velocity command: the arrows and z/c change nothing, the posture keys work "
            f"(one that walks: POLICY={WALKING_TEACHER}, or train one: docs/how-to/walk.md)",
            file=sys.stderr,
        )


def workers(cfg: RecordConfig) -> int:
    """The simulation processes `cfg` asks for: --workers, else the machine's cores (`common.workers`), but one for
    what runs in one process (the live view, keyboard teleoperation, the inline writer)."""
    if cfg.workers is not None:
        return cfg.workers
    single = cfg.live or cfg.controller in INTERACTIVE or cfg.writer == "inline"
    return 1 if single else default_workers(MOST_WORKERS)


def main(cfg: RecordConfig, summary: RecordSummary | None = None, made_by: str | None = None) -> RecordSummary:
    """Record `cfg.episodes` episodes into `cfg.dataset`; returns what was committed (in `summary`, if given).
    `made_by`: the session logs itself (`record`), so it marks the dataset while it writes."""
    cfg = effective(cfg)
    validate(cfg)
    summary = RecordSummary(cfg.dataset) if summary is None else summary
    if workers(cfg) == 1 and cfg.backend == "local":
        return _record(cfg, None, summary, made_by)
    # Workers start first: their start-up overlaps with opening the dataset.
    with _start_workers(cfg) as rollouts:
        return _record(cfg, rollouts, summary, made_by)


def record(cfg: RecordConfig, made_by: str = "teleop.record") -> RecordSummary:
    """`make record`: `main`, then the session's line in DATASET/recordings.jsonl, also after Ctrl-C or an error."""
    cfg = effective(cfg)
    summary = RecordSummary(cfg.dataset)
    complete = False
    try:
        main(cfg, summary, made_by)
        complete = True
    finally:
        recordings.append(cfg.dataset, made_by, config_dict(cfg), summary.episodes, complete, _logged_ranges(cfg))
        if summary.marked:  # a refused session leaves a killed one's mark for the next
            recordings.unmark(cfg.dataset)
    return summary


def _logged_ranges(cfg: RecordConfig) -> dict[str, Any]:
    """The randomisation's ranges for the session's line: what a preset's name stands for is this version's code."""
    try:
        ranges = parse_randomization(cfg.randomize).ranges
    except ValueError:  # refused before anything was recorded: the line is not written
        return {}
    return {"randomization": ranges} if ranges else {}


def condition(cfg: RecordConfig) -> Condition:
    """What each episode's environment changes (`humanoid.conditions.recording_condition`)."""
    return recording_condition(cfg.randomize, cfg.latency, cfg.kick)


def _record(
    cfg: RecordConfig,
    rollouts: ParallelRollouts | RayRollouts | None,
    summary: RecordSummary,
    made_by: str | None,
) -> RecordSummary:
    recorded = condition(cfg)
    env = recorded.wrap(make_env(cfg.max_steps))
    parameters = recorded_parameters(recorded)
    # Before the dataset opens: a port in use or a bad host is refused with nothing written.
    cameras = parse_cameras(cfg.cameras)
    live = start_live(env, cfg.live_host, cfg.live_port, cameras) if cfg.live else None
    # The writing stack (pandas, pyarrow, mcap) is imported by whichever process writes.
    sink: EpisodeSink
    try:
        if cfg.writer == "process" and rollouts is None:
            from teleop.writer_process import WriterProcess  # noqa: PLC0415

            # Opens the dataset while this process builds the controller.
            sink = WriterProcess(cfg.dataset, parameters, cameras)
        else:
            from teleop.store import DatasetSpec, EpisodeStore  # noqa: PLC0415

            sink = EpisodeStore(cfg.dataset, DatasetSpec.from_env(env, parameters, cameras))
    except BaseException:
        if live is not None:
            live.close()
        env.close()
        raise
    start = time.perf_counter()
    interactive = cfg.controller in INTERACTIVE
    bar = tqdm(
        total=cfg.episodes, unit="ep", disable=not cfg.progress or interactive, file=sys.stderr, dynamic_ncols=True
    )

    def report(committed: list[CommittedEpisode]) -> None:
        summary.episodes += committed
        if committed:
            elapsed = time.perf_counter() - start
            bar.set_postfix(
                frames_per_s=f"{summary.frames / elapsed:.0f}", last_return=f"{committed[-1].episode_return:.1f}"
            )
            bar.update(len(committed))

    try:
        controller = make_controller(cfg.controller, env) if rollouts is None and not interactive else None
        sink.wait_ready()
        recorded = sink.seeds()
        first_seed = next_free(recorded) if cfg.seed is None else cfg.seed
        seeds = range(first_seed, first_seed + cfg.episodes)
        clash = seed_clash(seeds, recorded, str(cfg.dataset))
        if clash:
            raise DatasetError(f"--seed {cfg.seed}: {clash} (leave --seed unset to start there)")
        if made_by is not None:
            recordings.take_over(
                cfg.dataset, made_by, config_dict(cfg), sink.num_episodes, lambda: recorded, _logged_ranges(cfg)
            )
            summary.marked = True
        if interactive:
            from teleop.keyboard import run_session  # noqa: PLC0415

            played = None if cfg.policy is None else make_controller(cfg.policy, env)
            run_session(
                env, sink, first_seed, cfg.episodes, cfg.noise, cfg.front_end, report, live, played, cameras, cfg.pace
            )
        elif controller is not None:
            buffer = EpisodeBuffer(env, cfg.max_steps, cameras)
            for seed in seeds:
                try:
                    episode = run_episode(env, controller, seed, cfg.noise, buffer, observer=live, task=cfg.task)
                except ControllerFailure as failure:
                    skipped(EpisodeFailure(seed, str(failure)))
                    continue
                report(sink.submit(episode))
        else:
            _record_in_parallel(rollouts, seeds, sink, report)
    finally:
        # Also on Ctrl-C or an error: what the writer already has gets committed.
        report(sink.close())
        bar.close()
        summary.total_episodes = sink.num_episodes
        summary.seconds = time.perf_counter() - start
        if live is not None:
            live.close()
        env.close()
    return summary


def _start_workers(cfg: RecordConfig) -> ParallelRollouts | RayRollouts:
    from teleop.parallel import ParallelRollouts, RolloutSettings  # noqa: PLC0415

    settings = RolloutSettings(
        built(cfg.controller),
        cfg.noise,
        cfg.max_steps,
        condition(cfg),
        cfg.task,
        cameras=parse_cameras(cfg.cameras),
    )
    count = min(workers(cfg), cfg.episodes)
    if cfg.backend == "ray":
        from teleop.ray_recording import RayRollouts  # noqa: PLC0415 - imports Ray (0.5 s), only for this backend

        return RayRollouts(settings, cfg.dataset, count, cfg.ray_address)
    return ParallelRollouts(settings, cfg.dataset, count)


def _record_in_parallel(
    rollouts: ParallelRollouts | RayRollouts,
    seeds: range,
    store: EpisodeStore,
    report: Callable[[list[CommittedEpisode]], None],
) -> None:
    interrupted = True
    try:
        for spooled in rollouts.in_seed_order(seeds, meanwhile=store.prepare):
            if isinstance(spooled, EpisodeFailure):
                skipped(spooled)
                continue
            report([store.append(store.spool.load(spooled), spooled=spooled)])
        interrupted = False
    finally:
        rollouts.close(interrupted)
        # After Ctrl-C or a worker's error: the episodes finished beyond the first unfinished one.
        report(store.commit_spool())


def skipped(failure: EpisodeFailure) -> None:
    """Say in one line that `failure`'s episode is not recorded; the recording goes on (the episodes before and after
    it are kept)."""
    tqdm.write(f"warning: episode {failure.seed} not recorded: {failure.message}", file=sys.stderr)


def _main_and_print(cfg: RecordConfig) -> None:
    print(record(cfg).describe())


def cli(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from teleop.keyboard import key_help  # noqa: PLC0415

    description = f"{__doc__}\nKeys of CONTROLLER=keyboard (--controller keyboard):\n{key_help()}\n"
    return run_cli(_main_and_print, RecordConfig, argv, description=description, prog="python -m teleop.record")


if __name__ == "__main__":
    sys.exit(cli())
