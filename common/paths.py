"""The default folders of the chained stages and the project's cache: one place, so every stage agrees.

Each stage reads by default what the stage before it writes by default, so `make record`, `make train-bc`,
`make dagger`, `make finetune-rl` and `make eval` chain with no folder named (docs/concepts/layout.md). The Makefile
passes no folder unless the user names one, and `tests/test_makefile.py` holds the two together.
"""

from __future__ import annotations

import os
from pathlib import Path

DATASET = Path("datasets/operator")
"""The operator's demonstrations: `make record` writes them, `make train-bc` and `make dagger` read them."""
BC_POLICY = Path("policies/bc_operator")
"""The deployable student `make train-bc` clones from DATASET."""
DAGGER_DATASET = Path("datasets/operator_dagger")
"""DATASET and the DAgger rounds the teacher labelled (`make dagger`)."""
DAGGER_POLICY = Path("policies/dagger_operator")
"""The student `make dagger` trains where it goes."""
PPO_POLICY = Path("policies/ppo_operator")
"""The actor `make finetune-rl` refines from a student."""
SCRATCH_POLICY = Path("policies/ppo_scratch_operator")
"""PPO from scratch on the same task and budget (`make scratch-rl`)."""
BLIND_POLICY = Path("policies/bc_operator_blind")
"""The student without the operator's command (`make pipeline`): what the command buys."""
TUTORIAL_PREFERRED_POLICY = Path("policies/tutorial_preferred")
"""The seed tutorial's "preferred action" learner (`make tutorial-rl`)."""
TUTORIAL_PPO_POLICY = Path("policies/tutorial_ppo")
"""The seed tutorial's PPO, saved by stable-baselines3 (`make tutorial-rl`)."""

NEWEST = "newest"
"""A policy setting's value that stands for the newest finished checkpoint among the chain's (`policies.folder.newest`):
`STUDENTS` for PPO's start, `LEARNED` for `make eval`, `make robustness` and `make play`."""
STUDENTS = (DAGGER_POLICY, BC_POLICY)
"""The students PPO can start from (`make finetune-rl`, `make scratch-rl`)."""
LEARNED = (PPO_POLICY, DAGGER_POLICY, BC_POLICY)
"""The chain's policies (`make eval`, `make robustness`, `make play`)."""


def cache_dir() -> Path:
    """Cached LQR gains and decoded frames: ``$HUMANOID_BC_CACHE``, else ``~/.cache/humanoid-bc``."""
    return Path(os.environ.get("HUMANOID_BC_CACHE", "~/.cache/humanoid-bc")).expanduser()
