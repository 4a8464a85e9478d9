"""The benchmarks' timed calls against today's code, each on the smallest run: a benchmark whose call drifted from
the code it times fails here, not hours into `make bench`."""

from __future__ import annotations

from pathlib import Path

import pytest

from bc.train import TrainConfig
from bc.train import main as train_bc
from bench.camera_cost import cameras_flag, frames_per_second, rendered, video_cost
from bench.ppo_throughput import learn, settings
from bench.ppo_throughput import main as ppo_throughput
from bench.record_throughput import cpu_per_episode
from bench.stepping import standing
from bench.walker import walking_cost, walking_episode
from support import SMALL_BC
from task.posture import Posture
from task.schedules import command_vector
from teachers.walker import SensedWalker, Walker

pytestmark = pytest.mark.slow  # a whole episode, a whole PPO rollout: seconds


def test_record_throughput_times_each_stage_of_an_append(tmp_path: Path) -> None:
    costs = cpu_per_episode(1, tmp_path / "dataset")
    assert set(costs) == {"simulate", "spool write", "spool read", "append (both formats)", "of which MCAP"}
    assert 0 < costs["of which MCAP"] < costs["append (both formats)"]


def test_ppo_throughput_times_one_rollout_and_its_update(recorded: Path, tmp_path: Path) -> None:
    train_bc(TrainConfig(dataset=recorded, policy=tmp_path / "bc", **SMALL_BC))
    run = learn(settings(tmp_path / "bc", workers=1, envs=4, timesteps=1, rollout_steps=2048))  # one minibatch
    assert run.simulation_s > 0 and run.update_s > 0
    seconds = run.simulation_s + run.update_s + run.learner_s
    assert run.steps_per_s * seconds == pytest.approx(2048)  # the whole rollout PPO ran, not the one step asked


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--envs", "64", "--rollout-steps", "100"], "--rollout-steps (100) must be a multiple of --envs (64)"),
        (["--workers", "1", "3", "--envs", "2", "--rollout-steps", "64"], "--workers (3) must not exceed --envs (2)"),
    ],
)
def test_ppo_throughput_refuses_what_the_stage_refuses_before_any_run(
    args: list[str], message: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("sys.argv", ["bench.ppo_throughput", "--bc-policy", "missing", *args])
    with pytest.raises(SystemExit) as exit_:
        ppo_throughput()
    assert exit_.value.code == f"error: {message}"


def test_the_stepping_bench_measures_a_still_stance() -> None:
    planned, moved = standing(1000)
    assert planned == 0 and 0 <= moved < 0.02


def test_the_walker_bench_measures_a_walk_its_smoothness_and_its_estimate() -> None:
    """Seed 1001's schedule walks forward at 0.4 m/s, turning, from 3 s: the bench sees the walk's action changes and,
    on leg odometry, the estimate's 1 s mean errors; an action costs some time."""
    row = walking_episode(SensedWalker(), 1001)
    assert len(row["changes"]) > 100 and 0 < sum(row["changes"]) / len(row["changes"]) < 0.1
    assert row["errors"] and 0 <= max(row["errors"]) < 0.1
    assert walking_cost(Walker(), 1001, command_vector(Posture(forward_speed=0.3)), steps=10) > 0


def test_the_camera_bench_records_with_the_cameras_it_names() -> None:
    assert cameras_flag(2, (480, 640)) == "head:480x640,tracking:480x640" and cameras_flag(0, (96, 128)) == ""
    assert frames_per_second(cameras_flag(1, (32, 48)), 1, 1, 20) > 0
    frames, seconds = rendered((32, 48), 4)
    assert len(frames) == 4 and frames[0].shape == (32, 48, 3) and seconds > 0
    for codec in ("av1", "h264"):
        encode, decode, size, error = video_cost(frames, codec)
        assert encode > 0 and decode > 0 and size > 0 and 0 <= error < 20
