"""The stepping expert's standing row and its cost per action (docs/decisions/stepping-teacher.md).

    python -m bench.stepping [--episodes 20] [--seed 1000]

Under the zero command and no push, for each held-out seed: whether the planner ever ran, and how far each foot moved
over the episode's last 10 s (the issue's "stands without stepping": under 2 cm). Then the cost of one action side by
side in this run: the LQR expert's, the stepping expert's while its trigger is armed but quiet, a planned one (after a
0.4 m/s kick) and a walking one (the walking planner's longer horizon). The kick rows:
`make robustness POLICY=expert-stepping CONDITIONS=clean,kick0.2,kick0.4,kick0.6 TASK=stand`. Prints markdown tables.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from humanoid.env import make_env, model_and_data
from humanoid.perturbations import VelocityKick
from humanoid.physics import FOOT_GEOMS
from task.posture import Posture
from task.schedules import command_vector
from teachers.expert import LQRExpert
from teachers.stepping import SteppingExpert

STILL_SECONDS = 10.0


def standing(seed: int) -> tuple[int, float]:
    """(planned steps, the largest foot displacement over the last STILL_SECONDS in m) of one zero-command episode."""
    env = make_env()
    _, data = model_and_data(env)
    expert = SteppingExpert()
    obs, _ = env.reset(seed=seed)
    expert.reset(seed)
    steps = env.spec.max_episode_steps
    start = steps - round(STILL_SECONDS / env.unwrapped.dt)
    feet, moved = None, 0.0
    try:
        for t in range(steps):
            obs, _, terminated, _, _ = env.step(expert.act(obs))
            if terminated:
                return expert.planned, float("inf")
            now = np.array([data.geom(name).xpos[:2] for name in FOOT_GEOMS])
            if t == start:
                feet = now
            elif feet is not None:
                moved = max(moved, float(np.linalg.norm(now - feet, axis=1).max()))
    finally:
        env.close()
    return expert.planned, moved


def seconds_per_action(
    controller: object,
    env: object,
    seed: int,
    steps: int,
    skip: int,
    command: np.ndarray | None = None,
    command_at: int = 0,
    must_stand: bool = False,
) -> float:
    """Mean wall time of `controller.act` over `steps` env steps after the first `skip` of an episode (told `command`
    at step `command_at`, if given). A fall ends the episode early, or with `must_stand` is a RuntimeError (a cost
    measured on fewer steps would read low)."""
    obs, _ = env.reset(seed=seed)
    controller.reset(seed)
    spent = 0.0
    for t in range(skip + steps):
        if command is not None and t == command_at:
            controller.set_command(command)
        begin = time.perf_counter()
        action = controller.act(obs)
        if t >= skip:
            spent += time.perf_counter() - begin
        obs, _, terminated, _, _ = env.step(action)
        if terminated:
            if must_stand:
                raise RuntimeError(f"{controller.name} fell on seed {seed} while its cost was measured")
            break
    return spent / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()

    print("| seed | planned steps | feet moved over the last 10 s (cm) |\n|---|---|---|")
    rows = [standing(seed) for seed in range(args.seed, args.seed + args.episodes)]
    for seed, (planned, moved) in zip(range(args.seed, args.seed + args.episodes), rows, strict=True):
        print(f"| {seed} | {planned} | {100 * moved:.2f} |")
    still = sum(planned == 0 and moved < 0.02 for planned, moved in rows)
    print(f"\nstood without stepping (no plan, each foot < 2 cm): {still}/{len(rows)}\n")

    kicked = VelocityKick(make_env(), 0.4, window=(2.0, 2.0))
    quiet, plain = make_env(), make_env()
    costs = {
        "LQR expert": seconds_per_action(LQRExpert(), plain, args.seed, 400, 150),
        "stepping expert, trigger armed, quiet": seconds_per_action(SteppingExpert(), quiet, args.seed, 400, 150),
        "stepping expert, planning (after a 0.4 m/s kick)": seconds_per_action(
            SteppingExpert(), kicked, args.seed, 200, 140
        ),
        "stepping expert, walking (0.3 m/s forward from the start)": seconds_per_action(
            SteppingExpert(), make_env(), args.seed, 200, 20, command_vector(Posture(forward_speed=0.3))
        ),
    }
    print("| action | ms per action | x real time (0.015 s a step) |\n|---|---|---|")
    for name, cost in costs.items():
        print(f"| {name} | {1e3 * cost:.3f} | {0.015 / cost:.1f} |")


if __name__ == "__main__":
    main()
