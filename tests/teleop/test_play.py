"""`make play`: scripted key presses through the terminal front end drive a learned policy that takes a command.

The policy is cloned here from demonstrations an operator gave by keys (the expert leaning forward and back, and
standing), cheap enough for the suite, and refined by a few PPO updates on command schedules (`make finetune-rl`'s
actor); a session of `make play`'s command behind a pseudo-terminal drives each.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bc.train import TrainConfig, teacher_of
from bc.train import main as train
from common import columns
from humanoid.env import QVEL_OBS, humanoid_model, make_env, model_and_data
from pipeline.targets import TARGETS
from policies.folder import WEIGHTS_FILE
from rl.finetune import FinetuneConfig
from rl.finetune import main as finetune
from students.inputs import STUDENT_INPUTS
from support import SESSION_PACE, Terminal, join_observation, one_core, snapshot
from task.command_fields import COMMAND_NAMES
from task.tracking import Tracking
from teachers.expert import LQRExpert
from teleop.dataset_reader import read_episodes, read_frames
from teleop.keyboard import TeleopSession
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # a policy trained, then sessions at 3× real time: about a minute

PLAY = [sys.executable, "-m", TARGETS["play"].module, *TARGETS["play"].preset_flags]
"""`make play`'s command (the recorder with the keyboard, datasets/play and no noise, unless set)."""
SESSION = [*PLAY, "--front-end", "terminal", f"--pace={SESSION_PACE}"]
"""That command in the terminal, run faster than real time."""

DEMONSTRATIONS = 16
DEMONSTRATION_SEED = 100  # the played episode's seed is 0: a landing no demonstration shows
SETTLE_STEPS = 200  # 3 s: the body drops 12 cm after reset and lands (the expert's landing plan)
HOLD_STEPS = 150  # each lean, and each return to neutral, held 2.25 s
LEANS = (-3, -2, -1, 1, 2, 3, 4)  # key presses of `w` (positive) or `s`: -0.15 .. 0.2 rad
HIDDEN = 128  # a narrower MLP than `make train-bc`'s 256: as reliable here, and faster to train
UPDATES = 2000  # Adam steps: 60 of 60 probes of 3 such policies reached 72 % or more of a lean, none fell

DT = 0.015  # s, an env step of Humanoid-v5 (checked below)
WITHIN = 3.0  # s: the target, at least 60 % of the way to the commanded lean, and back
SHARE = 0.6
PRESSES = "www"  # lean forward 0.15 rad (`Posture.STEP`)


def record_by_keys(root: Path, episodes: int) -> None:
    """Episodes of the expert driven by scripted keys, in simulated time: after the landing, `LEANS` drawn from a
    fixed stream, each held, then Space (neutral), held. The keyboard's own session (`TeleopSession`), its keys
    pressed in code rather than through a terminal, so the episodes are what a person at the keys records."""
    env = make_env(5000)  # never reached: each episode ends with Enter
    store = EpisodeStore(root, DatasetSpec.from_env(env))
    draw = np.random.default_rng(0)
    try:
        expert = LQRExpert(model_and_data(env)[0])
        session = TeleopSession(env, expert, store, DEMONSTRATION_SEED, episodes, 0.05, lambda committed: None)

        def hold(steps: int) -> None:
            for _ in range(steps):
                session.tick()

        for _ in range(episodes):
            session.press("enter")
            hold(SETTLE_STEPS)
            for presses in draw.choice(LEANS, size=3):
                for _ in range(abs(presses)):
                    session.press("w" if presses > 0 else "s")
                hold(HOLD_STEPS)
                session.press("space")
                hold(HOLD_STEPS)
            session.press("enter")
    finally:
        store.close()
        env.close()


@dataclass(frozen=True)
class Policies:
    commanded: Path  # INPUTS=full+command
    uncommanded: Path  # INPUTS=full, on the same data
    fine_tuned: Path  # PPO from `commanded`, on command schedules


def cheap_training(dataset: Path, policy: Path, inputs: str, updates: int) -> None:
    """`make train-bc` with a narrower MLP and few Adam steps, on one core (`support.one_core`), no evaluation."""
    with one_core():
        train(
            TrainConfig(
                dataset=dataset,
                policy=policy,
                inputs=inputs,
                hidden=HIDDEN,
                epochs=1,
                min_updates=updates,
                cache=False,
                eval_episodes=0,
                progress=False,
            )
        )


@pytest.fixture(scope="module")
def policies(tmp_path_factory: pytest.TempPathFactory) -> Policies:
    work = tmp_path_factory.mktemp("play")
    record_by_keys(work / "demonstrations", DEMONSTRATIONS)
    made = Policies(work / "bc_command", work / "bc_plain", work / "ppo_command")
    cheap_training(work / "demonstrations", made.commanded, "full+command", UPDATES)
    cheap_training(work / "demonstrations", made.uncommanded, "full", 0)
    fine_tune(made.commanded, made.fine_tuned)
    return made


def fine_tune(student: Path, actor: Path) -> None:
    """`make finetune-rl` from `student` at a tiny size: two updates of the actor (no critic warm-up), one process,
    one final episode under a held-out schedule."""
    settings = {"timesteps": 512, "envs": 4, "workers": 1, "rollout_steps": 256, "batch_size": 64, "epochs": 1}
    evaluations = {"eval_freq": 512, "eval_episodes": 1, "floor_episodes": 1, "final_eval_episodes": 1}
    finetune(
        FinetuneConfig(bc_policy=student, policy=actor, critic_warmup=0, progress=False, **settings, **evaluations)
    )
    assert (actor / WEIGHTS_FILE).read_bytes() != (student / WEIGHTS_FILE).read_bytes()  # PPO moved the actor


def test_a_student_of_the_keys_is_evaluated_beside_the_expert_they_drove(policies: Policies) -> None:
    """The keyboard's episodes are labelled by the expert the keys drive: `make train-bc`'s evaluation compares the
    student with that expert."""
    assert teacher_of(policies.commanded.parent / "demonstrations") == "expert"


@dataclass(frozen=True)
class Played:
    root: Path
    policy: Path
    output: str


@pytest.fixture(scope="module", params=["student", "fine-tuned"])
def played(policies: Policies, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Played:
    """One episode of `make play` on the commanded student, or the actor PPO refined from it: land, lean forward
    (www), back to neutral, quit."""
    policy = policies.commanded if request.param == "student" else policies.fine_tuned
    root = tmp_path_factory.mktemp("played") / "play"
    terminal = Terminal([*SESSION, "--dataset", str(root), "--policy", str(policy)])
    terminal.wait_for(b"keys:")
    terminal.press("\r", 0)  # start; the policy lands the body
    lean = SETTLE_STEPS * DT
    terminal.wait_until_simulated(lean)
    terminal.press(PRESSES, 0)  # lean forward, held half a second past the target's window
    terminal.wait_until_simulated(lean + WITHIN + 0.5)
    terminal.press(" ", 0)  # back to neutral
    terminal.wait_until_simulated(lean + 2 * (WITHIN + 0.5))
    terminal.press("\x1b", 0)  # quit: the episode is saved
    assert terminal.process.wait(timeout=60) == 0, terminal.output.decode(errors="replace")[-2000:]
    terminal.read_for(0.5)
    return Played(root, policy, terminal.output.decode(errors="replace"))


def way_travelled(achieved: np.ndarray, start: int, goal: float, steps: int) -> np.ndarray:
    """The share of the way from where the trunk was before `start` (its mean over 0.3 s) to `goal`, at each of
    the `steps` frames from `start` on."""
    before = achieved[start - 20 : start].mean()
    return (achieved[start : start + steps] - before) / (goal - before)


def test_the_keys_lean_the_policys_trunk_and_back_within_3_s(played: Played) -> None:
    """The issue's target: the trunk's pitch gets at least 60 % of the way to the commanded lean within 3 s of the
    keys, and 60 % of the way back within 3 s of Space; the body stays up."""
    frames = read_frames(
        played.root, [columns.OBS_STATE, columns.OBS_ENV_STATE, columns.OBS_COMMAND, columns.TERMINATED]
    )
    observation = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    command = frames[columns.OBS_COMMAND]
    changes = np.flatnonzero((np.diff(command, axis=0) != 0).any(axis=1)) + 1
    assert len(changes) == 2, changes  # the lean, then neutral
    env = make_env()
    assert env.unwrapped.dt == DT
    env.close()
    lean, back = changes
    np.testing.assert_allclose(command[lean], [0.15, 0, 0, 0, 0, 0, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(command[back], np.zeros(8))
    window = round(WITHIN / DT)
    assert back - lean >= window and len(command) - back >= window, (lean, back, len(command))
    tracking = Tracking(humanoid_model())
    pitch = tracking.achieved(observation)[:, 0]
    forward = way_travelled(pitch, lean, tracking.target(command[lean])[0], window)
    returned = way_travelled(pitch, back, tracking.target(command[back])[0], window)
    reached_at = np.flatnonzero(forward >= SHARE)
    returned_at = np.flatnonzero(returned >= SHARE)
    print(
        f"lean: {forward.max():.0%} of the way at most, {SHARE:.0%} after "
        f"{reached_at[0] * DT if len(reached_at) else float('nan'):.2f} s; back: {returned.max():.0%}, "
        f"{SHARE:.0%} after {returned_at[0] * DT if len(returned_at) else float('nan'):.2f} s"
    )
    assert forward.max() >= SHARE, forward.max()
    assert returned.max() >= SHARE, returned.max()
    assert not frames[columns.TERMINATED].any()


def test_the_play_dataset_names_the_keyboard_and_the_policy(played: Played) -> None:
    """Recorded like any keyboard episode, the controller named `keyboard:POLICY`; with no setpoint of its own,
    the policy's setpoint column is the command."""
    episode = read_episodes(played.root).to_pylist()[0]
    assert episode[columns.EPISODE_CONTROLLER] == f"keyboard:{played.policy}"
    assert episode[columns.EPISODE_LABELLER] == f"keyboard:{played.policy}"
    assert episode[columns.EPISODE_NOISE_STD] == 0.0  # `make play` drives the policy as it is
    assert episode["tasks"] == ["Stand still on both feet.", "Lean forward while standing."]
    frames = read_frames(played.root, [columns.OBS_COMMAND, columns.SETPOINT])
    np.testing.assert_array_equal(frames[columns.SETPOINT], frames[columns.OBS_COMMAND])
    assert "added 1 episode (seed " in played.output


def refused(tmp_path: Path, *flags: str) -> subprocess.CompletedProcess:
    """The recorder with `flags`, stdin not a terminal (the refusal comes first), writing into tmp_path/play."""
    return subprocess.run(
        [sys.executable, "-m", "teleop.record", "--dataset", str(tmp_path / "play"), *flags],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_policy_that_takes_no_command_is_refused_in_one_line(policies: Policies, tmp_path: Path) -> None:
    """`make play POLICY=` a policy without the command: the keys would change nothing; one line, nothing written."""
    before = snapshot(policies.uncommanded)
    result = refused(tmp_path, *PLAY[3:], "--policy", str(policies.uncommanded))
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        f"error: {policies.uncommanded} takes no command: the keys would change nothing "
        f"(train one on inputs that read it, such as the default INPUTS={STUDENT_INPUTS})"
    ]
    assert not (tmp_path / "play").exists()
    assert snapshot(policies.uncommanded) == before


def test_a_policy_without_the_keyboard_is_refused_in_one_line(policies: Policies, tmp_path: Path) -> None:
    """--policy is the keys' policy: with another controller it is refused in one line, nothing written."""
    result = refused(tmp_path, "--controller", "expert", "--policy", str(policies.commanded))
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        "error: --policy is driven by the keys: it needs --controller keyboard, got expert"
    ]
    assert not (tmp_path / "play").exists()


def test_a_registered_controller_that_takes_no_command_is_refused_in_one_line(tmp_path: Path) -> None:
    """`make play POLICY=random`: the registered controllers the keys can drive are those that take a command (the
    experts, `expert-stepping` among them); another is refused in one line, nothing written."""
    result = refused(tmp_path, *PLAY[3:], "--policy", "random")
    assert result.returncode == 1
    assert result.stderr.splitlines() == ["error: random takes no command: the keys would change nothing"]
    assert not (tmp_path / "play").exists()


def test_the_arrows_walk_the_walker_and_k_kicks_it(tmp_path: Path) -> None:
    """`make play POLICY=walker`: ↑ pressed five times (0.5 m/s) and held 5 s walks the body at least a metre
    forward without a fall; Space asks it to stop, and `k` kicks it (the push column records the kick). Whether it
    stays up after a kick is the suite's to measure (docs/decisions/walker-kicks.md): here the session ends 0.3 s
    after it."""
    root = tmp_path / "play"
    terminal = Terminal([*SESSION, "--dataset", str(root), "--policy", "walker"])
    terminal.wait_for(b"keys:")
    terminal.press("\r", 0)
    start = SETTLE_STEPS * DT
    terminal.wait_until_simulated(start)
    terminal.press("\x1b[A" * 5, 0)  # ↑ five times: forward at 0.5 m/s
    # Held 5 s from the first status line that shows them landed, not from `start`: the line read before pressing
    # lags the session, so the keys may land a few tenths of a simulated second after `start`.
    walked_from = terminal.shown_at(b"forward speed +0.50")
    terminal.wait_until_simulated(walked_from + 5.0)
    terminal.press(" ", 0)  # stop
    terminal.wait_until_simulated(walked_from + 6.0)
    terminal.press("k", 0)
    terminal.wait_until_simulated(walked_from + 6.3)
    terminal.press("\x1b", 0)
    assert terminal.process.wait(timeout=60) == 0, terminal.output.decode(errors="replace")[-2000:]
    frames = read_frames(
        root, [columns.OBS_STATE, columns.OBS_ENV_STATE, columns.OBS_COMMAND, columns.TERMINATED, columns.PUSH]
    )
    observation = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    command = frames[columns.OBS_COMMAND]
    walking = np.flatnonzero(command[:, COMMAND_NAMES.index("forward_speed")] > 0)
    assert len(walking) * DT >= 4.9
    velocity = observation[walking[0] : walking[-1] + 1, QVEL_OBS][:, :2]  # the root's, world frame
    moved = velocity.sum(axis=0) * DT
    print(f"walked {moved.round(2)} m in {len(walking) * DT:.1f} s")
    assert moved[0] >= 1.0
    assert not frames[columns.TERMINATED].any()
    kicked = np.flatnonzero(np.abs(frames[columns.PUSH]).sum(axis=1) > 0)
    assert len(kicked) == 1 and kicked[0] > walking[-1]
    assert "walker" in read_episodes(root).to_pylist()[0][columns.EPISODE_CONTROLLER]
