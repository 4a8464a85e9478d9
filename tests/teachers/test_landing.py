"""Tests of the expert's planned landing after a reset (real MuJoCo)."""

from __future__ import annotations

from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest

from humanoid.conditions import DomainRandomization, Randomization
from humanoid.env import make_env, model_and_data
from rollout.episode import run_episode
from task.posture import Posture
from teachers.expert import LQRExpert
from teachers.landing import Landing

NOISY_LANDING_SEED = 9021
"""Under DART noise σ 0.05 the steady gain falls within 60 steps of this reset; the planned landing stands."""


@pytest.fixture(scope="module")
def expert() -> LQRExpert:
    """The expert with its planned landing (the conftest's session cache holds the plan after the first design)."""
    return LQRExpert()


@pytest.fixture(scope="module")
def landing(expert: LQRExpert) -> Landing:
    assert expert.landing is not None
    return expert.landing


@pytest.fixture()
def env() -> Iterator[gym.Env]:
    env = make_env()
    yield env
    env.close()


def test_the_plan_is_what_the_env_does_from_its_nominal_reset(env: gym.Env, landing: Landing) -> None:
    """Humanoid-v5 stepped from its noise-free reset pose with the plan's actions passes through the plan's states."""
    env.reset(seed=0)
    env.unwrapped.set_state(env.unwrapped.init_qpos, env.unwrapped.init_qvel)
    _, data = model_and_data(env)
    for t in range(len(landing) - 1):
        env.step(landing.ctrl[t])
        np.testing.assert_array_equal(data.qpos, landing.qpos[t + 1])
        np.testing.assert_array_equal(data.qvel, landing.qvel[t + 1])


def test_the_plan_hands_over_to_a_gain_near_the_steady_one(expert: LQRExpert, landing: Landing) -> None:
    """The recursion runs past the plan's end, so its last gain differs from the steady gain by under 2 %."""
    steady = expert.gains.gain
    assert np.abs(landing.gain[-1] - steady).max() < 0.02 * np.abs(steady).max()


def test_after_a_reset_the_expert_tracks_the_plan_then_the_setpoint(expert: LQRExpert, landing: Landing) -> None:
    """On the plan's states the expert returns the plan's actions, and after them the steady law's."""
    expert.reset()
    for t in range(len(landing)):
        np.testing.assert_array_equal(expert.act_on_state(landing.qpos[t], landing.qvel[t]), landing.ctrl[t])
    at_rest = expert.act_on_state(expert.gains.qpos_ref, np.zeros(expert.model.nv))
    np.testing.assert_array_equal(at_rest, expert.gains.ctrl_ff.astype(np.float32))


def test_the_planned_landing_stands_where_the_steady_gain_falls(env: gym.Env, expert: LQRExpert) -> None:
    """Under σ 0.05 action noise on one seed: the steady gain from the reset falls, the planned landing stands."""
    assert run_episode(env, LQRExpert(landing=False), NOISY_LANDING_SEED, noise_std=0.05).fell
    assert not run_episode(env, expert, NOISY_LANDING_SEED, noise_std=0.05).fell


@pytest.mark.parametrize("case", ["delay", "body", "posture"])
def test_the_steady_gain_acts_when_the_plan_does_not_apply(env: gym.Env, landing: Landing, case: str) -> None:
    """With a delay, on a drawn body or once a posture is commanded, the expert acts as it does without a plan."""
    planned, steady = LQRExpert(), LQRExpert(landing=False)
    if case == "body":
        randomized = DomainRandomization(env, Randomization(mass=(0.8, 1.2)))
        randomized.reset(seed=3)
    for acting in (planned, steady):
        if case == "delay":
            acting.set_delay(1)
        if case == "body":
            acting.set_body(model_and_data(env)[0])
        acting.reset()
        if case == "posture":
            acting.hold(Posture(lean_forward=0.05))
    for t in range(3):
        np.testing.assert_array_equal(
            planned.act_on_state(landing.qpos[t], landing.qvel[t]),
            steady.act_on_state(landing.qpos[t], landing.qvel[t]),
        )
