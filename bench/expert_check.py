"""Check the LQR expert: set-up time, per-action time, survival and return over seeded episodes.

    python -m bench.expert_check [--first-seed 0] [--episodes 20] [--noise 0 0.05]

``--noise`` adds Gaussian noise of that standard deviation to every executed action (then clips to
the motor range), as when recording noise-injected demonstrations.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from humanoid.env import humanoid_model, make_env
from rollout.episode import EpisodeBuffer, run_episode
from teachers.expert import LQRExpert
from teachers.landing import design_landing
from teachers.lqr import LQRDesign, design_lqr, load_or_design


def time_setup() -> tuple[float, float, float]:
    """Seconds to design the gains from scratch, to load them from the (warmed) cache, and to plan the landing."""
    model = humanoid_model()
    start = time.perf_counter()
    gains = design_lqr(model)
    cold = time.perf_counter() - start
    load_or_design(model)  # makes sure the cache file exists
    start = time.perf_counter()
    load_or_design(model)
    cached = time.perf_counter() - start
    start = time.perf_counter()
    design_landing(model, gains, LQRDesign())
    return cold, cached, time.perf_counter() - start


def time_action(expert: LQRExpert, obs: np.ndarray, repeats: int = 20_000) -> float:
    """Mean seconds per ``act`` call (the steady law: without a `reset` the landing plan is not armed)."""
    start = time.perf_counter()
    for _ in range(repeats):
        expert.act(obs)
    return (time.perf_counter() - start) / repeats


def main(argv: list[str] | None = None) -> None:
    """Print set-up time, per-action time and, per noise level, survival and returns."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--noise", type=float, nargs="+", default=[0.0])
    args = parser.parse_args(argv)

    cold, cached, landing = time_setup()
    print(f"set-up: {cold:.3f} s from scratch, {1e3 * cached:.1f} ms from the cache; landing plan {landing:.1f} s")
    env = make_env()
    expert = LQRExpert(env.unwrapped.model)
    buffer = EpisodeBuffer(env, env.spec.max_episode_steps)
    obs, _ = env.reset(seed=args.first_seed)
    print(f"act: {1e6 * time_action(expert, obs):.1f} us per call")

    seeds = range(args.first_seed, args.first_seed + args.episodes)
    for noise in args.noise:
        episodes = [run_episode(env, expert, seed, noise, buffer) for seed in seeds]
        returns = np.array([e.episode_return for e in episodes])
        fallen = {e.seed: e.length for e in episodes if e.fell}
        line = (
            f"noise {noise:<5} seeds {seeds.start}..{seeds.stop - 1}: "
            f"stood {len(episodes) - len(fallen)}/{len(episodes)}, "
            f"return mean {returns.mean():.1f} min {returns.min():.1f}"
        )
        if fallen:
            line += f", fell (seed: steps) {fallen}"
        print(line)
    env.close()


if __name__ == "__main__":
    main()
