"""One BLAS thread per process: numpy's and scipy's OpenBLAS otherwise start a thread per core for every matrix
product, and the LQR expert takes a small one at each step (its gain times the state), where the threads' hand-offs
cost more than the product. With two simulating processes on two cores each product then waits for a core the other
process holds: the expert's evaluations ran 2.3x slower, with the same results (docs/decisions/blas-threads.md).
torch's own threads (the policies, BC and PPO's updates) are not BLAS threads of these libraries and keep their
settings."""

from __future__ import annotations

from threadpoolctl import threadpool_limits


def one_blas_thread() -> None:
    """Limit this process's BLAS libraries (numpy's, scipy's OpenBLAS) to one thread each, for its lifetime."""
    threadpool_limits(1, user_api="blas")
