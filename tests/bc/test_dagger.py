"""`make dagger`: policy rollouts labelled by the expert, appended as rounds, the demonstrations untouched."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bc.dagger import DaggerConfig, DaggerResult, cli, main
from common import keys
from common.cli import config_dict
from humanoid.expert import LQRExpert, SensedExpert
from policies import checkpoint
from policies.folder import CONFIG_FILE
from support import join_observation, snapshot
from teleop import recordings
from teleop.dataset_reader import read_episodes, read_frames

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)


ONE_ROUND = {"rounds": 1, "episodes": 2, "min_updates": 0, "eval_episodes": 0, "progress": False}
"""A tiny DAgger run: one round of 2 episodes, each training exactly its epochs, no final evaluation."""


@pytest.fixture(scope="module")
def dagger(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, DaggerResult, dict]:
    """One DAgger round of 2 episodes on a copy of the 3-episode recording, the student on the sensed features
    (the privileged expert teaching a proprioceptive student)."""
    folder = tmp_path_factory.mktemp("dagger")
    demonstrations = folder / "demonstrations"
    shutil.copytree(recorded, demonstrations)
    before = snapshot(demonstrations)
    output = folder / "aggregate"
    config = DaggerConfig(
        dataset=demonstrations, output=output, policy=folder / "policy", inputs="proprio", **ONE_ROUND
    )
    result = main(config)
    return demonstrations, output, result, before, config


def test_rounds_are_appended_after_the_demonstrations(dagger: tuple) -> None:
    """The aggregate holds the demonstrations (round 0) then the round's policy episodes, seeds continuing."""
    _, output, result, _, _ = dagger
    episodes = read_episodes(output).to_pylist()
    assert [e[keys.EPISODE_DAGGER_ROUND] for e in episodes] == [0, 0, 0, 1, 1]
    assert [e[keys.EPISODE_SEED] for e in episodes] == [0, 1, 2, 3, 4]
    assert [e[keys.EPISODE_LABELLER] for e in episodes] == ["expert"] * 5
    assert episodes[0][keys.EPISODE_CONTROLLER] == "expert"
    assert all(e[keys.EPISODE_CONTROLLER] != "expert" for e in episodes[3:])  # the policy drove
    assert [r.round for r in result.rounds] == [1]
    assert result.rounds[0].frames == sum(e["length"] for e in episodes[3:])


def test_labels_are_the_experts_actions_in_the_policys_states(dagger: tuple) -> None:
    """Every DAgger frame's label is what the expert does in the stored state; what ran was the policy's action."""
    _, output, _, _, _ = dagger
    frames = read_frames(output)
    rows = frames["episode_index"] >= 3
    observations = join_observation(frames[keys.OBS_STATE][rows], frames[keys.OBS_ENV_STATE][rows])
    expert = LQRExpert()
    labels = np.stack([expert.act(obs) for obs in observations])
    np.testing.assert_array_equal(frames[keys.ACTION][rows], labels)
    assert not np.array_equal(frames[keys.EXECUTED_ACTION][rows], frames[keys.ACTION][rows])


@pytest.fixture(scope="module")
def sensed_dagger(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One round of 2 episodes labelled by the expert on leg odometry, an odometry student: the aggregate."""
    folder = tmp_path_factory.mktemp("sensed_dagger")
    config = DaggerConfig(
        dataset=recorded,
        output=folder / "aggregate",
        policy=folder / "policy",
        inputs="odometry",
        expert="expert-sensed",
        **ONE_ROUND,
    )
    main(config)
    return config.output


def test_the_sensed_expert_labels_each_episode_from_its_start(sensed_dagger: Path) -> None:
    """EXPERT=expert-sensed: each round episode's labels are the sensed expert's actions along it, its estimator
    reset at the episode's start; the labeller column names it."""
    episodes = read_episodes(sensed_dagger).to_pylist()
    assert [e[keys.EPISODE_LABELLER] for e in episodes] == ["expert"] * 3 + ["expert-sensed"] * 2
    frames = read_frames(sensed_dagger)
    expert = SensedExpert()
    for episode in episodes[3:]:
        rows = frames["episode_index"] == episode["episode_index"]
        expert.reset(episode[keys.EPISODE_SEED])
        observations = join_observation(frames[keys.OBS_STATE][rows], frames[keys.OBS_ENV_STATE][rows])
        labels = np.stack([expert.act(obs) for obs in observations])
        np.testing.assert_array_equal(frames[keys.ACTION][rows], labels)


def test_demonstrations_are_left_unchanged_and_a_policy_is_saved(dagger: tuple) -> None:
    """DATASET is only read; the final policy is a loadable checkpoint trained on the aggregate, on the inputs asked."""
    demonstrations, output, result, before, _ = dagger
    assert snapshot(demonstrations) == before
    assert result.final.train_frames + result.final.val_frames == len(read_frames(output, ["index"])["index"])
    assert checkpoint.load(result.final.policy_dir).spec.inputs == "proprio"


def test_final_checkpoint_records_the_dagger_settings(dagger: tuple) -> None:
    """The final policy's config.json holds every DaggerConfig field beside its training's, and who ran it."""
    *_, config = dagger
    training = json.loads((config.policy / CONFIG_FILE).read_text())["training"]
    assert training["dagger"] == config_dict(config) and training["made_by"] == "bc.dagger"


def test_aggregate_logs_the_rounds_in_recordings_jsonl(dagger: tuple) -> None:
    """OUTPUT/recordings.jsonl ends with the DAgger run's line: its settings and the episodes the round added."""
    _, output, _, _, config = dagger
    line = recordings.read(output)[-1]
    assert (line["made_by"], line["config"], line["complete"]) == ("bc.dagger", config_dict(config), True)
    assert (line["episodes"], line["seeds"], line["count"]) == ([3, 4], [3, 4], 2)


def test_output_equal_to_dataset_is_refused(recorded: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """DAgger never appends to the demonstrations themselves."""
    code = cli(["--dataset", str(recorded), "--output", str(recorded), "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "--output must differ from --dataset" in err[0]
