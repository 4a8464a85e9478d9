"""`make tune-walker`: CMA-ES over the walker's gait on selection seeds, resumable, its best gait written with the run
that chose it (its start too); a resumed run with other settings is refused in one line."""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest

from common.cli import UserError
from evaluation import tune_walker
from evaluation.tune_walker import BOUNDS, TuneConfig, scaled, unscaled
from task.gait import Gait, load_gait


def test_a_gait_scales_into_its_bounds_and_back() -> None:
    gait = load_gait()
    assert asdict(unscaled(scaled(gait))) == pytest.approx(asdict(gait))
    lowest = unscaled(np.full(len(BOUNDS), -1.0))  # clipped into the bounds
    assert all(getattr(lowest, name) == low for name, (low, _) in BOUNDS.items())
    assert set(BOUNDS) == {field for field in Gait.__dataclass_fields__}


@pytest.mark.slow
def test_a_killed_tuning_run_resumes_and_writes_its_best_gait(tmp_path) -> None:
    """One generation, then the run asked for two more resumes at the second (its log grows by one line per
    generation); the gait file holds the best candidate and the run's settings; other settings are refused."""
    run, out = tmp_path / "run", tmp_path / "gait.json"
    settings = {"population": 2, "walks": 1, "kicks": 0, "workers": 1, "run": run, "out": out}
    tune_walker.main(TuneConfig(generations=1, **settings))
    first = json.loads(out.read_text())
    tune_walker.main(TuneConfig(generations=2, **settings))
    lines = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [line["generation"] for line in lines] == [1, 2]
    saved = json.loads(out.read_text())
    assert saved["tuning"]["generations"] == 2 and saved["tuning"]["population"] == 2
    assert saved["tuning"]["cost"] <= first["tuning"]["cost"]
    assert saved["tuning"]["cost"] == pytest.approx(min(line["best"] for line in lines))
    assert saved["tuning"]["start"] == asdict(load_gait())  # where it started: the tuned gait, by default
    load_gait(out)  # a gait file the walker reads
    with pytest.raises(UserError, match="other settings"):
        tune_walker.main(TuneConfig(generations=3, **{**settings, "population": 3}))
