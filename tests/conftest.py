"""Shared fixtures: small real recordings (MuJoCo, LeRobot format, MCAP) in temporary folders."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from support import SHORT_EPISODE
from teleop.record import RecordConfig, main

# Nothing may wait on a network, and the tests must not write caches into the user's home.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session", autouse=True)
def isolated_caches(tmp_path_factory: pytest.TempPathFactory) -> None:
    """LQR gains and HuggingFace caches go to a temporary folder for the whole session."""
    cache = tmp_path_factory.mktemp("caches")
    os.environ["HUMANOID_BC_CACHE"] = str(cache / "humanoid-bc")
    os.environ["HF_DATASETS_CACHE"] = str(cache / "hf-datasets")
    os.environ["HF_LEROBOT_HOME"] = str(cache / "lerobot")


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset of 3 short noisy expert episodes (seeds 0..2), written in-process."""
    root = tmp_path_factory.mktemp("recorded") / "dataset"
    main(RecordConfig(dataset=root, episodes=3, max_steps=SHORT_EPISODE, noise=0.05, writer="inline", progress=False))
    return root
