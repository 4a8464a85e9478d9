"""The keyboard's viewer front end in a real X display (Xvfb, Mesa on the CPU): keys typed into MuJoCo's window.

xdotool types into the viewer window through the X server (XTEST), so every key goes through GLFW
and MuJoCo's viewer to the front end's key callback, as a person's would. `.ci/run` installs Xvfb
and xdotool when they are missing; without them these tests say why they skip.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageGrab

from common import columns
from support import SESSION_PACE, join_observation, status_lines
from task.command_fields import COMMAND_NAMES
from teleop.dataset_reader import read_frames

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        shutil.which("Xvfb") is None or shutil.which("xdotool") is None,
        reason="the viewer test needs Xvfb and xdotool (Debian: apt-get install xvfb xdotool; .ci/run installs them)",
    ),
]

SETTLE = 2.0  # simulated s after Enter before the first command: the body drops 12 cm from the reset pose
HOLD = 2.5  # simulated s each command is held, so that the body has moved when the next one comes
POSTURE = slice(0, 5)  # the posture fields of the command (the push has its own column): the keys walk nothing


@pytest.fixture(scope="module")
def display() -> Iterator[str]:
    """A private X display (Xvfb) for the module, stopped after. Xvfb picks a free display number itself and writes
    it when it is ready (-displayfd): two test processes, or a lock file a dead server left, cannot hand a module
    another's display."""
    ready, told = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(told), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
        pass_fds=(told,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(told)
    with os.fdopen(ready) as pipe:
        number = pipe.readline().strip()  # empty if Xvfb exited before it was ready
    assert number, f"Xvfb did not start (exit {server.poll()})"
    yield f":{number}"
    server.terminate()
    server.wait(timeout=10)


def xdotool(display: str, *args: str) -> str:
    run = subprocess.run(  # bounded: `search --sync` waits for ever for the window of a recorder that crashed
        ["xdotool", *args], env={**os.environ, "DISPLAY": display}, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    return run.stdout.strip()


@pytest.fixture(scope="module")
def teleoperated(display: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """One episode driven by keys typed into the viewer window (crouch, then lean forward); a screenshot mid-way."""
    folder = tmp_path_factory.mktemp("viewer")
    root, shot, log = folder / "dataset", folder / "viewer.png", folder / "recorder.log"
    command = [sys.executable, "-m", "teleop.record", "--controller", "keyboard", "--front-end", "viewer"]
    command += ["--dataset", str(root), "--noise", "0", "--max-steps", "5000", f"--pace={SESSION_PACE}"]
    with log.open("w") as out:
        recorder = subprocess.Popen(
            command, env={**os.environ, "DISPLAY": display, "MUJOCO_GL": "glfw"}, stdout=out, stderr=out
        )
        try:
            window = xdotool(display, "search", "--sync", "--onlyvisible", "--name", "MuJoCo").splitlines()[0]
            xdotool(display, "windowfocus", "--sync", window)

            def press(key: str, until: float = 0.0) -> None:
                """Type `key`, then wait until the status line in the log shows the episode `until` s in: simulated
                time, as the terminal tests wait (Mesa renders on the CPU, so beside other work the viewer runs
                slower than the clock: waited on the clock, a crouch once landed 0.45 s into the episode)."""
                xdotool(display, "key", "--window", window, "--clearmodifiers", key)
                deadline = time.monotonic() + 120.0 + 10.0 * until
                while not (lines := status_lines(log.read_bytes())) or lines[-1][0] < until:
                    assert recorder.poll() is None and time.monotonic() < deadline, log.read_text()[-2000:]
                    time.sleep(0.05)

            press("Return", SETTLE)  # start
            press("f", SETTLE + 0.2)
            press("f", SETTLE + 0.2 + HOLD)  # crouch 4 cm
            press("w", SETTLE + 0.4 + HOLD)
            press("w", SETTLE + 0.4 + 2 * HOLD)  # lean forward 0.1 rad
            shell = xdotool(display, "getwindowgeometry", "--shell", window)  # X=.. Y=.. WIDTH=.. HEIGHT=..
            geometry = dict(line.split("=") for line in shell.split())
            left, top = int(geometry["X"]), int(geometry["Y"])
            box = (left, top, left + int(geometry["WIDTH"]), top + int(geometry["HEIGHT"]))
            ImageGrab.grab(bbox=box, xdisplay=display).save(shot)  # the viewer window, as the X server shows it
            press("Return")  # end and save
            time.sleep(0.5)
            press("Escape")  # quit
            assert recorder.wait(timeout=60) == 0, log.read_text()[-2000:]
        finally:
            if recorder.poll() is None:
                recorder.kill()
    return root, shot


def test_the_recorded_commands_follow_the_keys(teleoperated: tuple[Path, Path]) -> None:
    """observation.command goes from neutral to the crouch, then to the crouch leaning forward."""
    root, _ = teleoperated
    command = read_frames(root, [columns.OBS_COMMAND])[columns.OBS_COMMAND][:, POSTURE]
    changes = [0, *(np.flatnonzero(np.any(np.diff(command, axis=0) != 0, axis=1)) + 1)]
    held = [tuple(np.round(row, 6)) for row in command[changes]]
    assert held[0] == (0, 0, 0, 0, 0) and held[-1] == (0.1, 0, -0.04, 0, 0)
    assert (0, 0, -0.04, 0, 0) in held  # the crouch was complete before the lean began


def test_the_body_follows_the_commands(teleoperated: tuple[Path, Path]) -> None:
    """The torso is lower after the crouch, tilts forward after the lean, and the body stays up."""
    root, _ = teleoperated
    frames = read_frames(root, [columns.OBS_STATE, columns.OBS_ENV_STATE, columns.OBS_COMMAND, columns.TERMINATED])
    observation = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    height_command = frames[columns.OBS_COMMAND][:, COMMAND_NAMES.index("height")]
    lean_command = frames[columns.OBS_COMMAND][:, COMMAND_NAMES.index("lean_forward")]
    crouch, lean = int(np.argmax(height_command < 0)), int(np.argmax(lean_command > 0))
    w, x, y, z = observation[:, 1:5].T
    forward_tilt = 2 * (x * z + w * y)  # world x of the torso's up axis
    assert observation[lean - 30 : lean, 0].mean() < observation[crouch - 30 : crouch, 0].mean() - 0.02
    assert forward_tilt[-30:].mean() > forward_tilt[lean - 30 : lean].mean() + 0.05
    assert not frames[columns.TERMINATED].any()


def test_the_screenshot_shows_the_humanoid(teleoperated: tuple[Path, Path]) -> None:
    """The window shows the body: many pixels of the MJCF's orange (0.8, 0.6, 0.4), lit and shaded, in the scene
    between the viewer's panels; a blank or black frame has none (the floor is white and black, the panels grey)."""
    _, shot = teleoperated
    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    orange = (r > g + 15) & (g > b + 15) & (r > 60)
    assert orange.mean() > 0.01, f"{orange.mean():.4f} of the window's pixels are the body's colour"


X_ERROR = """
import ctypes, ctypes.util, sys
from teleop.keyboard import tolerate_x_errors
if sys.argv[1] == "tolerant":
    assert tolerate_x_errors(sys.stdout)
xlib = ctypes.CDLL(ctypes.util.find_library("X11"))
xlib.XOpenDisplay.restype = ctypes.c_void_p
display = ctypes.c_void_p(xlib.XOpenDisplay(None))
xlib.XFreePixmap(display, ctypes.c_ulong(0x1234567))  # no such pixmap: BadPixmap
xlib.XSync(display, 0)
print("went on")
"""


@pytest.mark.parametrize("mode", ["default", "tolerant"])
def test_an_x_error_is_one_line_not_an_exit(display: str, mode: str) -> None:
    """Xlib's default handler ends the process on an X error (the viewer's render thread met one after its window
    closed, and the recorder hung); the viewer's own handler says it in one line and goes on."""
    run = subprocess.run(
        [sys.executable, "-c", X_ERROR, mode], env={**os.environ, "DISPLAY": display}, capture_output=True, text=True
    )
    if mode == "default":
        assert run.returncode == 1 and "BadPixmap" in run.stderr and "went on" not in run.stdout
    else:
        assert run.returncode == 0, run.stderr
        assert run.stdout.splitlines() == ["viewer: X error 4 (request 54.0) ignored", "went on"]


VIEWER_EXIT = """
import threading
import gymnasium as gym
from humanoid.env import model_and_data
from teleop.keyboard import passive_viewer
env = gym.make("Humanoid-v5")
env.reset(seed=0)
with passive_viewer(*model_and_data(env)) as viewer:
    viewer.sync()
print(threading.active_count())
"""


def test_the_viewer_s_thread_has_ended_when_its_block_does(display: str) -> None:
    """The passive viewer's thread destroys its window after close(); a process that exited before it did segfaulted or
    hung (12 of 20 times). Leaving passive_viewer's block waits for it: only the main thread is left, and the exit is
    clean."""
    run = subprocess.run(
        [sys.executable, "-c", VIEWER_EXIT],
        env={**os.environ, "DISPLAY": display, "MUJOCO_GL": "glfw"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["1"]
