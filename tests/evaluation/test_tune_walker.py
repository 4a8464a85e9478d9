"""`make tune-walker`: CMA-ES over the walker's gait on selection seeds, resumable, its best gait written with the run
that chose it (its start too); a resumed run with other settings is refused in one line."""

from __future__ import annotations

import json
import pickle
from dataclasses import asdict

import numpy as np
import pytest

from common.cli import UserError
from evaluation import tune_walker
from evaluation.tune_walker import BOUNDS, TuneConfig, cli, scaled, search_bounds, start_gait, unscaled
from task.gait import GAIT_FILE, Gait, load_gait


def test_a_gait_scales_into_its_bounds_and_back() -> None:
    gait = load_gait()
    assert asdict(unscaled(scaled(gait))) == pytest.approx(asdict(gait))
    lowest = unscaled(np.full(len(BOUNDS), -1.0))  # clipped into the bounds
    assert all(getattr(lowest, name) == low for name, (low, _) in BOUNDS.items())
    assert set(BOUNDS) == {field for field in Gait.__dataclass_fields__}


def test_bounds_given_replace_those_ranges_only() -> None:
    """Known answers: `k_y` searched over 0.8-1.25 (the linear pendulum's stable range), the rest as BOUNDS has them;
    the tuned gait's `k_y` 1.48 lies past it, and its share is clipped back to the edge."""
    bounds = search_bounds(" k_y = 0.8:1.25 ")
    assert bounds == {**BOUNDS, "k_y": (0.8, 1.25)} and list(bounds) == list(BOUNDS)
    gait = load_gait()
    shares = scaled(gait, bounds)
    assert shares[list(BOUNDS).index("k_y")] == pytest.approx((gait.k_y - 0.8) / 0.45)
    assert unscaled(shares, bounds).k_y == 1.25 and unscaled(shares, bounds).period == pytest.approx(gait.period)
    assert search_bounds("") == BOUNDS


@pytest.mark.parametrize(
    "text, problem",
    [
        ("k_z=0.8:1.2", "unknown parameter 'k_z'"),
        ("k_y=1.25:0.8", "k_y's range must be finite with low < high, got 1.25:0.8"),
        ("k_y=1:1", "low < high"),
        ("k_y=0.8", "is not NAME=LOW:HIGH (e.g. k_y=0.8:1.25)"),
        ("k_y=0.8:1.2,k_y=0.9:1", "k_y is given twice"),
    ],
)
def test_bad_bounds_are_one_line_and_leave_no_run(text: str, problem: str, tmp_path, capsys) -> None:
    code = cli(["--bounds", text, "--run", str(tmp_path / "run"), "--out", str(tmp_path / "gait.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and err[0].startswith(f"error: --bounds {text!r}: ") and problem in err[0], err
    assert not (tmp_path / "run").exists() and not (tmp_path / "gait.json").exists()


@pytest.mark.slow
def test_a_killed_tuning_run_resumes_and_writes_its_best_gait(tmp_path, monkeypatch) -> None:
    """One generation, then the run asked for two more resumes at the second (its log grows by one line per
    generation) and, given no `--out`, writes where the run began writing, not over the tuned gait (a run saved
    before runs kept theirs is refused); the gait file holds the best candidate, within the run's `--bounds` (the
    tuned gait's `k_y` 1.48 starts at their edge), and the run's settings; other settings are refused."""
    run, out = tmp_path / "run", tmp_path / "gait.json"
    settings = {"population": 2, "walks": 1, "kicks": 0, "workers": 1, "run": run, "out": out, "bounds": "k_y=0.8:1.25"}
    tuned = tmp_path / "tuned.json"  # where a run without --out writes: not the checkout's gait, should this fail
    monkeypatch.setattr(tune_walker, "GAIT_FILE", tuned)
    tune_walker.main(TuneConfig(generations=1, **settings))
    first = json.loads(out.read_text())
    tune_walker.main(TuneConfig(generations=2, **{**settings, "out": None}))
    assert not tuned.exists()
    lines = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [line["generation"] for line in lines] == [1, 2]
    saved = json.loads(out.read_text())
    assert saved["tuning"]["generations"] == 2 and saved["tuning"]["population"] == 2
    assert saved["tuning"]["bounds"] == "k_y=0.8:1.25" and 0.8 <= saved["gait"]["k_y"] <= 1.25
    assert saved["tuning"]["cost"] <= first["tuning"]["cost"]
    assert saved["tuning"]["cost"] == pytest.approx(min(line["best"] for line in lines))
    assert saved["tuning"]["start"] == asdict(load_gait())  # where it started: the tuned gait, by default
    load_gait(out)  # a gait file the walker reads
    with pytest.raises(UserError, match="other settings"):
        tune_walker.main(TuneConfig(generations=3, **{**settings, "population": 3}))
    # A run saved before `--turn-weight` existed ran with its default: it resumes; one saved before runs kept their
    # `--out` is told to give it.
    state = pickle.loads((run / "state.pkl").read_bytes())
    del state["settings"]["turn_weight"], state["out"]
    (run / "state.pkl").write_bytes(pickle.dumps(state))
    with pytest.raises(UserError, match=r"does not say where its gait goes: give --out"):
        tune_walker.main(TuneConfig(generations=3, **{**settings, "out": None}))
    tune_walker.main(TuneConfig(generations=3, **settings))
    assert json.loads(out.read_text())["tuning"]["generations"] == 3


def test_a_run_starts_from_start_or_the_tuned_gait_or_the_middle_of_the_ranges(tmp_path, capsys) -> None:
    """`--start` naming no gait is one line; without it the tuned gait, and where that file is missing (or of another
    version) the middle of the ranges, said in one line: `make tune-walker` makes a gait file from none."""
    assert start_gait(None, BOUNDS) == (load_gait(), json.loads(GAIT_FILE.read_text())["tuning"])
    with pytest.raises(UserError, match=r"^--start: .*none\.json holds no walker gait of version") as missing:
        start_gait(tmp_path / "none.json", BOUNDS)
    assert "\n" not in str(missing.value)
    capsys.readouterr()
    gait, tuning = start_gait(None, BOUNDS, tuned=tmp_path / "none.json")
    assert tuning is None and gait.period == pytest.approx(0.375) and gait.k_y == pytest.approx(1.05)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("the search starts at the middle of its ranges"), err


@pytest.mark.parametrize(
    "args, problem",
    [
        (["--population", "1"], "--population must be at least 2"),
        (["--seed", "-1"], "--seed must be a seed, at least 0 and below 2**32, got -1"),
        (["--cma-seed", str(2**32)], "--cma-seed must be a seed"),
        (["--out", "{tmp}/notes.txt"], "--out {tmp}/notes.txt holds something other than a walker gait"),
        (["--out", "{tmp}"], "is a folder: give the gait's file"),
        (["--run", "{tmp}/notes.txt"], "is a file: give a folder for the run's state"),
        (["--run", "{tmp}"], "holds files of no tuning run: give another --run"),
    ],
)
def test_bad_places_and_settings_are_one_line_before_any_search(args, problem, tmp_path, capsys) -> None:
    """An OUT that holds something else than a gait, or a RUN folder of something else, is refused before the search
    (the file is not replaced, nothing is written in the folder), as are settings CMA-ES cannot run."""
    notes = tmp_path / "notes.txt"
    notes.write_text("not a gait")
    places = {"--run": str(tmp_path / "run"), "--out": str(tmp_path / "gait.json")}
    given = [arg.format(tmp=tmp_path) for arg in args]
    places.update(dict(zip(given[::2], given[1::2], strict=True)))
    code = cli([item for pair in places.items() for item in pair])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and problem.format(tmp=tmp_path) in err[0], err
    assert notes.read_text() == "not a gait" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_a_run_killed_in_its_first_generation_is_run_again(tmp_path) -> None:
    """Its folder holds its log alone (the state is saved at a generation's end): the same RUN is taken, not refused
    as another's folder."""
    run = tmp_path / "run"
    run.mkdir()
    (run / tune_walker.LOG_FILE).write_text("")
    tune_walker.validate(TuneConfig(run=run))
    (run / "notes.txt").write_text("")
    with pytest.raises(UserError, match="holds files of no tuning run"):
        tune_walker.validate(TuneConfig(run=run))
    (run / tune_walker.STATE_FILE).write_bytes(b"")  # a saved run resumes whatever else its folder holds (its OUT)
    tune_walker.validate(TuneConfig(run=run))
