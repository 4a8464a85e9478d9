"""`common.threads`: the BLAS kernels every process runs, pinned by the Makefile, and the note where they are not."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from common.threads import PINNED, pinnable

MAKEFILE = Path(__file__).resolve().parents[2] / "Makefile"


def test_the_makefile_exports_the_pinned_settings() -> None:
    """The Makefile's exports are `PINNED`, each a default a value already in the environment overrides."""
    exported = dict(re.findall(r"^export (\w+) \?= (\S+)$", MAKEFILE.read_text(), flags=re.MULTILINE))
    assert {name: exported.get(name) for name in PINNED} == PINNED


def unpinned_in(environment: dict[str, str]) -> str:
    """What `common.threads.unpinned` says in a fresh interpreter under `environment` (libraries loaded there)."""
    code = "import numpy, scipy.linalg; from common.threads import unpinned; print(unpinned())"
    return subprocess.run(
        [sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True
    ).stdout.strip()


@pytest.mark.skipif(not pinnable(), reason="the pinned kernels apply to x86-64 CPUs with AVX2")
def test_other_kernels_are_named_and_the_pinned_ones_pass() -> None:
    """Under the pinned settings nothing is said; under another OpenBLAS kernel (Sandybridge's, which any CPU with AVX2
    runs) its name, and without MKL_CBWR that."""
    pinned = {**os.environ, **PINNED}
    assert unpinned_in(pinned) == "None"
    assert unpinned_in({**pinned, "OPENBLAS_CORETYPE": "Sandybridge"}) == (
        "OpenBLAS runs its Sandybridge kernels here, not Haswell"
    )
    without_mkl = {name: value for name, value in pinned.items() if name != "MKL_CBWR"}
    assert unpinned_in(without_mkl) == "MKL_CBWR is not AVX2,STRICT"
