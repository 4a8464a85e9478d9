"""Keyboard teleoperation: a scripted key sequence through a pseudo-terminal drives what is recorded."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from common import columns
from humanoid.env import make_env, model_and_data
from rollout.controllers import make_controller
from support import SESSION_PACE, Terminal, join_observation, read_mcap_episode
from task.posture import Posture
from task.schedules import DEFAULT_TASK, task_for
from teachers.expert import LQRExpert
from teleop.dataset_reader import read_episodes, read_frames
from teleop.keyboard import KEY_MAP, KICK_SPEED, TeleopSession, key_help, parse_keys
from teleop.record import cli
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

SETTLE = 2.0  # simulated s after Enter before the first command: the body drops 12 cm from the reset pose
HOLD = 2.5  # simulated s each command is held, so that the body has moved when the next one comes
KEYBOARD_RECORDER = [sys.executable, "-m", "teleop.record", "--controller", "keyboard", "--front-end", "terminal"]


@pytest.fixture(scope="module")
def teleoperated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """One episode driven by keys (crouch, lean forward, arms up, walk forward, neutral, push), one discarded, then
    quit; at `SESSION_PACE` simulated seconds a second, never faster."""
    root = tmp_path_factory.mktemp("keyboard") / "dataset"
    terminal = Terminal(
        [*KEYBOARD_RECORDER, "--dataset", str(root), "--noise", "0", "--max-steps", "5000", f"--pace={SESSION_PACE}"]
    )
    terminal.wait_for(b"keys:")
    terminal.press("\r", 0)  # start
    at = SETTLE
    terminal.wait_until_simulated(at)
    began, simulated = time.monotonic(), terminal.simulated()
    for keys, hold in (
        ("ff", HOLD),  # crouch 4 cm
        ("ww", HOLD),  # lean forward 0.1 rad
        ("2", HOLD),  # arms up
        ("\x1b[A\x1b[A", 1.0),  # walk forward at 0.2 m/s (the expert stands: it does not walk)
        (" ", HOLD),  # back to neutral
        ("p", 1.5),  # push
    ):
        terminal.wait_until_simulated(at)  # on a busy machine the session runs slower than the clock
        terminal.press(keys, 0)
        at += hold
    terminal.wait_until_simulated(at)
    pace = (terminal.simulated() - simulated) / (time.monotonic() - began)
    assert pace <= 1.1 * SESSION_PACE, f"{pace:.2f} simulated seconds a second: the session ran ahead of --pace"
    terminal.press("\r", 0.5)  # end and save
    terminal.press("\r", 0.5)  # start another...
    terminal.press("\x7f", 0.5)  # ...and discard it
    terminal.press("\x1b", 0)  # quit
    assert terminal.process.wait(timeout=60) == 0, terminal.output.decode(errors="replace")[-2000:]
    terminal.read_for(0.5)
    return root, terminal.output.decode(errors="replace")


POSTURE = slice(None)  # every field of the command (the push has its own column)


def phases(command: np.ndarray) -> list[int]:
    """Rows where the commanded posture changes."""
    return [0, *(np.flatnonzero(np.any(np.diff(command[:, POSTURE], axis=0) != 0, axis=1)) + 1)]


def test_the_recorded_commands_follow_the_keys(teleoperated: tuple[Path, str]) -> None:
    """observation.command steps through crouch, lean, arms up, a walk and neutral, then records the push."""
    root, _ = teleoperated
    frames = read_frames(root, [columns.OBS_COMMAND, columns.PUSH, columns.SETPOINT, "episode_index"])
    command = frames[columns.OBS_COMMAND]
    held = command[phases(command)][:, POSTURE]
    # Two presses that arrive together both act before the next step: the command jumps two notches.
    np.testing.assert_allclose(
        held,
        [
            (0, 0, 0, 0, 0, 0, 0, 0),
            (0, 0, -0.04, 0, 0, 0, 0, 0),
            (0.1, 0, -0.04, 0, 0, 0, 0, 0),
            (0.1, 0, -0.04, 0, 2, 0, 0, 0),
            (0.1, 0, -0.04, 0, 2, 0.2, 0, 0),
            (0, 0, 0, 0, 0, 0, 0, 0),
        ],
        atol=1e-6,
    )
    # The expert's setpoint starts where the command does, moves toward each command and gets there.
    setpoint = frames[columns.SETPOINT]
    np.testing.assert_array_equal(setpoint[0], command[0])
    changes = phases(command)
    assert any((setpoint[start] != command[start]).any() for start in changes[1:])  # on its way
    np.testing.assert_allclose(setpoint[changes[2] - 1], command[changes[2] - 1], atol=1e-6)  # there
    pushed = np.flatnonzero(frames[columns.PUSH][:, 0] > 0)
    assert 1 <= len(pushed) <= 10 and np.all(np.diff(pushed) == 1) and pushed[0] > phases(command)[5]
    assert np.all(frames["episode_index"] == 0)  # the discarded episode left nothing


def test_the_body_follows_the_commands(teleoperated: tuple[Path, str]) -> None:
    """The torso is lower after the crouch, tilts forward after the lean, and the body stays up."""
    root, _ = teleoperated
    frames = read_frames(root, [columns.OBS_STATE, columns.OBS_ENV_STATE, columns.OBS_COMMAND, columns.TERMINATED])
    observation = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    command = frames[columns.OBS_COMMAND]
    starts = phases(command)
    height = observation[:, 0]  # root z
    w, x, y, z = observation[:, 1:5].T
    forward_tilt = 2 * (x * z + w * y)  # world x of the torso's up axis
    before_crouch = slice(starts[1] - 30, starts[1])
    before_lean = slice(starts[2] - 30, starts[2])
    before_arms = slice(starts[3] - 30, starts[3])
    assert height[before_lean].mean() < height[before_crouch].mean() - 0.02
    assert forward_tilt[before_arms].mean() > forward_tilt[before_lean].mean() + 0.05
    assert not frames[columns.TERMINATED].any()


def test_tasks_name_the_commands_in_dataset_and_mcap(teleoperated: tuple[Path, str]) -> None:
    """The episode lists one task per command held, and /command carries the same per step."""
    root, _ = teleoperated
    episode = read_episodes(root).to_pylist()[0]
    assert episode["tasks"] == [
        DEFAULT_TASK,
        "Crouch while standing.",
        "Lean forward, crouch while standing.",
        "Lean forward, crouch, arms up while standing.",
        "Walk forward at 0.2 m/s, lean forward, crouch, arms up.",
    ]  # and back to the first
    assert episode[columns.EPISODE_CONTROLLER] == "keyboard"
    mcap = read_mcap_episode(root / episode[columns.EPISODE_MCAP])
    frames = read_frames(root, [columns.OBS_COMMAND])
    np.testing.assert_array_equal(mcap.command, frames[columns.OBS_COMMAND])
    assert list(dict.fromkeys(mcap.command_tasks)) == episode["tasks"]


def test_the_terminal_shows_the_key_map_and_a_status_line(teleoperated: tuple[Path, str]) -> None:
    """The session prints the key map, then status lines with height, time, return and the command."""
    _, output = teleoperated
    assert key_help().splitlines()[0].strip() in output
    assert "REC seed 0" in output and "height 1.2" in output and "return" in output and "arms up" in output
    assert "added 1 episode (seed " in output


def test_parse_keys_reads_arrows_and_special_keys() -> None:
    """Raw terminal bytes become key names: arrows, Enter, Backspace, Esc and letters."""
    assert parse_keys("w\x1b[A\r\x7f \x1bQ") == ["w", "up", "enter", "backspace", "space", "esc", "q"]


def test_no_key_is_bound_twice() -> None:
    """Each key has one effect."""
    bound = [key for binding in KEY_MAP for key in binding.keys]
    assert len(bound) == len(set(bound))


def test_help_lists_every_binding(capsys: pytest.CaptureFixture[str]) -> None:
    """--help shows each binding's keys with its help line."""
    with pytest.raises(SystemExit):
        cli(["--help"])
    shown = capsys.readouterr().out
    for binding in KEY_MAP:
        assert f"{' / '.join(binding.keys)}" in shown and binding.help in shown


def test_task_for_neutral_is_the_default_task() -> None:
    """The neutral posture is the plain standing task; others name each field away from neutral."""
    assert task_for(Posture()) == DEFAULT_TASK
    assert task_for(Posture(lean_left=-0.1, twist=0.2)) == "Lean right, twist left while standing."


def test_keyboard_without_a_terminal_is_a_one_line_error(tmp_path: Path) -> None:
    """With stdin not a TTY the recorder exits non-zero with one line, before the dataset's folder exists."""
    result = subprocess.run(
        [*KEYBOARD_RECORDER, "--dataset", str(tmp_path / "d")],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0 and not (tmp_path / "d").exists()
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("error: keyboard teleoperation needs a terminal")


def test_a_keyboard_session_skips_the_seeds_its_dataset_holds(tmp_path: Path) -> None:
    """Past SEED's range (a discarded episode uses its seed up), the next episode takes the next seed the dataset does
    not hold: none is recorded twice (teleop.seeds)."""
    env = make_env(5)
    store = EpisodeStore(tmp_path / "dataset", DatasetSpec.from_env(env))
    expert = LQRExpert(env.unwrapped.model)
    first = TeleopSession(env, expert, store, 8, 1, 0.0, lambda committed: None)
    first.press("enter")
    while first.recording:
        first.tick()
    assert store.seeds() == [8]
    session = TeleopSession(env, expert, store, 7, 1, 0.0, lambda committed: None)
    session.press("enter")
    session.press("backspace")  # seed 7 discarded: 8 is the dataset's
    session.press("enter")
    while session.recording:
        session.tick()
    store.close()
    assert read_episodes(tmp_path / "dataset", [columns.EPISODE_SEED])[columns.EPISODE_SEED].to_pylist() == [8, 9]


def test_the_kick_key_kicks_the_body_and_the_stepping_expert_steps_out_of_it(tmp_path: Path) -> None:
    """`k` changes the root's forward velocity by KICK_SPEED at once and records the impulse in the push column; the
    stepping expert, driven by the keys as `make play POLICY=expert-stepping` drives it, stays up by stepping."""
    env = make_env(5000)
    store = EpisodeStore(tmp_path / "dataset", DatasetSpec.from_env(env))
    stepping = make_controller("expert-stepping", env)
    try:
        session = TeleopSession(env, stepping, store, 0, 1, 0.0, lambda committed: None)
        session.press("enter")
        for _ in range(150):
            session.tick()
        before = session.data.qvel[0]
        session.press("k")
        session.tick()
        assert session.data.qvel[0] - before == pytest.approx(KICK_SPEED, abs=0.1)  # one step of dynamics after it
        for _ in range(200):
            session.tick()
        assert session.recording and stepping.planned > 0  # still up, planning its steps
        session.press("enter")
    finally:
        store.close()
        env.close()
    push = read_frames(tmp_path / "dataset")[columns.PUSH]
    mass = float(model_and_data(env)[0].body_subtreemass[0])
    assert push[:, 0].max() == pytest.approx(KICK_SPEED * mass / env.unwrapped.dt)
    # Foxglove's view of it: in the MCAP's /tf a foot leaves the floor and lands elsewhere.
    episode = read_mcap_episode(next((tmp_path / "dataset").rglob("*.mcap")))
    feet = episode.body_position[:, [episode.body_frames.index(name) for name in ("left_foot", "right_foot")]]
    lifted = (feet[150:, :, 2] - feet[150, :, 2]).max()
    moved = np.linalg.norm(feet[-1, :, :2] - feet[150, :, :2], axis=-1).max()
    assert lifted > 0.05 and moved > 0.1
