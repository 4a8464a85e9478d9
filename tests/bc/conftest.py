"""Small BC checkpoints that the PPO tests start from (`test_finetune.py`, `test_finetune_resume.py`), each trained once
per test process."""

from __future__ import annotations

from pathlib import Path

import pytest

from bc.train import TrainConfig
from bc.train import main as train_bc
from support import SMALL_BC
from teleop.record import RecordConfig, record


@pytest.fixture(scope="session")
def bc_policy(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint trained on the 3-episode recording."""
    folder = tmp_path_factory.mktemp("bc") / "policy"
    train_bc(TrainConfig(dataset=recorded, policy=folder, **SMALL_BC))
    return folder


@pytest.fixture(scope="session")
def proprio_policy(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint on the sensed features (INPUTS=proprio) of the 3-episode recording."""
    folder = tmp_path_factory.mktemp("bc_proprio") / "policy"
    train_bc(TrainConfig(dataset=recorded, policy=folder, inputs="proprio", **SMALL_BC))
    return folder


@pytest.fixture(scope="session")
def pending_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small BC checkpoint on the "pending" inputs of 3 short noisy expert episodes, each delayed by one step."""
    root = tmp_path_factory.mktemp("delayed") / "dataset"
    record(RecordConfig(dataset=root, episodes=3, max_steps=60, latency=1.0, writer="inline", progress=False))
    folder = tmp_path_factory.mktemp("bc_pending") / "policy"
    train_bc(TrainConfig(dataset=root, policy=folder, inputs="pending", **SMALL_BC))
    return folder
