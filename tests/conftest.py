"""Shared fixtures: small real recordings (MuJoCo, LeRobot format, MCAP) in temporary folders."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from common import workers
from common.threads import PINNED, pinnable

# The BLAS kernels `make test` runs with, also under a bare `pytest`: they act only if set before numpy loads, which
# the imports below do (common/threads.py).
if pinnable():
    for name, value in PINNED.items():
        os.environ.setdefault(name, value)
# Under pytest-xdist each test process's torch (`common.workers.torch_threads`) and OpenBLAS get its share of the cores,
# as a command's own process limits OpenBLAS (`common.threads.one_blas_thread`): two BC fits of a thread per core each,
# side by side, took 7 times as long as one alone (docs/decisions/test-workers.md).
if (processes := int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))) > 1:
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, workers.available_cores() // processes)))

import pytest

from teleop.parallel import WORKER_MODULES
from teleop.writer_process import WRITER_MODULES

if TYPE_CHECKING:
    from support import RayCluster

# Nothing may wait on a network, and the tests must not write caches into the user's home.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")
# Ray resolves 127.0.0.1 to the machine's outward address (in `ray.init(address=...)` too) unless it thinks
# it cannot form clusters; read when ray is imported, by this process and the commands tests start.
# Every Ray address in the tests is then a loopback one.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
# Ray 2.60's token authentication, as a local Ray has it by default, with a token of this session's: in the
# environment, so every cluster and driver the tests start shares it and none is written to ~/.ray.
os.environ.setdefault("RAY_AUTH_MODE", "token")
os.environ.setdefault("RAY_AUTH_TOKEN", uuid.uuid4().hex)
# Every worker process the tests start is a fork of this process's one forkserver, which imports only the modules
# declared before it started (common.workers): declared here, before any test starts it, a recording, writer, PPO,
# robustness-suite or tutorial worker starts in milliseconds whichever test started the server, instead of
# importing torch, SB3 and MuJoCo anew (seconds each).
workers.declare_preload(
    [*WORKER_MODULES, *WRITER_MODULES, "rl.learner", "rl.vec_env", "evaluation.robustness", "pipeline.run"]
)


@pytest.fixture(scope="session", autouse=True)
def isolated_caches(tmp_path_factory: pytest.TempPathFactory) -> None:
    """LQR gains and HuggingFace caches go to a temporary folder for the whole session.

    Under pytest-xdist the LQR gains, stance and landing plan (`common.cache`, written by rename, safe to share) go to
    one folder beside the workers' own, so that a design one worker made (the landing plan takes 10 s) is loaded by
    the other instead of made again."""
    cache = tmp_path_factory.mktemp("caches")
    shared = tmp_path_factory.getbasetemp().parent if os.environ.get("PYTEST_XDIST_WORKER") else cache
    os.environ["HUMANOID_BC_CACHE"] = str(shared / "humanoid-bc")
    os.environ["HF_DATASETS_CACHE"] = str(cache / "hf-datasets")
    os.environ["HF_LEROBOT_HOME"] = str(cache / "lerobot")


# The fixtures below import what they run where they run it: `make test`'s controlling process imports this file
# too and runs no test, and the recorder, BC and the tests' helpers (torch, LeRobot) cost it 5–9 s before it starts
# the processes that do (docs/benchmarks.md, The test suite).


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset of 3 short noisy expert episodes (seeds 0..2), written in-process."""
    from support import SHORT_EPISODE  # noqa: PLC0415 - see above
    from teleop.record import STANDING, RecordConfig, main  # noqa: PLC0415

    root = tmp_path_factory.mktemp("recorded") / "dataset"
    main(
        RecordConfig(
            dataset=root, episodes=3, max_steps=SHORT_EPISODE, noise=0.05, writer="inline", progress=False, **STANDING
        )
    )
    return root


@pytest.fixture(scope="session")
def operated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset of 2 episodes of the expert under the scripted operator's schedules (seeds 0..1) of 300 steps:
    neutral for 3 s, then a command."""
    from teleop.record import RecordConfig, main  # noqa: PLC0415 - see above

    root = tmp_path_factory.mktemp("operated") / "dataset"
    main(
        RecordConfig(
            dataset=root, episodes=2, max_steps=300, controller="expert", latency=0.0, writer="inline", progress=False
        )
    )
    return root


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[RayCluster]:
    """A Ray cluster of two 1-CPU nodes on loopback: a head and one worker node (Ray's own cluster utility)."""
    from support import RayCluster  # noqa: PLC0415 - see above

    cluster = RayCluster()
    try:
        yield cluster
    finally:
        cluster.shutdown()


@pytest.fixture(scope="session")
def bc_policy(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint trained on the 3-episode recording."""
    from bc.train import TrainConfig, main  # noqa: PLC0415 - see above
    from support import SMALL_BC  # noqa: PLC0415

    folder = tmp_path_factory.mktemp("bc") / "policy"
    main(TrainConfig(dataset=recorded, policy=folder, **SMALL_BC))
    return folder


@pytest.fixture(scope="session")
def proprio_policy(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint on the sensed features (INPUTS=proprio) of the 3-episode recording."""
    from bc.train import TrainConfig, main  # noqa: PLC0415 - see above
    from support import SMALL_BC  # noqa: PLC0415

    folder = tmp_path_factory.mktemp("bc_proprio") / "policy"
    main(TrainConfig(dataset=recorded, policy=folder, **{**SMALL_BC, "inputs": "proprio"}))
    return folder


@pytest.fixture(scope="session")
def pending_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint on the "pending" inputs of 3 short noisy expert episodes, each delayed by one step."""
    from bc.train import TrainConfig  # noqa: PLC0415 - see above
    from bc.train import main as train_bc  # noqa: PLC0415
    from support import SMALL_BC  # noqa: PLC0415
    from teleop.record import STANDING, RecordConfig, record  # noqa: PLC0415

    root = tmp_path_factory.mktemp("delayed") / "dataset"
    record(
        RecordConfig(
            dataset=root, episodes=3, max_steps=60, writer="inline", progress=False, **{**STANDING, "latency": 1.0}
        )
    )
    folder = tmp_path_factory.mktemp("bc_pending") / "policy"
    train_bc(TrainConfig(dataset=root, policy=folder, **{**SMALL_BC, "inputs": "pending"}))
    return folder
