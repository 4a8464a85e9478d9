"""`make export FORMAT=lerobot-command`: a LeRobot policy trained by `lerobot-train` reads the operator's command.

LeRobot's built-in policies read `observation.state` and `observation.environment_state` only; the copy's
`observation.state` ends with the command, so a policy trained on it by LeRobot's own trainer acts on it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors

from common import columns
from support import run_lerobot_train, snapshot
from task.command_fields import COMMAND_NAMES
from teleop.dataset_reader import read_episodes, read_frames, read_info
from teleop.export import COMMAND_STATE_NAMES, ExportConfig, main

pytestmark = pytest.mark.slow  # lerobot-train in a subprocess: seconds

REPO_ID = "local/operated_command"
STEPS = 3


@pytest.fixture(scope="module")
def copy(operated: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The scripted operator's recording exported for lerobot-train."""
    out = tmp_path_factory.mktemp("lerobot-command") / "operated_command"
    assert main(ExportConfig(dataset=operated, out=out, format="lerobot-command")) == str(out)
    return out


@dataclass(frozen=True)
class TrainRun:
    returncode: int
    output: str
    model: Path


@pytest.fixture(scope="module")
def trained(copy: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainRun:
    """3 steps of a small ACT by `lerobot-train` on the copy, as on a recording (tests/teleop/test_lerobot_train.py)."""
    work = tmp_path_factory.mktemp("lerobot-train-command")
    result = run_lerobot_train(copy, work, REPO_ID, STEPS)
    model = work / "outputs" / "checkpoints" / "last" / "pretrained_model"
    return TrainRun(result.returncode, result.stdout + result.stderr, model)


def test_the_state_ends_with_the_command(copy: Path, operated: Path) -> None:
    """LeRobot loads the copy: each frame's observation.state is the recorded state, then the command in force;
    observation.command is gone (no second copy for a policy to ignore), every other column as recorded."""
    dataset = LeRobotDataset(REPO_ID, root=copy, video_backend="pyav")
    source = read_frames(operated)
    assert len(dataset) == len(source["index"])
    names = dataset.meta.features[columns.OBS_STATE]["names"]
    assert names[-len(COMMAND_NAMES) :] == list(COMMAND_STATE_NAMES)
    assert names[: -len(COMMAND_NAMES)] == read_info(operated)["features"][columns.OBS_STATE]["names"]
    assert columns.OBS_COMMAND not in dataset.meta.features
    for index in (0, len(dataset) - 1):  # as LeRobot serves them: float32 tensors
        frame = dataset[index]
        expected = np.concatenate([source[columns.OBS_STATE][index], source[columns.OBS_COMMAND][index]])
        np.testing.assert_allclose(frame[columns.OBS_STATE].numpy(), expected, rtol=1e-6)
        np.testing.assert_array_equal(frame[columns.ACTION].numpy(), source[columns.ACTION][index])
    copied = read_frames(copy)  # as stored: the state float64, bit for bit, the command's float32 widened
    expected = np.hstack([source[columns.OBS_STATE], source[columns.OBS_COMMAND].astype(np.float64)])
    np.testing.assert_array_equal(copied[columns.OBS_STATE], expected)
    for column in set(source) - {columns.OBS_STATE, columns.OBS_COMMAND}:
        np.testing.assert_array_equal(copied[column], source[column], err_msg=column)


def test_statistics_cover_the_command(copy: Path, operated: Path) -> None:
    """stats.json, which lerobot-train normalises with, describes the extended state: the command's entries
    included (their spread is what MEAN_STD divides by)."""
    stats = json.loads((copy / "meta/stats.json").read_text())[columns.OBS_STATE]
    source = read_frames(operated, [columns.OBS_STATE, columns.OBS_COMMAND])
    state = np.hstack([source[columns.OBS_STATE], source[columns.OBS_COMMAND].astype(np.float64)])
    np.testing.assert_allclose(stats["mean"], state.mean(axis=0), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(stats["std"], state.std(axis=0), rtol=1e-6, atol=1e-12)
    assert stats["count"] == [len(state)]
    assert np.max(stats["std"][-len(COMMAND_NAMES) :]) > 0


def test_episodes_keep_their_columns_and_final_state(copy: Path, operated: Path) -> None:
    """The episode rows keep seeds, controller and the final observation (its state extended by the last command);
    the MCAP files stay with the recording."""
    ours, theirs = read_episodes(copy).to_pylist(), read_episodes(operated).to_pylist()
    commands = read_frames(operated, [columns.OBS_COMMAND, "episode_index"])
    for row, source in zip(ours, theirs, strict=True):
        assert row[columns.EPISODE_SEED] == source[columns.EPISODE_SEED]
        assert row[columns.EPISODE_CONTROLLER] == source[columns.EPISODE_CONTROLLER] == "expert"
        assert row["tasks"] == source["tasks"]
        last = commands[columns.OBS_COMMAND][commands["episode_index"] == source["episode_index"]][-1]
        np.testing.assert_array_equal(row[columns.EPISODE_FINAL_STATE], [*source[columns.EPISODE_FINAL_STATE], *last])
        assert columns.EPISODE_MCAP not in row
    assert not (copy / "mcap").exists()


def test_lerobot_train_conditions_act_on_the_command(trained: TrainRun, copy: Path) -> None:
    """lerobot-train trains ACT on the copy; the policy's state input has the command's entries, and changing the
    command alone changes the action it chooses."""
    assert trained.returncode == 0, trained.output[-4000:]
    config = json.loads((trained.model / "config.json").read_text())
    assert config["input_features"][columns.OBS_STATE]["shape"] == [48 + len(COMMAND_NAMES)]
    assert columns.OBS_COMMAND not in config["input_features"]
    policy = ACTPolicy.from_pretrained(trained.model)
    preprocess, postprocess = make_pre_post_processors(policy.config, pretrained_path=str(trained.model))
    frame = LeRobotDataset(REPO_ID, root=copy, video_backend="pyav")[0]
    actions = []
    for lean in (0.0, 0.2):
        observation = {key: frame[key].clone() for key in policy.config.input_features}
        observation[columns.OBS_STATE][-len(COMMAND_NAMES)] = lean  # command.lean_forward
        policy.reset()
        with torch.inference_mode():
            actions.append(postprocess(policy.select_action(preprocess(observation))))
    assert actions[0].shape == (1, 17) and torch.isfinite(actions[0]).all()
    assert not torch.equal(actions[0], actions[1])


def export_cli(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "teleop.export", "--format", "lerobot-command", *args]
    return subprocess.run(command, capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})


def test_a_dataset_without_a_command_is_refused_in_one_line(recorded: Path, tmp_path: Path) -> None:
    """The expert's standing recording: every command zero, nothing to condition on; one line, nothing written."""
    before = snapshot(recorded)
    run = export_cli("--dataset", str(recorded), "--out", str(tmp_path / "out"))
    assert run.returncode == 1 and len(run.stderr.splitlines()) == 1, run.stderr
    assert "command is zero in every frame" in run.stderr
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []
    assert snapshot(recorded) == before


def test_the_command_line_names_the_copy_and_the_fields_never_commanded(operated: Path, tmp_path: Path) -> None:
    """`make export FORMAT=lerobot-command` says where the copy is and how to train on it."""
    run = export_cli("--dataset", str(operated), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"{tmp_path / 'out'}: LeRobot dataset whose observation.state ends with the command")
    assert f"lerobot-train --dataset.root={tmp_path / 'out'}" in run.stdout
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging folder left
