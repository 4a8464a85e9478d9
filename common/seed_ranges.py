"""Which seeds each use takes, in one place: an episode is fixed by its seed, so no two uses may share one.

0 ..            recordings (`make record` continues a dataset's seeds; DAgger's rounds continue its dataset's)
EVAL_SEED ..    held-out evaluations (`make eval`, the robustness suite, the pipeline's table, a stage's final one)
VALIDATION_SEED ..  PPO's evaluations during training, which choose the actor kept
SELECTION_SEED ..   comparisons that pick a default (docs/decisions/): never the held-out ones
TRAINING_SEEDS  the schedules PPO's training episodes draw
"""

EVAL_SEED = 1000
"""First held-out evaluation seed: recordings use 0, 1, 2, ... and stay far below it."""
VALIDATION_SEED = 2000
"""First seed of PPO's evaluations during training (they choose the actor kept): apart from EVAL_SEED's."""
SELECTION_SEED = 3000
"""First seed of the comparisons that choose a default (docs/decisions/), so no held-out seed picks one."""
TRAINING_SEEDS = (1_000_000, 2**31 - 1)
"""PPO's training episodes draw their schedule's seed from here: never a recording's or an evaluation's."""
RUN_SEED_LIMIT = 2**32
"""A run's own seeds (its learner's, its sampler's, its first episode's) lie below this: CMA-ES takes 32 bits, torch
overflows past 63 (`common.cli.check_seed`)."""
SEED_LIMIT = 2**63
"""Seeds a dataset can hold: below this (an int64 column)."""
