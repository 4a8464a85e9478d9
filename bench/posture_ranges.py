"""Measure how far each commanded posture can go before the LQR expert lets the body fall.

    python -m bench.posture_ranges [--seeds 5] [--hold 3.0] [--fields lean_forward twist ...]

For every field of ``Posture`` and every magnitude in ``MAGNITUDES`` (both signs): from
``env.reset(seed)`` and a 2 s neutral stand, ``expert.hold`` the posture (unclipped), let the ramp
get there, hold it ``--hold`` seconds, and record whether the body stayed up (the env did not
terminate) on every seed, and, on the first seed, the torso's forward/left tilt, its yaw relative
to the pelvis, its height and the centre of mass's offset from the feet mid-point at the end.
Then combinations at the limits, a return to neutral, and the cost of ``act`` (still and moving).
Prints markdown tables.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from humanoid import physics
from humanoid.env import make_env, model_and_data
from task.command_fields import FIELDS
from task.posture import Posture
from teachers.expert import LQRExpert
from teachers.postures import posture_reference

SETTLE_S = 2.0
MAGNITUDES: dict[str, tuple[float, ...]] = {
    "lean_forward": (0.1, 0.2, 0.3, 0.35, 0.4, 0.5),
    "lean_left": (0.1, 0.2, 0.3, 0.4, 0.5),
    "height": (0.005, 0.008, -0.05, -0.1, -0.15, -0.2, -0.25, -0.3),  # signed: rise has under 1 cm of room
    "twist": (0.2, 0.4, 0.6, 0.7, 0.75),
    "arms": (1.0, 2.0, 3.0),
}
SIGNED = ("height", "arms")  # fields whose magnitudes above carry their own sign


@dataclass
class Outcome:
    """What one held posture did."""

    up: bool
    tilt: tuple[float, float] = (np.nan, np.nan)  # torso (forward, left) at the end, rad
    yaw: float = np.nan  # torso yaw relative to the pelvis at the end, rad
    height: float = np.nan  # torso height at the end, m
    com: tuple[float, float] = (np.nan, np.nan)  # centre of mass minus feet mid-point (x, y), m


class Runner:
    """One env and one expert, reused across runs."""

    def __init__(self, hold_s: float) -> None:
        self.env = make_env(max_episode_steps=100_000)
        self.model, self.data = model_and_data(self.env)
        self.expert = LQRExpert(self.model)
        self.dt = self.env.unwrapped.dt
        self.hold_steps = round(hold_s / self.dt)

    def settle(self, seed: int) -> np.ndarray:
        obs, _ = self.env.reset(seed=seed)
        self.expert.reset(seed)
        for _ in range(round(SETTLE_S / self.dt)):
            obs, *_ = self.env.step(self.expert.act(obs))
        return obs

    def hold(self, obs: np.ndarray, posture: Posture) -> tuple[np.ndarray, bool]:
        """Command ``posture`` and step until the ramp ends plus the hold time; (obs, still up)."""
        self.expert.hold(posture, clip=False)
        steps = 0
        while self.expert.moving or steps < self.hold_steps:
            obs, _, terminated, _, _ = self.env.step(self.expert.act(obs))
            if terminated:
                return obs, False
            steps += 0 if self.expert.moving else 1
        return obs, True

    def measure(self, up: bool) -> Outcome:
        if not up:
            return Outcome(False)
        model, data = self.model, self.data
        mujoco.mj_comPos(model, data)
        return Outcome(
            True,
            physics.torso_tilt(model, data),
            physics.torso_yaw_relative_to_pelvis(model, data),
            physics.torso_height(model, data),
            tuple(physics.com_over_feet(model, data)),
        )

    def run(self, postures: list[Posture], seed: int) -> Outcome:
        """Hold each posture in turn from a settled stand; the outcome after the last."""
        obs = self.settle(seed)
        for posture in postures:
            obs, up = self.hold(obs, posture)
            if not up:
                return Outcome(False)
        return self.measure(True)


def row(label: str, ups: list[bool], out: Outcome) -> str:
    return (
        f"| {label} | {sum(ups)}/{len(ups)} | {out.tilt[0]:+.3f} | {out.tilt[1]:+.3f} | {out.yaw:+.3f} "
        f"| {out.height:.3f} | {out.com[0]:+.4f} | {out.com[1]:+.4f} |"
    )


HEADER = (
    "| posture | stayed up | torso forward (rad) | torso left (rad) | torso yaw rel. pelvis (rad) "
    "| torso height (m) | CoM-feet x (m) | CoM-feet y (m) |\n|---|---|---|---|---|---|---|---|"
)


def main(argv: list[str] | None = None) -> None:
    """Print the ranges table, the combinations table and act() timings."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--hold", type=float, default=3.0, help="seconds to hold each posture once reached")
    parser.add_argument("--fields", nargs="+", default=list(MAGNITUDES))
    parser.add_argument("--skip-combos", action="store_true")
    args = parser.parse_args(argv)
    runner = Runner(args.hold)
    seeds = range(args.seeds)
    start = time.perf_counter()

    print(f"## Single fields (held {args.hold:g} s after the ramp, seeds 0..{args.seeds - 1}; values from seed 0)\n")
    print(HEADER)
    for name in args.fields:
        values = MAGNITUDES[name] if name in SIGNED else [s * m for m in MAGNITUDES[name] for s in (1, -1)]
        for value in sorted(values, key=lambda v: (v < 0, abs(v))):
            posture = Posture(**{name: value})
            try:
                posture_reference(runner.model, posture)
            except RuntimeError:
                print(f"| {name}={value:+g} | no balanced pose | | | | | | |")
                continue
            outcomes = [runner.run([posture], seed) for seed in seeds]
            print(row(f"{name}={value:+g}", [o.up for o in outcomes], outcomes[0]), flush=True)

    if not args.skip_combos:
        print("\n## Combinations at the limits, and back to neutral\n")
        print(HEADER)
        lim_lo, lim_hi = (
            {name: field.low for name, field in FIELDS.items()},
            {name: field.high for name, field in FIELDS.items()},
        )
        combos = {
            "lean fwd + arms up + crouch": [
                Posture(lean_forward=lim_hi["lean_forward"], arms=2, height=lim_lo["height"])
            ],
            "lean back + arms out + crouch": [
                Posture(lean_forward=lim_lo["lean_forward"], arms=3, height=lim_lo["height"])
            ],
            "lean left + twist left + arms fwd": [
                Posture(lean_left=lim_hi["lean_left"], twist=lim_hi["twist"], arms=1)
            ],
            "lean right + twist right + arms up": [
                Posture(lean_left=lim_lo["lean_left"], twist=lim_lo["twist"], arms=2)
            ],
            "all at max (arms out, crouch)": [
                Posture(lim_hi["lean_forward"], lim_hi["lean_left"], lim_lo["height"], lim_hi["twist"], 3)
            ],
            "lean fwd + arms up + crouch, then neutral": [
                Posture(lean_forward=lim_hi["lean_forward"], arms=2, height=lim_lo["height"]),
                Posture(),
            ],
            "all at max, then neutral": [
                Posture(lim_hi["lean_forward"], lim_hi["lean_left"], lim_lo["height"], lim_hi["twist"], 3),
                Posture(),
            ],
            "lean fwd max -> lean back max -> neutral": [
                Posture(lean_forward=lim_hi["lean_forward"]),
                Posture(lean_forward=lim_lo["lean_forward"]),
                Posture(),
            ],
            "neutral (never commanded)": [],
        }
        for label, sequence in combos.items():
            outcomes = [runner.run(sequence, seed) for seed in seeds]
            print(row(label, [o.up for o in outcomes], outcomes[0]), flush=True)

    print("\n## act() cost\n")
    fresh = LQRExpert(runner.model)
    obs = runner.settle(0)
    for label, expert in (("never commanded", fresh), ("holding a reached posture", runner.expert)):
        if expert is runner.expert:
            expert.hold(Posture(lean_forward=0.1))
            while expert.moving:
                expert.act(obs)
        t0 = time.perf_counter()
        for _ in range(20_000):
            expert.act(obs)
        print(f"- {label}: {1e6 * (time.perf_counter() - t0) / 20_000:.1f} us per act")
    moving = []
    for target in (Posture(arms=3, lean_forward=0.15), Posture()):
        t0 = time.perf_counter()
        runner.expert.hold(target)
        plan = time.perf_counter() - t0
        steps = 0
        t0 = time.perf_counter()
        while runner.expert.moving:
            runner.expert.act(obs)
            steps += 1
        moving.append((target, plan, (time.perf_counter() - t0) / max(steps, 1), steps))
    for target, plan, per_act, steps in moving:
        print(
            f"- moving to {target}: hold() {1e3 * plan:.1f} ms (waypoints, and the target's gain if new), "
            f"then {1e6 * per_act:.1f} us per act over {steps} steps"
        )
    print(f"\n(total {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
