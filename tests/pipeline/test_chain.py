"""The stage targets chain on their defaults: `make record && make train-bc && make dagger && make finetune-rl &&
make eval` in an empty folder, given budgets only, each stage reading what the one before it wrote."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from common import columns, paths
from common.cli import UserError
from policies.folder import CONFIG_FILE, DATASET_FILE, WEIGHTS_FILE, chosen_policy, newest
from teleop.dataset_reader import fingerprint, read_episodes, read_frames

MAKEFILE = Path(__file__).resolve().parents[2] / "Makefile"
PPO_BUDGET = (
    "--rollout-steps 256 --batch-size 64 --eval-freq 256 --eval-episodes 1 --floor-episodes 1 --final-eval-episodes 1 "
    "--critic-warmup 0"
)
"""PPO's budget below its defaults: one rollout of 256 steps, one episode per evaluation."""


def make(folder: Path, target: str, *variables: str) -> subprocess.CompletedProcess[str]:
    """`make -f <the project's Makefile> TARGET VAR=value ...` run in `folder`."""
    return subprocess.run(
        ["make", "-s", "-f", str(MAKEFILE), target, *variables], cwd=folder, capture_output=True, text=True, check=True
    )


def training(folder: Path) -> dict:
    return json.loads((folder / CONFIG_FILE).read_text())["training"]


@pytest.mark.slow
def test_the_five_commands_chain_in_an_empty_folder(tmp_path: Path) -> None:
    """Budgets only (episodes, steps, epochs, rounds, updates, environments; no evaluation before `make eval`'s): the
    recording is the operator's demonstrations by the teacher on what a robot senses; the student trains on them;
    DAgger starts from them; PPO refines the newest student, the DAgger one, and says so; `make eval` takes the newest
    policy, PPO's, on held-out schedules."""
    make(tmp_path, "record", "EPISODES=3", "MAX_STEPS=250")
    dataset = tmp_path / paths.DATASET
    episodes = read_episodes(dataset, [columns.EPISODE_CONTROLLER]).to_pydict()[columns.EPISODE_CONTROLLER]
    assert episodes == ["expert-sensed"] * 3
    assert len(np.unique(read_frames(dataset, [columns.OBS_COMMAND])[columns.OBS_COMMAND], axis=0)) > 1

    make(tmp_path, "train-bc", "EPOCHS=1", "MIN_UPDATES=20", "EVAL_EPISODES=0")
    student = tmp_path / paths.BC_POLICY
    identity = json.loads((student / DATASET_FILE).read_text())
    assert (Path(identity["path"]), identity["fingerprint"]) == (dataset.resolve(), fingerprint(dataset))

    make(tmp_path, "dagger", "ROUNDS=1", "EPISODES=1", "EPOCHS=1", "MIN_UPDATES=20", "EVAL_EPISODES=0")
    dagger = tmp_path / paths.DAGGER_POLICY
    assert training(dagger)["dagger"]["dataset"] == str(paths.DATASET)
    assert training(dagger)["demonstrations"] == fingerprint(dataset)

    tuned = make(tmp_path, "finetune-rl", "TIMESTEPS=256", "ENVS=1", f"ARGS={PPO_BUDGET}")
    assert f"policy: {paths.DAGGER_POLICY}, the newest of " in tuned.stderr
    ppo = tmp_path / paths.PPO_POLICY
    assert training(ppo)["bc_policy"] == str(paths.DAGGER_POLICY)
    assert training(ppo)["bc_policy_sha256"] == hashlib.sha256((dagger / WEIGHTS_FILE).read_bytes()).hexdigest()

    evaluated = make(tmp_path, "eval", "EPISODES=1")
    result = json.loads(evaluated.stdout.splitlines()[-1])
    assert result["policy"] == str(paths.PPO_POLICY) and result["tracking"] is not None
    assert sorted(path.name for path in (tmp_path / "policies").iterdir()) == sorted(
        path.name for path in paths.LEARNED
    )


def checkpoint_at(folder: Path, written_ns: int) -> Path:
    """The files that make `folder` a checkpoint (their content aside), its weights written at `written_ns`."""
    folder.mkdir(parents=True)
    (folder / CONFIG_FILE).write_text("{}")
    (folder / WEIGHTS_FILE).write_bytes(b"")
    os.utime(folder / WEIGHTS_FILE, ns=(written_ns, written_ns))
    return folder


def test_the_newest_checkpoint_is_the_one_whose_weights_were_written_last(tmp_path: Path) -> None:
    """Known answer on three candidates, one no checkpoint: the later weights win, whatever the order given."""
    early, late = checkpoint_at(tmp_path / "a", 10**18), checkpoint_at(tmp_path / "b", 2 * 10**18)
    (tmp_path / "c").mkdir()
    assert newest([early, late, tmp_path / "c"]) == newest([tmp_path / "c", late, early]) == late
    assert newest([tmp_path / "c", tmp_path / "missing"]) is None
    assert chosen_policy("kept/as/given", [early, late], "make it") == "kept/as/given"


def test_no_checkpoint_yet_is_refused_in_one_line_naming_what_makes_one(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"^no policy checkpoint yet at .*/x, .*/y: make train-bc makes one$"):
        chosen_policy(paths.NEWEST, [tmp_path / "x", tmp_path / "y"], "make train-bc")
