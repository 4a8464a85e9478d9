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
"""The behaviour-cloned policy: `make train-bc`'s output, `make finetune-rl`'s starting actor."""
PROPRIO_POLICY = Path("policies/bc_proprio_humanoid_stand")
"""Behaviour cloning on the sensed features of the same demonstrations (`make pipeline`)."""
SENSED_DATASET = Path("datasets/humanoid_stand_sensed")
"""Demonstrations of the expert on leg odometry (`make pipeline`)."""
ODOMETRY_POLICY = Path("policies/bc_odometry_humanoid_stand")
"""Behaviour cloning on the sensed features and leg odometry (and, INPUTS=pending, the command in flight), from
SENSED_DATASET (`make pipeline`)."""
PPO_POLICY = Path("policies/ppo_humanoid_stand")
"""The PPO-refined policy of `make finetune-rl`."""
SCRATCH_POLICY = Path("policies/ppo_scratch_humanoid_stand")
"""PPO from scratch on the same budget (`make baseline-rl`)."""
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
