"""`make robustness`: a policy (or the expert) on the same seeds under every condition of the suite.

    conditions x seeds --(chunks, over the cores: WORKERS)--> rollouts under `Condition.wrap` --> per condition:
    survival rate, mean return (and, pushed, which directions toppled it) --> a table,
    POLICY/robustness.json, POLICY/robustness.png, and the JSON summary as the last line printed

The conditions (`humanoid.conditions.SUITE`) and their magnitudes: docs/concepts/robustness-suite.md.
"""

from __future__ import annotations

import dataclasses
import itertools
import sys
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from common import paths
from common.cli import (
    UserError,
    check_positive,
    check_seed,
    config_dict,
    flag,
    json_text,
    run_cli,
    setting,
    write_json,
)
from common.figures import save_figure
from common.paths import NEWEST
from common.seed_ranges import EVAL_SEED
from common.workers import default_workers
from evaluation.evaluate import POLICY_HELP, evaluate_each, evaluation_pool, init_worker
from humanoid.conditions import SUITE, condition
from policies.folder import chosen_policy
from rollout.controllers import check_controller, registered
from task.command_fields import POSTURE_TASK, STAND, TASKS, WALK
from task.tracking import combine_tracking, error_text, tracked_names

SECTOR_DEGREES = 45
"""Width of the push-direction sectors, centred on forward (0), left (90), back (180), right (-90) and between."""
RESULT_FILE = "robustness.json"
FIGURE_FILE = "robustness.png"
SUFFIXES = {STAND: "", POSTURE_TASK: "_schedules", WALK: "_walk"}
"""The files of each task: robustness.json and .png standing, robustness_schedules.* under posture schedules,
robustness_walk.* under walking ones: a policy keeps every task's results."""
CONTROLLER_FOLDER = Path("policies")
"""Where a registered controller's results go (`policies/expert/`): it has no checkpoint folder of its own."""


# The episodes of each condition run in two chunks (`run_suite`), independent of each other: more workers than the
# full suite's chunks would wait.
MOST_WORKERS = 2 * len(SUITE)


@dataclass
class RobustnessConfig:
    """Settings of one robustness run."""

    policy: str = setting(NEWEST, POLICY_HELP)
    episodes: int = setting(20, "episodes per condition (seeds SEED..SEED+EPISODES-1, the same for every condition)")
    seed: int = setting(EVAL_SEED, "seed of the first episode")
    conditions: str = setting("all", f"comma-separated conditions, or 'all': {', '.join(SUITE)}")
    task: str = setting(
        POSTURE_TASK,
        "what the operator commands (evaluation.evaluate --task): the held-out posture schedule of each seed, rows "
        "adding tracking; walk: walks mixed in; stand: the zero command",
        choices=TASKS,
    )
    workers: int | None = setting(
        None, f"processes the episodes are spread over; default: the machine's cores, at most {MOST_WORKERS}"
    )
    output: Path | None = setting(
        None,
        f"folder for {RESULT_FILE} and {FIGURE_FILE} (robustness{SUFFIXES[POSTURE_TASK]}.* under --task "
        f"{POSTURE_TASK}, robustness{SUFFIXES[WALK]}.* under --task {WALK}; default: POLICY's folder)",
    )
    progress: bool = setting(True, "show a progress bar")


def selected(cfg: RobustnessConfig) -> list[str]:
    names = list(SUITE) if cfg.conditions == "all" else [n.strip() for n in cfg.conditions.split(",") if n.strip()]
    for name in names:
        try:
            condition(name)
        except ValueError as error:
            raise UserError(str(error)) from None
    if not names:
        raise UserError(f"{flag('conditions')} names no condition")
    twice = next((name for i, name in enumerate(names) if name in names[:i]), None)
    if twice is not None:  # its row would merge both runs of the same seeds
        raise UserError(f"{flag('conditions')} names {twice} twice")
    return names


def validate(cfg: RobustnessConfig) -> list[str]:
    """Reject bad settings before anything runs; returns the conditions to run."""
    check_positive(cfg, "episodes", "workers")
    check_seed(cfg, "seed")
    try:
        check_controller(cfg.policy, interactive=False)
    except ValueError as error:
        raise UserError(str(error)) from None
    return selected(cfg)


def output_folder(cfg: RobustnessConfig) -> Path:
    if cfg.output is not None:
        return cfg.output
    return CONTROLLER_FOLDER / cfg.policy if cfg.policy in registered() else Path(cfg.policy)


def worker_count(workers: int | None) -> int:
    """The processes a suite runs on: `workers`, or by default the machine's cores, at most MOST_WORKERS."""
    return default_workers(MOST_WORKERS) if workers is None else workers


def result_paths(cfg: RobustnessConfig) -> tuple[Path, Path]:
    """Where `cfg`'s results and figure go."""
    folder, suffix = output_folder(cfg), SUFFIXES[cfg.task]
    return tuple(folder / name.replace(".", f"{suffix}.") for name in (RESULT_FILE, FIGURE_FILE))


def push_sectors(directions: list[float], toppled: list[bool]) -> dict[str, list]:
    """Pushes and the pushes that toppled the body per direction sector (`SECTOR_DEGREES` wide, centred on
    0, 45, ..., -45: the direction seen from the torso, 0 forward, 180 back)."""
    centres = np.arange(-180 + SECTOR_DEGREES, 181, SECTOR_DEGREES)
    nearest = np.round(np.asarray(directions, dtype=float) / SECTOR_DEGREES).astype(int)  # in centre steps
    index = (nearest - centres[0] // SECTOR_DEGREES) % len(centres)  # -180 and 180 fall in one sector
    pushes = np.bincount(index, minlength=len(centres))
    fell = np.bincount(index, weights=np.asarray(toppled, dtype=float), minlength=len(centres))
    return {"centres": centres.tolist(), "pushes": pushes.tolist(), "toppled": fell.astype(int).tolist()}


def summarise(chunks: list[dict[str, Any]]) -> dict[str, Any]:
    """One condition's row from its chunks' evaluations, in seed order."""
    chunks = sorted(chunks, key=lambda chunk: chunk["seeds"][0])
    returns = np.array([r for chunk in chunks for r in chunk["returns"]])
    directions = [d for chunk in chunks for d in chunk["pushes"]["direction"]]
    toppled = [t for chunk in chunks for t in chunk["pushes"]["toppled"]]
    pushed = {"push_sectors": push_sectors(directions, toppled)} if directions else {}
    if chunks[0]["tracking"] is not None:
        pushed["tracking"] = combine_tracking([e for chunk in chunks for e in chunk["tracking"]["episodes"]])
    if chunks[0].get("kick"):
        pushed["kick"] = chunks[0]["kick"]  # its speed (m/s) and impulse (N·s)
    return {
        "survival_rate": float(np.mean([s for chunk in chunks for s in chunk["survivals"]])),
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "episodes": len(returns),
        "returns": returns.tolist(),
        "lengths": [n for chunk in chunks for n in chunk["lengths"]],
        "parameters": [p for chunk in chunks for p in chunk["parameters"]],
        **pushed,
    }


@dataclass(frozen=True)
class SuiteRuns:
    """A suite's evaluations (`evaluate_each`'s runs: each condition's seeds in chunks), and its rows from their
    results. A caller may submit several suites' runs at once, as the pipeline's table does."""

    names: list[str]
    runs: list[tuple[str, dict[str, Any]]]

    def rows(self, evaluations: Iterable[dict[str, Any]]) -> dict[str, dict[str, Any]]:
        """The results per condition from the runs' evaluations, in the runs' order."""
        chunks: dict[str, list] = {name: [] for name in self.names}
        for (_, settings), evaluation in zip(self.runs, evaluations, strict=True):
            chunks[settings["condition"]].append(evaluation)
        return {name: summarise(chunks[name]) for name in self.names}


def suite_runs(policy: str, names: list[str], seeds: range, workers: int, task: str = STAND) -> SuiteRuns:
    """Every condition in `names` on `seeds` (the operator commanding `task`), in chunks for `workers` processes."""
    chunk = max(1, len(seeds) // 2) if workers > 1 else len(seeds)
    return SuiteRuns(
        names,
        [
            (policy, {"episodes": len(part), "seed": part.start, "condition": name, "task": task})
            for name in names
            for part in (seeds[i : i + chunk] for i in range(0, len(seeds), chunk))
        ],
    )


def evaluate_suites(suites: Sequence[SuiteRuns], workers: int, bar: tqdm | None = None) -> Iterator[dict[str, Any]]:
    """Each suite's rows, in order, its runs and every other's submitted at once to one pool of `workers` processes
    (no worker waits at a suite's end for the next one's runs); `bar` counts the episodes done."""
    if workers == 1:
        init_worker()  # this process evaluates: the same setting as a worker's
    with evaluation_pool(workers) as pool:
        evaluations = evaluate_each([run for suite in suites for run in suite.runs], pool)
        for suite in suites:
            done = []
            for evaluation in itertools.islice(evaluations, len(suite.runs)):
                done.append(evaluation)
                if bar is not None:
                    bar.update(evaluation["episodes"])
            yield suite.rows(done)


def run_suite(
    policy: str, names: list[str], seeds: range, workers: int, progress: bool = False, task: str = STAND
) -> dict:
    """Every condition in `names` on `seeds` (the operator commanding `task`), in chunks over `workers` processes;
    results per condition."""
    with tqdm(
        total=len(names) * len(seeds), unit="ep", disable=not progress, file=sys.stderr, dynamic_ncols=True
    ) as bar:
        [rows] = evaluate_suites([suite_runs(policy, names, seeds, workers, task)], workers, bar)
    return rows


def plot(result: dict[str, Any], path: Path) -> None:
    """Survival rate and mean return per condition, side by side; pushed, the share of pushes that toppled the
    body by direction (sectors without a push left out), on a dial seen from above with the body facing up."""
    names = list(result["conditions"])
    pushed = [n for n in names if "push_sectors" in result["conditions"][n]]
    panels = 3 if pushed else 2
    figure = Figure(figsize=(13 if pushed else 9, 4))
    survival = figure.add_subplot(1, panels, 1)
    returns = figure.add_subplot(1, panels, 2)
    survival.bar(names, [100 * result["conditions"][n]["survival_rate"] for n in names], color="tab:green")
    survival.set_ylabel("survival (%)")
    survival.set_ylim(0, 100)
    returns.bar(names, [result["conditions"][n]["mean_return"] for n in names], color="tab:blue")
    returns.set_ylabel("mean return")
    for axes in (survival, returns):
        axes.tick_params(axis="x", rotation=60)
    if pushed:
        dial = figure.add_subplot(1, panels, 3, projection="polar")
        dial.set_theta_zero_location("N")  # forward up, left to the left: the body seen from above
        for name in pushed:
            sectors = result["conditions"][name]["push_sectors"]
            pushes = np.asarray(sectors["pushes"], dtype=float)
            share = np.divide(sectors["toppled"], pushes, out=np.full(len(pushes), np.nan), where=pushes > 0)
            angles = np.radians(sectors["centres"] + sectors["centres"][:1])
            dial.plot(angles, 100 * np.append(share, share[0]), marker="o", label=name)
        dial.set_ylim(0, 100)
        dial.set_xticks(np.radians([0, 90, 180, 270]), ["forward", "left", "back", "right"])
        dial.set_title("pushes that toppled it (%), by direction", fontsize=9)
        dial.legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.25, -0.15))
    seeds = result["seeds"]
    figure.suptitle(f"{result['policy']}: {len(seeds)} episodes per condition, seeds {seeds[0]}..{seeds[-1]}")
    figure.tight_layout()
    save_figure(figure, path)


def table(result: dict[str, Any]) -> str:
    rows = list(result["conditions"].values())
    tracked = tracked_names(rows[0]["tracking"]) if all(row.get("tracking") for row in rows) else ()
    lines = [f"{'condition':<10} {'survival':>9} {'mean return':>12}" + "".join(f" {name:>12}" for name in tracked)]
    for name, row in result["conditions"].items():
        errors = "".join(f" {error_text(row['tracking']['settled_error'][field]):>12}" for field in tracked)
        lines.append(f"{name:<10} {row['survival_rate']:>8.0%} {row['mean_return']:>12.1f}{errors}")
    for name, row in result["conditions"].items():
        if "push_sectors" in row:
            sectors = row["push_sectors"]
            counts = zip(sectors["centres"], sectors["toppled"], sectors["pushes"], strict=True)
            shares = ", ".join(f"{centre}: {fell}/{pushes}" for centre, fell, pushes in counts)
            what = f"kicks of {row['kick']['impulse']:g} N·s" if "kick" in row else "pushes"
            lines.append(f"{name} {what} that toppled it, by direction (0 forward, 90 left, 180 back): {shares}")
    return "\n".join(lines)


def main(cfg: RobustnessConfig) -> dict[str, Any]:
    """Run the suite as configured; writes the results and the figure (`result_paths`), returns the summary."""
    cfg = dataclasses.replace(cfg, policy=chosen_policy(cfg.policy, paths.LEARNED, "make train-bc"))
    names = validate(cfg)
    seeds = range(cfg.seed, cfg.seed + cfg.episodes)
    return save(cfg, run_suite(cfg.policy, names, seeds, worker_count(cfg.workers), cfg.progress, cfg.task))


def save(cfg: RobustnessConfig, conditions: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The result of `cfg`'s suite from its rows per condition, written with its figure (`result_paths`)."""
    result_path, figure_path = result_paths(cfg)
    seeds = range(cfg.seed, cfg.seed + cfg.episodes)
    result = {"policy": cfg.policy, "seeds": list(seeds), "conditions": conditions, "config": config_dict(cfg)}
    try:
        result_path.parent.mkdir(parents=True, exist_ok=True)
        write_json(result_path, result, indent=1)  # `make pipeline` reuses it
        plot(result, figure_path)
    except OSError as error:
        raise UserError(f"cannot write the results to {result_path.parent}: {error.strerror or error}") from None
    return result


def _main_and_print(cfg: RobustnessConfig) -> None:
    result = main(cfg)
    print(table(result))
    brief = {
        k: {m: v[m] for m in ("survival_rate", "mean_return", "episodes", "tracking") if m in v}
        for k, v in result["conditions"].items()
    }
    print(json_text({"policy": result["policy"], "seeds": result["seeds"], "conditions": brief}))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, RobustnessConfig, argv, description=__doc__, prog="python -m evaluation.robustness")


if __name__ == "__main__":
    sys.exit(cli())
