"""When a teacher that steps takes the body from its standing balance: the hand-over rule, computed alike by the
teacher and by its students (docs/decisions/walking-student.md).

A teacher that steps (`teachers.stepping`) balances as the LQR expert does until it must step: when a walk is
commanded, or, once armed, when the capture point leaves the feet (`humanoid.capture`) or the body moves faster than a
stance holds (a kick). From then on its actions are another law's, so a student that imitates it must know when that
happened: the walking input sets compute the same rule on the leg odometry's estimate (their `planning` input), and the
teacher on what a robot senses hands over on that same estimate. One rule, `HandOver`, read by both; a teacher
declares the one it runs (`teachers.registry`), and a test holds the students' to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from humanoid.capture import Support


@dataclass(frozen=True)
class HandOver:
    """The thresholds of the hand-over on a kick."""

    trigger_offset: float = 0.02
    """Hand over once the capture point is this far (m) off the segment between the feet: the LQR's schedules reach
    0.0075 at most."""
    trigger_speed: float = 0.12
    """Or once the centre of mass moves this fast (m/s) horizontally: the LQR's schedules reach 0.03."""
    armed_after: int = 100
    """Env steps after a reset before the rule is armed: the landing's drop is the LQR's."""

    def armed(self, steps: int) -> bool:
        """Whether the rule is armed at the `steps`-th env step of an episode (the first is 1)."""
        return steps > self.armed_after

    def leaves(self, offset: float, speed: float) -> bool:
        """Whether a body whose capture point is `offset` off the feet and whose centre of mass moves at `speed` needs
        a step (`humanoid.capture.capture_offset`)."""
        return offset > self.trigger_offset or speed > self.trigger_speed


STEPPING = HandOver()
"""The stepping teachers' rule (`teachers.stepping`), which the walking students compute."""


class HandOverFlag:
    """Whether a teacher running `rule` has handed the body over since the episode began: latched at the first step
    where a walk is commanded or, once armed, the capture point of the state given (the leg odometry's estimate) leaves
    the feet. One call per env step, as the teacher's `act`."""

    def __init__(self, model: mujoco.MjModel, rule: HandOver = STEPPING) -> None:
        self.rule = rule
        self.support = Support(model)
        self.reset()

    def reset(self) -> None:
        self.handed_over = False
        self.steps = 0

    def __call__(self, walking: bool, qpos: np.ndarray, qvel: np.ndarray) -> bool:
        """This step's flag, after a step under a walk (`walking`: a velocity on the command filter) in state (qpos,
        qvel)."""
        self.steps += 1
        self.handed_over = (
            self.handed_over or walking or (self.rule.armed(self.steps) and self.rule.leaves(*self.support(qpos, qvel)))
        )
        return self.handed_over
