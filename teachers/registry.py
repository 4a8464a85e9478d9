"""The registered teachers, by name: one line each (docs/concepts/controllers.md, "Adding a teacher").

A teacher is a class deriving from `teachers.base.Teacher`, which declares what it can do (`takes_command`, `walks`,
`handover`). `make record CONTROLLER=`, `make dagger EXPERT=`, `make eval POLICY=` and `make robustness
POLICY=` accept every name here and check each capability they need against the class; `rollout.controllers` builds
one as ``cls(delay=steps)``. A new teacher is its own module and one line in `TEACHERS`.
"""

from __future__ import annotations

from common.cli import UserError
from teachers.base import Teacher
from teachers.expert import LQRExpert, SensedExpert
from teachers.stepping import SensedSteppingExpert, SteppingExpert
from teachers.walker import SensedWalker, Walker

TEACHERS: dict[str, type[Teacher]] = {
    teacher.name: teacher
    for teacher in (
        LQRExpert,  # the LQR expert on the simulator's state
        SensedExpert,  # the same on the leg odometry: the pipeline's teacher
        SteppingExpert,  # the LQR expert until the capture point leaves the feet, then a sampling planner
        SensedSteppingExpert,  # the same around the expert on the leg odometry
        Walker,  # the LQR expert while standing, foot placement and whole-body control once it walks or is kicked
        SensedWalker,  # the same on the leg odometry
    )
}
"""Every teacher, by its `name`."""
TEACHER = SensedExpert.name
"""Who demonstrates and labels by default: the expert on leg odometry, whose law a student on what a robot senses can
read (docs/concepts/controllers.md)."""
WALKING_TEACHER = SensedWalker.name
"""Who demonstrates and labels where walking is asked (`make record TASK=walk`, `make dagger` for a walking student):
the walker on leg odometry, whose gait clock such a student computes too (docs/decisions/walking-teacher.md)."""


def teacher_named(name: str, role: str = "teacher") -> type[Teacher]:
    """The teacher registered as `name`; UserError in one line listing the registered ones otherwise."""
    if name not in TEACHERS:
        raise UserError(f"unknown {role} {name!r}; registered teachers: {', '.join(TEACHERS)}")
    return TEACHERS[name]


def able(capability: str) -> tuple[str, ...]:
    """The names of the teachers that declare `capability` (`walks`, `takes_command`)."""
    return tuple(name for name, teacher in TEACHERS.items() if getattr(teacher, capability))
