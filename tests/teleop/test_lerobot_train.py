"""LeRobot's own trainer (`lerobot-train --policy.type=act`) on a recording, as written, with no conversion."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors

from common import columns
from support import run_lerobot_train, snapshot
from teleop.lerobot_io import format as lerobot_format

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

STEPS = 3
REPO_ID = "local/humanoid_stand"
LOSS = re.compile(r"\bstep:(\d+)\b.*?\sloss:(\S+)")  # LeRobot's log line: "step:3 smpl:6 ... loss:68.272 grdn:..."


@dataclass(frozen=True)
class TrainRun:
    returncode: int
    output: str  # stdout and stderr together
    output_dir: Path
    dataset_before: dict[str, bytes]
    dataset_after: dict[str, bytes]


@pytest.fixture(scope="module")
def train_run(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainRun:
    """`lerobot-train` run once, in a subprocess, on the shared recording; every cache in a temporary folder."""
    work = tmp_path_factory.mktemp("lerobot-train")
    before = snapshot(recorded)
    result = run_lerobot_train(recorded, work, REPO_ID, STEPS)
    return TrainRun(result.returncode, result.stdout + result.stderr, work / "outputs", before, snapshot(recorded))


def test_lerobot_train_exits_cleanly(train_run: TrainRun) -> None:
    """lerobot-train accepts the recording as it is and finishes with exit code 0."""
    assert train_run.returncode == 0, train_run.output[-4000:]


def test_lerobot_train_prints_no_traceback(train_run: TrainRun) -> None:
    """No page-long torchcodec traceback before LeRobot falls back to pyav: torchcodec is left out of the lock
    (these datasets hold no video; docs/how-to/lerobot-train.md#no-torchcodec)."""
    assert "Traceback" not in train_run.output, train_run.output[:4000]


def test_loading_with_lerobot_prints_no_traceback(recorded: Path) -> None:
    """`LeRobotDataset(...)` in a process of its own (this project's `teleop` package quiets LeRobot's logger; a user's
    script does not): with `video_backend="pyav"` nothing on stderr at all, without it no traceback (one line saying
    LeRobot decodes with pyav)."""
    script = (
        "import sys\n"
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        f"print(len(LeRobotDataset({REPO_ID!r}, root={str(recorded)!r}, video_backend='pyav')))\n"
        "print('--- default backend', file=sys.stderr, flush=True)\n"
        f"print(len(LeRobotDataset({REPO_ID!r}, root={str(recorded)!r})))"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and result.stdout.split() == [str(total_frames(recorded))] * 2, result.stderr
    with_pyav, default = result.stderr.split("--- default backend\n")
    assert with_pyav == ""
    assert "Traceback" not in default and len(default.splitlines()) <= 1, default[:4000]


def total_frames(root: Path) -> int:
    return json.loads((root / lerobot_format.INFO_PATH).read_text())["total_frames"]


def test_trainer_reads_every_frame_and_episode(recorded: Path, train_run: TrainRun) -> None:
    """The trainer sees the recording's frame and episode counts from meta/info.json."""
    info = json.loads((recorded / lerobot_format.INFO_PATH).read_text())
    assert f"dataset.num_frames={info['total_frames']}" in train_run.output
    assert f"dataset.num_episodes={info['total_episodes']}" in train_run.output


def test_logged_loss_is_finite_at_every_step(train_run: TrainRun) -> None:
    """Every step logs a finite loss."""
    losses = {int(step): float(loss) for step, loss in LOSS.findall(train_run.output)}
    assert sorted(losses) == list(range(1, STEPS + 1)), train_run.output[-4000:]
    assert all(math.isfinite(loss) for loss in losses.values()), losses


def test_checkpoint_holds_the_trained_act_model(recorded: Path, train_run: TrainRun) -> None:
    """checkpoints/last/pretrained_model holds the ACT weights, its config and the normalisation statistics."""
    features = json.loads((recorded / lerobot_format.INFO_PATH).read_text())["features"]
    model = train_run.output_dir / "checkpoints" / "last" / "pretrained_model"
    assert (train_run.output_dir / "checkpoints" / "last").resolve().name == f"{STEPS:06d}"
    assert (model / "model.safetensors").stat().st_size > 0
    config = json.loads((model / "config.json").read_text())
    assert config["type"] == "act"
    assert {columns.OBS_STATE, columns.OBS_ENV_STATE} <= set(config["input_features"])
    assert set(config["input_features"]) == {key for key in features if key.startswith("observation.")}
    assert config["output_features"][columns.ACTION]["shape"] == [17]
    assert (model / "policy_preprocessor.json").is_file()
    assert (model / "policy_postprocessor.json").is_file()


def test_training_leaves_the_dataset_untouched(train_run: TrainRun) -> None:
    """Training writes nothing into the dataset folder: every file is byte for byte as recorded."""
    assert train_run.dataset_after == train_run.dataset_before


def test_saved_policy_acts_on_a_recorded_frame(recorded: Path, train_run: TrainRun) -> None:
    """LeRobot's ACTPolicy loads the checkpoint and gives a finite 17-dim action for a frame of the recording."""
    model = train_run.output_dir / "checkpoints" / "last" / "pretrained_model"
    policy = ACTPolicy.from_pretrained(model)
    preprocess, postprocess = make_pre_post_processors(policy.config, pretrained_path=str(model))
    frame = LeRobotDataset(REPO_ID, root=recorded)[0]
    observation = {key: frame[key] for key in policy.config.input_features}
    policy.reset()
    with torch.inference_mode():
        action = postprocess(policy.select_action(preprocess(observation)))
    assert action.shape == (1, 17)
    assert torch.isfinite(action).all()
