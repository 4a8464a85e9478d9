"""`make record`: appending, determinism, DART noise, and refusing bad input without touching the disk."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

import teleop.record
from common import columns
from common.cli import config_dict, parse_config
from humanoid.env import make_env
from policies.folder import CONFIG_FILE, WEIGHTS_FILE
from rollout.episode import injected_noise, run_episode
from support import (
    SHORT_EPISODE,
    STANDING_FLAGS,
    FailingTeacher,
    assert_consistent,
    record_short,
    registered,
    snapshot,
    untrained_checkpoint,
)
from teachers.registry import TEACHER, WALKING_TEACHER
from teleop import recordings
from teleop.dataset_reader import read_episodes, read_frames, read_info
from teleop.record import LATENCY_SHARE, STANDING, WALKING_LATENCY_SHARE, RecordConfig, cli, effective
from teleop.seeds import seed_clash
from teleop.store import DatasetSpec, EpisodeStore


def record(root: Path, **settings: object) -> None:
    """A short in-process recording (the writer process is exercised by the CLI and crash tests)."""
    record_short(root, **{"episodes": 2, "max_steps": SHORT_EPISODE, **settings})


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """Exit code and stderr lines of `python -m teleop.record ARGS`."""
    code = cli(["--progress", "false", *args])
    return code, capsys.readouterr().err.strip().splitlines()


def test_recording_again_appends_new_seeds(recorded: Path, tmp_path: Path) -> None:
    """A second recording adds episodes after the first, continuing the seeds, leaving the old files as they were."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    before = snapshot(root / "data") | snapshot(root / "mcap")
    record(root)
    episodes = read_episodes(root)
    assert episodes["episode_index"].to_pylist() == [0, 1, 2, 3, 4]
    assert episodes[columns.EPISODE_SEED].to_pylist() == [0, 1, 2, 3, 4]
    assert read_info(root)["total_frames"] == len(read_frames(root, ["index"])["index"])
    after = snapshot(root / "data") | snapshot(root / "mcap")
    assert {name: after[name] for name in before} == before


def test_same_seed_and_controller_give_identical_arrays(recorded: Path, tmp_path: Path) -> None:
    """Re-recording seeds 0..2 with the same settings reproduces every stored array exactly."""
    record(tmp_path / "again", episodes=3, seed=0, noise=0.05)
    first, second = read_frames(recorded), read_frames(tmp_path / "again")
    for key in first:
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)


def test_noise_is_the_only_difference_between_executed_and_label(recorded: Path) -> None:
    """Executed action = clip(label + the seed's injected noise), and the noise has the requested spread."""
    frames = read_frames(recorded, [columns.ACTION, columns.EXECUTED_ACTION, "episode_index"])
    deviations = []
    for seed in range(3):
        rows = frames["episode_index"] == seed
        label, executed = frames[columns.ACTION][rows], frames[columns.EXECUTED_ACTION][rows]
        noise = injected_noise(seed, len(label), 0.05, label.shape[1])
        np.testing.assert_array_equal(executed, np.clip(label + noise, -0.4, 0.4).astype(np.float32))
        inside = np.abs(label + noise) < 0.4
        deviations.append((executed - label)[inside])
    spread = np.concatenate(deviations).std()
    assert 0.045 < spread < 0.055


def test_clean_recording_executes_the_labels(tmp_path: Path) -> None:
    """With NOISE=0 the executed actions are the labels."""
    record(tmp_path / "clean", episodes=1, noise=0.0)
    frames = read_frames(tmp_path / "clean", [columns.ACTION, columns.EXECUTED_ACTION])
    np.testing.assert_array_equal(frames[columns.ACTION], frames[columns.EXECUTED_ACTION])


def test_random_controller_records_falls(tmp_path: Path) -> None:
    """The random baseline falls early; the episode is kept with terminated set."""
    record(tmp_path / "random", episodes=1, controller="random", max_steps=1000, noise=0.0)
    (episode,) = read_episodes(tmp_path / "random").to_pylist()
    assert episode[columns.EPISODE_TERMINATED] and episode["length"] < 100
    assert episode[columns.EPISODE_CONTROLLER] == "random"


def test_cli_records_with_the_writer_process_and_prints_a_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command line records through the writer process and ends with a one-line summary."""
    args = ["--dataset", str(tmp_path / "cli"), "--episodes", "2", "--max-steps", "30", "--workers", "1"]
    code = cli([*args, "--progress", "false"])
    out = capsys.readouterr().out.strip().splitlines()
    assert code == 0
    assert "added 2 episodes (seeds 0..1), 60 frames" in out[-1]
    assert read_info(tmp_path / "cli")["total_episodes"] == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["--controller", "teleport"], "unknown controller 'teleport'"),
        (["--episodes", "0"], "--episodes must be positive"),
        (["--episodes", "-3"], "--episodes must be positive"),
        (["--noise", "-0.1"], "--noise must be >= 0"),
        (["--noise", "inf"], "--noise must be >= 0"),
        (["--kick", "-0.4"], "--kick must be >= 0"),
        (["--kick", "nan"], "--kick must be >= 0"),
        (["--controller", "keyboard", "--kick", "0.4"], "kicks with its k key: --kick must be 0"),
        (["--controller", "keyboard", "--pace", "0"], "--pace must be positive"),
        (["--walking", "true"], "--walking was removed; give --task (TASK=stand|posture|walk; WALKING=1 is TASK=walk)"),
        (["--schedules", "false"], "--schedules was removed; give --task (TASK=stand|posture|walk; SCHEDULES=0 is"),
        (
            ["--task", "walk", "--controller", "expert-sensed"],
            "--task walk: expert-sensed does not walk, so nobody would follow the walks recorded",
        ),
        (["--task", "walk", "--controller", "random"], "--task walk: random does not walk"),
        (["--controller", "keyboard", "--task", "walk"], "--task walk draws the scripted operator's walking schedules"),
        (["--seed", "-1"], "--seed must be >= 0"),
        (["--seed", str(2**63 - 1), "--episodes", "2"], "below 2**63"),
    ],
)
def test_bad_settings_are_refused_before_touching_the_disk(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bad setting gives one error line and a non-zero exit; the dataset folder is not even created."""
    code, err = run_cli(["--dataset", str(tmp_path / "new"), *args], capsys)
    assert code != 0 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("damage", ["weights", "config"])
def test_a_damaged_policy_is_refused_before_the_dataset_is_made(
    damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A checkpoint whose weights were cut short (or whose config.json is not JSON) is refused in one line by the
    recorder, which loads no policy itself (its workers do): no empty dataset is left to refuse a retry."""
    policy = untrained_checkpoint(tmp_path / "policy")
    if damage == "weights":
        weights = policy / WEIGHTS_FILE
        weights.write_bytes(weights.read_bytes()[:-10])
    else:
        (policy / CONFIG_FILE).write_text('{"format": ')
    code, err = run_cli(["--dataset", str(tmp_path / "new"), "--controller", str(policy), "--workers", "2"], capsys)
    assert code != 0 and len(err) == 1 and "the checkpoint is damaged, train it again" in err[0], err
    assert not (tmp_path / "new").exists()


def test_the_teacher_and_the_delayed_share_recorded_by_default_are_the_tasks() -> None:
    """No --controller: the teacher on leg odometry, and for a walking task the walker on it; no --latency: half the
    episodes delayed, a fifth of the walking ones; given, either stands."""
    assert effective(RecordConfig()).controller == TEACHER == "expert-sensed"
    assert effective(RecordConfig(task="stand")).controller == TEACHER
    assert effective(RecordConfig(task="walk")).controller == WALKING_TEACHER == "walker-sensed"
    assert effective(RecordConfig(task="walk", controller="walker")).controller == "walker"
    assert effective(RecordConfig()).latency == effective(RecordConfig(task="stand")).latency == LATENCY_SHARE == 0.5
    assert effective(RecordConfig(task="walk")).latency == WALKING_LATENCY_SHARE == 0.2
    assert effective(RecordConfig(task="walk", latency=0.5)).latency == 0.5


@pytest.mark.parametrize(
    ("content", "message"), [("[]", "holds list, not an object"), ('{"fps": ', "is not readable JSON")]
)
def test_a_dataset_whose_info_is_no_json_object_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, message: str
) -> None:
    """Appending to a dataset whose meta/info.json is damaged: one line naming it, the file untouched."""
    info = tmp_path / "dataset" / "meta" / "info.json"
    info.parent.mkdir(parents=True)
    info.write_text(content)
    code, err = run_cli(["--dataset", str(tmp_path / "dataset"), "--writer", "inline", *STANDING_FLAGS], capsys)
    assert code != 0 and len(err) == 1 and f"meta/info.json {message}" in err[0], err
    assert info.read_text() == content


def test_dataset_that_is_a_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """DATASET naming a file: one error line, the file untouched."""
    target = tmp_path / "notes.txt"
    target.write_text("keep me")
    code, err = run_cli(["--dataset", str(target), "--writer", "inline"], capsys)
    assert code != 0 and len(err) == 1 and "is a file" in err[0]
    assert target.read_text() == "keep me"


def test_dataset_with_other_features_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A LeRobot dataset with other features is left exactly as it was."""
    root = tmp_path / "other"
    other = LeRobotDataset.create(
        "local/other",
        fps=67,
        root=root,
        use_videos=False,
        robot_type="mujoco_humanoid",
        features={
            "observation.state": {"dtype": "float32", "shape": (4,), "names": None},
            "action": {"dtype": "float32", "shape": (2,), "names": None},
        },
    )
    for _ in range(3):
        other.add_frame({"observation.state": np.zeros(4, np.float32), "action": np.ones(2, np.float32), "task": "t"})
    other.save_episode()
    other.finalize()
    capsys.readouterr()  # LeRobot's own progress output
    before = snapshot(root)
    code, err = run_cli(["--dataset", str(root)], capsys)
    assert code != 0 and len(err) == 1 and "other features" in err[0]
    assert snapshot(root) == before


def test_dataset_with_a_truncated_data_file_is_refused(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A data parquet cut short (a copy interrupted): one line naming it, before anything is written."""
    root = tmp_path / "truncated"
    shutil.copytree(recorded, root)
    path = root / "data/chunk-000/file-001.parquet"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    before = snapshot(root)
    code, err = run_cli(["--dataset", str(root)], capsys)
    assert code != 0 and len(err) == 1 and f"{path} is not a readable parquet file" in err[0]
    assert snapshot(root) == before


@pytest.mark.parametrize(("seed", "repeated"), [(0, "seeds 0..1"), (2, "seeds 2")])
def test_a_seed_the_dataset_holds_is_refused(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], seed: int, repeated: str
) -> None:
    """SEED whose episodes would repeat the dataset's seeds (0..2): one line naming them and the next free seed, as
    `make merge` refuses overlapping shards; nothing written."""
    root = tmp_path / "again"
    shutil.copytree(recorded, root)
    before = snapshot(root)
    code, err = run_cli(["--dataset", str(root), "--seed", str(seed), "--episodes", "2", *STANDING_FLAGS], capsys)
    assert code != 0 and len(err) == 1
    assert f"{repeated} are already in {root}" in err[0] and "the next free seed is 3" in err[0]
    assert snapshot(root) == before


def test_seed_clash_names_the_repeated_runs_and_the_next_free_seed() -> None:
    assert seed_clash(range(5, 9), [0, 1, 2, 10], "d") is None  # a gap is free
    clash = seed_clash([1, 2, 3, 10, 11, 20, 40, 40], [0, 1, 2, 3, 10, 11, 20, 30], "d")
    assert clash is not None and clash.startswith("seeds 1..3, 10..11, 20 and 1 more runs are already in d")
    assert clash.endswith("the next free seed is 31")


def test_folder_that_is_not_a_dataset_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A non-empty folder without meta/info.json is not written into."""
    root = tmp_path / "photos"
    root.mkdir()
    (root / "cat.jpg").write_bytes(b"\xff\xd8")
    code, err = run_cli(["--dataset", str(root), "--writer", "inline"], capsys)
    assert code != 0 and len(err) == 1 and "holds no LeRobot dataset" in err[0]
    assert snapshot(root) == {"cat.jpg": b"\xff\xd8"}


def test_unwritable_folder_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    """A folder on a read-only file system (/sys, unwritable even for root) gives one error line."""
    code, err = run_cli(["--dataset", "/sys/fs/humanoid_bc_dataset"], capsys)
    assert code != 0 and len(err) == 1 and "cannot write to /sys/fs/humanoid_bc_dataset" in err[0]


def test_second_recorder_on_the_same_dataset_refuses(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """While one recorder holds the dataset, another exits with a clear message and writes nothing."""
    root = tmp_path / "busy"
    shutil.copytree(recorded, root)

    holder = EpisodeStore(root, DatasetSpec.from_env(make_env()))
    try:
        before = snapshot(root)
        code, err = run_cli(["--dataset", str(root)], capsys)
        assert code != 0 and len(err) == 1 and "another recorder is writing" in err[0]
        assert snapshot(root) == before
    finally:
        holder.close()
    assert json.loads((root / "meta/info.json").read_text())["total_episodes"] == 3


def test_each_session_adds_its_config_to_recordings_jsonl(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`make record` appends one line per session: who ran, every setting as it recorded (the teacher it defaulted
    to named), the episodes and seeds it added."""
    root = tmp_path / "logged"
    args = ["--dataset", str(root), "--episodes", "2", "--max-steps", "30", "--progress", "false"]
    assert cli(args) == 0 and cli([*args[:3], "1", *args[4:]]) == 0
    first, second = recordings.read(root)
    assert first["config"] == config_dict(effective(parse_config(RecordConfig, args, description="")))
    assert first["config"]["controller"] == TEACHER
    assert (first["made_by"], first["complete"]) == ("teleop.record", True)
    assert (first["episodes"], first["seeds"], first["count"]) == ([0, 1], [0, 1], 2)
    assert (second["episodes"], second["seeds"], second["count"]) == ([2, 2], [2, 2], 1)


def test_dataset_with_recordings_jsonl_still_loads_in_lerobot(tmp_path: Path) -> None:
    """The line beside meta/ and data/ leaves LeRobot's loader, the frames and the MCAP files as they were."""
    root = tmp_path / "logged"
    teleop.record.record(
        RecordConfig(dataset=root, episodes=2, max_steps=30, writer="inline", progress=False, **STANDING)
    )
    assert (root / recordings.RECORDINGS_FILE).is_file()
    assert_consistent(root, 2)


def test_interrupted_session_still_logs_what_it_committed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C during the second episode: the session's line says so, with the one episode committed."""
    root = tmp_path / "interrupted"
    episodes_run = []

    def run_then_interrupt(*args: object, **kwargs: object) -> object:
        if episodes_run:
            raise KeyboardInterrupt
        episodes_run.append(1)
        return run_episode(*args, **kwargs)

    monkeypatch.setattr(teleop.record, "run_episode", run_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        teleop.record.record(
            RecordConfig(dataset=root, episodes=3, max_steps=30, writer="inline", progress=False, **STANDING)
        )
    (line,) = recordings.read(root)
    assert (line["complete"], line["count"], line["episodes"]) == (False, 1, [0, 0])
    assert read_info(root)["total_episodes"] == 1


def test_a_kicked_recording_holds_the_kicks_impulse_in_its_push_column(tmp_path: Path) -> None:
    """`make record KICK=0.4`: each episode is kicked once at its seeded step, whose push column holds the force that
    gives the impulse over that step (seed 0 is kicked at step 277); every other row is zero."""
    root = tmp_path / "kicked"
    record_short(root, controller="expert", episodes=1, max_steps=300, kick=0.4, task="stand", latency=0.0)
    push = read_frames(root)[columns.PUSH]
    model = make_env().unwrapped.model
    force = 0.4 * float(model.body_subtreemass[0]) / 0.015
    assert np.flatnonzero(np.linalg.norm(push, axis=1)).tolist() == [277]
    assert np.linalg.norm(push[277]) == pytest.approx(force, rel=1e-5)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_controller_that_fails_ends_its_episode_alone(
    workers: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A controller that raises in one episode (`support.FailingTeacher`, on seed 1's): that episode is not recorded,
    one line names its seed, step and command, and the episodes before and after are kept, in one process or over
    workers."""
    root = tmp_path / "failing"
    with registered(FailingTeacher):
        record_short(root, controller=FailingTeacher.name, task="posture", episodes=3, max_steps=30, workers=workers)
    lines = [line for line in capsys.readouterr().err.splitlines() if "not recorded" in line]
    assert len(lines) == 1
    assert lines[0].startswith("warning: episode 1 not recorded: controller 'toy-failing' failed at step 5 of the ")
    assert "with seed 1, commanded 'stand still on both feet': RuntimeError: no balanced pose" in lines[0]
    assert read_episodes(root, [columns.EPISODE_SEED]).to_pydict()[columns.EPISODE_SEED] == [0, 2]
    assert_consistent(root, 2)
