"""Every transition complete: each episode keeps the observation its last action led to, in both formats."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from common import columns
from common.cli import DatasetError
from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import run_episode
from support import SHORT_EPISODE, snapshot
from teleop.dataset_reader import read_episodes, read_frames, read_mcap_final, read_transitions
from teleop.record import RecordConfig, main


@pytest.fixture(scope="module")
def fallen(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two episodes of the random controller, which falls within a few dozen steps."""
    root = tmp_path_factory.mktemp("fallen") / "dataset"
    main(RecordConfig(dataset=root, episodes=2, controller="random", writer="inline", progress=False))
    return root


def test_each_episode_has_one_more_observation_than_actions(recorded: Path) -> None:
    """T frames give T actions and T+1 observations; the first T are the frames' own."""
    transitions = read_transitions(recorded)
    frames = read_frames(recorded, ["episode_index"])
    assert len(transitions) == 3
    for episode, t in enumerate(transitions):
        length = int(np.sum(frames["episode_index"] == episode))
        assert t.observations.shape == (length + 1, 348) and t.actions.shape == (length, 17)
        assert len(t.rewards) == len(t.terminated) == len(t.truncated) == length


def test_final_observation_is_where_the_last_action_led(recorded: Path) -> None:
    """Re-running episode 0 (seed 0, the same noise and length) ends in the stored final observation, bit for bit."""
    env = make_env(max_episode_steps=SHORT_EPISODE)
    episode = run_episode(env, make_controller("expert", env), seed=0, noise_std=0.05)
    env.close()
    stored = read_transitions(recorded)[0]
    assert stored.observations[-1].tobytes() == episode.final_observation.tobytes()
    assert stored.observations[:-1].tobytes() == episode.observation.tobytes()
    assert stored.truncated[-1] and not stored.terminated[-1]


def test_a_fall_keeps_the_fallen_state(fallen: Path) -> None:
    """A terminated episode's last observation is the state that ended it: the torso below the healthy height."""
    for t in read_transitions(fallen):
        assert t.terminated[-1] and not t.truncated[-1]
        assert t.observations[-1, 0] < 1.0 <= t.observations[-2, 0]  # root z; Humanoid-v5 is healthy from 1.0


def test_mcap_holds_the_same_final_observation(fallen: Path) -> None:
    """/final_observation, logged once at time T with frame index T, equals the episode columns."""
    transitions = read_transitions(fallen)
    rows = read_episodes(fallen).to_pylist()
    for t, row in zip(transitions, rows, strict=True):
        final = read_mcap_final(fallen / row[columns.EPISODE_MCAP])
        assert final["frame_index"] == len(t.actions)
        np.testing.assert_array_equal(final["observation"], t.observations[-1])
        np.testing.assert_array_equal(final["state"], row[columns.EPISODE_FINAL_STATE])


def test_lerobot_still_loads_t_frames_per_episode(fallen: Path) -> None:
    """The final observation is an episode column: LeRobot's loader sees T frames and the column beside its own."""
    dataset = LeRobotDataset("local/fallen", root=fallen)
    lengths = [len(t.actions) for t in read_transitions(fallen)]
    assert len(dataset) == sum(lengths) and dataset.meta.total_episodes == 2
    assert len(dataset.meta.episodes[columns.EPISODE_FINAL_STATE][0]) == 48


@pytest.fixture()
def without_finals(recorded: Path, tmp_path: Path) -> Path:
    """A copy of the recording whose episode rows lack the final observation, as recorded before it was kept."""
    copy = tmp_path / "old"
    shutil.copytree(recorded, copy)
    for path in (copy / "meta/episodes").rglob("*.parquet"):
        table = pq.read_table(path)
        pq.write_table(table.drop_columns([columns.EPISODE_FINAL_STATE, columns.EPISODE_FINAL_ENV_STATE]), path)
    return copy


def test_dataset_without_final_observations_is_refused_by_the_reader(without_finals: Path) -> None:
    with pytest.raises(DatasetError, match="no final observations"):
        read_transitions(without_finals)


def test_appending_to_a_dataset_without_final_observations_is_refused(without_finals: Path) -> None:
    """The recorder will not mix episode rows with and without the columns: one line, nothing on disk changed."""
    before = snapshot(without_finals)
    with pytest.raises(DatasetError, match="before episodes kept their final observation"):
        main(RecordConfig(dataset=without_finals, episodes=1, max_steps=20, writer="inline", progress=False))
    assert snapshot(without_finals) == before
