"""The digest of a computation's code: every project module it imports at any depth, so no cache of its results can
go stale (`common.digest`; the input sets' cache, `students.inputs.computation_digest`)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bc.data import load_demonstrations
from common.digest import ROOT, source_closure, source_digest
from humanoid.env import make_env

DATASET_V1 = ROOT / "tests" / "data" / "dataset_v1"
PACKAGES = ("common", "policies", "humanoid", "task", "teachers", "students", "rollout", "teleop", "evaluation", "bc")
"""The packages a copy of the project needs to load demonstrations."""


def write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_digest_covers_every_module_imported_at_any_depth_and_no_other(tmp_path: Path) -> None:
    """A known answer on a tree of four modules: `a` imports `b` at module level, `b` imports `c` inside a function;
    `d` is imported by nobody."""
    tree = write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": "from pkg import b\n",
            "pkg/b.py": "def f():\n    from pkg.c import THRESHOLD\n    return THRESHOLD\n",
            "pkg/c.py": "THRESHOLD = 0.02\n",
            "pkg/d.py": "import numpy\n",
        },
    )
    assert set(source_closure("pkg.a", tree)) == {"pkg.a", "pkg", "pkg.b", "pkg.c"}
    before = source_digest("pkg.a", tree)
    (tree / "pkg/d.py").write_text("import numpy as np\n")
    assert source_digest("pkg.a", tree) == before
    (tree / "pkg/c.py").write_text("THRESHOLD = 0.03\n")
    assert source_digest("pkg.a", tree) != before


def test_the_input_sets_digest_covers_the_hand_over_rule_the_odometry_and_the_command_filter() -> None:
    closure = source_closure("students.inputs")
    assert {"task.handover", "humanoid.capture", "humanoid.estimator", "task.posture", "task.command_fields"} <= set(
        closure
    )
    assert not any(name.startswith(("teachers", "bc", "rl", "tests")) for name in closure)


@pytest.mark.slow
def test_a_changed_trigger_threshold_misses_the_cache_of_computed_inputs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Inputs computed and cached by this checkout are read back here; a copy of it whose hand-over threshold differs
    (`task.handover.HandOver.trigger_offset`, which no posture input reads: the digest is of the computation's code
    as a whole) computes them afresh."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("HUMANOID_BC_CACHE", str(cache))
    env = make_env()
    try:
        assert not load_demonstrations(DATASET_V1, env, inputs="pending+ramp").from_cache
        assert load_demonstrations(DATASET_V1, env, inputs="pending+ramp").from_cache
    finally:
        env.close()
    copy = tmp_path / "copy"
    for package in PACKAGES:
        shutil.copytree(ROOT / package, copy / package, ignore=shutil.ignore_patterns("__pycache__"))
    code = (
        "from pathlib import Path; from bc.data import load_demonstrations; from humanoid.env import make_env; "
        f"import common.digest; assert common.digest.ROOT.samefile({str(copy)!r}); "
        f"print(load_demonstrations(Path({str(DATASET_V1)!r}), make_env(), inputs='pending+ramp').from_cache)"
    )

    def cached_in_copy() -> bool:
        run = subprocess.run(
            [sys.executable, "-c", code],
            cwd=copy,
            env={**os.environ, "PYTHONPATH": str(copy)},
            capture_output=True,
            text=True,
            check=True,
        )
        return run.stdout.strip().splitlines()[-1] == "True"

    assert cached_in_copy()  # the same code elsewhere: the same digest
    handover = copy / "task" / "handover.py"
    text = handover.read_text()
    assert "trigger_offset: float = 0.02" in text
    handover.write_text(text.replace("trigger_offset: float = 0.02", "trigger_offset: float = 0.03"))
    assert not cached_in_copy()
