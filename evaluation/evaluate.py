"""`make eval`: run a saved policy (or the expert) on Humanoid-v5 and print the outcome as JSON.

Episodes start from the environment's own reset on seeds SEED..SEED+EPISODES-1; the default
SEED 1000 keeps clear of the recorder's seeds (0, 1, 2, ...). Survival is the fraction of
episodes that reach the 1000-step time limit without falling. The last line printed is one JSON
object, with the run's full settings under "config"; `evaluate()` returns the same dict (without
them) to callers such as `bc.train`.

    PUSH=F     a horizontal push of F newtons on the torso for 0.1 s every 2 s, random direction
    KICK=Δv    a velocity kick instead: once per episode, at a seeded time 4-8 s in, the root's horizontal velocity
               changes by Δv m/s in a seeded direction (`humanoid.perturbations.VelocityKick`)
    NOISE=σ    Gaussian noise of std σ added to every executed action (then clipped)
    CONDITION=name  a condition of the robustness suite instead (`humanoid.conditions.SUITE`:
               masses, friction, motor strength, latency, sensor noise, pushes, kicks;
               docs/concepts/robustness-suite.md)
    VIDEO=f    an MP4 of every episode, rendered offscreen on the CPU: a frame every step, so slow
               (docs/how-to/evaluate.md); use a few episodes
    TASK=posture  (the default) the operator's command follows the posture schedule drawn from each seed (held out:
               seeds from 1000 are never recorded); the JSON adds "tracking": per command field the error once
               settled, and the time to settle (`task.tracking`; docs/how-to/follow-commands.md). TASK=walk: the
               schedules mix walks in (forward, sideways and turning speeds: `task.schedules.WALKING_SHARE`), and
               tracking measures the velocity fields too (docs/how-to/walk.md); TASK=stand: the zero command
    PLOT=f.png commanded against achieved posture over the first episode, a panel per field
    HOLD=FIELD=VALUE,...  one command held instead of a schedule, as `make play`'s keys hold it (`forward_speed=0.5`:
               ↑ pressed five times): the zero command for 3 s, this one for 5 s, then the zero command; the JSON adds
               "held": how far the body walked and turned while it was held, and how far it moved from 2 s after
               (docs/how-to/walk.md)
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import multiprocessing as mp
import os
import sys
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from common import paths
from common.cli import (
    UserError,
    check_file,
    check_non_negative,
    check_positive,
    check_seed,
    config_dict,
    json_text,
    run_cli,
    setting,
)
from common.figures import save_figure
from common.paths import NEWEST
from common.seed_ranges import EVAL_SEED
from common.threads import one_blas_thread
from common.workers import forkserver_context
from humanoid.conditions import SUITE, Condition
from humanoid.env import EPISODE_STEPS, make_env, nominal_model
from humanoid.perturbations import VelocityKick, perturbation, toppling
from humanoid.physics import PELVIS_BODY, TORSO_BODY
from humanoid.sensors import body_axes
from humanoid.video import CAMERA, VideoRecorder
from policies.folder import chosen_policy
from policies.mlp import MLPPolicy
from rollout.controllers import Controller, make_controller, registered
from rollout.episode import Episode, EpisodeBuffer, run_episode
from students.learned import PolicyController
from task.command_fields import COMMAND_FIELDS, COMMAND_NAMES, POSTURE_TASK, STAND, TASKS, task_fields
from task.posture import Posture
from task.schedules import FIRST_NEUTRAL_SECONDS, HELD_SECONDS, held_commands, parse_held
from task.tracking import PLOTTED, Tracking, combine_tracking, trailing_mean
from teachers.base import Teacher
from teleop.live import DEFAULT_HOST, DEFAULT_PORT, check_port, start_live

POLICY_HELP = (
    f"policy checkpoint folder, a registered controller ({', '.join(registered())}), or '{NEWEST}': the newest of "
    f"{', '.join(map(str, paths.LEARNED))}"
)
"""What `make eval`'s and `make robustness`'s POLICY takes."""


@dataclass
class EvalConfig:
    """Settings of one evaluation."""

    policy: str = setting(NEWEST, POLICY_HELP)
    episodes: int = setting(20, "number of episodes")
    seed: int = setting(EVAL_SEED, "seed of the first episode (episode i uses SEED+i)")
    push: float = setting(0.0, "force in newtons of a horizontal push on the torso for 0.1 s every 2 s; 0 = none")
    kick: float = setting(
        0.0,
        "one kick of the root's horizontal velocity, in m/s, in a seeded direction 4 to 8 s into each episode (the "
        "suite's kick conditions: docs/concepts/robustness-suite.md); 0 = none",
    )
    noise: float = setting(0.0, "std of the Gaussian noise added to every executed action; 0 = none")
    condition: str = setting(
        "clean", f"a condition of the robustness suite: {', '.join(SUITE)} (docs/concepts/robustness-suite.md)"
    )
    video: Path | None = setting(None, "write an MP4 of the episodes here (offscreen on the CPU, a frame a step: slow)")
    task: str = setting(
        POSTURE_TASK,
        "what the operator commands, the held-out schedule drawn from each episode's seed: stand (the zero command), "
        "posture, or walk (walks mixed in, their speeds tracked too: docs/how-to/walk.md); the JSON adds the tracking "
        "error per command field (a policy that takes no command, or no velocity, is run blind to it)",
        choices=TASKS,
    )
    plot: Path | None = setting(None, "a PNG of commanded against achieved posture over the first episode")
    hold: str = setting(
        "",
        "one command held instead of the task's schedule, FIELD=VALUE,... (forward_speed=0.5: the up arrow pressed "
        f"five times): the zero command for {FIRST_NEUTRAL_SECONDS:g} s, this one for {HELD_SECONDS:g} s, then the "
        "zero command; the JSON adds how far the body walked while it was held (docs/how-to/walk.md)",
    )
    progress: bool = setting(True, "show a progress bar")
    live: bool = setting(False, "publish every step to a Foxglove WebSocket server as it happens")
    live_port: int = setting(DEFAULT_PORT, "port of the live view's server (0: any free port)")
    live_host: str = setting(DEFAULT_HOST, "address the live view's server binds to (0.0.0.0: every interface)")


def validate(cfg: EvalConfig) -> None:
    """Reject bad settings before anything runs."""
    check_positive(cfg, "episodes")
    check_port(cfg.live_port)
    check_seed(cfg, "seed")
    if not (math.isfinite(cfg.push) and cfg.push >= 0):
        raise UserError(f"--push must be a force >= 0 in newtons, got {cfg.push}")
    if not (math.isfinite(cfg.kick) and cfg.kick >= 0):
        raise UserError(f"--kick must be a speed >= 0 in m/s, got {cfg.kick}")
    if cfg.push and cfg.kick:
        raise UserError("--push and --kick are two perturbations: give one of them")
    check_non_negative(cfg, "noise")
    if cfg.condition not in SUITE:
        raise UserError(f"unknown --condition {cfg.condition!r}; known: {', '.join(SUITE)}")
    if cfg.condition != "clean" and (cfg.push or cfg.noise or cfg.kick):
        raise UserError("--condition brings its own perturbation: leave --push, --kick and --noise at 0 with it")
    check_file(cfg, "video", ".mp4")
    check_file(cfg, "plot", ".png")
    if cfg.hold:
        parse_held(cfg.hold)
        if cfg.task != POSTURE_TASK:
            raise UserError(f"--hold holds one command instead of --task {cfg.task}'s schedule: give one of them")


def evaluate(
    controller: Controller | str | type[Teacher],
    episodes: int = 20,
    seed: int = EVAL_SEED,
    push: float = 0.0,
    noise: float = 0.0,
    video: Path | None = None,
    progress: bool = False,
    condition: str = "clean",
    live: tuple[str, int] | None = None,
    plot: Path | None = None,
    kick: float = 0.0,
    task: str = STAND,
    hold: Posture | None = None,
) -> dict[str, Any]:
    """Roll `controller` (or the controller named so) out on seeds seed..seed+episodes-1; a JSON-ready summary.

    `push`, `kick` and `noise` add to what the robustness `condition` (by name) brings (`evaluated_condition`);
    `live` = (host, port) publishes every step to a Foxglove WebSocket server there (`teleop.live`). The operator
    commands `task` (`task.schedules.task_commands`): under a schedule the summary adds "tracking" (`tracking`, of the
    fields the task commands), or holds the command `hold` instead (`task.schedules.held_commands`: the summary adds
    "held", `held_motion`, and tracks every field); `plot` draws the first episode's commanded and achieved posture.
    """
    env = make_env() if video is None else make_env(render_mode="rgb_array", default_camera_config=CAMERA)
    evaluated = evaluated_condition(condition, push, kick, noise)
    env = evaluated.wrap(env)
    noise = evaluated.action_noise
    if video is not None:
        env = VideoRecorder(env, video)
    publisher = None
    try:
        publisher = None if live is None else start_live(env, *live)
        if isinstance(controller, (str, type)):
            try:
                controller = make_controller(controller, env)
            except ValueError as error:
                raise UserError(str(error)) from None
        seeds = list(range(seed, seed + episodes))
        buffer = EpisodeBuffer(env, EPISODE_STEPS)
        held = None if hold is None else held_commands(hold, EPISODE_STEPS, env.unwrapped.dt)
        pusher = perturbation(env)  # the toppling breakdown of pushes, or of a kick
        results, directions, toppled = [], [], []
        for s in tqdm(seeds, unit="ep", disable=not progress, file=sys.stderr, dynamic_ncols=True):
            results.append(run_episode(env, controller, s, noise, buffer, observer=publisher, task=task, commands=held))
            if pusher is not None:
                directions += [direction for _, direction in pusher.pushes]
                toppled += toppling([start for start, _ in pusher.pushes], results[-1].fell)
    finally:
        if publisher is not None:
            publisher.close()
        env.close()
    # The nominal body's targets, solved once per process.
    measure = Tracking(nominal_model(), COMMAND_FIELDS if hold is not None else task_fields(task))
    if plot is not None:
        plot_tracking(results[0], measure, env.unwrapped.dt, plot)
    returns = np.array([episode.episode_return for episode in results])
    lengths = np.array([episode.length for episode in results])
    survived = [episode.length == EPISODE_STEPS and not episode.fell for episode in results]
    return {
        "policy": controller.name,
        "episodes": episodes,
        "seeds": seeds,
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "mean_length": float(lengths.mean()),
        "survival_rate": float(np.mean(survived)),
        "survived": int(sum(survived)),
        "push_newtons": push,
        # The kick (the condition's or KICK): its speed (m/s) and impulse on the body (N·s); None without one.
        "kick": kick_size(pusher),
        "noise_std": noise,
        "condition": condition,
        "returns": [round(float(r), 3) for r in returns],
        "survivals": survived,
        "lengths": lengths.tolist(),
        # Every push in seed order: its direction seen from the torso (0 forward, 90 left, 180 back) and
        # whether it was the last before a fall (`humanoid.perturbations.toppling`); empty when unpushed.
        "pushes": {"direction": [round(d, 2) for d in directions], "toppled": toppled},
        # Each episode's drawn body (scale factors, `humanoid.conditions.DomainRandomization`), to see which draws fell.
        "parameters": [episode.parameters for episode in results],
        "video": None if video is None else str(video),
        "takes_command": controller.takes_command,
        "walks": controller.walks,
        "task": None if hold is not None else task,  # a held command runs no task's schedule
        "tracking": tracking(results, measure, env.unwrapped.dt) if task != STAND or hold is not None else None,
        "held": None if hold is None else held_motion(results, hold, env.unwrapped.dt),
    }


AFTER_SECONDS = 2.0
"""`held_motion` measures the drift from this long after the held command's release: issue 71 asks a walk to be at
rest within 2 s of the zero command."""


def held_motion(episodes: list[Episode], hold: Posture, dt: float) -> dict[str, Any]:
    """How the body moved under `held_commands(hold)`, per episode (None where it fell before the window's end): the
    torso's way forward and to the left (m) in the pelvis's heading at the press, and the pelvis's turn (rad), from the
    press to the release; the torso's way from `AFTER_SECONDS` after the release to the episode's end (m: a stop is
    near 0). Means over the episodes that reached each window's end; `walked_1m`, those that walked a metre forward."""
    model = nominal_model()
    torso, pelvis = model.body(TORSO_BODY).id - 1, model.body(PELVIS_BODY).id - 1  # `body_poses` leaves the world out
    press, release = round(FIRST_NEUTRAL_SECONDS / dt), round((FIRST_NEUTRAL_SECONDS + HELD_SECONDS) / dt)
    settled = release + round(AFTER_SECONDS / dt)
    moved, turned, after = [], [], []
    for episode in episodes:
        x_axis = body_axes(episode.body_orientation[:, pelvis])[:, 0]  # where the pelvis faces, as `physics.heading`
        yaw = np.unwrap(np.arctan2(x_axis[:, 1], x_axis[:, 0]))
        if episode.length > release:
            way = episode.body_position[release, torso, :2] - episode.body_position[press, torso, :2]
            c, s = np.cos(yaw[press]), np.sin(yaw[press])
            moved.append([round(float(c * way[0] + s * way[1]), 3), round(float(c * way[1] - s * way[0]), 3)])
            turned.append(round(float(yaw[release] - yaw[press]), 3))
        else:
            moved.append(None)
            turned.append(None)
        if episode.length > settled and not episode.fell:
            way_after = episode.body_position[-1, torso, :2] - episode.body_position[settled, torso, :2]
            after.append(round(float(np.linalg.norm(way_after)), 3))
        else:
            after.append(None)
    walked = [m for m in moved if m is not None]
    return {
        "command": {name: value for name, value in dataclasses.asdict(hold).items() if value},
        "seconds": HELD_SECONDS,
        "forward": _mean([m[0] for m in walked]),
        "sideways": _mean([m[1] for m in walked]),
        "turned": _mean([t for t in turned if t is not None]),
        "walked_1m": sum(m[0] >= 1.0 for m in walked),
        "after": _mean([a for a in after if a is not None]),
        "episodes": {"moved": moved, "turned": turned, "after": after},
    }


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 3) if values else None


def evaluated_condition(name: str, push: float = 0.0, kick: float = 0.0, noise: float = 0.0) -> Condition:
    """The suite's condition `name`, with a push of `push` N, a kick of `kick` m/s and action noise `noise` on top
    (`make eval PUSH= KICK= NOISE=`; `validate` keeps those to the clean condition)."""
    suite = SUITE[name]
    return dataclasses.replace(
        suite,
        push=push if push > 0 else suite.push,
        kick=kick or suite.kick,
        action_noise=suite.action_noise + noise,
    )


def kick_size(pusher: object) -> dict[str, float] | None:
    """A kick's speed (m/s) and impulse on the body (N·s); None where `pusher` is no kick."""
    return {"speed": pusher.speed, "impulse": round(pusher.impulse, 2)} if isinstance(pusher, VelocityKick) else None


def tracking(episodes: list[Episode], measure: Tracking, dt: float) -> dict[str, Any]:
    """Over `episodes` (until each ends): per command field the mean error once settled, the mean time to settle
    (`task.tracking.tracking_summary`), and each episode's."""
    each = [measure.summary(measure.errors(e.observation, e.command), e.command, dt) for e in episodes]
    return {**combine_tracking(each), "episodes": each}


def plot_tracking(episode: Episode, measure: Tracking, dt: float, path: Path) -> None:
    """A PNG of `episode`'s commanded (and the setpoint toward it) against achieved posture, a panel per field."""
    from matplotlib.figure import Figure  # noqa: PLC0415 - the object API draws to files without a GUI backend

    plotted = [field for field in PLOTTED if field in measure.fields]
    achieved = dict(zip(plotted, measure.achieved(episode.observation).T, strict=True))
    errors = measure.errors(episode.observation, episode.command)
    time = np.arange(episode.length) * dt
    figure = Figure(figsize=(8, 1.8 * len(measure.fields)), layout="constrained")
    axes = figure.subplots(len(measure.fields), 1, sharex=True, squeeze=False)[:, 0]
    for at, (ax, field) in enumerate(zip(axes, measure.fields, strict=True)):
        column = COMMAND_NAMES.index(field.name)
        ax.step(time, episode.command[:, column], where="post", label="commanded", color="C0")
        ax.plot(time, episode.setpoint[:, column], label="setpoint", color="C0", alpha=0.4, linestyle="--")
        # A field without one achieved value (the arm preset) shows its error instead.
        if not field.posed:  # a walk sways within each stride: its speed is the mean over SPEED_SECONDS
            ax.plot(time, achieved[field], color="C1", alpha=0.3, linewidth=0.6)
            achieved[field] = trailing_mean(achieved[field][:, None], measure.speed_steps)[:, 0]
        ax.plot(time, achieved[field] if field in achieved else errors[:, at], label="achieved", color="C1")
        unit = field.unit if field in achieved else f"{field.unit}; error (rad)"
        ax.set_ylabel(f"{field.name.replace('_', ' ')} ({unit})", fontsize=8)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"{episode.controller}, seed {episode.seed}: commanded and achieved posture")
    axes[-1].set_xlabel("time (s)")
    save_figure(figure, path)


def main(cfg: EvalConfig) -> dict[str, Any]:
    """Evaluate `cfg.policy` as configured; returns the summary `cli` prints, `cfg` under "config"."""
    validate(cfg)
    cfg = dataclasses.replace(cfg, policy=chosen_policy(cfg.policy, paths.LEARNED, "make train-bc"))
    result = evaluate(
        cfg.policy,
        cfg.episodes,
        cfg.seed,
        cfg.push,
        cfg.noise,
        cfg.video,
        cfg.progress,
        condition=cfg.condition,
        live=(cfg.live_host, cfg.live_port) if cfg.live else None,
        plot=cfg.plot,
        kick=cfg.kick,
        task=cfg.task,
        hold=parse_held(cfg.hold) if cfg.hold else None,
    )
    return {**result, "config": config_dict(cfg)}


def init_worker() -> None:
    """Set up a process that evaluates: one torch and one BLAS thread, since a forward pass or an LQR product of one
    row gains nothing from more and the processes share the cores (docs/decisions/blas-threads.md)."""
    torch.set_num_threads(1)
    one_blas_thread()


def _init_pool_worker() -> None:
    """`init_worker`, and the worker ends with the process that started its pool (`_exit_with_parent`)."""
    init_worker()
    threading.Thread(target=_exit_with_parent, daemon=True).start()


def _exit_with_parent() -> None:
    """End this worker once the process that started its pool is gone: the workers wait on a queue that never closes,
    and would otherwise outlive a killed run (kill -9), holding its forkserver too."""
    parent = mp.parent_process()  # its sentinel: a pipe from the starting process, at its end once that one is gone
    if parent is not None:
        parent.join()
        os._exit(1)


_open_pools: dict[int, Executor] = {}  # the pools of the `evaluation_pool` blocks now open, by size


@contextlib.contextmanager
def evaluation_pool(workers: int) -> Iterator[Executor | None]:
    """A pool of `workers` evaluation processes (forkserver, `_init_pool_worker`) for `evaluate_each`, for the block:
    the outermost block of a size starts it and shuts it down, the blocks inside it reuse it (the pipeline's table holds
    one open over every controller's suite, so the workers' start-up, seconds each, is paid once). None for one
    worker: evaluations run here. No pool outlives its block: idle ones beside BC's training halved its speed."""
    if workers <= 1:
        yield None
    elif workers in _open_pools:
        yield _open_pools[workers]
    else:
        context = forkserver_context()
        with ProcessPoolExecutor(workers, mp_context=context, initializer=_init_pool_worker) as pool:
            _open_pools[workers] = pool
            try:
                yield pool
            finally:
                del _open_pools[workers]


Evaluated = str | type[Teacher] | tuple[MLPPolicy, str]
"""What `evaluate_each` evaluates: a registered controller's name or a checkpoint folder, a teacher's class
(`rollout.controllers.built`), or a policy in memory and the name its results go by (the policy travels to a worker
pickled; its inputs are rebuilt there)."""


def _evaluate(what: Evaluated, settings: dict[str, Any]) -> dict[str, Any]:
    return evaluate(what if isinstance(what, (str, type)) else PolicyController(*what), **settings)


def evaluate_each(runs: Sequence[tuple[Evaluated, dict[str, Any]]], pool: Executor | None = None) -> Iterator[dict]:
    """`evaluate` of each (what, its keyword arguments) of `runs`: all submitted to `pool` at once (the first first),
    else one after the other here; the results in order. They are the same either way: an episode depends on its
    seed alone."""
    if pool is None:
        yield from (_evaluate(what, settings) for what, settings in runs)
        return
    futures = [pool.submit(_evaluate, what, settings) for what, settings in runs]
    try:
        for future in futures:
            yield future.result()
    finally:
        for future in futures:
            future.cancel()  # the caller stopped early or failed: nothing more to run


def _main_and_print(cfg: EvalConfig) -> None:
    print(json_text(main(cfg)))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, EvalConfig, argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(cli())
