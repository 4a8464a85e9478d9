"""`make export FORMAT=minari`: Minari's own loader reads the dataset, every transition equal to the LeRobot frames,
the operator's command beside each observation where one was commanded."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import minari
import numpy as np
import pytest

from common import columns
from common.seed_ranges import EVAL_SEED
from evaluation.evaluate import evaluate
from support import snapshot
from task.command_fields import COMMAND_NAMES, FIELDS
from teleop.dataset_reader import read_frames
from teleop.export import ExportConfig, dataset_id, main

pytestmark = pytest.mark.slow  # reference episodes of the expert: seconds


@pytest.fixture(scope="module")
def exported(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[minari.MinariDataset]:
    """The 3-episode recording exported to a new Minari root, loaded back by Minari with its root set; a killed
    export's staging root beside it (its name's) is replaced, and none is left."""
    folder = tmp_path_factory.mktemp("minari")
    (folder / ".root.partial/humanoid-bc").mkdir(parents=True)
    yield from export_and_load(recorded, folder / "root", reference_episodes=2)
    assert sorted(path.name for path in folder.iterdir()) == ["root"]


@pytest.fixture(scope="module")
def exported_commands(operated: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[minari.MinariDataset]:
    """The scripted operator's recording, exported and loaded back the same way."""
    yield from export_and_load(operated, tmp_path_factory.mktemp("minari-command") / "root", reference_episodes=1)


def export_and_load(dataset: Path, out: Path, reference_episodes: int) -> Iterator[minari.MinariDataset]:
    """`dataset` exported to the new Minari root `out`, loaded back by Minari with its root set."""
    name = main(ExportConfig(dataset=dataset, out=out, reference_episodes=reference_episodes))
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MINARI_DATASETS_PATH", str(out))
        yield minari.load_dataset(name)


def test_each_episode_has_t_plus_one_observations_for_t_actions(exported: minari.MinariDataset, recorded: Path) -> None:
    """Minari serves T+1 observations and all T actions (given T observations it would silently drop an action).
    Nothing was commanded (standing is the zero command), so the observation is the gymnasium one, a Box."""
    frames = read_frames(recorded, ["episode_index"])
    lengths = np.bincount(frames["episode_index"])
    episodes = list(exported.iterate_episodes())
    assert [len(e.actions) for e in episodes] == lengths.tolist()
    assert all(e.observations.shape == (len(e.actions) + 1, 348) for e in episodes)
    assert exported.total_steps == lengths.sum()
    assert exported.observation_space == exported.recover_environment().observation_space


def test_a_commanded_observation_holds_the_command_in_force(
    exported_commands: minari.MinariDataset, operated: Path
) -> None:
    """Where an operator commanded, each observation is a Dict: the gymnasium observation, and the command in force
    at it (the final observation under the last frame's), within the posture's limits; the actions are the frames'."""
    space = exported_commands.observation_space
    assert isinstance(space, gym.spaces.Dict) and set(space) == {"observation", "command"}
    assert space["observation"] == exported_commands.recover_environment().observation_space
    for bounds, limits in ((space["command"].low, "low"), (space["command"].high, "high")):
        np.testing.assert_array_equal(
            bounds, np.array([getattr(FIELDS[name], limits) for name in COMMAND_NAMES], np.float32)
        )
    frames = read_frames(operated, [columns.OBS_COMMAND, columns.ACTION, "episode_index"])
    for episode in exported_commands.iterate_episodes():
        rows = frames["episode_index"] == episode.id
        command = frames[columns.OBS_COMMAND][rows]
        np.testing.assert_array_equal(episode.observations["command"], np.vstack([command, command[-1:]]))
        assert episode.observations["observation"].shape == (rows.sum() + 1, 348)
        np.testing.assert_array_equal(episode.actions, frames[columns.ACTION][rows])
        assert command.any()  # the schedule commanded something after its neutral start


def test_steps_equal_the_lerobot_frames(exported: minari.MinariDataset, recorded: Path) -> None:
    """Actions, rewards, terminations and truncations are the frames' own, in order."""
    names = [columns.ACTION, columns.REWARD, columns.TERMINATED, columns.TRUNCATED, "episode_index"]
    frames = read_frames(recorded, names)
    for episode in exported.iterate_episodes():
        rows = frames["episode_index"] == episode.id
        np.testing.assert_array_equal(episode.actions, frames[columns.ACTION][rows])
        np.testing.assert_array_equal(episode.rewards, frames[columns.REWARD][rows].reshape(-1))
        np.testing.assert_array_equal(episode.terminations, frames[columns.TERMINATED][rows].reshape(-1))
        np.testing.assert_array_equal(episode.truncations, frames[columns.TRUNCATED][rows].reshape(-1))


def test_the_environment_is_humanoid_v5(exported: minari.MinariDataset) -> None:
    assert exported.recover_environment().spec.id == "Humanoid-v5"


def test_scores_normalise_between_the_random_and_the_expert_returns(exported: minari.MinariDataset) -> None:
    """The reference scores are the random controller's and the expert's mean returns on the export's seeds."""
    returns = [evaluate(name, 2, EVAL_SEED)["mean_return"] for name in ("random", "expert")]
    np.testing.assert_allclose(minari.get_normalized_score(exported, np.array(returns)), [0.0, 1.0], atol=1e-9)


def export_cli(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "teleop.export", "--reference-episodes", "1", *args]
    return subprocess.run(command, capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})


def test_folder_that_is_not_a_dataset_is_refused(tmp_path: Path) -> None:
    run = export_cli("--dataset", str(tmp_path), "--out", str(tmp_path / "out"))
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1 and "no recorded dataset" in run.stderr
    assert not (tmp_path / "out").exists()


def test_existing_out_is_refused_and_left_alone(recorded: Path, tmp_path: Path) -> None:
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "mine.txt").write_text("keep")
    before = snapshot(tmp_path / "out")
    run = export_cli("--dataset", str(recorded), "--out", str(tmp_path / "out"))
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1 and "exists" in run.stderr
    assert snapshot(tmp_path / "out") == before


def test_an_out_inside_the_dataset_is_refused_and_the_dataset_left_alone(recorded: Path, tmp_path: Path) -> None:
    dataset = tmp_path / "dataset"
    shutil.copytree(recorded, dataset)
    before = snapshot(dataset)
    run = export_cli("--dataset", str(dataset), "--out", str(dataset / "minari"))
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1 and "lies inside DATASET" in run.stderr
    assert snapshot(dataset) == before


@pytest.mark.parametrize("out_format", ["minari", "lerobot-command"])
def test_a_dataset_whose_info_is_cut_short_is_refused_in_one_line(
    recorded: Path, tmp_path: Path, out_format: str
) -> None:
    dataset = tmp_path / "dataset"
    shutil.copytree(recorded, dataset)
    info = dataset / "meta" / "info.json"
    info.write_text(info.read_text()[:40])
    run = export_cli("--dataset", str(dataset), "--out", str(tmp_path / "out"), "--format", out_format)
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1, run.stderr
    assert "meta/info.json is not readable JSON" in run.stderr and not (tmp_path / "out").exists()


def test_an_out_the_disk_refuses_is_one_line_naming_it(recorded: Path, tmp_path: Path) -> None:
    """An OUT below a file (as below a folder the user may not write): the disk's refusal in one line, not a
    traceback (`common.cli.PLACE_ERRORS`)."""
    (tmp_path / "notes.txt").write_text("keep")
    run = export_cli("--dataset", str(recorded), "--out", str(tmp_path / "notes.txt" / "out"))
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1, run.stderr
    assert run.stderr.startswith(f"error: {tmp_path / 'notes.txt'}") and "Not a directory" in run.stderr
    assert (tmp_path / "notes.txt").read_text() == "keep"


def test_unknown_format_is_refused(recorded: Path, tmp_path: Path) -> None:
    run = export_cli("--dataset", str(recorded), "--out", str(tmp_path / "out"), "--format", "d4rl")
    assert run.returncode == 2 and len(run.stderr.splitlines()) == 1 and "'d4rl'" in run.stderr
    assert not (tmp_path / "out").exists()


def test_the_id_names_the_dataset_folder(recorded: Path) -> None:
    assert dataset_id(recorded) == f"humanoid-bc/{recorded.resolve().name}-v0"
