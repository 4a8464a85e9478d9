"""Keyboard teleoperation (`make record CONTROLLER=keyboard`, `make play POLICY=...`): keys set the command.

Balancing 17 motors by hand is impossible, so a key changes the operator's command, a posture
(`task.posture`, `task.schedules`), and the controller keeps the body up while it follows it: the
LQR expert, or with `--policy` a learned policy that takes a command (`make play`). One key pushes the
torso, a perturbation to recover from. Every step of an episode is recorded as with the expert, plus the
command in force (`observation.command`, the `/command` MCAP channel), the task string that names it, the
controller's setpoint and the push.

Two front ends drive the same `TeleopSession`, in real time (one env step per 15 ms):
- `terminal`: raw key reads from the TTY (works over SSH, no display), a live status line;
- `viewer`: MuJoCo's viewer window and its key callback, showing the robot (needs a display).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import select
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, TextIO

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import UserError
from humanoid.cameras import Camera
from humanoid.env import model_and_data
from humanoid.perturbations import kick, kick_force
from humanoid.physics import TORSO_BODY, torso_height
from rollout.controllers import KEYBOARD, KEYBOARD_EXPERT, Controller, make_controller
from rollout.episode import EpisodeBuffer, StepObserver, injected_noise, rollout_step
from task.command_fields import COMMAND_FIELDS, CommandField
from task.posture import NEUTRAL, Posture
from task.schedules import command_vector, task_for

if TYPE_CHECKING:
    import mujoco.viewer

    from teleop.store import CommittedEpisode, EpisodeSink

PUSH_FORCE = 8.0  # N, horizontal, forward: the expert recovers from it (10 N topples it on many seeds)
PUSH_SECONDS = 0.1
KICK_SPEED = 0.4
"""m/s of the whole body, forward (world x, as the push): a kick the expert falls to and the teachers that step step
out of (`make play POLICY=walker-sensed` or `expert-stepping`; docs/decisions/walking-teacher.md)."""
STATUS_EVERY = 5  # steps between two status lines while recording: 13 a second is what a person reads


@dataclass(frozen=True)
class Binding:
    """One entry of the key map: the keys (terminal names) and what they do."""

    keys: tuple[str, ...]
    help: str
    effect: Callable[[TeleopSession], None]


def _nudge(field: CommandField, presses: int) -> Callable[[TeleopSession], None]:
    step = presses * field.step
    return lambda session: session.command_posture(
        dataclasses.replace(session.target, **{field.name: getattr(session.target, field.name) + step})
    )


def _preset(field: CommandField, preset: int) -> Callable[[TeleopSession], None]:
    return lambda session: session.command_posture(dataclasses.replace(session.target, **{field.name: float(preset)}))


def field_bindings(field: CommandField) -> tuple[Binding, ...]:
    """The keys of a command field, as its row gives them: one per preset, or raise then lower by one step."""
    if field.presets:
        return tuple(
            Binding(keys, phrase, _preset(field, i))
            for i, (keys, phrase) in enumerate(zip(field.keys, field.phrases, strict=True))
        )
    (lower, raise_), (lowered, raised) = field.keys, field.phrases
    return Binding(raise_, raised, _nudge(field, 1)), Binding(lower, lowered, _nudge(field, -1))


KEY_MAP: tuple[Binding, ...] = (
    Binding(("enter",), "start an episode / end it and save it", lambda s: s.start_or_end()),
    Binding(("backspace",), "discard the episode in progress", lambda s: s.discard()),
    Binding(("esc",), "quit (an episode in progress is saved; Ctrl-C too)", lambda s: s.quit()),
    *(binding for field in COMMAND_FIELDS for binding in field_bindings(field)),
    Binding(("space",), "back to the neutral stand", lambda s: s.command_posture(NEUTRAL)),
    Binding(("p",), f"push the torso forward ({PUSH_FORCE:g} N for {PUSH_SECONDS:g} s)", lambda s: s.push()),
    Binding(("k",), f"kick the body forward ({KICK_SPEED:g} m/s at once: a step is the way out)", lambda s: s.kick()),
)
KEY_ACTIONS = {key: binding.effect for binding in KEY_MAP for key in binding.keys}


def key_help() -> str:
    """The key map as aligned lines, for --help (docs/how-to/teleoperate.md explains it)."""
    return "\n".join(f"  {' / '.join(binding.keys):<12} {binding.help}" for binding in KEY_MAP)


class TeleopSession:
    """The state of a teleoperation session: the command in force, the episode being recorded.

    Front ends call `press(key)` for each key and `tick()` once per env step; `tick` advances
    the simulation only while an episode is being recorded. `controller` follows the command: the expert, or a
    learned policy that takes one.
    """

    def __init__(
        self,
        env: gym.Env,
        controller: Controller,
        sink: EpisodeSink,
        first_seed: int,
        episodes: int,
        noise_std: float,
        report: Callable[[list[CommittedEpisode]], None],
        observer: StepObserver | None = None,
        cameras: tuple[Camera, ...] = (),
    ) -> None:
        self.env = env
        self.observer = observer
        self.controller = controller
        self.target = NEUTRAL
        """The command in force (clipped to the posture's limits)."""
        self.sink = sink
        self.held = set(sink.seeds())  # the dataset's seeds: a session's discarded episodes may run it past SEED's
        self.next_seed = first_seed
        self.episodes_left = episodes
        self.noise_std = noise_std
        self.report = report
        self.model, self.data = model_and_data(env)
        self.torso = self.model.body(TORSO_BODY).id
        self.mass = float(self.model.body_subtreemass[0])
        self.max_steps = env.spec.max_episode_steps
        self.buffer = EpisodeBuffer(env, self.max_steps, cameras)
        self.push_steps = max(1, round(PUSH_SECONDS / env.unwrapped.dt))
        self.recording = False
        self.finished = False
        self.saved = 0
        self.discarded = 0
        self.message = "press Enter to start an episode"
        self._reset_episode_state()

    def _reset_episode_state(self) -> None:
        self.t = 0
        self.episode_return = 0.0
        self.pushing_left = 0
        self.kicking = False
        self.obs: np.ndarray | None = None
        self.noise: np.ndarray | None = None

    # Key effects.
    def press(self, key: str) -> None:
        effect = KEY_ACTIONS.get(key)
        if effect is not None:
            effect(self)

    def command_posture(self, posture: Posture) -> None:
        self.target = posture.clipped()
        self.controller.set_command(command_vector(self.target))

    def push(self) -> None:
        if self.recording:
            self.pushing_left = self.push_steps

    def kick(self) -> None:
        if self.recording:
            self.kicking = True

    def start_or_end(self) -> None:
        if self.recording:
            self._end(save=True, why="ended")
        else:
            self._start()

    def discard(self) -> None:
        if self.recording:
            self._end(save=False, why="discarded")

    def quit(self) -> None:
        if self.recording:
            self._end(save=True, why="ended")
        self.finished = True

    # The episode.
    def _start(self) -> None:
        seed = self.next_seed
        # Every episode starts from the neutral stand: the body drops 12 cm from the reset pose.
        self.controller.reset(seed)
        self.target = NEUTRAL
        self.controller.set_command(command_vector(NEUTRAL))
        self._reset_episode_state()
        self.obs, _ = self.env.reset(seed=seed)
        if self.noise_std > 0:
            self.noise = injected_noise(seed, self.max_steps, self.noise_std, self.env.action_space.shape[0])
        self.recording = True
        self.message = f"recording episode with seed {seed}"
        if self.observer is not None:
            self.observer.episode_started(seed)

    def _end(self, save: bool, why: str) -> None:
        self.recording = False
        self.data.xfrc_applied[self.torso] = 0.0
        seed = self.next_seed
        self.next_seed += 1  # a discarded seed is not reused: the next episode starts fresh
        while self.next_seed in self.held:  # nor is one the dataset holds (teleop.seeds)
            self.next_seed += 1
        if save and self.t > 0:
            episode = self.buffer.episode(
                self.t,
                self.obs,
                seed=seed,
                controller=self.name,
                labeller=self.name,
                noise_std=self.noise_std,
            )
            self.report(self.sink.submit(episode))
            self.saved += 1
            self.episodes_left -= 1
            if self.episodes_left <= 0:
                self.finished = True
        else:
            self.discarded += 1
        self.message = f"episode {why} after {self.t} steps (return {self.episode_return:.1f}); Enter starts the next"

    @property
    def name(self) -> str:
        """Who acts, as the episodes record it: `keyboard`, or `keyboard:POLICY` when the keys drive a policy."""
        if self.controller.name == KEYBOARD_EXPERT:
            return KEYBOARD
        return f"{KEYBOARD}:{self.controller.name}"

    def tick(self) -> None:
        """One env step of the episode in progress (nothing while idle)."""
        if not self.recording:
            return
        self.data.xfrc_applied[self.torso, :3] = (PUSH_FORCE, 0.0, 0.0) if self.pushing_left else 0.0
        push = self.data.xfrc_applied[self.torso, :2].copy()
        if self.kicking:  # recorded as the force that gives its impulse over this step
            change = np.array([KICK_SPEED, 0.0])
            kick(self.data, change)
            push += kick_force(change, self.mass, self.env.unwrapped.dt)
            self.kicking = False
        self.obs, reward, terminated, truncated = rollout_step(
            self.env,
            self.data,
            self.controller,
            self.obs,
            self.t,
            self.next_seed,
            self.noise,
            self.buffer,
            command_vector(self.target),
            task_for(self.target),
            push=push,
            observer=self.observer,
        )
        self.pushing_left = max(0, self.pushing_left - 1)
        self.t += 1
        self.episode_return += reward
        if terminated or truncated:
            self._end(save=True, why="fell" if terminated else "reached the time limit")

    def status(self) -> str:
        """One line: recording state, time, height, return and the command in force."""
        target = self.target
        state = f"REC seed {self.next_seed} t {self.t * self.env.unwrapped.dt:5.2f} s" if self.recording else "idle"
        return (
            f"{state} | height {torso_height(self.model, self.data):.2f} m | return {self.episode_return:7.1f} | "
            f"{command_status(target)}{' | PUSH' if self.pushing_left else ''} | saved {self.saved} | {self.message}"
        )


def command_status(posture: Posture) -> str:
    """The command in force as the status line shows it: each field's value (a preset by its phrase), a limit
    reached marked `[max]` or `[min]` (a key past it changes nothing)."""
    parts = []
    for field in COMMAND_FIELDS:
        value = getattr(posture, field.name)
        shown = field.phrases[round(value)] if field.presets else f"{field.name.replace('_', ' ')} {value:+.2f}"
        limit = " [max]" if value >= field.high else " [min]" if value <= field.low and field.low < 0 else ""
        parts.append(shown + limit)
    return " | ".join(parts)


class StatusLine:
    """The session's status on one terminal line, rewritten in place when it changes.

    While recording it is refreshed every STATUS_EVERY steps: formatting it (a torso-height query
    and a dozen fields) every 15 ms step would be work in the real-time loop nobody can read.
    """

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.shown = ""

    def update(self, session: TeleopSession) -> None:
        if session.recording and session.t % STATUS_EVERY:
            return
        status = session.status()
        if status != self.shown:
            self.shown = status
            self.out.write("\r\x1b[2K" + status)
            self.out.flush()

    def close(self) -> None:
        self.out.write("\n")
        self.out.flush()


# The terminal front end.
_ESCAPES = {"\x1b[A": "up", "\x1b[B": "down", "\x1b[C": "right", "\x1b[D": "left"}
_SPECIAL = {"\r": "enter", "\n": "enter", "\x7f": "backspace", "\x08": "backspace", " ": "space", "\x1b": "esc"}


def parse_keys(text: str) -> list[str]:
    """Key names in raw terminal input: arrow escape sequences, special keys, and characters."""
    keys = []
    i = 0
    while i < len(text):
        sequence = next((seq for seq in _ESCAPES if text.startswith(seq, i)), None)
        if sequence:
            keys.append(_ESCAPES[sequence])
            i += len(sequence)
            continue
        keys.append(_SPECIAL.get(text[i], text[i].lower()))
        i += 1
    return keys


def run_terminal(session: TeleopSession, stdin_fd: int, out: TextIO, pace: float) -> None:
    """Real-time loop (`pace` simulated seconds a second) reading keys from the TTY `stdin_fd` (cbreak: Ctrl-C still
    interrupts)."""
    front_end_here("terminal", stdin_fd)
    saved_mode = termios.tcgetattr(stdin_fd)
    tty.setcbreak(stdin_fd)
    dt = session.env.unwrapped.dt / pace  # s of wall clock a step
    status_line = StatusLine(out)
    try:
        print("keys:\n" + key_help(), file=out)
        next_step = time.monotonic()
        while not session.finished:
            timeout = max(0.0, next_step - time.monotonic())
            readable, _, _ = select.select([stdin_fd], [], [], timeout)
            if readable:
                data = os.read(stdin_fd, 64)
                if not data:  # the terminal closed
                    session.quit()
                for key in parse_keys(data.decode(errors="ignore")):
                    session.press(key)
                    if session.finished:
                        break
                continue  # keys are handled at once; the step waits for its time
            session.tick()
            next_step = max(next_step + dt, time.monotonic() - dt)  # never run ahead to catch up a stall
            status_line.update(session)
    except KeyboardInterrupt:
        session.quit()
    finally:
        termios.tcsetattr(stdin_fd, termios.TCSADRAIN, saved_mode)
        status_line.close()


# The viewer front end: GLFW key codes, as MuJoCo's viewer passes them to its key callback.
_GLFW_KEYS = {
    257: "enter",
    259: "backspace",
    256: "esc",
    32: "space",
    265: "up",
    264: "down",
    263: "left",
    262: "right",
}


def glfw_key_name(keycode: int) -> str | None:
    if keycode in _GLFW_KEYS:
        return _GLFW_KEYS[keycode]
    if 48 <= keycode <= 57 or 65 <= keycode <= 90:  # digits and letters (GLFW reports upper case)
        return chr(keycode).lower()
    return None


_X_ERROR_HANDLER: list[object] = []  # the installed handler, kept alive for as long as Xlib may call it


def tolerate_x_errors(err: TextIO = sys.stderr) -> bool:
    """Make an X protocol error one line on `err` instead of Xlib's default, which prints it and calls exit(): when
    the passive viewer closes, its render thread can still swap the buffers of the destroyed window (GLXBadDrawable),
    and that exit() from the render thread hung the recorder after the dataset was saved (tests/teleop/test_viewer.py
    timed out so in two fresh clones' `make test`; passive_viewer now waits for that thread, and this handler stays
    for any other). GLFW sets its own handler only around its calls, and puts back the one it found. False where
    there is no libX11 (Wayland, macOS): nothing to do."""
    import ctypes  # noqa: PLC0415 - only the viewer front end needs it
    import ctypes.util  # noqa: PLC0415

    name = ctypes.util.find_library("X11")
    if name is None:
        return False
    xlib = ctypes.CDLL(name)

    class XErrorEvent(ctypes.Structure):
        _fields_ = [  # Xlib.h's XErrorEvent
            ("type", ctypes.c_int),
            ("display", ctypes.c_void_p),
            ("resourceid", ctypes.c_ulong),
            ("serial", ctypes.c_ulong),
            ("error_code", ctypes.c_ubyte),
            ("request_code", ctypes.c_ubyte),
            ("minor_code", ctypes.c_ubyte),
        ]

    @ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(XErrorEvent))
    def handler(_display: int, event: ctypes._Pointer) -> int:
        error = event.contents
        print(
            f"viewer: X error {error.error_code} (request {error.request_code}.{error.minor_code}) ignored",
            file=err,
            flush=True,
        )
        return 0

    xlib.XSetErrorHandler.restype = ctypes.c_void_p
    xlib.XSetErrorHandler(handler)
    _X_ERROR_HANDLER[:] = [handler]
    return True


@contextlib.contextmanager
def passive_viewer(
    model: mujoco.MjModel, data: mujoco.MjData, key_callback: Callable[[int], None] | None = None
) -> Iterator[mujoco.viewer.Handle]:
    """MuJoCo's passive viewer, closed on leaving and its thread waited for. The viewer's daemon thread destroys its
    window after close() returns; a process that exits first runs GLFW's terminate (an atexit hook) under that thread
    and segfaults (mujoco issue 790) or hangs: 12 of 20 such exits did here (0 of 20 with the wait), and the
    recorder once exited -11 after saving (docs/log.md, "2026-12-06: the viewer's thread waited for at exit; the viewer
    tests' display (fortieth session, issue 71)")."""
    import mujoco.viewer  # noqa: PLC0415 - needs a display

    before = set(threading.enumerate())
    started: list[threading.Thread] = []
    try:
        with mujoco.viewer.launch_passive(model, data, key_callback=key_callback) as viewer:
            started = [thread for thread in threading.enumerate() if thread not in before]
            yield viewer
    finally:
        for thread in started:
            thread.join(timeout=10.0)


def run_viewer(session: TeleopSession, out: TextIO, pace: float) -> None:
    """Real-time loop (`pace` simulated seconds a second) in MuJoCo's passive viewer; keys arrive through its
    callback."""
    tolerate_x_errors()

    pressed: list[str] = []

    def on_key(keycode: int) -> None:  # called on the viewer's thread: only queue the key
        name = glfw_key_name(keycode)
        if name:
            pressed.append(name)

    dt = session.env.unwrapped.dt / pace  # s of wall clock a step
    print("keys (in the viewer window):\n" + key_help(), file=out)
    status_line = StatusLine(out)
    try:
        with passive_viewer(session.model, session.data, key_callback=on_key) as viewer:
            with viewer.lock():  # follow the torso from 4 m, slightly above: the whole body in view
                viewer.cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
                viewer.cam.trackbodyid = session.torso
                viewer.cam.distance, viewer.cam.elevation, viewer.cam.azimuth = 4.0, -10.0, 135.0
            next_step = time.monotonic()
            while viewer.is_running() and not session.finished:
                while pressed:
                    session.press(pressed.pop(0))
                session.tick()
                viewer.sync()
                status_line.update(session)
                next_step = max(next_step + dt, time.monotonic() - dt)
                time.sleep(max(0.0, next_step - time.monotonic()))
    except KeyboardInterrupt:
        pass
    finally:
        session.quit()
        status_line.close()


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def front_end_here(front_end: str, stdin_fd: int | None = None) -> str:
    """The front end `front_end` ("auto": the viewer if a display exists, else the terminal) resolves to here;
    UserError in one line if it cannot run: no display for the viewer, no TTY on `stdin_fd` (stdin's by default) for
    the terminal. `make record` asks before it opens the dataset."""
    if front_end == "auto":
        front_end = "viewer" if has_display() else "terminal"
    if front_end == "viewer" and not has_display():
        raise UserError(
            "the viewer front end needs a display (DISPLAY or WAYLAND_DISPLAY): run it on a desktop, or in a terminal "
            "with --front-end terminal (FRONT_END=terminal)"
        )
    if front_end == "terminal" and not os.isatty(sys.stdin.fileno() if stdin_fd is None else stdin_fd):
        raise UserError(
            "keyboard teleoperation needs a terminal: stdin is not a TTY (run it in a terminal, or on a desktop with "
            "--front-end viewer, FRONT_END=viewer)"
        )
    return front_end


def run_session(
    env: gym.Env,
    sink: EpisodeSink,
    first_seed: int,
    episodes: int,
    noise_std: float,
    front_end: str,
    report: Callable[[list[CommittedEpisode]], None],
    observer: StepObserver | None = None,
    controller: Controller | None = None,
    cameras: tuple[Camera, ...] = (),
    pace: float = 1.0,
) -> None:
    """Teleoperate until the user quits or `episodes` episodes are saved; `observer` (a live view) sees every step.
    The keys command `controller` (a policy that takes a command: `make play`), by default the expert; each episode
    records `cameras`; the simulation runs `pace` simulated seconds per wall-clock second."""
    import scipy.optimize  # noqa: F401, PLC0415 - now, not as a 0.3 s hitch at the first posture key

    front_end = front_end_here(front_end)
    controller = make_controller(KEYBOARD_EXPERT, env) if controller is None else controller
    session = TeleopSession(env, controller, sink, first_seed, episodes, noise_std, report, observer, cameras)
    if front_end == "viewer":
        run_viewer(session, sys.stderr, pace)
    else:
        run_terminal(session, sys.stdin.fileno(), sys.stderr, pace)
