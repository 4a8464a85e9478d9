"""A dataset's seeds identify its episodes: no seed goes into one dataset twice.

One rule for every way episodes join a dataset: `make record` refuses a SEED whose episodes would repeat seeds
the dataset holds, and `make merge` refuses shards whose seeds overlap; both say which seeds and the next free one.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence


def next_free(recorded: Iterable[int]) -> int:
    """One past the largest seed in `recorded` (0 for none): where appending starts, so that it repeats none."""
    return max(recorded, default=-1) + 1


def seed_clash(new: Sequence[int], recorded: Sequence[int], where: str) -> str | None:
    """Why episodes of seeds `new` may not join those of seeds `recorded` (in `where`), naming the seeds repeated
    and the next free seed; None if none repeats."""
    held = set(recorded)
    repeated = sorted({seed for seed, count in Counter(new).items() if count > 1 or seed in held})
    if not repeated:
        return None
    return (
        f"seeds {_spans(repeated)} are already in {where} (a dataset's seeds identify its episodes, so none is "
        f"recorded twice); the next free seed is {next_free(recorded)}"
    )


def _spans(seeds: list[int], most: int = 3) -> str:
    """Sorted seeds as runs, "0..4, 7, 9..12", the first `most` of them."""
    runs: list[list[int]] = []
    for seed in seeds:
        if runs and seed == runs[-1][1] + 1:
            runs[-1][1] = seed
        else:
            runs.append([seed, seed])
    text = ", ".join(str(a) if a == b else f"{a}..{b}" for a, b in runs[:most])
    return text + (f" and {len(runs) - most} more runs" if len(runs) > most else "")
