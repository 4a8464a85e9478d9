"""The walker's walking rows beside what the suite measures (docs/decisions/walking-teacher.md).

    python -m bench.walker [--episodes 20] [--seed 1000]

For `walker` and `walker-sensed` on held-out walking schedules (`TASK=walk`, seeds 1000..): survivors; how smooth the
action is while walking (the mean change per entry from one env step to the next: what a student regresses); how long
after the command filter reaches the zero walk the walk is over (the clock done, the body at rest over its feet, and
no step again while the zero walk holds); and, for the sensed walker, how far its leg odometry's velocity is from the
simulator's over 1 s means while walking. Then the cost of one action side by side in this run: the LQR expert's, the
walker's standing (its trigger armed, quiet), walking (0.3 m/s forward) and on leg odometry, and the walking sampling
planner's. Prints markdown tables. Survival and tracking per field under the suite's conditions:
`make robustness POLICY=walker TASK=walk CONDITIONS=clean,kick0.4,kick0.6` (and `TASK=stand`).
"""

from __future__ import annotations

import argparse

import numpy as np

from bench.stepping import seconds_per_action
from humanoid.env import EPISODE_STEPS, make_env, model_and_data
from task.command_fields import COMMAND_NAMES, VELOCITY_NAMES
from task.posture import Posture
from task.schedules import command_vector, task_commands
from teachers.expert import LQRExpert
from teachers.stepping import SteppingExpert
from teachers.walker import SensedWalker, Walker

_SPEEDS = [COMMAND_NAMES.index(name) for name in VELOCITY_NAMES]
WINDOW_SECONDS = 1.0


class Stops:
    """The seconds from each zero walk's arrival on the command filter to the walk's end (`rests`): a walk that steps
    again while the zero walk holds was not over, and its stop runs on (issue 71: at rest within 2 s, and standing
    after)."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.rests: list[float] = []
        self._since: int | None = None  # the step the zero walk arrived while the walk went on
        self._rested: int | None = None  # that step of the last stop, while the body stands after it

    @property
    def stopping(self) -> bool:
        """Whether a zero walk is still waiting for the walk to end."""
        return self._since is not None

    def step(self, t: int, walking: bool, zero_walk: bool, done: bool) -> None:
        """Env step `t`: whether the clock walks, the command filter is at the zero walk, the walk has just ended."""
        if not zero_walk:
            self._rested = None
        if self._rested is not None and walking:  # it steps again under the zero walk: that was no stop
            self.rests.pop()
            self._since, self._rested = self._rested, None
        if self._since is None and walking and zero_walk:
            self._since = t
        if self._since is not None and done:
            self.rests.append((t - self._since) * self.dt)
            self._since, self._rested = None, self._since


def walking_episode(walker: Walker, seed: int) -> dict[str, object]:
    """One held-out walking schedule: survived, the action changes while walking, the seconds from each zero walk's
    arrival on the command filter to the walk's end (a walk that steps again while the zero walk holds was not over:
    its stop runs on), and (on leg odometry) the 1 s mean velocity errors."""
    env = make_env(EPISODE_STEPS)
    _, data = model_and_data(env)
    dt = env.unwrapped.dt
    commands = task_commands("walk", seed, EPISODE_STEPS, dt)
    obs, _ = env.reset(seed=seed)
    walker.reset(seed)
    window = round(WINDOW_SECONDS / dt)
    changes, errors, estimated, true = [], [], [], []
    previous, fell = None, False
    stops = Stops(dt)
    for t in range(EPISODE_STEPS):
        if t == 0 or (commands[t] != commands[t - 1]).any():
            walker.set_command(commands[t])
        action = walker.act(obs)
        walking = walker.clock.active
        if walking and previous is not None:
            changes.append(float(np.abs(action - previous).mean()))
        previous = action
        stops.step(t, walking, not walker.expert.setpoint()[_SPEEDS].any(), walker.clock.done)
        if walking and isinstance(walker, SensedWalker):
            estimated.append(walker.state(obs)[1][:2].copy())
            true.append(data.qvel[:2].copy())
            if len(true) >= window:
                errors.append(float(np.linalg.norm(np.mean(estimated[-window:], 0) - np.mean(true[-window:], 0))))
        else:
            estimated, true = [], []
        obs, _, terminated, _, _ = env.step(action)
        if terminated:
            fell = True
            break
    env.close()
    return {
        "survived": not fell,
        "changes": changes,
        "rests": stops.rests,
        "still_walking": stops.stopping,
        "errors": errors,
    }


def walking_cost(controller: object, seed: int, command: np.ndarray, steps: int = 300) -> float:
    """Mean wall time of `controller.act` over `steps` env steps of a walk commanded after the 3 s landing and under
    way for 1.5 s."""
    landed, walking = 200, 300
    env = make_env(EPISODE_STEPS)
    try:
        return seconds_per_action(controller, env, seed, steps, landed + walking, command, landed, must_stand=True)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    seeds = range(args.seed, args.seed + args.episodes)

    print(
        "| walker | walking schedules survived | action change per step while walking | walks over within 2 s of "
        "the zero walk | seconds to the walk's end (mean, most) | velocity estimate's error, 1 s means (m/s) |"
    )
    print("|---|---|---|---|---|---|")
    for teacher in (Walker, SensedWalker):
        rows = [walking_episode(teacher(), seed) for seed in seeds]
        changes = np.concatenate([row["changes"] for row in rows if row["changes"]])
        rests = np.array([rest for row in rows for rest in row["rests"]])
        stops = len(rests) + sum(row["still_walking"] for row in rows)
        errors = np.concatenate([row["errors"] for row in rows if row["errors"]] or [np.zeros(0)])
        error = f"{errors.mean():.3f} (95th percentile {np.percentile(errors, 95):.3f})" if len(errors) else "n/a"
        rest = f"{rests.mean():.2f}, {rests.max():.2f}" if len(rests) else "n/a (none ended)"
        print(
            f"| {teacher.name} | {sum(row['survived'] for row in rows)}/{len(rows)} | {changes.mean():.4f} | "
            f"{int((rests <= 2.0).sum())}/{stops} | {rest} | {error} |"
        )

    forward = command_vector(Posture(forward_speed=0.3))
    costs = {
        "LQR expert": seconds_per_action(LQRExpert(), make_env(), args.seed, 400, 150),
        "walker, standing (trigger armed, quiet)": seconds_per_action(Walker(), make_env(), args.seed, 400, 150),
        "walker, walking (0.3 m/s forward)": walking_cost(Walker(), args.seed, forward),
        "walker-sensed, walking (0.3 m/s forward)": walking_cost(SensedWalker(), args.seed, forward),
        "stepping expert, walking (0.3 m/s forward)": walking_cost(SteppingExpert(), args.seed, forward, 100),
    }
    print("\n| action | ms per action | x real time (0.015 s a step) |\n|---|---|---|")
    for name, cost in costs.items():
        print(f"| {name} | {1e3 * cost:.3f} | {0.015 / cost:.1f} |")


if __name__ == "__main__":
    main()
