"""`make scratch-rl`: PPO from scratch, the yardstick of `make finetune-rl`.

The same network shape, environments and budget as the fine-tuning run, fresh weights (the input
normalisation still comes from the BC checkpoint's data), and the same PPO clip range, target KL and
clipped critic inputs, so that the two differ only in their start and the guards against forgetting.
Those it drops: no critic warm-up, the actor and the critic both at SB3's default rate, the
environment's own rewards, and no keep rule (the last actor is kept: a random start is no floor).
What each guard is for: docs/decisions/ppo-guards.md.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from common import paths
from common.cli import run_cli, setting
from rl.finetune import FinetuneConfig, main, print_summary


@dataclass
class ScratchConfig(FinetuneConfig):
    """Settings of PPO from scratch: `rl.finetune`'s, with the guards against forgetting off."""

    policy: Path = setting(paths.SCRATCH_POLICY, "checkpoint folder to write")
    learning_rate: float = setting(3e-4, "Adam learning rate of the actor (SB3's PPO default)")
    critic_learning_rate: float = setting(3e-4, "Adam learning rate of the critic (the actor's, as in SB3)")
    critic_warmup: int = setting(0, "first steps that train the critic only (actor frozen); 0 = none")

    fresh: ClassVar[bool] = True
    reward_scale: ClassVar[float] = 1.0  # the environment's own rewards
    OWN: ClassVar[tuple[str, ...]] = ("policy", "learning_rate", "critic_learning_rate", "critic_warmup")
    """The settings it has otherwise than fine-tuning (the rest are `make finetune-rl`'s: `make pipeline` runs both
    with the same)."""


def _main_and_print(cfg: ScratchConfig) -> None:
    print_summary(cfg, main(cfg, made_by="rl.scratch"))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, ScratchConfig, argv, description=__doc__, prog="python -m rl.scratch")


if __name__ == "__main__":
    sys.exit(cli())
