"""What a teacher declares: the class attributes every registered teacher has (`teachers.registry`).

A teacher is a `rollout.controllers.Controller` a student learns from, built as ``cls(delay=steps)`` (the episode's
action latency, which it may predict through) and told the rest by the rollout. What it can do is declared here once,
on its class, and every stage's choices derive from it: `make record`'s CONTROLLER (a walking task needs one that
walks), `make dagger`'s EXPERT (one that walks for a walking student), `make eval`'s POLICY.
"""

from __future__ import annotations

from typing import ClassVar

from task.handover import HandOver


class Teacher:
    """The capabilities a teacher declares (its subclass overrides those it has)."""

    name: ClassVar[str]
    """Its registered name: CONTROLLER=, EXPERT=, POLICY=, and the dataset's `labeller`."""
    takes_command: ClassVar[bool] = True
    """Whether it follows the operator's posture command."""
    walks: ClassVar[bool] = False
    """Whether it follows the velocity command too (`TASK=walk`)."""
    handover: ClassVar[HandOver | None] = None
    """The rule by which it hands the body from its balance to another law, which a walking student computes
    (`task.handover`); None: one law throughout."""
