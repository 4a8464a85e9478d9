"""`make record LATENCY=share`: a share of the episodes delayed by one step, the delay stored and told to the expert."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bc.data import load_demonstrations
from common import columns
from humanoid.conditions import LATENCY_PARAMETER, ActionLatency
from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import run_episode
from support import drawn_delay, mcap_parameters
from teachers.registry import TEACHER
from teleop.dataset_reader import read_episodes, read_frames, read_parameters
from teleop.inspect_dataset import InspectConfig
from teleop.inspect_dataset import main as inspect
from teleop.record import DART_NOISE, STANDING, RecordConfig, cli, effective, main

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

STEPS = 40
EPISODES = 6


@pytest.fixture(scope="module")
def delayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """EPISODES episodes (seeds 0..5) of the expert recorded with LATENCY=0.5."""
    root = tmp_path_factory.mktemp("latency") / "dataset"
    main(
        RecordConfig(
            dataset=root,
            episodes=EPISODES,
            max_steps=STEPS,
            writer="inline",
            progress=False,
            **{**STANDING, "latency": 0.5},
        )
    )
    return root


def test_each_episode_stores_its_drawn_delay_in_both_formats(delayed: Path) -> None:
    """The episode column and the MCAP metadata hold the wrapper's draw for the episode's seed."""
    expected = [{LATENCY_PARAMETER: drawn_delay(seed)} for seed in range(EPISODES)]
    assert {d[LATENCY_PARAMETER] for d in expected} == {0, 1}  # both kinds among these seeds
    assert read_parameters(delayed) == expected
    rows = read_episodes(delayed).to_pylist()
    assert [mcap_parameters(delayed / row[columns.EPISODE_MCAP]) for row in rows] == expected


def test_the_expert_is_told_each_episodes_delay(delayed: Path) -> None:
    """A delayed episode's labels are those of the expert built for one step of latency, the others the plain one's."""
    frames = read_frames(delayed, [columns.ACTION, "episode_index"])
    for episode, drawn in enumerate(read_parameters(delayed)):
        env = ActionLatency(make_env(STEPS), 1) if drawn[LATENCY_PARAMETER] else make_env(STEPS)
        reference = run_episode(env, make_controller("expert", env), seed=episode, noise_std=DART_NOISE)
        np.testing.assert_array_equal(frames[columns.ACTION][frames["episode_index"] == episode], reference.action)


def test_pending_inputs_read_each_episodes_recorded_delay(delayed: Path) -> None:
    """`make train-bc INPUTS=pending`: each frame's delay entry is its episode's, its pending command the previous
    frame's label in a delayed episode."""
    demos = load_demonstrations(delayed, make_env(), cache=False, inputs="pending")
    delays = np.array([drawn[LATENCY_PARAMETER] for drawn in read_parameters(delayed)])
    np.testing.assert_array_equal(demos.inputs[:, -1].numpy(), delays[demos.episode_index])
    first = np.r_[True, demos.episode_index[1:] != demos.episode_index[:-1]]
    carried = ~first & (delays[demos.episode_index] == 1)
    pending = demos.inputs[:, -18:-1].numpy()
    np.testing.assert_array_equal(pending[carried], demos.actions.numpy()[np.flatnonzero(carried) - 1])
    np.testing.assert_array_equal(pending[~carried], 0.0)


def test_inspect_counts_the_episodes_of_each_delay(delayed: Path) -> None:
    delays = [drawn[LATENCY_PARAMETER] for drawn in read_parameters(delayed)]
    report = inspect(InspectConfig(dataset=delayed, lerobot=False))
    expected = f"0 in {delays.count(0)} episodes, 1 in {delays.count(1)} episodes"
    assert report.randomized == {LATENCY_PARAMETER: expected}


@pytest.mark.parametrize("share", ["1.5", "-0.1", "nan"])
def test_a_latency_share_outside_0_1_is_refused_in_one_line(
    share: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli(["--dataset", str(tmp_path / "new"), "--latency", share, "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and err == [f"error: --latency must be a share in [0, 1], got {float(share)}"]
    assert not (tmp_path / "new").exists()


def test_the_keyboard_records_no_delayed_episode_and_no_schedule() -> None:
    """With the keys the command is theirs and no episode is delayed, whatever the recording's defaults say."""
    keyed = effective(RecordConfig(controller="keyboard", latency=0.5, task="posture"))
    assert (keyed.latency, keyed.task) == (0.0, "stand")
    assert effective(RecordConfig(latency=0.5)) == RecordConfig(latency=0.5, controller=TEACHER)
