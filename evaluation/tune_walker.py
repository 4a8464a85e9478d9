"""`make tune-walker`: the walker's free parameters (`teachers.walker.Gait`) tuned by CMA-ES on selection seeds.

Each candidate gait walks the held-out walking schedules' kind of episode on the selection seeds (`--seed`, never an
evaluation's 1000-1019) and stands through kicks, and is scored by `cost`: a fall costs most, then the tracking error
of the speeds once settled. CMA-ES (the `cma` library, Hansen's) searches the parameters scaled to their `BOUNDS` (or
`--bounds`), seeded, so a run repeats; every generation's state is kept in `--run`, so a killed run resumes where it
was. At the end the best gait seen goes to `--out` (by default the resumed run's, else the walker's `GAIT_FILE`) with
the run that chose it. Docs:
docs/decisions/walker-speed.md#the-tuning (the table that chose the default), docs/how-to/walk.md.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cma
import numpy as np
from tqdm import tqdm

from common.cli import (
    Range,
    UserError,
    check_non_negative,
    check_positive,
    check_seed,
    field_default,
    json_text,
    parse_ranges,
    run_cli,
    setting,
)
from common.files import PARTIAL_SUFFIX, write_atomically
from common.seed_ranges import SELECTION_SEED
from evaluation.evaluate import evaluate, evaluation_pool
from task.command_fields import STAND, WALK
from task.gait import GAIT_FILE, Gait, is_gait_file, read_gait, save_gait
from teachers.walker import SensedWalker, Walker

Bounds = dict[str, Range]
"""Each tuned parameter's search range (least, most), in `Gait`'s order."""
BOUNDS: Bounds = {
    "period": (0.25, 0.50),
    "double": (0.0, 0.15),
    "first": (0.3, 1.0),
    "height": (0.70, 0.84),
    "clearance": (0.03, 0.10),
    "width": (0.10, 0.30),
    "min_side": (0.10, 0.20),
    "k_x": (0.5, 1.6),
    "k_y": (0.5, 1.6),
    "pitch": (-0.2, 0.2),
    "waist_roll": (-0.2, 0.2),
    "w_attitude": (4.0, 30.0),
    "w_height": (3.0, 25.0),
    "w_foot": (6.0, 40.0),
    "w_joint": (5.0, 30.0),
    "yaw_single": (0.0, 1.0),
}
"""The search space, each parameter's (least, most), in its unit (`Gait`): a period under 0.25 s or a lift under 3 cm
shuffles the feet over the floor, which the cost's few seeds reward and a longer walk punishes. `--bounds` replaces
some of them for a run (the records' `k_y` within the linear pendulum's stable range:
docs/decisions/walker-sideways.md)."""
BOUNDS_EXAMPLE = "k_y=0.8:1.25"
FALL_COST = 10.0
"""What falling at the start of an episode costs (in proportion to the share of the episode lost), against the
speeds' errors in m/s (a turn's rad/s counts `TuneConfig.turn_weight`): a gait that stands up always beats one that
tracks better."""


@dataclass
class TuneConfig:
    """Settings of one tuning run."""

    generations: int = setting(30, "CMA-ES generations")
    population: int = setting(12, "candidate gaits per generation")
    walks: int = setting(8, "walking schedules per candidate, on seeds SEED, SEED+1, ...")
    kicks: int = setting(4, "kicked standing episodes per candidate, on the same seeds")
    kick: float = setting(0.4, "the kicks' speed, m/s (the suite's kick conditions: directions and times drawn)")
    noise: float = setting(
        0.03, "std of the noise on the walks' executed actions: the DART noise walking demonstrations are recorded with"
    )
    seed: int = setting(SELECTION_SEED, "the first selection seed: evaluations use 1000-1019, recordings 0 upwards")
    cma_seed: int = setting(1, "the CMA-ES sampler's seed: the same run repeats")
    sigma: float = setting(0.15, "CMA-ES's first step size, as a share of each parameter's range")
    bounds: str = setting(
        "",
        f"search ranges that replace those of BOUNDS for this run, NAME=LOW:HIGH,... (e.g. {BOUNDS_EXAMPLE}); a start "
        "outside them starts at the nearest edge",
    )
    turn_weight: float = setting(0.5, "the turn rate's error's weight in the cost (rad/s), the speeds' being 1 (m/s)")
    sensed: bool = setting(
        False, "tune the walker on the leg odometry (walker-sensed) instead of the simulator's state"
    )
    workers: int = setting(2, "processes evaluating candidates at once")
    start: Path | None = setting(
        None,
        "the gait file the search starts from (its centre); default: the tuned one (task/gait.json), or the middle of "
        "the search ranges where that file is missing or of another version",
    )
    run: Path = setting(Path("policies/walker_tuning"), "the run's folder: its state after every generation, its log")
    out: Path | None = setting(
        None,
        "where the best gait goes at the end; default: where the run resumed goes, else the tuned one's file "
        "(task/gait.json)",
    )


def search_bounds(text: str) -> Bounds:
    """`BOUNDS` with the ranges `text` gives instead (`--bounds`: NAME=LOW:HIGH,...; empty, none); UserError, one line,
    for a malformed list, an unknown or repeated parameter, or a range that is not finite with LOW < HIGH."""
    if not text.strip():
        return dict(BOUNDS)
    try:
        return {**BOUNDS, **parse_ranges(text, list(BOUNDS), f"--bounds {text!r}", BOUNDS_EXAMPLE, _check_bound)}
    except ValueError as error:
        raise UserError(str(error)) from None


def _check_bound(name: str, bounds: Range) -> None:
    low, high = bounds
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ValueError(f"{name}'s range must be finite with low < high, got {low:g}:{high:g}")


def scaled(gait: Gait, bounds: Bounds = BOUNDS) -> np.ndarray:
    """The gait's tuned parameters as shares of their `bounds` (0 at the least, 1 at the most)."""
    return np.array([(getattr(gait, name) - low) / (high - low) for name, (low, high) in bounds.items()])


def unscaled(x: np.ndarray, bounds: Bounds = BOUNDS) -> Gait:
    """The gait at shares `x` of `bounds` (clipped into them)."""
    shares = np.clip(x, 0.0, 1.0)
    return Gait(**{name: low + s * (high - low) for (name, (low, high)), s in zip(bounds.items(), shares, strict=True)})


def cost(gait: Gait, cfg: TuneConfig) -> tuple[float, dict[str, float]]:
    """A gait's score on the selection seeds (lower is better) and its parts: `FALL_COST` times the share of the
    episodes' steps lost to falls, plus the walks' mean settled errors of the forward and sideways speeds and
    `turn_weight` times the turn rate's over the commands that asked for that field (`evaluation.evaluate`'s
    tracking, "moved_error"). The walks run under `noise`, as `make record` records them (DART), so the gait
    chosen is one a student can be taught."""
    walker = (SensedWalker if cfg.sensed else Walker)(gait=gait)
    walked = evaluate(walker, cfg.walks, cfg.seed, task=WALK, noise=cfg.noise)
    kicked = evaluate(walker, cfg.kicks, cfg.seed, task=STAND, kick=cfg.kick) if cfg.kicks else None
    lengths = walked["lengths"] + (kicked["lengths"] if kicked else [])
    lost = 1.0 - float(np.mean(lengths)) / 1000.0
    errors = walked["tracking"]["moved_error"]  # over the commands that asked for the field: the walks
    speed = {name: _number(errors[name]) for name in ("forward_speed", "sideways_speed", "turn_rate")}
    total = FALL_COST * lost + speed["forward_speed"] + speed["sideways_speed"] + cfg.turn_weight * speed["turn_rate"]
    parts = {"lost": lost, "walks": walked["survived"], "kicks": kicked["survived"] if kicked else 0, **speed}
    return total, parts


def _number(value: float) -> float:
    """An error the walks never measured (NaN: no walk reached that field) counts as none."""
    return 0.0 if value is None or math.isnan(value) else float(value)


def _cost(x: np.ndarray, cfg: TuneConfig, bounds: Bounds) -> tuple[float, dict[str, float]]:
    return cost(unscaled(x, bounds), cfg)


STATE_FILE = "state.pkl"
"""The run's state in its folder, after every generation: what a run resumes from."""
LOG_FILE = "log.jsonl"
"""A line per generation: its best and mean cost, the best candidate's parts and gait."""
RUN_FILES = {STATE_FILE, LOG_FILE, STATE_FILE + PARTIAL_SUFFIX, "state.partial"}
"""What a run's folder may hold (a run killed in its first generation: its log alone; "state.partial": an earlier
version's staging name)."""
ADDED_SETTINGS = {name: field_default(TuneConfig, name) for name in ("bounds", "turn_weight")}
"""Settings added since runs were first saved, at their defaults: what an older run ran with, so that it resumes."""


def start_gait(start: Path | None, bounds: Bounds, tuned: Path = GAIT_FILE) -> tuple[Gait, dict | None]:
    """The gait a run starts from, and the run that tuned it: `start`'s (UserError in one line if it holds none), or
    the `tuned` one's; where that is missing or of another version (a changed `Gait`), the middle of `bounds`, said
    in one line on stderr."""
    try:
        return read_gait(tuned if start is None else start)
    except ValueError as error:
        if start is not None:
            raise UserError(f"--start: {error}") from None
        print(f"tune-walker: {error}: the search starts at the middle of its ranges", file=sys.stderr)
        return unscaled(np.full(len(bounds), 0.5), bounds), None


def _settings(cfg: TuneConfig) -> dict[str, Any]:
    """What a resumed run must share with the run it resumes (all but how long and how many processes)."""
    return {
        k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("generations", "workers", "run", "out", "start")
    }


def validate(cfg: TuneConfig) -> None:
    """The settings alone, refused in one line before anything runs."""
    check_positive(cfg, "generations", "population", "walks", "workers")
    check_non_negative(cfg, "kicks", "kick", "noise", "turn_weight")
    check_seed(cfg, "seed", "cma_seed")
    if cfg.population < 2:
        raise UserError(f"--population must be at least 2 (CMA-ES ranks its candidates), got {cfg.population}")
    if not (0 < cfg.sigma <= 0.5):
        raise UserError(f"--sigma must be in (0, 0.5], a share of each parameter's range, got {cfg.sigma}")
    if cfg.run.exists() and not cfg.run.is_dir():
        raise UserError(f"--run {cfg.run} is a file: give a folder for the run's state")
    saved = (cfg.run / STATE_FILE).exists()  # a run's folder, whatever else it holds (its OUT, say)
    if cfg.run.is_dir() and not saved and any(path.name not in RUN_FILES for path in cfg.run.iterdir()):
        raise UserError(f"--run {cfg.run} holds files of no tuning run: give another --run")


def check_out(out: Path) -> None:
    """UserError in one line unless `out` may take the gait: a new file, or one that holds a gait (of any version)."""
    if out.is_dir():
        raise UserError(f"--out {out} is a folder: give the gait's file")
    if out.exists() and not is_gait_file(out):
        raise UserError(f"--out {out} holds something other than a walker gait: give another --out")


def read_state(state_file: Path) -> dict[str, Any]:
    """The run saved in `state_file`; UserError in one line where it cannot be read."""
    try:
        with state_file.open("rb") as f:
            return pickle.load(f)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError) as error:
        raise UserError(f"{state_file} holds no tuning run that loads ({error}): give another --run") from None


def main(cfg: TuneConfig) -> dict[str, Any]:
    validate(cfg)
    bounds = search_bounds(cfg.bounds)
    state_file = cfg.run / STATE_FILE
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in _settings(cfg).items()}
    if state_file.exists():
        state = read_state(state_file)
        if {**ADDED_SETTINGS, **state["settings"]} != settings:
            raise UserError(f"{cfg.run} holds a run with other settings ({state['settings']}): give another --run")
        if "out" not in state and cfg.out is None:  # saved before runs kept theirs: it may have begun elsewhere
            raise UserError(
                f"{cfg.run} does not say where its gait goes: give --out ({GAIT_FILE} replaces the tuned one)"
            )
        print(f"tune-walker: resuming {cfg.run} at generation {state['generation']}", file=sys.stderr)
    else:
        start, start_tuning = start_gait(cfg.start, bounds)
        options = {"popsize": cfg.population, "seed": cfg.cma_seed, "bounds": [0.0, 1.0], "verbose": -9}
        state = {
            "settings": settings,
            "es": cma.CMAEvolutionStrategy(np.clip(scaled(start, bounds), 0.0, 1.0), cfg.sigma, options),
            "start": dataclasses.asdict(start),
            "start_tuning": start_tuning,
            "generation": 0,
            "best": (math.inf, None, None),
            "out": None if cfg.out is None else str(cfg.out),
        }
    out = Path(cfg.out or state["out"] or GAIT_FILE)  # a resumed run's, as it began
    check_out(out)
    cfg.run.mkdir(parents=True, exist_ok=True)  # a place the disk refuses: one line (`common.cli.run_cli`)
    es = state["es"]
    with evaluation_pool(cfg.workers) as pool, (cfg.run / LOG_FILE).open("a") as log:
        bar = tqdm(total=cfg.generations, initial=state["generation"], unit="gen", file=sys.stderr, dynamic_ncols=True)
        while state["generation"] < cfg.generations:
            xs = es.ask()
            jobs = [(x, cfg, bounds) for x in xs]
            results = list(pool.map(_cost, *zip(*jobs, strict=True))) if pool else [_cost(*job) for job in jobs]
            costs = [c for c, _ in results]
            es.tell(xs, costs)
            best = int(np.argmin(costs))
            if costs[best] < state["best"][0]:
                state["best"] = (costs[best], np.array(xs[best]), results[best][1])
            state["generation"] += 1
            log.write(
                json_text(
                    {
                        "generation": state["generation"],
                        "best": costs[best],
                        "mean": float(np.mean(costs)),
                        "parts": results[best][1],
                        "gait": dataclasses.asdict(unscaled(xs[best], bounds)),
                    }
                )
                + "\n"
            )
            log.flush()
            _save(state, state_file)
            bar.update()
            bar.set_postfix(best=f"{state['best'][0]:.3f}", generation_best=f"{costs[best]:.3f}")
        bar.close()
    score, x, parts = state["best"]
    gait = unscaled(x, bounds)
    tuning = {
        "command": "make tune-walker",
        "cost": score,
        "parts": parts,
        **settings,
        "generations": state["generation"],
        "start": state["start"],
        "start_tuning": state["start_tuning"],
    }
    try:
        save_gait(gait, out, tuning)
    except OSError as error:
        raise UserError(
            f"cannot write the gait to {out}: {error.strerror or error}; the run is saved in {cfg.run}: run again with "
            "another --out to write it"
        ) from None
    return {"gait": dataclasses.asdict(gait), "tuning": tuning}


def _save(state: dict[str, Any], path: Path) -> None:
    """The run's state, replaced whole (a kill mid-write leaves the previous generation's)."""
    write_atomically(path, lambda partial: partial.write_bytes(pickle.dumps(state)))


def _main_and_print(cfg: TuneConfig) -> None:
    print(json_text(main(cfg)))


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, TuneConfig, argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(cli())
