"""A crash at any moment of a recording costs no committed episode, and the next recording continues."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from common import columns
from common.cli import DatasetError
from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import run_episode
from support import assert_consistent, assert_no_leftovers, committed_episodes, start_recording, wait_for_episodes
from teleop import recordings
from teleop.dataset_reader import read_episodes
from teleop.inspect_dataset import cli as inspect_cli
from teleop.record import STANDING, RecordConfig, main, record
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

FILES_PER_EPISODE = 5  # renames in one append: data, episode row, MCAP, stats.json, info.json (the commit)


class SimulatedCrash(Exception):
    """Raised in place of a rename: the process 'dies' with the disk exactly as it stands."""


def append_crashing(root: Path, monkeypatch: pytest.MonkeyPatch, crash: Callable[[int, Path], bool]) -> None:
    """An episode appended to `root` as a crash leaves it: the append's rename to `target` after `renamed` others
    raises instead where `crash(renamed, target)`."""
    env = make_env(60)
    store = EpisodeStore(root, DatasetSpec.from_env(env))
    episode = run_episode(env, store_controller(env), seed=7)
    real_replace, renamed = os.replace, []

    def replace_or_crash(source: str | Path, target: str | Path) -> None:
        if crash(len(renamed), Path(target)):
            raise SimulatedCrash(target)
        renamed.append(target)
        real_replace(source, target)

    monkeypatch.setattr(os, "replace", replace_or_crash)
    with pytest.raises(SimulatedCrash):
        store.append(episode)
    monkeypatch.undo()
    store.close()


@pytest.mark.parametrize("renames_before_crash", range(FILES_PER_EPISODE))
def test_crash_before_commit_keeps_the_committed_episodes(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, renames_before_crash: int
) -> None:
    """Killed after any of an append's file writes but the last, the dataset still holds exactly the committed ones."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    append_crashing(root, monkeypatch, lambda renamed, _: renamed == renames_before_crash)
    assert_consistent(root, 3)  # readable as it lies, before any recovery

    main(RecordConfig(dataset=root, episodes=1, max_steps=60, writer="inline", progress=False, **STANDING))
    assert_consistent(root, 4)
    assert_no_leftovers(root, 4)
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == [0, 1, 2, 3]


def test_a_crash_in_the_first_commit_leaves_no_statistics_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Killed between the first episode's stats.json and its info.json, a new dataset's statistics count no episode
    once reopened: the next episode's are its own, not merged with the lost one's."""
    root = tmp_path / "dataset"
    append_crashing(root, monkeypatch, lambda _, target: target.name == "info.json")
    assert (root / "meta/stats.json").is_file()  # the lost episode's statistics

    main(RecordConfig(dataset=root, episodes=1, max_steps=60, writer="inline", progress=False, **STANDING))
    assert_consistent(root, 1)
    assert_no_leftovers(root, 1)


def store_controller(env):
    return make_controller("expert", env)


@pytest.mark.parametrize("delay", [0.0, 0.037, 0.081])
def test_kill_9_of_the_whole_recording_keeps_every_committed_episode(tmp_path: Path, delay: float) -> None:
    """SIGKILL to the recorder and its writer mid-run: the dataset loads and the next recording continues."""
    root = tmp_path / "dataset"
    recorder = start_recording(root, episodes=100)
    wait_for_episodes(root, 2, recorder)
    time.sleep(delay)  # land somewhere inside the writing of a later episode
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait()
    survived = committed_episodes(root)
    assert survived >= 2
    assert_consistent(root, survived)

    main(RecordConfig(dataset=root, episodes=2, max_steps=60, writer="inline", progress=False, **STANDING))
    assert_consistent(root, survived + 2)
    assert_no_leftovers(root, survived + 2)
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == list(range(survived + 2))


def kill_after_two_episodes(root: Path, kill: Callable[[subprocess.Popen], None]) -> int:
    """Record 100 episodes into `root`, `kill` the recording once two are committed, and wait for the writer;
    the episodes committed when the kill landed."""
    recorder = start_recording(root, episodes=100)
    wait_for_episodes(root, 2, recorder)
    kill(recorder)
    recorder.wait()
    at_kill = committed_episodes(root)
    wait_for_the_writer(root)
    return at_kill


def wait_for_the_writer(root: Path) -> None:
    """Until the writer process, which outlives a killed recorder, has drained its pipe and released the dataset."""
    deadline = time.monotonic() + 30
    while True:
        try:
            EpisodeStore(root, DatasetSpec.from_env(make_env())).close()
            return
        except DatasetError:
            assert time.monotonic() < deadline, "the writer process never released the dataset"
            time.sleep(0.05)


def test_kill_9_of_the_recorder_alone_lets_the_writer_commit_what_it_received(tmp_path: Path) -> None:
    """The writer process outlives a killed recorder just long enough to commit the episodes it was sent."""
    root = tmp_path / "dataset"
    at_kill = kill_after_two_episodes(root, lambda recorder: os.kill(recorder.pid, signal.SIGKILL))
    assert committed_episodes(root) >= at_kill >= 2
    assert_consistent(root, committed_episodes(root))


@pytest.fixture
def killed(tmp_path: Path) -> tuple[Path, int]:
    """A dataset whose recording (100 episodes asked for) was killed with -9 after its second episode or later."""
    root = tmp_path / "dataset"
    kill_after_two_episodes(root, lambda recorder: os.killpg(recorder.pid, signal.SIGKILL))
    return root, committed_episodes(root)


def test_the_next_session_writes_the_line_of_a_session_killed_with_9(killed: tuple[Path, int]) -> None:
    """kill -9 leaves no time for recordings.jsonl: the next session logs the killed one (its settings, the episodes
    it committed, complete false), then its own, so that every episode is accounted for."""
    root, survived = killed
    assert recordings.read(root) == []
    record(RecordConfig(dataset=root, episodes=2, max_steps=60, writer="inline", progress=False, **STANDING))
    first, second = recordings.read(root)
    assert (first["made_by"], first["complete"], first["config"]["episodes"]) == ("teleop.record", False, 100)
    assert (first["episodes"], first["seeds"], first["count"]) == ([0, survived - 1], [0, survived - 1], survived)
    assert (second["complete"], second["episodes"], second["config"]["episodes"]) == (True, [survived, survived + 1], 2)
    assert not (root / recordings.RUN_FILE).exists()


def test_a_refused_session_leaves_the_killed_sessions_mark(killed: tuple[Path, int]) -> None:
    """A session refused before it opens the dataset writes nothing: the mark waits for a session that runs."""
    root, _ = killed
    mark = (root / recordings.RUN_FILE).read_bytes()
    with pytest.raises(DatasetError):
        record(RecordConfig(dataset=root, episodes=1, randomize="mild", writer="inline", progress=False, **STANDING))
    assert (root / recordings.RUN_FILE).read_bytes() == mark and recordings.read(root) == []


def test_inspect_lists_the_killed_session_before_its_line_is_written(
    killed: tuple[Path, int], capsys: pytest.CaptureFixture[str]
) -> None:
    """`make inspect` on the killed dataset names the session that recorded its episodes, interrupted."""
    root, survived = killed
    assert inspect_cli(["--dataset", str(root), "--lerobot", "false"]) == 0
    (session,) = [line for line in capsys.readouterr().out.splitlines() if "teleop.record at " in line]
    assert session.endswith(f": episodes 0..{survived - 1}, interrupted")
