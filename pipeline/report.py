"""The pipeline's closing table: survival and command tracking of the experts and every policy (`command_table`)."""

from __future__ import annotations

from typing import Any

from task.tracking import error_text, tracked_names, tracking_score


def survivors(row: dict[str, Any]) -> int:
    """Episodes of an evaluation (`evaluation.evaluate.evaluate`'s result, a suite's condition) that ran to the end."""
    return round(row["survival_rate"] * row["episodes"])


def mean_return(result: dict[str, Any]) -> float:
    """A suite's mean return over its conditions (`evaluation.robustness`'s result): what "× scratch" compares."""
    conditions = result["conditions"]
    return sum(c["mean_return"] for c in conditions.values()) / len(conditions)


def _survivors(row: dict[str, Any]) -> str:
    return f"{survivors(row)}/{row['episodes']}"


def command_table(standing: dict[str, dict[str, Any]], tracked: dict[str, dict[str, Any]]) -> str:
    """The pipeline's closing table, in two parts. First a row per controller: survivors with the command zero
    (`standing`: one evaluation each, clean), then, on held-out command schedules (`tracked`: `evaluation.robustness`
    results under schedules), survivors and the tracking score (`task.tracking.tracking_score`: 1 on the
    command) per condition, and the mean return over the conditions (what "× scratch" compares). Then a row per
    condition and controller: the settled tracking error per command field, over every command held and over those
    that move the field (where a policy that holds the stand but ignores a field shows it), and the time to settle."""
    first = next(iter(tracked.values()))
    names = list(first["conditions"])
    head = "| controller | standing | " + " | ".join(names) + " | mean return |"
    rows = [head, "|---|---|" + "---|" * len(names) + "---|"]
    for controller, result in tracked.items():
        conditions = result["conditions"]
        cells = [f"{_survivors(c)} · {tracking_score(c['tracking']):.2f}" for c in conditions.values()]
        rows.append(
            f"| {controller} | {_survivors(standing[controller])} | {' | '.join(cells)} | {mean_return(result):,.1f} |"
        )
    seeds, fields = first["seeds"], tracked_names(next(iter(first["conditions"].values()))["tracking"])
    rows += [
        "",
        f"(survivors · tracking score, 1 = on the command, on held-out schedules, seeds {seeds[0]}..{seeds[-1]}; "
        "standing: the same seeds with the command zero; the conditions: docs/concepts/robustness-suite.md)",
        "",
        "| condition | controller | survivors | " + " | ".join(fields) + " | settle (s) |",
        "|---|---|---|" + "---|" * len(fields) + "---|",
    ]
    for name in names:
        for controller, result in tracked.items():
            row = result["conditions"][name]
            held, moved = row["tracking"]["settled_error"], row["tracking"]["moved_error"]
            errors = " | ".join(f"{error_text(held[field])} / {error_text(moved[field])}" for field in fields)
            settle = error_text(row["tracking"]["settle_seconds"], 2)
            rows.append(f"| {name} | {controller} | {_survivors(row)} | {errors} | {settle} |")
    rows.append(
        "\n(settled tracking error per command field, over every command held / over those that move the field away"
        " from neutral: rad, height in m; n/a: fell before any such command settled)"
    )
    return "\n".join(rows)
