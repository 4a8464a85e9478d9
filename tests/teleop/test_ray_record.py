"""`make record BACKEND=ray`: Ray actors simulate, the dataset is the one a single process writes, faults lose nothing.

Clusters here are Ray's own cluster utility on 127.0.0.1 (`support.RayCluster`): two 1-CPU nodes, so
that two workers land one on each and a node can be killed under one of them.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from common import columns
from support import STANDING_FLAGS, RayCluster, record_short, snapshot, wait_for_episodes
from teleop.dataset_reader import read_episodes, read_frames
from teleop.record import cli
from teleop.spool import Spool

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (a Ray cluster takes seconds to start)

EPISODE_STEPS = 150


def record(root: Path, episodes: int = 5, **settings: object) -> None:
    record_short(root, **{"episodes": episodes, "max_steps": EPISODE_STEPS, **settings})


def recording_command(root: Path, episodes: int, address: str) -> list[str]:
    return [
        *(sys.executable, "-m", "teleop.record", "--dataset", str(root), "--episodes", str(episodes)),
        *("--max-steps", str(EPISODE_STEPS), "--workers", "2", "--backend", "ray", "--ray-address", address),
        *("--progress", "false", *STANDING_FLAGS),
    ]


def assert_recorded_as_one_process(root: Path, reference: Path, episodes: int) -> None:
    """`root` holds seeds 0.. once each, in order, file for file what one process records for them."""
    assert read_episodes(root)[columns.EPISODE_SEED].to_pylist() == list(range(episodes))
    record(reference, episodes=episodes)
    ours = {name: content for name, content in snapshot(root).items() if name != "recordings.jsonl"}
    assert ours == snapshot(reference)


def test_ray_workers_write_the_files_one_process_writes(ray_cluster: RayCluster, tmp_path: Path) -> None:
    """Two actors on two nodes: every file byte-identical to the same recording by one process."""
    record(tmp_path / "ray", workers=2, backend="ray", ray_address=ray_cluster.address)
    record(tmp_path / "one")
    assert snapshot(tmp_path / "ray") == snapshot(tmp_path / "one")


def test_without_an_address_a_local_ray_is_started_and_stopped(tmp_path: Path) -> None:
    """No RAY_ADDRESS: the command starts its own Ray, records, and leaves none running in this process."""
    import ray  # noqa: PLC0415 - Ray only for the tests that use it

    record(tmp_path / "ray", episodes=2, workers=2, backend="ray")
    assert not ray.is_initialized()
    record(tmp_path / "one", episodes=2)
    assert snapshot(tmp_path / "ray") == snapshot(tmp_path / "one")


def test_a_node_lost_mid_recording_costs_no_episode(tmp_path: Path) -> None:
    """The worker node is killed after 2 episodes: its seeds go to the head's worker, none is skipped or doubled."""
    cluster = RayCluster()
    try:
        root = tmp_path / "dataset"
        recorder = subprocess.Popen(recording_command(root, 30, cluster.address), stderr=subprocess.PIPE, text=True)
        wait_for_episodes(root, 2, recorder)
        cluster.remove_worker_node()
        _, err = recorder.communicate(timeout=180)
    finally:
        cluster.shutdown()
    assert recorder.returncode == 0, err[-2000:]
    assert "recording worker" in err and "was lost" in err and "go to the other workers" in err
    assert not (root / ".spool").exists()
    assert_recorded_as_one_process(root, tmp_path / "reference", 30)


def test_kill_9_of_the_recorder_loses_no_finished_episode(ray_cluster: RayCluster, tmp_path: Path) -> None:
    """SIGKILL to the recorder mid-recording: every episode it committed or spooled is in the dataset once the same
    command runs again, each seed once, each episode what one process records for its seed."""
    root = tmp_path / "dataset"
    recorder = subprocess.Popen(recording_command(root, 40, ray_cluster.address), stderr=subprocess.PIPE)
    wait_for_episodes(root, 3, recorder)
    recorder.kill()
    recorder.wait()
    finished = {*read_episodes(root)[columns.EPISODE_SEED].to_pylist(), *(int(p.stem) for p in Spool(root).ready())}
    again = subprocess.run(recording_command(root, 2, ray_cluster.address), capture_output=True, text=True)
    assert again.returncode == 0, again.stderr[-2000:]
    seeds = read_episodes(root)[columns.EPISODE_SEED].to_pylist()
    # Ray's actors outlive a killed driver for a moment and may spool an episode or two after the count: more, not less.
    assert finished <= set(seeds) and len(seeds) >= len(finished) + 2 and seeds == sorted(set(seeds))
    reference = tmp_path / "reference"
    record(reference, episodes=seeds[-1] + 1)
    ours, theirs = read_frames(root), read_frames(reference)
    for index, seed in enumerate(seeds):
        for key in (columns.ACTION, columns.OBS_STATE):
            np.testing.assert_array_equal(
                ours[key][ours["episode_index"] == index], theirs[key][theirs["episode_index"] == seed], f"seed {seed}"
            )


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_address_nothing_answers_on_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """RAY_ADDRESS with no cluster behind it: one line, and no dataset folder."""
    address = f"127.0.0.1:{free_port()}"
    args = ["--dataset", str(tmp_path / "new"), "--backend", "ray", "--ray-address", address]
    code = cli([*args, "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and f"no Ray cluster answers at {address}" in err[0]
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--backend", "spark"], "invalid choice: 'spark'"),
        (["--backend", "ray", "--ray-address", "head-node"], "--ray-address must be HOST:PORT"),
        (["--backend", "ray", "--controller", "keyboard"], "--backend local"),
        (["--backend", "ray", "--live", "true"], "--backend local"),
    ],
)
def test_bad_backend_settings_are_refused_before_touching_the_disk(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    try:
        code = cli(["--dataset", str(tmp_path / "new"), *args, "--progress", "false"])
    except SystemExit as exit_:  # argparse refuses a choice before the config exists
        code = exit_.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "new").exists()


def test_more_workers_than_the_cluster_has_cpus_are_refused(
    ray_cluster: RayCluster, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """3 workers on 2 CPUs would wait for a CPU forever: one line instead, nothing recorded."""
    args = ["--dataset", str(tmp_path / "new"), "--workers", "3", "--backend", "ray", "--ray-address"]
    code = cli([*args, ray_cluster.address, "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "needs 3 CPUs in the Ray cluster, it has 2" in err[0]
    assert not (tmp_path / "new").exists()
