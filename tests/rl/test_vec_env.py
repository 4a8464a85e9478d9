"""Environments in worker processes (`rl.vec_env`): the same steps as SB3's DummyVecEnv, whatever the workers."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from humanoid.env import make_env
from humanoid.perturbations import TorsoPushes
from rl.learner import training_env
from rl.vec_env import SB3_INFO_KEYS, WorkerGroupVecEnv, split

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

SHORT = 15  # steps per episode: the rollout below crosses two time limits and a fall or two
short_env = functools.partial(make_env, SHORT)


def rollout(env, steps: int, seed: int = 7) -> list[tuple]:
    """Observations, rewards, dones and SB3's info keys for `steps` steps of seeded random actions."""
    env.seed(seed)
    obs = env.reset()
    rng = np.random.default_rng(seed)
    trace = [(obs,)]
    for _ in range(steps):
        obs, rewards, dones, infos = env.step(rng.uniform(-0.4, 0.4, (env.num_envs, 17)))
        kept = [{k: info[k] for k in SB3_INFO_KEYS if k in info} for info in infos]
        trace.append((obs, rewards, dones, kept))
    return trace


def assert_same(a: list[tuple], b: list[tuple]) -> None:
    for step, (x, y) in enumerate(zip(a, b, strict=True)):
        np.testing.assert_array_equal(x[0], y[0], err_msg=f"observations differ at step {step}")
        if step:
            np.testing.assert_array_equal(x[1], y[1])
            np.testing.assert_array_equal(x[2], y[2])
            for info_x, info_y in zip(x[3], y[3], strict=True):
                assert info_x.keys() == info_y.keys()
                assert info_x["TimeLimit.truncated"] == info_y["TimeLimit.truncated"]
                if "terminal_observation" in info_x:
                    np.testing.assert_array_equal(info_x["terminal_observation"], info_y["terminal_observation"])


def test_split_makes_contiguous_balanced_groups() -> None:
    """7 environments over 3 workers: 0-1, 2-4, 5-6 (sizes differ by at most one, order kept)."""
    assert split(7, 3) == [range(0, 2), range(2, 5), range(5, 7)]
    assert split(4, 1) == [range(0, 4)]


@pytest.mark.parametrize("workers", [1, 3])
def test_steps_equal_dummy_vec_env(workers: int) -> None:
    """5 environments over 1 or 3 workers give DummyVecEnv's observations, rewards, dones, resets and terminal obs."""
    expected = rollout(DummyVecEnv([short_env] * 5), 2 * SHORT + 3)
    assert any(d.any() for _, _, d, _ in expected[1:])  # the comparison covers auto-resets
    grouped = WorkerGroupVecEnv([short_env] * 5, workers)
    try:
        assert_same(rollout(grouped, 2 * SHORT + 3), expected)
    finally:
        grouped.close()


def test_attributes_and_methods_reach_the_right_environment() -> None:
    """get_attr, set_attr, env_method and env_is_wrapped address environments by their global index."""
    env = WorkerGroupVecEnv([functools.partial(training_env, 10.0)] * 2 + [short_env] * 2, workers=2)
    try:
        assert env.env_is_wrapped(TorsoPushes) == [True, True, False, False]
        env.set_attr("force", 3.0, indices=[1])
        assert env.get_attr("force", indices=[1, 0]) == [3.0, 10.0]
        assert env.env_method("get_wrapper_attr", "spec", indices=3)[0].id == "Humanoid-v5"
        assert env.has_attr("spec") and not env.has_attr("no_such_attribute")
    finally:
        env.close()


def test_a_worker_error_is_raised_in_the_learner() -> None:
    """An exception in a worker process reaches the caller as itself, and the workers still answer."""
    env = WorkerGroupVecEnv([short_env] * 2, workers=2)
    try:
        with pytest.raises(AttributeError):
            env.get_attr("no_such_attribute", indices=[1])
        assert env.get_attr("spec", indices=[1])[0].id == "Humanoid-v5"
    finally:
        env.close()
