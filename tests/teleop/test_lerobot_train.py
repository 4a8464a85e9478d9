"""LeRobot's own trainer (`lerobot-train --policy.type=act`) on a recording, as written, with no conversion."""

from __future__ import annotations

import json
import math
import os
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

from common import keys
from support import snapshot
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


def train_command(dataset: Path, output_dir: Path) -> list[str]:
    """A CPU run of a small ACT for a few steps; nothing from the Hub, no wandb, a checkpoint at the last step."""
    return [
        str(Path(sys.executable).parent / "lerobot-train"),
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={dataset}",
        "--policy.type=act",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--wandb.enable=false",
        f"--output_dir={output_dir}",
        f"--steps={STEPS}",
        f"--save_freq={STEPS}",
        "--log_freq=1",
        "--batch_size=2",
        "--num_workers=0",
        # Small enough to train in a fraction of a second; ACT with no camera builds no ResNet.
        "--policy.chunk_size=10",
        "--policy.n_action_steps=10",
        "--policy.dim_model=64",
        "--policy.n_heads=2",
        "--policy.dim_feedforward=128",
        "--policy.n_encoder_layers=1",
        "--policy.n_vae_encoder_layers=1",
    ]


@pytest.fixture(scope="module")
def train_run(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainRun:
    """`lerobot-train` run once, in a subprocess, on the shared recording; every cache in a temporary folder."""
    work = tmp_path_factory.mktemp("lerobot-train")
    output_dir = work / "outputs"  # must not exist yet: lerobot-train refuses an existing one unless resuming
    env = {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "HF_HOME": str(work / "hf"),
        "HF_DATASETS_CACHE": str(work / "hf-datasets"),
        "HF_LEROBOT_HOME": str(work / "lerobot"),
        "WANDB_MODE": "disabled",
    }
    before = snapshot(recorded)
    result = subprocess.run(
        train_command(recorded, output_dir), cwd=work, env=env, capture_output=True, text=True, timeout=300
    )
    return TrainRun(result.returncode, result.stdout + result.stderr, output_dir, before, snapshot(recorded))


def test_lerobot_train_exits_cleanly(train_run: TrainRun) -> None:
    """lerobot-train accepts the recording as it is and finishes with exit code 0."""
    assert train_run.returncode == 0, train_run.output[-4000:]


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
    assert {keys.OBS_STATE, keys.OBS_ENV_STATE} <= set(config["input_features"])
    assert set(config["input_features"]) == {key for key in features if key.startswith("observation.")}
    assert config["output_features"][keys.ACTION]["shape"] == [17]
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
