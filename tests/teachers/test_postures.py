"""The LQR teacher's postures: the balanced pose solve, its gains, and the expert holding a posture (real MuJoCo)."""

from __future__ import annotations

from collections.abc import Iterator

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from humanoid import physics
from humanoid.env import make_env, model_and_data
from task.command_fields import FIELDS
from task.posture import NEUTRAL, Posture
from teachers.expert import LQRExpert
from teachers.lqr import CTRL_LIMIT
from teachers.postures import posture_gain, posture_reference

SETTLE_STEPS = 133  # 2 s of neutral stand after the env's reset drop
HOLD_STEPS = 150  # about 2 s at the posture once the ramp has got there


@pytest.fixture(scope="module")
def env() -> Iterator[gym.Env]:
    """One Humanoid-v5 env with room for long holds."""
    environment = make_env(max_episode_steps=10_000)
    yield environment
    environment.close()


@pytest.fixture(scope="module")
def model(env: gym.Env) -> mujoco.MjModel:
    """The env's model (the posture caches key on the model object)."""
    return model_and_data(env)[0]


@pytest.fixture(scope="module")
def expert(model: mujoco.MjModel) -> LQRExpert:
    """An expert shared by the tests, reset before each use."""
    return LQRExpert(model)


def stand(env: gym.Env, expert: LQRExpert, seed: int = 0) -> np.ndarray:
    """Reset env and expert, stand neutral for 2 s; the observation then."""
    obs, _ = env.reset(seed=seed)
    expert.reset(seed)
    for _ in range(SETTLE_STEPS):
        obs, *_ = env.step(expert.act(obs))
    return obs


def hold(env: gym.Env, expert: LQRExpert, obs: np.ndarray, posture: Posture) -> np.ndarray:
    """Command ``posture``, follow the ramp, hold HOLD_STEPS more; fails the test if the body falls."""
    expert.hold(posture)
    steps = 0
    while expert.moving or steps < HOLD_STEPS:
        obs, _, terminated, _, _ = env.step(expert.act(obs))
        assert not terminated, f"fell while holding {posture}"
        steps += 0 if expert.moving else 1
    return obs


def measurements(env: gym.Env) -> dict[str, float]:
    """Torso tilt, yaw relative to the pelvis, height, CoM offset and hand height, now."""
    model, data = model_and_data(env)
    mujoco.mj_comPos(model, data)
    forward, left = physics.torso_tilt(model, data)
    com = physics.com_over_feet(model, data)
    return {
        "forward": forward,
        "left": left,
        "yaw": physics.torso_yaw_relative_to_pelvis(model, data),
        "height": physics.torso_height(model, data),
        "com_y": float(com[1]),
        "hands": float(np.mean([data.geom(g).xpos[2] for g in ("right_hand", "left_hand")])),
        "lower_arms": float(np.mean([data.body(b).xpos[2] for b in ("right_lower_arm", "left_lower_arm")])),
    }


def held_at_limit(env: gym.Env, expert: LQRExpert, field: str, side: float) -> tuple[float, dict[str, float]]:
    """Stand, then hold `field` at its limit on `side` (+1: MAX, -1: MIN); the limit and the measurements then."""
    limit = FIELDS[field].high if side > 0 else FIELDS[field].low
    hold(env, expert, stand(env, expert), Posture(**{field: limit}))
    return limit, measurements(env)


@pytest.fixture(scope="module")
def neutral_stand(env: gym.Env, expert: LQRExpert) -> dict[str, float]:
    """Measurements of the neutral stand after the same settle and hold time as the postures."""
    obs = stand(env, expert)
    for _ in range(HOLD_STEPS):
        obs, *_ = env.step(expert.act(obs))
    return measurements(env)


def test_neutral_posture_is_the_designs_setpoint_bit_for_bit(model: mujoco.MjModel, expert: LQRExpert) -> None:
    """posture_reference and posture_gain of Posture() are exactly the designed qpos_ref, ctrl_ff and gain."""
    qpos, ctrl = posture_reference(model, Posture())
    np.testing.assert_array_equal(qpos, expert.gains.qpos_ref)
    np.testing.assert_array_equal(ctrl, expert.gains.ctrl_ff)
    np.testing.assert_array_equal(posture_gain(model, Posture()), expert.gains.gain)


def test_reset_after_a_posture_acts_exactly_like_a_never_commanded_expert(
    env: gym.Env, model: mujoco.MjModel, expert: LQRExpert
) -> None:
    """After hold(...) and reset(seed), actions are bit-identical to a fresh expert's over 100 steps."""
    obs = stand(env, expert)
    expert.hold(Posture(lean_forward=0.1, arms=1))
    for _ in range(20):
        obs, *_ = env.step(expert.act(obs))
    fresh = LQRExpert(model)
    obs, _ = env.reset(seed=4)
    expert.reset(4)
    fresh.reset(4)
    assert expert.posture == expert.target == NEUTRAL and not expert.moving
    for _ in range(100):
        action = expert.act(obs)
        np.testing.assert_array_equal(action, fresh.act(obs))
        obs, *_ = env.step(action)


def test_a_second_default_expert_plans_a_posture_without_designing_again() -> None:
    """Default experts share the nominal model, so the second to hold a posture finds every gain the first designed
    (a suite builds an expert per task): no new design, and the same actions."""
    posture = Posture(lean_left=0.1, twist=-0.2)
    first = LQRExpert()
    first.hold(posture)
    designed = posture_gain.cache_info().misses
    second = LQRExpert()
    second.hold(posture)
    assert second.model is first.model
    assert posture_gain.cache_info().misses == designed
    obs = np.zeros(348)
    obs[: len(first.qpos_ref) - 2] = first.qpos_ref[2:]
    np.testing.assert_array_equal(first.act(obs), second.act(obs))


@pytest.mark.parametrize("field", ["lean_forward", "lean_left", "height", "twist", "arms"])
def test_static_pose_at_the_limits_needs_no_help_from_the_root(model: mujoco.MjModel, field: str) -> None:
    """At each field's limits the solved pose leaves no root force or moment and its feed-forward fits the motors."""
    weight = model.body_subtreemass[0] * -model.opt.gravity[2]
    data = mujoco.MjData(model)
    # arms' MIN is the neutral pose, whose design (balanced_pose) leaves a 1e-3 N m roll moment unsolved.
    for value in (v for v in (FIELDS[field].low, FIELDS[field].high) if v != 0.0):
        qpos, ctrl = posture_reference(model, Posture(**{field: value}))
        data.qpos[:] = qpos
        residual = physics.static_inverse_dynamics(model, data)[:6]
        assert np.abs(residual).max() < 1e-7 * weight, (field, value, residual)
        assert np.abs(ctrl).max() < CTRL_LIMIT
        assert data.ncon == 2  # the feet on the floor, no limb touching another


def test_lean_forward_pitches_the_torso_forward_with_the_com_over_the_feet(
    env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float]
) -> None:
    """Holding the largest forward lean keeps the body up, tilts the torso forward, keeps the CoM over the feet."""
    limit, reached = held_at_limit(env, expert, "lean_forward", 1.0)
    assert reached["forward"] > neutral_stand["forward"] + 0.8 * limit
    model, data = model_and_data(env)
    assert abs(physics.com_over_feet(model, data)[0]) < 0.01


def test_lean_back_pitches_the_torso_back(env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float]) -> None:
    """Holding the largest backward lean keeps the body up and tilts the torso back."""
    limit, reached = held_at_limit(env, expert, "lean_forward", -1.0)
    assert reached["forward"] < neutral_stand["forward"] + 0.8 * limit


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_lean_left_rolls_the_torso_and_moves_the_com_that_way(
    env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float], side: float
) -> None:
    """Holding the largest sideways lean keeps the body up; torso roll and CoM follow the sign of lean_left."""
    limit, reached = held_at_limit(env, expert, "lean_left", side)
    assert side * (reached["left"] - neutral_stand["left"]) > 0.8 * abs(limit)
    assert side * (reached["com_y"] - neutral_stand["com_y"]) > 0.01


def test_crouch_lowers_the_torso(env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float]) -> None:
    """Holding the deepest crouch keeps the body up and lowers the torso by about the commanded height."""
    limit, reached = held_at_limit(env, expert, "height", -1.0)
    assert reached["height"] - neutral_stand["height"] == pytest.approx(limit, abs=0.01)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_twist_turns_the_torso_relative_to_the_pelvis(
    env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float], side: float
) -> None:
    """Holding the largest twist keeps the body up and turns the torso that way relative to the pelvis."""
    limit, reached = held_at_limit(env, expert, "twist", side)
    assert side * (reached["yaw"] - neutral_stand["yaw"]) > 0.8 * abs(limit)


def test_arms_up_raises_the_hands_and_lower_arms(
    env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float]
) -> None:
    """Holding arms up keeps the body up with hands and lower arms well above where neutral arms hang."""
    hold(env, expert, stand(env, expert), Posture(arms=2))
    reached = measurements(env)
    assert reached["hands"] > neutral_stand["hands"] + 0.4
    assert reached["lower_arms"] > neutral_stand["lower_arms"] + 0.2


@pytest.mark.parametrize("arms", [1.0, 3.0])
def test_arms_forward_and_out_stay_up(env: gym.Env, expert: LQRExpert, arms: float) -> None:
    """Holding arms forward, or out to the sides, keeps the body up."""
    hold(env, expert, stand(env, expert), Posture(arms=arms))


def test_combined_limits_then_neutral_return_near_the_neutral_pose(
    env: gym.Env, expert: LQRExpert, neutral_stand: dict[str, float]
) -> None:
    """Lean forward, crouch and arms up together stay up; returning to Posture() gets back near the neutral stand."""
    obs = stand(env, expert)
    obs = hold(env, expert, obs, Posture(lean_forward=FIELDS["lean_forward"].high, height=FIELDS["height"].low, arms=2))
    hold(env, expert, obs, Posture())
    back = measurements(env)
    assert expert.posture == NEUTRAL
    np.testing.assert_array_equal(expert.qpos_ref, expert.gains.qpos_ref)
    for key in ("forward", "left", "yaw"):
        assert back[key] == pytest.approx(neutral_stand[key], abs=0.03)
    assert back["height"] == pytest.approx(neutral_stand["height"], abs=0.01)


def test_hold_clips_to_the_limits_and_rounds_arms(expert: LQRExpert) -> None:
    """Out-of-range commands are held at the limits, and arms at the nearest preset."""
    expert.reset()
    expert.hold(Posture(lean_forward=9.0, lean_left=-9.0, height=-9.0, twist=9.0, arms=2.4))
    assert expert.target == Posture(
        FIELDS["lean_forward"].high, FIELDS["lean_left"].low, FIELDS["height"].low, FIELDS["twist"].high, 2.0
    )
    expert.reset()


def test_setpoint_moves_gradually(env: gym.Env, expert: LQRExpert) -> None:
    """While moving, the setpoint's joint angles change by at most a few hundredths of a radian per step."""
    obs = stand(env, expert)
    expert.hold(Posture(lean_forward=FIELDS["lean_forward"].high, twist=FIELDS["twist"].high, arms=3))
    previous = expert.qpos_ref.copy()
    largest = 0.0
    while expert.moving:
        obs, _, terminated, _, _ = env.step(expert.act(obs))
        assert not terminated
        largest = max(largest, float(np.abs(expert.qpos_ref[7:] - previous[7:]).max()))
        previous = expert.qpos_ref.copy()
    assert 0.0 < largest < 0.03
