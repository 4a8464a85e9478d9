"""Tests of the LQR standing expert and the physics queries it relies on (real MuJoCo)."""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from humanoid import physics
from humanoid.conditions import ActionLatency, DomainRandomization, Randomization, action_delay
from humanoid.env import humanoid_model, model_and_data
from rollout.controllers import RandomController, make_controller
from rollout.episode import run_episode
from teachers.expert import LQRExpert, Predictor
from teachers.lqr import CTRL_LIMIT, LQRDesign, design_lqr, load_or_design
from teachers.postures import body_gains

STANDING_RETURN = 4_900.0


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    """Humanoid-v5's model."""
    return humanoid_model()


@pytest.fixture(scope="module")
def expert(model: mujoco.MjModel) -> LQRExpert:
    """The nominal expert, its gains and landing from the session's cache (`conftest.isolated_caches`): designed
    by the first test process that needs them (the processes share the cache), not once more here (the landing plan
    takes seconds)."""
    return LQRExpert(model)


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty cache directory that load_or_design uses."""
    monkeypatch.setenv("HUMANOID_BC_CACHE", str(tmp_path))
    return tmp_path


@pytest.mark.parametrize("seed", [0, 7, 1000])
def test_expert_stands_a_whole_episode_from_reset(expert: LQRExpert, seed: int) -> None:
    """From env.reset the expert stays up for all 1000 steps and earns a standing return."""
    env = gym.make("Humanoid-v5")
    obs, _ = env.reset(seed=seed)
    total, steps, terminated, truncated = 0.0, 0, False, False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, _ = env.step(expert.act(obs))
        total += float(reward)
        steps += 1
    env.close()
    assert (steps, terminated) == (1000, False)
    assert total > STANDING_RETURN


def test_act_is_deterministic_float32_within_the_motor_range(expert: LQRExpert) -> None:
    """act returns the same float32 (nu,) action for the same observation, within +-0.4, even far off."""
    env = gym.make("Humanoid-v5")
    obs, _ = env.reset(seed=3)
    env.close()
    far_off = obs + np.random.default_rng(0).normal(scale=1.0, size=obs.shape)
    for o in (obs, far_off):
        action = expert.act(o)
        assert action.dtype == np.float32 and action.shape == (17,)
        assert np.all(np.abs(action) <= CTRL_LIMIT)
        np.testing.assert_array_equal(action, expert.act(o.copy()))


def test_balanced_pose_needs_no_vertical_force_or_pitch_moment(model: mujoco.MjModel) -> None:
    """At the designed pose the contacts carry the whole weight with the COM over the feet."""
    gains = design_lqr(model)
    data = mujoco.MjData(model)
    data.qpos[:] = gains.qpos_ref
    residual = physics.static_inverse_dynamics(model, data)
    weight = model.body_subtreemass[0] * -model.opt.gravity[2]
    assert abs(residual[2]) < 1e-9 * weight
    assert abs(residual[4]) < 1e-9 * weight
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(physics.com_over_feet(model, data), 0.0, atol=1e-9)
    assert 1.0 < physics.torso_height(model, data) < 1.4  # inside the env's healthy range


def test_com_over_feet_jacobian_matches_finite_differences(model: mujoco.MjModel) -> None:
    """com_over_feet_jacobian agrees with central differences of com_over_feet in the tangent space."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    qpos = model.qpos0 + np.r_[0.0, 0.0, 0.3, np.zeros(4), rng.uniform(-0.3, 0.3, model.nq - 7)]
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    analytic = physics.com_over_feet_jacobian(model, data)

    def offset(dq: np.ndarray) -> np.ndarray:
        data.qpos[:] = qpos
        mujoco.mj_integratePos(model, data.qpos, dq, 1.0)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        return physics.com_over_feet(model, data)

    eps = 1e-6
    numeric = np.stack([(offset(eps * e) - offset(-eps * e)) / (2 * eps) for e in np.eye(model.nv)], 1)
    np.testing.assert_allclose(analytic, numeric, atol=1e-6)


def test_cache_reuses_gains_for_the_same_design(model: mujoco.MjModel, cache: Path) -> None:
    """A second load with the same model and design reads the cached file without rewriting it."""
    first = load_or_design(model)
    (path,) = cache.iterdir()
    written = path.stat().st_mtime_ns
    second = load_or_design(model)
    assert path.stat().st_mtime_ns == written
    np.testing.assert_array_equal(first.gain, second.gain)


def test_cache_is_rebuilt_when_the_design_changes(model: mujoco.MjModel, cache: Path) -> None:
    """Changing a design parameter yields freshly designed gains, not the cached ones."""
    default = load_or_design(model)
    changed = dataclasses.replace(LQRDesign(), q_com=500.0)
    rebuilt = load_or_design(model, changed)
    assert len(list(cache.iterdir())) == 2
    assert not np.allclose(default.gain, rebuilt.gain)
    np.testing.assert_allclose(rebuilt.gain, design_lqr(model, changed).gain)


def test_cache_is_rebuilt_when_the_file_is_corrupt(model: mujoco.MjModel, cache: Path) -> None:
    """A truncated cache file is replaced by a freshly designed one."""
    load_or_design(model)
    (path,) = cache.iterdir()
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    gains = load_or_design(model)
    np.testing.assert_allclose(gains.gain, design_lqr(model).gain)
    with np.load(path) as rewritten:
        np.testing.assert_array_equal(rewritten["gain"], gains.gain)


def test_expert_built_for_a_delayed_env_knows_the_delay() -> None:
    """The registry gives the expert the latency of the env it will drive (the wrappers' sum)."""
    env = ActionLatency(ActionLatency(gym.make("Humanoid-v5"), steps=1), steps=2)
    assert action_delay(env) == 3 and make_controller("expert", env).delay == 3
    assert make_controller("expert", gym.make("Humanoid-v5")).delay == 0


def test_prediction_of_the_pending_action_is_where_the_env_goes(model: mujoco.MjModel) -> None:
    """Stepping the predictor from the observed state with the pending action gives the env's next state."""
    env = gym.make("Humanoid-v5")
    obs, _ = env.reset(seed=4)
    data = env.unwrapped.data
    action = np.random.default_rng(4).uniform(-0.4, 0.4, 17)
    qpos, qvel = Predictor(model, frame_skip=5).predict(data.qpos.copy(), data.qvel.copy(), deque([action]))
    env.step(action.astype(np.float32))
    # The env's solver starts from its previous step's accelerations (warm start); the predictor from zero.
    np.testing.assert_allclose(qpos, data.qpos, atol=1e-6)
    np.testing.assert_allclose(qvel, data.qvel, atol=1e-3)


def test_a_labeller_predicts_with_what_ran_not_with_its_labels(model: mujoco.MjModel) -> None:
    """Under a step of latency the expert steps its prediction with the action in flight. As DAgger's labeller it is
    told what ran: told its own label, it labels as the expert that acted; told another action, its next label
    changes."""
    obs, _ = gym.make("Humanoid-v5").reset(seed=4)
    acting, told_own, told_other = (LQRExpert(model, delay=1, landing=False) for _ in range(3))
    for expert in (acting, told_own, told_other):
        expert.reset(4)
    label = acting.act(obs)
    np.testing.assert_array_equal(told_own.act(obs), label)
    told_own.ran(label)
    told_other.act(obs)
    told_other.ran(np.zeros_like(label))
    following = acting.act(obs)
    np.testing.assert_array_equal(told_own.act(obs), following)
    assert np.abs(told_other.act(obs) - following).max() > 1e-3


def test_the_rollout_tells_a_labeller_what_ran(model: mujoco.MjModel) -> None:
    """A delayed rollout of random actions labelled by the expert: its labels are those of an expert told, after each
    label, the random action that ran."""
    env = ActionLatency(gym.make("Humanoid-v5", max_episode_steps=20), steps=1)
    episode = run_episode(env, RandomController(env.action_space), 3, labeller=LQRExpert(model, landing=False))
    replay = LQRExpert(model, delay=1, landing=False)
    replay.reset(3)
    for obs, label, ran in zip(episode.observation, episode.action, episode.executed_action, strict=True):
        np.testing.assert_array_equal(replay.act(obs), label)
        replay.ran(ran)


class Untold:
    """`expert` deaf to `set_delay` and `set_body`: the rollout tells it the delay and the body in vain, so it acts as
    if there were no delay, on the body it was designed on."""

    takes_command = False

    def __init__(self, expert: LQRExpert) -> None:
        self.expert, self.name = expert, "untold"

    def set_command(self, command: np.ndarray) -> None:
        """Standing: the rollout's command is zero."""

    def setpoint(self) -> None:
        return None

    def set_delay(self, steps: int) -> None:
        """Ignored."""

    def set_body(self, model: mujoco.MjModel) -> None:
        """Ignored."""

    def reset(self, seed: int | None = None) -> None:
        self.expert.set_delay(0)
        self.expert.reset(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.expert.act(obs)


@pytest.mark.parametrize("seed", [1000, 1001])
def test_delay_aware_expert_stands_where_the_plain_one_falls(model: mujoco.MjModel, seed: int) -> None:
    """With one step of action latency the plain expert (the steady gain: a landing plan untold of the delay
    also falls on most seeds, not all) falls within 100 steps; told the delay, it stands."""
    env = ActionLatency(gym.make("Humanoid-v5", max_episode_steps=300), steps=1)
    plain = run_episode(env, Untold(LQRExpert(model, landing=False)), seed)
    aware = run_episode(env, make_controller("expert", env), seed)
    assert plain.fell and plain.length < 100
    assert not aware.fell and aware.length == 300 and aware.episode_return > 4.9 * 300


class DelayOnly(Untold):
    """The expert told the action latency but not the body: it predicts on the nominal body."""

    def set_delay(self, steps: int) -> None:
        self.expert.set_delay(steps)

    def reset(self, seed: int | None = None) -> None:
        self.expert.reset(seed)


def drawn_masses(seed: int, max_episode_steps: int = 1000) -> DomainRandomization:
    """Humanoid-v5 reset with the suite's `mass` draw of `seed` (each body x U(0.8, 1.2))."""
    env = gym.make("Humanoid-v5", max_episode_steps=max_episode_steps)
    env = DomainRandomization(env, Randomization(mass=(0.8, 1.2)))
    env.reset(seed=seed)
    return env


def test_stance_for_a_told_body_needs_no_help_from_the_root(model: mujoco.MjModel, cache: Path) -> None:
    """The design's pose does not balance a body with drawn masses (it needs a roll moment); the told body's does."""
    drawn, _ = model_and_data(drawn_masses(1001))
    weight = drawn.body_subtreemass[0] * -drawn.opt.gravity[2]
    design = load_or_design(model)
    data = mujoco.MjData(drawn)
    data.qpos[:] = design.qpos_ref
    assert np.abs(physics.static_root_residual(drawn, data)).max() > 1e-3 * weight
    data.qpos[:] = body_gains(drawn, LQRDesign(), design.qpos_ref).qpos_ref
    np.testing.assert_allclose(physics.static_root_residual(drawn, data), 0.0, atol=1e-9 * weight)


def test_expert_told_its_body_stands_where_the_design_falls(expert: LQRExpert) -> None:
    """On seed 1007's drawn masses the design's gains fall within 100 steps; told the body, the expert stands."""
    env = drawn_masses(1007, max_episode_steps=300)
    untold = run_episode(env, Untold(expert), 1007)
    told = run_episode(env, LQRExpert(humanoid_model()), 1007)
    assert untold.fell and untold.length < 100
    assert not told.fell and told.length == 300 and told.episode_return > 4.9 * 300


def test_told_the_design_body_again_the_expert_acts_as_never_told(model: mujoco.MjModel) -> None:
    """After a drawn body, the design's own body brings back the design's gains bit for bit."""
    env = drawn_masses(1001)
    obs, _ = env.reset(seed=1001)
    told, fresh = LQRExpert(model), LQRExpert(model)
    told.set_body(model_and_data(env)[0])
    told.reset()
    on_drawn = told.act(obs)
    env.restore()
    told.set_body(model_and_data(env)[0])
    told.reset()
    fresh.reset()
    np.testing.assert_array_equal(told.act(obs), fresh.act(obs))
    assert not np.array_equal(on_drawn, fresh.act(obs))


def test_told_a_body_and_a_delay_the_expert_predicts_on_that_body() -> None:
    """Seed 1007's drawn masses under a step of latency: predicting on the nominal body falls at step 90, on the
    told body it stands."""
    env = ActionLatency(drawn_masses(1007, max_episode_steps=300), steps=1)
    nominal = run_episode(env, DelayOnly(make_controller("expert", env)), 1007)
    episode = run_episode(env, make_controller("expert", env), 1007)
    assert nominal.fell and nominal.length < 100
    assert not episode.fell and episode.length == 300
