"""Tables of results: each policy's evaluation (POLICY/eval.json) beside the expert's, and the pipeline's closing
table of survival and command tracking (`command_table`).

python -m bc.report policies/bc_humanoid_stand [more checkpoint folders ...]
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from common.keys import COMMAND_NAMES
from humanoid.commands import tracking_score
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


def _survivors(row: dict[str, Any]) -> str:
    return f"{round(row['survival_rate'] * row['episodes'])}/{row['episodes']}"


def _number(value: float, digits: int) -> str:
    return "n/a" if math.isnan(value) else f"{value:.{digits}f}"


def command_table(standing: dict[str, dict[str, Any]], tracked: dict[str, dict[str, Any]]) -> str:
    """The pipeline's closing table, in two parts. First a row per controller: survivors with the command zero
    (`standing`: one evaluation each, clean), then, on held-out command schedules (`tracked`: `bc.robustness`
    results under schedules), survivors and the tracking score (`humanoid.commands.tracking_score`: 1 on the
    command) per condition, and the mean return over the conditions (what "× scratch" compares). Then a row per
    condition and controller: the settled tracking error per command field and the time to settle."""
    first = next(iter(tracked.values()))
    names = list(first["conditions"])
    head = "| controller | standing | " + " | ".join(names) + " | mean return |"
    rows = [head, "|---|---|" + "---|" * len(names) + "---|"]
    for controller, result in tracked.items():
        conditions = result["conditions"]
        cells = [f"{_survivors(c)} · {tracking_score(c['tracking']):.2f}" for c in conditions.values()]
        mean_return = sum(c["mean_return"] for c in conditions.values()) / len(conditions)
        rows.append(f"| {controller} | {_survivors(standing[controller])} | {' | '.join(cells)} | {mean_return:,.1f} |")
    seeds = first["seeds"]
    rows += [
        "",
        f"(survivors · tracking score, 1 = on the command, on held-out schedules, seeds {seeds[0]}..{seeds[-1]}; "
        "standing: the same seeds with the command zero; the conditions: docs/concepts/robustness-suite.md)",
        "",
        "| condition | controller | survivors | " + " | ".join(COMMAND_NAMES) + " | settle (s) |",
        "|---|---|---|" + "---|" * len(COMMAND_NAMES) + "---|",
    ]
    for name in names:
        for controller, result in tracked.items():
            row = result["conditions"][name]
            errors = " | ".join(_number(row["tracking"]["settled_error"][field], 3) for field in COMMAND_NAMES)
            settle = _number(row["tracking"]["settle_seconds"], 2)
            rows.append(f"| {name} | {controller} | {_survivors(row)} | {errors} | {settle} |")
    rows.append("\n(settled tracking error per command field: rad, height in m; n/a: fell before any command settled)")
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
