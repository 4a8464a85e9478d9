"""The pipeline's closing table: each policy's evaluation (POLICY/eval.json) beside the expert's.

python -m bc.report policies/bc_humanoid_stand [more checkpoint folders ...]
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from policies.folder import EVAL_FILE


def table(policy_dirs: Sequence[Path]) -> str:
    """A Markdown table, one row per evaluated policy and one for the expert (from the first that has it)."""
    evaluations = {path: json.loads((path / EVAL_FILE).read_text()) for path in policy_dirs}
    reference = next((ev for ev in evaluations.values() if ev.get("expert_mean_return")), None)
    expert = reference["expert_mean_return"] if reference else None
    rows = ["| policy | seeds | survival | mean return | vs expert |", "|---|---|---|---|---|"]
    for path, ev in evaluations.items():
        versus = f"{ev['mean_return'] / expert:.1%}" if expert else "n/a"
        rows.append(
            f"| {path} | {ev['seeds'][0]}..{ev['seeds'][-1]} | {ev['survival_rate']:.0%} | "
            f"{ev['mean_return']:,.1f} ± {ev['std_return']:,.1f} | {versus} |"
        )
    if reference:
        rows.append(
            f"| expert (LQR) | {reference['seeds'][0]}..{reference['seeds'][-1]} | "
            f"{reference['expert_survival_rate']:.0%} | {expert:,.1f} | 100.0% |"
        )
    return "\n".join(rows)


def suite_table(results: dict[str, dict[str, Any]]) -> str:
    """A Markdown table of robustness results (`bc.robustness` JSON) per policy: the clean mean return, the
    mean return over the suite's conditions (what the RL issue's "× scratch under the suite" compares), and
    survivors per condition."""
    names = list(next(iter(results.values()))["conditions"])
    head = "| policy | clean return | suite mean return | " + " | ".join(names) + " |"
    rows = [head, "|---|---|---|" + "---|" * len(names)]
    for policy, result in results.items():
        conditions = result["conditions"]
        suite_mean = sum(c["mean_return"] for c in conditions.values()) / len(conditions)
        cells = [f"{round(c['survival_rate'] * c['episodes'])}/{c['episodes']}" for c in conditions.values()]
        returns = f"{conditions['clean']['mean_return']:,.1f} | {suite_mean:,.1f}"
        rows.append(f"| {policy} | {returns} | " + " | ".join(cells) + " |")
    seeds = next(iter(results.values()))["seeds"]
    rows.append(
        f"\n(survivors per condition, seeds {seeds[0]}..{seeds[-1]}; what each is: docs/concepts/robustness-suite.md)"
    )
    return "\n".join(rows)


def main(argv: Sequence[str] | None = None) -> int:
    paths = [Path(arg) for arg in (sys.argv[1:] if argv is None else argv)]
    missing = [str(path / EVAL_FILE) for path in paths if not (path / EVAL_FILE).is_file()]
    if not paths or missing:
        print(f"error: no evaluation at {', '.join(missing) or '(no folder given)'}", file=sys.stderr)
        return 1
    print(table(paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
