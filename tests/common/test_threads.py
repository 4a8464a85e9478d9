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
    without_numpy = {name: value for name, value in pinned.items() if name != "NPY_DISABLE_CPU_FEATURES"}
    assert unpinned_in(without_numpy).startswith("NPY_DISABLE_CPU_FEATURES is not AVX512F,")


FINGERPRINT_CODE = """
import hashlib, numpy as np, scipy.linalg
angles = np.linspace(-3.0, 3.0, 1001)
lqr = np.random.default_rng(0).standard_normal((44, 44))
parts = {
    "numpy's arctan2 and arcsin": np.concatenate([np.arctan2(np.sin(angles), np.cos(angles)), np.arcsin(angles / 3)]),
    "OpenBLAS's dgemm and LAPACK": scipy.linalg.solve_discrete_are(lqr * 0.1, np.eye(44), np.eye(44), np.eye(44)),
}
for name, array in parts.items():
    print(name, hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()[:16])
"""
PINNED_FINGERPRINTS = {
    "numpy's arctan2 and arcsin": "2389739b12b4faa0",
    "OpenBLAS's dgemm and LAPACK": "358c3a365f42fa96",
}
"""What numpy and OpenBLAS compute under `PINNED` on an AMD EPYC (Zen 4, AVX-512): the same on any x86-64 CPU with
AVX2 is what their pins are for, so a CPU that computes otherwise fails here (docs/decisions/cpu-kernels.md). Each pin
moves its own line: numpy's AVX-512 loops the first, OpenBLAS's SkylakeX kernels the second. MKL is not here: it runs
the branch it is told on Intel's CPUs only, so its bits differ between Intel's and AMD's."""


@pytest.mark.skipif(not pinnable(), reason="the pinned kernels apply to x86-64 CPUs with AVX2")
def test_the_pinned_libraries_compute_the_same_bits_on_any_x86_cpu() -> None:
    result = subprocess.run(
        [sys.executable, "-c", FINGERPRINT_CODE],
        env={**os.environ, **PINNED},
        capture_output=True,
        text=True,
        check=True,
    )
    computed = dict(line.rsplit(" ", 1) for line in result.stdout.strip().splitlines())
    assert computed == PINNED_FINGERPRINTS


def test_one_blas_thread_holds_for_a_blas_loaded_after_it() -> None:
    """A worker limits its BLAS first and imports scipy.linalg later (the expert's gains): scipy's own OpenBLAS runs
    one thread too."""
    code = (
        "from common.threads import one_blas_thread; one_blas_thread()\n"
        "import scipy.linalg\n"
        "from threadpoolctl import threadpool_info\n"
        "print(sorted({info['num_threads'] for info in threadpool_info() if info['user_api'] == 'blas'}))"
    )
    environment = {name: value for name, value in os.environ.items() if name != "OPENBLAS_NUM_THREADS"}
    result = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[1]"
