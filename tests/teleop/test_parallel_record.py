"""`make record WORKERS=N`: one dataset in seed order, identical to one process's, and kill -9 safe."""

from __future__ import annotations

import os
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from common import columns
from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import run_episode
from support import (
    SHORT_EPISODE,
    assert_consistent,
    assert_no_leftovers,
    committed_episodes,
    record_short,
    snapshot,
    start_recording,
    wait_for_episodes,
)
from teleop.dataset_reader import read_episodes, read_frames
from teleop.record import DART_NOISE, cli
from teleop.spool import Spool
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)


def record(root: Path, workers: int, **settings: object) -> None:
    record_short(root, **{"episodes": 5, "max_steps": SHORT_EPISODE, "workers": workers, **settings})


def test_two_workers_write_the_files_one_process_writes(tmp_path: Path) -> None:
    """Every file of a 2-worker recording is byte-identical to the same recording made by one process."""
    record(tmp_path / "one", workers=1)
    record(tmp_path / "two", workers=2)
    assert snapshot(tmp_path / "two") == snapshot(tmp_path / "one")


def test_two_workers_write_the_files_one_process_writes_with_randomisation(tmp_path: Path) -> None:
    """With RANDOMIZE=suite too: the workers draw each seed's body as one process does, byte for byte."""
    record(tmp_path / "one", workers=1, randomize="suite")
    record(tmp_path / "two", workers=2, randomize="suite")
    assert snapshot(tmp_path / "two") == snapshot(tmp_path / "one")
    assert columns.RANDOMIZATION_PREFIX + "mass_scale" in read_episodes(tmp_path / "two").column_names


def test_more_workers_than_episodes_still_commit_in_seed_order(tmp_path: Path) -> None:
    """Three workers recording two episodes after existing ones append seeds in order."""
    root = tmp_path / "dataset"
    record(root, workers=1, episodes=2)
    record(root, workers=3, episodes=2)
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == [0, 1, 2, 3]
    assert not (root / ".spool").exists()


def spool_episodes(root: Path, seeds: list[int]) -> None:
    """Episodes a killed parallel recording finished but did not commit, as its workers left them."""
    env = make_env(SHORT_EPISODE)
    controller = make_controller("expert", env)
    for seed in seeds:
        Spool(root).put(run_episode(env, controller, seed, noise_std=DART_NOISE))  # `make record`'s


def test_opening_a_dataset_commits_its_spool_in_seed_order(recorded: Path, tmp_path: Path) -> None:
    """Spooled episodes (seeds 6 and 4) become episodes 3 and 4, with the values a fresh rollout gives."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    spool_episodes(root, [6, 4])
    EpisodeStore(root, DatasetSpec.from_env(make_env())).close()
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == [0, 1, 2, 4, 6]
    assert not (root / ".spool").exists()
    record(tmp_path / "fresh", workers=1, episodes=1, seed=6)
    fresh, merged = read_frames(tmp_path / "fresh"), read_frames(root)
    np.testing.assert_array_equal(merged[columns.ACTION][merged["episode_index"] == 4], fresh[columns.ACTION])


@pytest.mark.parametrize("already_committed", [True, False])
def test_an_episode_killed_mid_commit_is_committed_exactly_once(
    recorded: Path, tmp_path: Path, already_committed: bool
) -> None:
    """A `.committing` spool file counts once: dropped if info.json counts its index, else committed."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    spool_episodes(root, [5])
    spool = Spool(root)
    spool.begin_commit(spool.ready()[0], episode_index=2 if already_committed else 3)
    EpisodeStore(root, DatasetSpec.from_env(make_env())).close()
    expected = [0, 1, 2] if already_committed else [0, 1, 2, 5]
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == expected
    assert not (root / ".spool").exists()


def test_kill_9_of_a_parallel_recording_loses_no_finished_episode(tmp_path: Path) -> None:
    """SIGKILL to the recorder and its workers: committed and spooled episodes all end up in the dataset."""
    root = tmp_path / "dataset"
    recorder = start_recording(root, 100, "--workers", "2")
    wait_for_episodes(root, 3, recorder)
    deadline = time.monotonic() + 60
    # Freeze the committing process so that the workers' next episodes are finished but not committed.
    os.kill(recorder.pid, signal.SIGSTOP)
    while len(Spool(root).ready()) < 2:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait()
    committed = committed_episodes(root)
    assert_consistent(root, committed)
    # Finished: those waiting, and one a stopped commit had taken from the spool before info.json counted it.
    finished = committed + Spool(root).contents(committed)[0]
    assert finished >= committed + 2

    record(root, workers=2, episodes=2, max_steps=150)
    assert_consistent(root, finished + 2)
    assert_no_leftovers(root, finished + 2)
    seeds = read_episodes(root)[columns.EPISODE_SEED].to_pylist()
    assert seeds == sorted(seeds) and len(set(seeds)) == len(seeds)
    assert seeds[:committed] == list(range(committed))


def test_zero_workers_is_refused_before_touching_the_disk(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--workers 0: one-line error, non-zero exit, no dataset folder created."""
    code = cli(["--dataset", str(tmp_path / "new"), "--workers", "0", "--progress", "false"])
    assert code != 0
    assert capsys.readouterr().err.strip() == "error: --workers must be positive, got 0"
    assert not (tmp_path / "new").exists()


def test_the_spool_counts_what_a_recovery_commits(tmp_path: Path) -> None:
    """Waiting episodes, and one taken out for a commit info.json does not count yet, are finished; a `.committing`
    file whose episode info.json counts (a kill after the commit) and a partial file are not."""
    spool = Spool(tmp_path)
    spool.folder.mkdir()
    for name in ("000000000003.npz", "000000000004.index-3.committing", "000000000005.index-4.committing", "x.partial"):
        (spool.folder / name).write_bytes(b"")
    assert spool.contents(4) == (2, 1)
    spool.recover(4)
    assert [path.name for path in spool.ready()] == ["000000000003.npz", "000000000005.npz"]
