"""`make baseline-rl`: PPO from scratch, the yardstick of `make finetune-rl`.

The same network shape, environments and budget as the fine-tuning run, fresh weights (the input
normalisation still comes from the BC checkpoint's data), and none of its guards: no critic
warm-up, no BC term, the critic at the actor's rate, the environment's own rewards.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from bc.finetune import FinetuneConfig, main, print_summary
from common import paths
from common.cli import run_cli, setting


@dataclass
class BaselineConfig(FinetuneConfig):
    """Settings of PPO from scratch: `bc.finetune`'s, with the defaults of an unguarded run."""

    policy: Path = setting(paths.SCRATCH_POLICY, "checkpoint folder to write")
    learning_rate: float = setting(3e-4, "Adam learning rate of the actor (SB3's PPO default)")
    critic_learning_rate: float = setting(3e-4, "Adam learning rate of the critic (the actor's, as in SB3)")
    critic_warmup: int = setting(0, "first steps that train the critic only (actor frozen); 0 = none")

    fresh: ClassVar[bool] = True
    reward_scale: ClassVar[float] = 1.0  # the environment's own rewards


def _main_and_print(cfg: BaselineConfig) -> None:
    print_summary(cfg, main(cfg, made_by="bc.baseline"))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, BaselineConfig, argv, description=__doc__, prog="python -m bc.baseline")


if __name__ == "__main__":
    sys.exit(cli())
