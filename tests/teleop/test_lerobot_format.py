"""The recorder's LeRobot v3.0 output, held against LeRobot's own writer and reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from lerobot.datasets import compute_stats, dataset_metadata, utils
from lerobot.datasets.compute_stats import aggregate_stats
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils import constants
from lerobot.utils.constants import DEFAULT_FEATURES

from common import columns
from humanoid.env import make_env
from support import join_observation
from teleop.dataset_reader import read_episodes, read_frames
from teleop.lerobot_io import format as lerobot_format
from teleop.store import DatasetSpec

USER_KEYS = [
    columns.OBS_STATE,
    columns.OBS_ENV_STATE,
    columns.OBS_COMMAND,
    columns.SETPOINT,
    columns.PUSH,
    columns.ACTION,
    columns.EXECUTED_ACTION,
    columns.REWARD,
    columns.DONE,
    columns.TERMINATED,
    columns.TRUNCATED,
]
PROJECT_EPISODE_COLUMNS = {
    columns.EPISODE_SEED,
    columns.EPISODE_CONTROLLER,
    columns.EPISODE_LABELLER,
    columns.EPISODE_DAGGER_ROUND,
    columns.EPISODE_NOISE_STD,
    columns.EPISODE_RETURN,
    columns.EPISODE_TERMINATED,
    columns.EPISODE_TRUNCATED,
    columns.EPISODE_MCAP,
    columns.EPISODE_FINAL_STATE,
    columns.EPISODE_FINAL_ENV_STATE,
}


@pytest.fixture(scope="module")
def lerobot_copy(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same frames written by LeRobot's own LeRobotDataset.create / add_frame / save_episode."""
    root = tmp_path_factory.mktemp("lerobot") / "dataset"
    frames = read_frames(recorded)
    features = DatasetSpec.from_env(make_env()).features
    dataset = LeRobotDataset.create(
        "local/reference", fps=67, features=features, root=root, robot_type="mujoco_humanoid", use_videos=False
    )
    for episode in np.unique(frames["episode_index"]):
        for row in np.flatnonzero(frames["episode_index"] == episode):
            frame = {key: np.atleast_1d(frames[key][row]) for key in USER_KEYS}
            dataset.add_frame({**frame, "task": "Stand still on both feet."})
        dataset.save_episode()
    dataset.finalize()
    return root


def test_key_names_are_lerobots() -> None:
    """The key constants spelled out in common.columns are LeRobot's own."""
    assert (
        columns.OBS_STATE,
        columns.OBS_ENV_STATE,
        columns.ACTION,
        columns.REWARD,
        columns.DONE,
        columns.TRUNCATED,
    ) == (
        constants.OBS_STATE,
        constants.OBS_ENV_STATE,
        constants.ACTION,
        constants.REWARD,
        constants.DONE,
        constants.TRUNCATED,
    )


def test_format_constants_are_lerobots() -> None:
    """Paths, version, default features and quantiles in teleop.lerobot_io.format match lerobot.datasets."""
    assert lerobot_format.CODEBASE_VERSION == dataset_metadata.CODEBASE_VERSION
    assert (lerobot_format.INFO_PATH, lerobot_format.STATS_PATH, lerobot_format.TASKS_PATH) == (
        utils.INFO_PATH,
        utils.STATS_PATH,
        utils.DEFAULT_TASKS_PATH,
    )
    assert (lerobot_format.DATA_PATH, lerobot_format.EPISODES_PATH) == (
        utils.DEFAULT_DATA_PATH,
        utils.DEFAULT_EPISODES_PATH,
    )
    assert lerobot_format.CHUNKS_SIZE == utils.DEFAULT_CHUNK_SIZE
    assert lerobot_format.DEFAULT_FEATURES == DEFAULT_FEATURES
    assert list(lerobot_format.QUANTILES) == compute_stats.DEFAULT_QUANTILES
    for chunk, file in [(0, 0), (0, 998), (0, 999), (3, 999)]:
        assert lerobot_format.next_chunk_file(chunk, file) == utils.update_chunk_file_indices(chunk, file, 1000)


def test_info_json_equals_lerobots(recorded: Path, lerobot_copy: Path) -> None:
    """meta/info.json is what LeRobot writes for the same features and episodes, field for field."""
    ours = json.loads((recorded / lerobot_format.INFO_PATH).read_text())
    theirs = json.loads((lerobot_copy / lerobot_format.INFO_PATH).read_text())
    assert ours == theirs


def test_frame_parquet_schema_equals_lerobots(recorded: Path, lerobot_copy: Path) -> None:
    """Data files carry LeRobot's Arrow schema, HuggingFace feature metadata included."""
    ours = pq.read_schema(recorded / "data/chunk-000/file-000.parquet")
    theirs = pq.read_schema(lerobot_copy / "data/chunk-000/file-000.parquet")
    assert ours.equals(theirs)
    # LeRobot's copy also carries a random `fingerprint` of the in-memory dataset it came from.
    hf_info = [json.loads(schema.metadata[b"huggingface"])["info"] for schema in (ours, theirs)]
    assert hf_info[0] == hf_info[1]


def test_episode_rows_have_lerobots_columns_and_ours(recorded: Path, lerobot_copy: Path) -> None:
    """Episode metadata has every LeRobot column with LeRobot's type, plus this project's facts."""
    ours = pq.read_schema(recorded / "meta/episodes/chunk-000/file-000.parquet")
    theirs = pq.read_schema(lerobot_copy / "meta/episodes/chunk-000/file-000.parquet")
    for field in theirs:
        assert ours.field(field.name).type == field.type, field.name
    assert set(ours.names) - set(theirs.names) == PROJECT_EPISODE_COLUMNS


def test_frames_equal_lerobots(recorded: Path, lerobot_copy: Path) -> None:
    """Every column of every frame, read back, equals what LeRobot's writer stored."""
    ours, theirs = read_frames(recorded), read_frames(lerobot_copy)
    assert ours.keys() == theirs.keys()
    for key in ours:
        np.testing.assert_array_equal(ours[key], theirs[key], err_msg=key)
    assert (
        read_episodes(recorded)["dataset_to_index"].to_pylist()
        == read_episodes(lerobot_copy)["dataset_to_index"].to_pylist()
    )


def test_stats_match_lerobots(recorded: Path, lerobot_copy: Path) -> None:
    """stats.json has LeRobot's keys and shapes; moments agree, quantiles within its histogram resolution."""
    ours = json.loads((recorded / lerobot_format.STATS_PATH).read_text())
    theirs = json.loads((lerobot_copy / lerobot_format.STATS_PATH).read_text())
    assert ours.keys() == theirs.keys()
    for key in ours:
        assert ours[key].keys() == theirs[key].keys(), key
        value_range = np.asarray(theirs[key]["max"]) - np.asarray(theirs[key]["min"])
        for stat in ours[key]:
            mine, reference = np.asarray(ours[key][stat]), np.asarray(theirs[key][stat])
            assert mine.shape == reference.shape, (key, stat)
            # LeRobot's quantiles interpolate inside 5000-bin histograms; ours are exact.
            tolerance = value_range / 1000 + 1e-9 if stat.startswith("q") else 1e-6 * (1 + np.abs(reference))
            assert np.all(np.abs(mine - reference) <= tolerance), (key, stat)


def test_aggregate_stats_equals_lerobots() -> None:
    """Aggregating per-episode statistics gives LeRobot's aggregate, on a hand-built case."""
    rng = np.random.default_rng(0)
    episodes = [{"x": rng.normal(size=(n, 4))} for n in (5, 40, 11)]
    per_episode = [lerobot_format.episode_stats(frames) for frames in episodes]
    ours, theirs = lerobot_format.aggregate_stats(per_episode), aggregate_stats(per_episode)
    for stat in theirs["x"]:
        np.testing.assert_allclose(ours["x"][stat], theirs["x"][stat], rtol=1e-12, err_msg=stat)
    everything = np.concatenate([frames["x"] for frames in episodes])
    np.testing.assert_allclose(ours["x"]["mean"], everything.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(ours["x"]["std"], everything.std(axis=0), rtol=1e-12)


def test_lerobot_dataset_loads_offline_and_serves_our_values(recorded: Path) -> None:
    """LeRobotDataset(root=...) opens the recording without the Hub; its items hold the recorded values."""
    dataset = LeRobotDataset("local/humanoid", root=recorded)
    frames = read_frames(recorded)
    assert len(dataset) == len(frames["index"]) == dataset.meta.total_frames
    assert dataset.meta.total_episodes == 3
    for i in (0, len(dataset) // 2, len(dataset) - 1):
        item = dataset[i]
        assert item["task"] == "Stand still on both feet."
        for key in (columns.OBS_STATE, columns.OBS_ENV_STATE, columns.ACTION, columns.EXECUTED_ACTION):
            np.testing.assert_allclose(item[key].numpy(), frames[key][i], rtol=1e-6, atol=1e-6, err_msg=key)
    assert dataset.meta.episodes[columns.EPISODE_SEED] == [0, 1, 2]


def test_observation_is_exactly_reconstructible(recorded: Path) -> None:
    """observation.state + observation.environment_state is the gymnasium observation, bit for bit."""
    frames = read_frames(recorded, [columns.OBS_STATE, columns.OBS_ENV_STATE, "episode_index", "frame_index"])
    env = make_env()
    first_of_episode_1 = np.flatnonzero((frames["episode_index"] == 1) & (frames["frame_index"] == 0))[0]
    obs, _ = env.reset(seed=1)
    stored = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    assert stored.dtype == np.float64 and stored.shape[1] == 348
    np.testing.assert_array_equal(stored[first_of_episode_1], obs)


def test_episode_facts_are_readable(recorded: Path) -> None:
    """Seed, controller, return, length and how each episode ended are in the episode metadata."""
    episodes = read_episodes(recorded).to_pylist()
    frames = read_frames(recorded, [columns.REWARD, "episode_index"])
    for episode in episodes:
        rewards = frames[columns.REWARD][frames["episode_index"] == episode["episode_index"]]
        assert episode[columns.EPISODE_CONTROLLER] == "expert"
        assert episode[columns.EPISODE_NOISE_STD] == 0.05
        assert episode["length"] == len(rewards)
        assert episode[columns.EPISODE_RETURN] == pytest.approx(rewards.sum(), rel=1e-12)
        assert episode[columns.EPISODE_TERMINATED] != episode[columns.EPISODE_TRUNCATED]
    assert [e[columns.EPISODE_SEED] for e in episodes] == [0, 1, 2]
