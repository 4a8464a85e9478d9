"""`make eval`: the JSON it prints, survival of a falling and a standing controller, pushes, video, bad input."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from common.cli import config_dict
from evaluation.evaluate import EvalConfig, cli, evaluate, evaluate_each, evaluation_pool
from humanoid.conditions import RANDOMIZATION_STREAM
from humanoid.env import make_env
from humanoid.perturbations import TorsoPushes, VelocityKick, relative_direction, toppling
from humanoid.video import VideoError
from policies import checkpoint
from policies.checkpoint import load
from policies.folder import WEIGHTS_FILE
from policies.mlp import MLPPolicy, MLPSpec
from support import untrained_checkpoint
from task.schedules import parse_held

FIELDS = {"mean_return", "std_return", "mean_length", "survival_rate", "episodes", "seeds"}


DT = 0.015  # s, Humanoid-v5's env step


def eval_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], list[str]]:
    """Exit code, stdout lines and stderr lines of `python -m evaluation.evaluate ARGS`."""
    code = cli(["--progress", "false", *args])
    out, err = capsys.readouterr()
    return code, out.strip().splitlines(), err.strip().splitlines()


def corrupt_checkpoint(folder: Path) -> Path:
    """A checkpoint whose weights file is garbage."""
    untrained_checkpoint(folder).joinpath(WEIGHTS_FILE).write_bytes(b"garbage")
    return folder


def test_json_last_line_has_the_fields(capsys: pytest.CaptureFixture[str]) -> None:
    """The last stdout line is one JSON object with returns, length, survival, episodes and seeds."""
    code, out, _ = eval_cli(["--policy", "random", "--episodes", "2", "--seed", "5"], capsys)
    result = json.loads(out[-1])
    assert code == 0 and FIELDS <= result.keys()
    assert result["episodes"] == 2 and result["seeds"] == [5, 6]


def test_json_holds_the_runs_full_config(capsys: pytest.CaptureFixture[str]) -> None:
    """What `make eval` writes carries every setting it ran with, defaults included."""
    code, out, _ = eval_cli(["--policy", "random", "--episodes", "1", "--push", "5"], capsys)
    expected = EvalConfig(policy="random", episodes=1, push=5.0, progress=False)
    assert code == 0 and json.loads(out[-1])["config"] == config_dict(expected)


def test_random_controller_falls_at_once() -> None:
    """Random actions survive no episode and end within a few dozen steps."""
    result = evaluate("random", episodes=3)
    assert result["survival_rate"] == 0.0 and result["survived"] == 0 and result["mean_length"] < 60


def test_expert_stands_every_episode() -> None:
    """The expert reaches the 1000-step limit on every seed with a standing return."""
    result = evaluate("expert", episodes=2)
    assert result["survival_rate"] == 1.0 and result["lengths"] == [1000, 1000] and result["mean_return"] > 4900


def test_a_held_arrow_walks_the_walker_a_metre_and_the_expert_stands(capsys: pytest.CaptureFixture[str]) -> None:
    """`make eval HOLD=forward_speed=0.5` (`make play`'s up arrow pressed five times and held 5 s): the walker walks a
    metre forward along its heading and steps on after; the LQR expert stands whatever speed is asked (known answer:
    it does not move). A speed past its field's limit is clipped as the keys clip it. The line is strict JSON: a field
    no command moved has no error, null (not Python's NaN)."""
    code, out, _ = eval_cli(["--policy", "walker", "--episodes", "1", "--hold", "forward_speed=0.5"], capsys)
    result = json.loads(out[-1], parse_constant=lambda name: pytest.fail(f"{name} is no JSON"))
    assert result["tracking"]["moved_error"]["turn_rate"] is None
    held = result["held"]
    assert result["task"] is None  # no task's schedule ran
    assert code == 0 and result["survived"] == 1 and held["command"] == {"forward_speed": 0.5}
    assert held["walked_1m"] == 1 and held["forward"] >= 1.0 and abs(held["sideways"]) < 0.2 and held["after"] > 0
    assert result["tracking"]["moved_error"]["forward_speed"] > 0 and result["config"]["hold"] == "forward_speed=0.5"
    expert = evaluate("expert", episodes=1, hold=parse_held("forward_speed=9"))["held"]
    assert expert["command"] == {"forward_speed": 0.6} and expert["walked_1m"] == 0  # the field's limit
    assert abs(expert["forward"]) < 0.01 and abs(expert["turned"]) < 0.01


def test_saved_policy_runs_by_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A checkpoint folder is evaluated by its path and named by it in the JSON."""
    folder = untrained_checkpoint(tmp_path / "policy")
    code, out, _ = eval_cli(["--policy", str(folder), "--episodes", "1"], capsys)
    assert code == 0 and json.loads(out[-1])["policy"] == str(folder)


def test_a_suite_condition_is_applied_by_name(capsys: pytest.CaptureFixture[str]) -> None:
    """CONDITION=push20 topples the expert, which stands the same seed clean (docs/concepts/robustness-suite.md)."""
    clean = evaluate("expert", episodes=1, seed=1000)
    pushed = evaluate("expert", episodes=1, seed=1000, condition="push20")
    assert clean["survival_rate"] == 1.0 and pushed["survival_rate"] == 0.0
    code, out, _ = eval_cli(["--policy", "expert", "--episodes", "1", "--condition", "push20", "--task=stand"], capsys)
    assert code == 0 and json.loads(out[-1])["returns"] == pushed["returns"]


def test_pushes_follow_the_schedule_and_repeat_with_the_seed() -> None:
    """The torso gets `force` newtons horizontally during the first `duration` of each period, seeded directions."""
    env = TorsoPushes(make_env(), force=7.0, period=0.15, duration=0.03)  # 10-step period, 2-step pushes
    torso = env.unwrapped.model.body("torso").id

    def forces(seed: int) -> list[np.ndarray]:
        env.reset(seed=seed)
        applied = []
        for _ in range(30):
            env.step(np.zeros(17))
            applied.append(env.unwrapped.data.xfrc_applied[torso].copy())
        return applied

    applied = forces(3)
    pushing = [int(np.linalg.norm(f[:3]) > 0) for f in applied]
    assert pushing == ([0] * 10 + [1, 1] + [0] * 8) + ([1, 1] + [0] * 8)
    for force in (applied[10], applied[20]):
        assert np.isclose(np.linalg.norm(force[:2]), 7.0) and force[2] == 0 and not force[3:].any()
    assert not np.allclose(applied[10], applied[20])  # a new direction for each push
    assert all(np.array_equal(a, b) for a, b in zip(applied, forces(3), strict=True))


def kicked_velocity(speed: float, seed: int, steps: int) -> tuple[np.ndarray, list[tuple[int, float]]]:
    """The root's horizontal velocity just before each step of an episode under `VelocityKick` (the window 3 to 5
    steps in) with the actions zero, and its kicks."""
    env = VelocityKick(make_env(), speed, window=(3 * DT, 5 * DT))
    env.reset(seed=seed)
    velocity = []
    for _ in range(steps):
        velocity.append(env.unwrapped.data.qvel[:2].copy())
        env.step(np.zeros(17))
    return np.array(velocity), env.pushes


def test_a_kick_changes_the_roots_velocity_once_by_its_speed_at_a_seeded_time() -> None:
    """Known answer against the same episode unkicked: before the kick the velocities are equal, at its step the
    difference is the kick (0.4 m/s in the seeded direction, which the listed direction names from the torso facing
    world x), and there is one kick; the same seed repeats it, another moves it."""
    still, _ = kicked_velocity(0.0, 5, 8)
    moved, kicks = kicked_velocity(0.4, 5, 8)
    ((at, direction),) = kicks
    assert 3 <= at <= 5
    np.testing.assert_array_equal(moved[: at + 1], still[: at + 1])
    difference = moved[at + 1] - still[at + 1]  # one env step of contact after the kick
    assert np.linalg.norm(difference) == pytest.approx(0.4, rel=0.1)
    assert np.degrees(np.arctan2(difference[1], difference[0])) == pytest.approx(direction, abs=5.0)
    assert kicked_velocity(0.4, 5, 8)[1] == kicks and kicked_velocity(0.4, 6, 8)[1] != kicks


@pytest.mark.parametrize("value", ["-0.1", "nan", "inf"])
def test_a_kick_that_is_negative_or_not_finite_is_refused_in_one_line(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = eval_cli(["--policy", "expert", "--kick", value], capsys)
    assert (code, out, err) == (1, [], [f"error: --kick must be a speed >= 0 in m/s, got {float(value)}"])


def test_a_push_and_a_kick_together_are_refused_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = eval_cli(["--policy", "expert", "--push", "20", "--kick", "0.2"], capsys)
    assert (code, out, err) == (1, [], ["error: --push and --kick are two perturbations: give one of them"])


def test_the_suites_kicks_are_reported_in_metres_per_second_and_newton_seconds() -> None:
    """kick0.4: one kick of 0.4 m/s per episode, its impulse the body's 42.1 kg times it, listed for the toppling
    breakdown."""
    result = evaluate("expert", episodes=1, seed=1000, condition="kick0.4")
    assert result["kick"] == {"speed": 0.4, "impulse": 16.85}  # 0.4 m/s × 42.116 kg
    assert len(result["pushes"]["direction"]) == 1


def test_pushes_are_listed_with_their_direction_seen_from_the_torso() -> None:
    """Each push is listed at its start step, its direction measured from where the torso faces (here turned 90°)."""
    env = TorsoPushes(make_env(), force=7.0, period=0.15, duration=0.03)  # pushes start on steps 10 and 20
    data = env.unwrapped.data
    env.reset(seed=3)
    data.qpos[3:7] = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]  # the body turned to face world +y
    world = []
    for t in range(25):
        env.step(np.zeros(17))
        if t in (10, 20):
            force = data.xfrc_applied[env.unwrapped.model.body("torso").id, :2]
            world.append(np.degrees(np.arctan2(force[1], force[0])))
    assert [start for start, _ in env.pushes] == [10, 20]
    for (_, seen), angle in zip(env.pushes, world, strict=True):
        assert np.isclose((seen - (angle - 90.0) + 180.0) % 360.0, 180.0, atol=2.0)  # the yaw drifts a little
    env.reset(seed=3)
    assert env.pushes == []


@pytest.mark.parametrize(
    "push, facing, direction",
    [
        ((1, 0), 0.0, 0.0),
        ((0, 1), 0.0, 90.0),
        ((-1, 0), 0.0, 180.0),
        ((1, 0), np.pi / 2, -90.0),
        ((0, -1), np.pi / 2, 180.0),
    ],
)
def test_relative_direction_is_zero_forward_and_counter_clockwise(
    push: tuple[float, float], facing: float, direction: float
) -> None:
    assert np.isclose(relative_direction(np.array([*push, 0.0]), facing), direction)


def test_the_last_push_before_a_fall_is_the_one_that_toppled() -> None:
    assert toppling([133, 266, 399], fell=True) == [False, False, True]
    assert toppling([133, 266], fell=False) == [False, False]
    assert toppling([], fell=True) == []


def test_evaluation_lists_every_push_and_puts_each_fall_on_one() -> None:
    """Every push begun before an episode ended is listed; a fallen episode's last push is marked as toppling."""
    result = evaluate("expert", episodes=2, seed=1000, condition="push40")
    period = 133  # 2 s of 0.015 s steps
    assert len(result["pushes"]["direction"]) == sum((length - 1) // period for length in result["lengths"])
    assert sum(result["pushes"]["toppled"]) == result["episodes"] - result["survived"] > 0
    assert all(-180 < d <= 180 for d in result["pushes"]["direction"])
    assert evaluate("expert", episodes=1, seed=1000)["pushes"] == {"direction": [], "toppled": []}


def test_evaluation_keeps_each_episodes_drawn_body() -> None:
    """Under a randomised condition every episode's draw is in the result, the one its seed gives."""
    result = evaluate("expert", episodes=2, seed=1000, condition="mass")
    for seed, drawn in zip(result["seeds"], result["parameters"], strict=True):
        scale = np.random.default_rng((seed, RANDOMIZATION_STREAM)).uniform(0.8, 1.2, size=13).round(6)
        assert drawn == {"mass_scale": scale.tolist()}
    assert evaluate("expert", episodes=1, seed=1000)["parameters"] == [{}]


@pytest.mark.slow
def test_video_has_a_frame_per_step(tmp_path: Path) -> None:
    """VIDEO writes an MP4 of the episode, rendered offscreen: one frame after reset and after each step."""
    path = tmp_path / "clip.mp4"
    try:
        result = evaluate("random", episodes=1, video=path)
    except VideoError as error:
        pytest.skip(f"no offscreen rendering here: {error}")
    frames = iio.improps(path, plugin="pyav").shape[0]
    assert frames == result["lengths"][0] + 1


def test_non_finite_actions_stop_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A policy that outputs NaN fails in one line naming the step, not in a traceback."""
    folder = untrained_checkpoint(tmp_path / "nan", poison=True)
    code, out, err = eval_cli(["--policy", str(folder), "--episodes", "1"], capsys)
    assert code == 1 and out == [] and len(err) == 1 and "non-finite action at step 0" in err[0]


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        (lambda root: root, "not a policy checkpoint"),
        (lambda root: root / "missing", "no policy checkpoint at"),
        (lambda root: corrupt_checkpoint(root / "corrupt"), "the checkpoint is damaged, train it again"),
        (lambda root: "expertt", "unknown controller 'expertt'"),
    ],
)
def test_bad_policy_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], setup: Callable[[Path], Path | str], message: str
) -> None:
    """A folder that is not a checkpoint, a missing one, corrupt weights or an unknown name: one line, exit 1."""
    code, out, err = eval_cli(["--policy", str(setup(tmp_path)), "--episodes", "1"], capsys)
    assert code == 1 and out == [] and len(err) == 1 and message in err[0]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--episodes", "0"], "--episodes must be positive"),
        (["--push", "-1"], "--push must be a force >= 0"),
        (["--noise", "nan"], "--noise must be >= 0"),
        (["--video", "x.avi"], "--video must be a .mp4 file's path, got x.avi"),
        (["--condition", "gravity"], "unknown --condition 'gravity'"),
        (["--condition", "mass", "--push", "10"], "--condition brings its own perturbation"),
        (["--hold", "forward=0.5"], "--hold: 'forward=0.5' is not FIELD=VALUE"),
        (["--hold", "turn_rate=fast"], "with a number VALUE"),
        (["--hold", "forward_speed=0.5", "--task", "walk"], "instead of --task walk's schedule: give one of them"),
    ],
)
def test_bad_settings_are_refused(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Impossible settings fail in one line, naming the setting, before anything runs."""
    code, out, err = eval_cli(["--policy", "random", *args], capsys)
    assert code == 1 and out == [] and len(err) == 1 and message in err[0]


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (MLPSpec(("observation.state", "observation.environment_state"), 45, 17, hidden=(8,)), "45 full inputs"),
        (MLPSpec(("observation.state",), 45, 17, hidden=(8,), inputs="proprio"), "45 proprio inputs"),
        (MLPSpec(("observation.state",), 42, 17, hidden=(8,), inputs="camera"), "reads 'camera'"),
    ],
)
def test_policy_that_does_not_fit_the_env_is_refused(tmp_path: Path, spec: MLPSpec, message: str) -> None:
    """A checkpoint whose inputs the environment cannot give fails with a message saying what differs."""
    checkpoint.save(MLPPolicy(spec), tmp_path / "small", {}, {})
    with pytest.raises(checkpoint.CheckpointError, match=message):
        evaluate(str(tmp_path / "small"), episodes=1)


def test_evaluations_side_by_side_give_what_they_give_one_after_the_other(bc_policy: Path) -> None:
    """A learned policy's evaluations in a pool's processes (the policy pickled) return what they return here, in
    the order given: what PPO's evaluations during training rely on."""
    runs = [((load(bc_policy), "bc"), {"episodes": 1, "seed": 1000, "condition": name}) for name in ("clean", "mass")]
    here = list(evaluate_each(runs))
    with evaluation_pool(2) as pool, evaluation_pool(2) as inner:
        assert pool is not None and inner is pool  # a block inside another reuses its pool
        there = list(evaluate_each(runs, pool))
    assert there == here
    assert here[0]["parameters"] != here[1]["parameters"]  # in order: each condition's own result
