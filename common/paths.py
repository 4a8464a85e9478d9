"""The pipeline's default folders and the project's cache: one place, so every stage agrees.

The stages' configs take their defaults from here; the Makefile passes no folder unless the user
names one, and `tests/test_makefile.py` holds the two together.
"""

from __future__ import annotations

import os
from pathlib import Path

DATASET = Path("datasets/humanoid_stand")
"""Demonstrations `make record` writes and `make train-bc` reads."""
BC_POLICY = Path("policies/bc_humanoid_stand")
"""The behaviour-cloned policy of `make train-bc`."""
OPERATOR_DATASET = Path("datasets/operator_sensed")
"""Demonstrations of the expert on leg odometry following the scripted operator's command schedules (`make
pipeline`)."""
STUDENT_POLICY = Path("policies/bc_operator")
"""Behaviour cloning on what a robot senses, leg odometry, the command in flight and the operator's command
(INPUTS=pending+command), from OPERATOR_DATASET (`make pipeline`)."""
OPERATOR_DAGGER_DATASET = Path("datasets/operator_sensed_dagger")
"""OPERATOR_DATASET and the DAgger rounds the expert on leg odometry labelled (`make pipeline`)."""
DAGGER_STUDENT_POLICY = Path("policies/dagger_operator")
"""DAgger on OPERATOR_DATASET with the command through the expert's ramp (INPUTS=pending+ramp; `make pipeline`):
`make finetune-rl`'s starting actor."""
BLIND_POLICY = Path("policies/bc_operator_blind")
"""The same without the operator's command (INPUTS=pending): what the command buys (`make pipeline`)."""
PPO_POLICY = Path("policies/ppo_operator")
"""The PPO-refined policy of `make finetune-rl`."""
SCRATCH_POLICY = Path("policies/ppo_scratch_operator")
"""PPO from scratch on the same task and budget (`make scratch-rl`)."""
TUTORIAL_PREFERRED_POLICY = Path("policies/tutorial_preferred")
"""The seed tutorial's "preferred action" learner (`make tutorial-rl`)."""
TUTORIAL_PPO_POLICY = Path("policies/tutorial_ppo")
"""The seed tutorial's PPO, saved by stable-baselines3 (`make tutorial-rl`)."""
DAGGER_DATASET = Path("datasets/humanoid_stand_dagger")
"""The aggregate dataset of `make dagger`."""
DAGGER_POLICY = Path("policies/dagger_humanoid_stand")
"""The final policy of `make dagger`."""


def cache_dir() -> Path:
    """Cached LQR gains and decoded frames: ``$HUMANOID_BC_CACHE``, else ``~/.cache/humanoid-bc``."""
    return Path(os.environ.get("HUMANOID_BC_CACHE", "~/.cache/humanoid-bc")).expanduser()
