"""The BLAS libraries as every process of the project runs them: one thread each, and one kernel on every CPU.

One thread: numpy's and scipy's OpenBLAS otherwise start a thread per core for every matrix product, and the LQR
expert takes a small one at each step (its gain times the state), where the threads' hand-offs cost more than the
product. With two simulating processes on two cores each product then waits for a core the other process holds: the
expert's evaluations ran 2.3x slower, with the same results (docs/decisions/blas-threads.md). torch's own threads
(the policies, BC and PPO's updates) are not BLAS threads of these libraries and keep their settings.

One kernel: OpenBLAS picks its kernels by CPU, and so the LQR gains, the demonstrations and everything learnt from
them differed between two x86 machines; torch's MKL likewise for BC's weights, numpy its loops for the tracking's
trigonometry. `PINNED` are the settings under which they are the same on any x86-64 CPU with AVX2 (MKL's on any of
Intel's: it runs the branch it is told on Intel's CPUs only); the Makefile exports them, since they act only when set
before the libraries load (docs/decisions/cpu-kernels.md).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

from threadpoolctl import threadpool_info, threadpool_limits

PINNED = {
    "OPENBLAS_CORETYPE": "Haswell",
    "MKL_CBWR": "AVX2,STRICT",
    "NPY_DISABLE_CPU_FEATURES": "AVX512F,AVX512CD,AVX512_KNL,AVX512_KNM,AVX512_SKX,AVX512_CLX,AVX512_CNL,AVX512_ICL",
}
"""The environment the Makefile sets on an x86-64 CPU with AVX2: OpenBLAS's Haswell kernels (which AMD's Zen CPUs run
too); MKL's AVX2 branch in its strict mode (the same bits whatever the threads and the batch of 4 rows or more), which
MKL runs on Intel's CPUs only: on AMD's it runs its own branch whatever it is told, and its one branch common to both,
COMPATIBLE, cost 1.6x the training and gave other bits for other batch sizes; and numpy's AVX2 loops where the CPU has
AVX-512 too (its AVX-512 ones compute the tracking's arctangents to other last bits)."""


def pinnable() -> bool:
    """Whether PINNED applies here: an x86-64 CPU with AVX2 (Haswell's kernels need it), as the Makefile checks."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return False
    try:
        return " avx2 " in f" {Path('/proc/cpuinfo').read_text()} ".replace("\n", " ")
    except OSError:
        return False


BLAS_THREADS = {"OPENBLAS_NUM_THREADS": "1"}
"""What an OpenBLAS loaded later reads when it starts: threadpoolctl limits only the libraries already loaded, and
scipy's own OpenBLAS loads with the first `scipy.linalg` import, in a worker after its limit (it then ran a thread per
core and, with two workers and the renderer on two cores, spun for minutes)."""


def one_blas_thread() -> None:
    """Limit this process's BLAS libraries (numpy's, scipy's OpenBLAS) to one thread each, for its lifetime: those
    loaded now, and those loaded later (`BLAS_THREADS`, a value already in the environment winning)."""
    for name, value in BLAS_THREADS.items():
        os.environ.setdefault(name, value)
    threadpool_limits(1, user_api="blas")


def openblas_kernels() -> list[str]:
    """The kernels the OpenBLAS libraries loaded in this process run (threadpoolctl's "architecture")."""
    return sorted({str(info.get("architecture")) for info in threadpool_info() if info["internal_api"] == "openblas"})


def unpinned() -> str | None:
    """Why this process's results may differ from the README's on another CPU, in one line; None if it runs the
    pinned kernels (or PINNED does not apply here: `pinnable`)."""
    if not pinnable():
        return None
    kernels = openblas_kernels()
    pinned = PINNED["OPENBLAS_CORETYPE"]
    if kernels and kernels != [pinned]:
        return f"OpenBLAS runs its {', '.join(kernels)} kernels here, not {pinned}"
    for name in ("MKL_CBWR", "NPY_DISABLE_CPU_FEATURES"):
        if os.environ.get(name, "").upper() != PINNED[name]:
            return f"{name} is not {PINNED[name]}"
    return None
