"""`make finetune-rl` resumes: killed with -9 and run again, or after losing a worker node, a run ends with the weights
of a run never interrupted; a finished run is not run again.

Apart from `test_finetune.py` and `test_finetune_workers.py` so that the two test processes of `make test` share PPO's
tests (each takes whole files).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from policies import checkpoint
from policies import folder as policy_files
from rl.finetune import FinetuneConfig, cli, main
from rl.validation import CURVE_FILE
from support import TINY_PPO, RayCluster, snapshot

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)


def ppo_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    code = cli(["--progress", "false", *args])
    return code, capsys.readouterr().err.strip().splitlines()


# With a push curriculum that moves on after every rollout (the tiny BC policy falls often), randomised
# bodies, and shares of the episodes delayed and noisy: the kills fall where episodes in progress began under
# an earlier stage's force and shares.
RESUMABLE = {
    **TINY_PPO,
    "timesteps": 256 * 6,
    "envs": 8,
    "eval_freq": 1024,
    "curriculum": "0,10,20",
    "curriculum_advance": 0.0,
    "curriculum_episodes": 1,
    "randomize": "suite",
    "latency_share": 1.0,
    "obs_noise_share": 1.0,
}


def resumable_command(bc_policy: Path, policy: Path, **changes: object) -> list[str]:
    settings = {**RESUMABLE, **changes}
    args = [f"--{name.replace('_', '-')}={value}" for name, value in settings.items()]
    return [sys.executable, "-m", "rl.finetune", f"--bc-policy={bc_policy}", f"--policy={policy}", *args]


def kill_after_snapshots(command: list[str], policy: Path, snapshots: int, delay: float) -> str:
    """Run `command`, kill -9 it `delay` s after it has written `snapshots` more resume snapshots; its stderr."""
    state = checkpoint.running_folder(policy) / "resume.pt"
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    seen, last = 0, state.stat().st_mtime_ns if state.exists() else None
    deadline = time.monotonic() + 120
    while seen < snapshots and process.poll() is None and time.monotonic() < deadline:
        now = state.stat().st_mtime_ns if state.exists() else None
        if now is not None and now != last:
            seen, last = seen + 1, now
        time.sleep(0.005)
    time.sleep(delay)
    process.kill()
    _, err = process.communicate(timeout=60)
    assert seen == snapshots, f"the run ended after {seen} snapshots: {err[-2000:]}"
    return err


@pytest.fixture(scope="module")
def resumable_reference(pending_policy: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[FinetuneConfig, dict]:
    """The RESUMABLE run never interrupted, of the pending actor (whose environments carry an estimator, the last
    actions and the delay along each episode: what a resume has to rebuild): what the resumed runs must equal."""
    config = FinetuneConfig(
        bc_policy=pending_policy, policy=tmp_path_factory.mktemp("resumable") / "reference", **RESUMABLE
    )
    return config, main(config)


def test_a_run_killed_twice_and_resumed_ends_with_the_uninterrupted_weights(
    resumable_reference: tuple[FinetuneConfig, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """kill -9 mid-rollout or mid-update (twice, at different moments), then the same settings: the final actor,
    the evaluation curve and the actor kept equal those of a run never interrupted, bit for bit, with the
    environments' estimators rebuilt by replaying the episodes in progress. Resuming with other settings is refused
    in one line and leaves the saved run as it was."""
    reference, bc_policy = resumable_reference[0].policy, resumable_reference[0].bc_policy
    broken = tmp_path / "broken"
    command = resumable_command(bc_policy, broken)
    kill_after_snapshots(command, broken, snapshots=2, delay=0.02)
    saved = snapshot(checkpoint.running_folder(broken))
    code, err = ppo_cli(resumable_command(bc_policy, broken, learning_rate=1e-3)[3:], capsys)
    assert code == 1 and len(err) == 1 and "interrupted run with other settings" in err[0] and "learning_rate" in err[0]
    assert snapshot(checkpoint.running_folder(broken)) == saved and not broken.exists()
    assert "resuming" in kill_after_snapshots(command, broken, snapshots=2, delay=0.15)
    # The last resume in this process: the command's own code path, without paying for its imports once more.
    resumed = main(FinetuneConfig(bc_policy=bc_policy, policy=broken, **RESUMABLE))
    assert "resuming" in capsys.readouterr().err
    assert 0 < resumed["resumed_at"] < resumed["timesteps"]  # its steps per second count the steps it ran
    for name in (policy_files.WEIGHTS_FILE, CURVE_FILE):
        assert (broken / name).read_bytes() == (reference / name).read_bytes(), name
    assert not checkpoint.running_folder(broken).exists() and not (broken / "resume.pt").exists()


def test_a_finished_run_is_not_run_again(
    resumable_reference: tuple[FinetuneConfig, dict], capsys: pytest.CaptureFixture[str]
) -> None:
    config, first = resumable_reference
    before = snapshot(config.policy)
    assert main(config) == first and snapshot(config.policy) == before
    assert "not run again" in capsys.readouterr().err


def test_a_worker_lost_stops_the_run_in_one_line_and_it_resumes(
    resumable_reference: tuple[FinetuneConfig, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The worker node dies after the first snapshot: one line, exit 1; the same settings on local workers resume
    from the snapshot and end with an uninterrupted run's weights."""
    reference, bc_policy = resumable_reference[0].policy, resumable_reference[0].bc_policy
    broken = tmp_path / "broken"
    cluster = RayCluster()
    try:
        command = resumable_command(bc_policy, broken, backend="ray", ray_address=cluster.address)
        process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        state = checkpoint.running_folder(broken) / "resume.pt"
        deadline = time.monotonic() + 120
        while not state.exists() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        cluster.remove_worker_node()
        _, err = process.communicate(timeout=120)
    finally:
        cluster.shutdown()
    lines = err.strip().splitlines()
    assert process.returncode == 1 and lines[-1].startswith("error: environment worker "), err[-2000:]
    assert "was lost" in lines[-1]
    main(FinetuneConfig(bc_policy=bc_policy, policy=broken, **RESUMABLE))
    assert "resuming" in capsys.readouterr().err
    assert (broken / policy_files.WEIGHTS_FILE).read_bytes() == (reference / policy_files.WEIGHTS_FILE).read_bytes()


def test_a_second_run_into_a_running_folder_is_refused_until_the_first_is_gone(tmp_path: Path) -> None:
    """While one process runs into POLICY (`checkpoint.running`) another is refused in one line, and leaves the folder
    as it was; killed with -9, the first holds nothing and the run resumes there."""
    policy = tmp_path / "ppo"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nfrom pathlib import Path\nfrom policies import checkpoint\n"
            f"with checkpoint.running(Path({str(policy)!r}), False) as folder:\n"
            "    (folder / 'resume.pt').write_text('1')\n    print('in', flush=True)\n    time.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "in"
        before = snapshot(checkpoint.running_folder(policy))
        with pytest.raises(checkpoint.CheckpointError, match="another run is writing") as refused:
            with checkpoint.running(policy, False):
                pass
        assert "\n" not in str(refused.value) and snapshot(checkpoint.running_folder(policy)) == before
    finally:
        holder.kill()
        holder.wait(timeout=60)
    with checkpoint.running(policy, False) as folder:
        assert (folder / "resume.pt").read_text() == "1"  # what the killed run left, to resume from
    assert (policy / "resume.pt").exists() and not checkpoint.running_folder(policy).exists()
