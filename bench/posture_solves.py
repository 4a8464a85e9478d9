"""How the poses the operator's schedules ask for are solved: which of `humanoid.balance.ATTEMPTS` balances each, and
how many fall back to the nearest posture that balances (`task.posture.nearest_pose`).

    python -m bench.posture_solves [--seeds 9600:9701 1000:1101]

For each schedule (`task.schedules.command_schedule`, the posture task), every pose the LQR teacher's ramp solves as
`teachers.postures.PostureRamp.hold` plans it: each command's balanced pose and the waypoints on the way to it, the
setpoint moving as the command filter moves it (`task.posture.PosturePath`). Prints a markdown table: poses, and per
attempt how many it balanced; the fallbacks; the largest static residual left (docs/decisions/posture-fallback.md).
"""

from __future__ import annotations

import argparse
import logging
from collections import Counter
from collections.abc import Iterable, Iterator

import mujoco
import numpy as np

from humanoid import balance, physics
from humanoid.balance import standing_pose
from humanoid.env import EPISODE_STEPS, nominal_model, step_seconds
from task import posture
from task.posture import PosturePath, arm_angles, commanded_pose
from task.schedules import command_posture, command_schedule
from teachers.postures import _pieces, waypoint_poses


def ramp_poses(model: mujoco.MjModel, seeds: Iterable[int]) -> Iterator[tuple[int, int, np.ndarray]]:
    """(seed, step, pose) of every pose the LQR teacher's ramp solves under the posture schedules of `seeds`: at each
    change of command, the waypoints on the way to it and its own balanced pose."""
    neutral, dt = standing_pose(model), step_seconds(model)
    for seed in seeds:
        commands = command_schedule(seed, EPISODE_STEPS, dt)
        path = PosturePath(model)
        for t in range(EPISODE_STEPS):
            target = command_posture(commands[t]).clipped()
            if target != path.target:
                path.hold(target)
                start, posed, from_arms = path.start.posed(), target.posed(), path.from_arms
                change = float(np.abs(arm_angles(posed.arms) - from_arms).max())
                pieces = _pieces(start, posed, change, "waypoint_step")
                for pose in [
                    *waypoint_poses(model, neutral, start, posed, from_arms, pieces),
                    commanded_pose(model, posed),
                ]:
                    yield seed, t, pose
            path.step()


def residual(model: mujoco.MjModel, qpos: np.ndarray) -> float:
    """The largest force or moment (N, N·m) the contacts leave unsupported at rest in `qpos`."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    return float(np.abs(physics.static_root_residual(model, data)).max())


def seed_range(text: str) -> range:
    start, stop = (int(part) for part in text.split(":"))
    return range(start, stop)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=seed_range, default=[range(9600, 9701), range(1000, 1101)])
    args = parser.parse_args()
    solved: Counter[str] = Counter()  # the method the balance solves needed: Powell's alone, or Levenberg-Marquardt
    methods: list[str] = []
    solve, balance_legs = balance._solve, posture.balance_legs

    def recorded(fun: object, x0: np.ndarray, tol: float, method: str = "hybr") -> object:
        methods.append(method)
        return solve(fun, x0, tol, method)

    def classified(*args: object, **kwargs: object) -> np.ndarray:
        methods.clear()
        try:
            return balance_legs(*args, **kwargs)
        finally:
            solved["lm" if "lm" in methods else "hybr"] += 1

    fallbacks: list[str] = []

    class Counting(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            fallbacks.append(record.getMessage())

    logging.getLogger(posture.__name__).addHandler(Counting())
    balance._solve, posture.balance_legs = recorded, classified
    model = nominal_model()
    poses, worst = 0, 0.0
    for range_ in args.seeds:
        for _, _, pose in ramp_poses(model, range_):
            poses += 1
            worst = max(worst, residual(model, pose))
    seeds = ", ".join(f"{r.start}..{r.stop - 1}" for r in args.seeds)
    print(
        "| schedules (seeds) | poses | balance solves | by Powell's method | Levenberg-Marquardt needed | fallbacks | "
        "largest residual (N, N·m) |"
    )
    print("|---|---|---|---|---|---|---|")
    total = solved["hybr"] + solved["lm"]
    print(f"| {seeds} | {poses} | {total} | {solved['hybr']} | {solved['lm']} | {len(fallbacks)} | {worst:.1e} |")
    for message in fallbacks:
        print(f"- {message}")


if __name__ == "__main__":
    main()
