"""`make eval`: run a saved policy (or the expert) on Humanoid-v5 and print the outcome as JSON.

Episodes start from the environment's own reset on seeds SEED..SEED+EPISODES-1; the default
SEED 1000 keeps clear of the recorder's seeds (0, 1, 2, ...). Survival is the fraction of
episodes that reach the 1000-step time limit without falling. The last line printed is one JSON
object, with the run's full settings under "config"; `evaluate()` returns the same dict (without
them) to callers such as `bc.train`.

    PUSH=F     a horizontal push of F newtons on the torso for 0.1 s every 2 s, random direction
    NOISE=σ    Gaussian noise of std σ added to every executed action (then clipped)
    CONDITION=name  a condition of the robustness suite instead (`humanoid.conditions.SUITE`:
               masses, friction, motor strength, latency, sensor noise, pushes; docs/concepts/robustness-suite.md)
    VIDEO=f    an MP4 of every episode, rendered offscreen on the CPU: a frame every step, so slow
               (docs/how-to/evaluate.md); use a few episodes
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from common import paths
from common.cli import UserError, config_dict, run_cli, setting
from humanoid.conditions import SUITE
from humanoid.controllers import Controller, make_controller
from humanoid.env import EPISODE_STEPS, make_env
from humanoid.episode import EpisodeBuffer, run_episode
from humanoid.perturbations import TorsoPushes, toppling, torso_pushes
from humanoid.video import CAMERA, VideoRecorder
from teleop.live import DEFAULT_HOST, DEFAULT_PORT, check_port, start_live

EVAL_SEED = 1000  # first evaluation seed: recordings use 0, 1, 2, ... and stay far below it


@dataclass
class EvalConfig:
    """Settings of one evaluation."""

    policy: str = setting(
        str(paths.BC_POLICY),
        "policy checkpoint folder, or a registered controller (expert, expert-sensed, random)",
    )
    episodes: int = setting(20, "number of episodes")
    seed: int = setting(EVAL_SEED, "seed of the first episode (episode i uses SEED+i)")
    push: float = setting(0.0, "force in newtons of a horizontal push on the torso for 0.1 s every 2 s; 0 = none")
    noise: float = setting(0.0, "std of the Gaussian noise added to every executed action; 0 = none")
    condition: str = setting(
        "clean", f"a condition of the robustness suite: {', '.join(SUITE)} (docs/concepts/robustness-suite.md)"
    )
    video: Path | None = setting(None, "write an MP4 of the episodes here (offscreen on the CPU, a frame a step: slow)")
    progress: bool = setting(True, "show a progress bar")
    live: bool = setting(False, "publish every step to a Foxglove WebSocket server as it happens")
    live_port: int = setting(DEFAULT_PORT, "port of the live view's server (0: any free port)")
    live_host: str = setting(DEFAULT_HOST, "address the live view's server binds to (0.0.0.0: every interface)")


def validate(cfg: EvalConfig) -> None:
    """Reject bad settings before anything runs."""
    if cfg.episodes <= 0:
        raise UserError(f"--episodes must be positive, got {cfg.episodes}")
    check_port(cfg.live_port)
    if cfg.seed < 0:
        raise UserError(f"--seed must be >= 0, got {cfg.seed}")
    if not (math.isfinite(cfg.push) and cfg.push >= 0):
        raise UserError(f"--push must be a force >= 0 in newtons, got {cfg.push}")
    if not (math.isfinite(cfg.noise) and cfg.noise >= 0):
        raise UserError(f"--noise must be >= 0, got {cfg.noise}")
    if cfg.condition not in SUITE:
        raise UserError(f"unknown --condition {cfg.condition!r}; known: {', '.join(SUITE)}")
    if cfg.condition != "clean" and (cfg.push or cfg.noise):
        raise UserError("--condition brings its own perturbation: leave --push and --noise at 0 with it")
    if cfg.video is not None and cfg.video.suffix.lower() != ".mp4":
        raise UserError(f"--video must be an .mp4 path, got {cfg.video}")


def evaluate(
    controller: Controller | str,
    episodes: int = 20,
    seed: int = EVAL_SEED,
    push: float = 0.0,
    noise: float = 0.0,
    video: Path | None = None,
    progress: bool = False,
    condition: str = "clean",
    live: tuple[str, int] | None = None,
) -> dict[str, Any]:
    """Roll `controller` (or the controller named so) out on seeds seed..seed+episodes-1; a JSON-ready summary.

    `push` and `noise` add to what the robustness `condition` (by name) brings; `live` = (host, port)
    publishes every step to a Foxglove WebSocket server there (`teleop.live`).
    """
    env = make_env() if video is None else make_env(render_mode="rgb_array", default_camera_config=CAMERA)
    suite_condition = SUITE[condition]
    env = suite_condition.wrap(env)
    noise = noise + suite_condition.action_noise
    if push > 0:
        env = TorsoPushes(env, push)
    if video is not None:
        env = VideoRecorder(env, video)
    publisher = None
    try:
        publisher = None if live is None else start_live(env, *live)
        if isinstance(controller, str):
            try:
                controller = make_controller(controller, env)
            except ValueError as error:
                raise UserError(str(error)) from None
        seeds = list(range(seed, seed + episodes))
        buffer = EpisodeBuffer(env, EPISODE_STEPS)
        pusher = torso_pushes(env)
        results, directions, toppled = [], [], []
        for s in tqdm(seeds, unit="ep", disable=not progress, file=sys.stderr, dynamic_ncols=True):
            results.append(run_episode(env, controller, s, noise, buffer, observer=publisher))
            if pusher is not None:
                directions += [direction for _, direction in pusher.pushes]
                toppled += toppling([start for start, _ in pusher.pushes], results[-1].fell)
    finally:
        if publisher is not None:
            publisher.close()
        env.close()
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
    }


def main(cfg: EvalConfig) -> dict[str, Any]:
    """Evaluate `cfg.policy` as configured; returns the summary `cli` prints, `cfg` under "config"."""
    validate(cfg)
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
    )
    return {**result, "config": config_dict(cfg)}


def _main_and_print(cfg: EvalConfig) -> None:
    print(json.dumps(main(cfg)))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, EvalConfig, argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(cli())
