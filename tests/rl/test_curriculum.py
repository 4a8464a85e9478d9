"""The push curriculum and the randomised training environments of `make finetune-rl` (real MuJoCo)."""

from __future__ import annotations

import numpy as np
import pytest

from humanoid.conditions import PRESETS, DomainRandomization, Randomization
from humanoid.env import make_env, model_and_data
from humanoid.perturbations import TorsoPushes
from humanoid.physics import TORSO_BODY
from rl.curriculum import PushCurriculum, parse_stages, rollout_survival, stage_width
from rl.learner import make_vec_env


def test_stages_are_read_as_newtons() -> None:
    assert parse_stages("0, 10,20.5") == [0.0, 10.0, 20.5]
    assert parse_stages("") == [] and parse_stages("none") == []


@pytest.mark.parametrize("text", ["20,10", "10,x", "-5,10", "10,inf"])
def test_malformed_stages_are_refused(text: str) -> None:
    with pytest.raises(ValueError, match="--curriculum"):
        parse_stages(text)


def test_rollout_survival_counts_ended_episodes_and_those_at_the_time_limit() -> None:
    dones = np.array([[True, False], [False, True], [True, True]])
    infos = [
        [{"TimeLimit.truncated": True}, {}],
        [{}, {"TimeLimit.truncated": False}],
        [{"TimeLimit.truncated": False}, {"TimeLimit.truncated": True}],
    ]
    assert rollout_survival(dones, infos) == (4, 2)


def test_the_stage_moves_on_only_with_enough_episodes_surviving_enough() -> None:
    curriculum = PushCurriculum([10.0, 20.0, 40.0], advance=0.8, min_episodes=16)
    assert not curriculum.ready(ended=15, survived=15)  # too few episodes to judge
    assert not curriculum.ready(ended=20, survived=15)  # 75 % < 80 %
    assert curriculum.ready(ended=20, survived=16)
    curriculum.stage = 2
    assert not curriculum.ready(ended=100, survived=100)  # the last stage is the last


def test_a_new_force_applies_from_the_next_episode() -> None:
    """`set_force` mid-episode leaves that episode's pushes as they were; the next episode gets the new force."""
    env = TorsoPushes(make_env(), force=10.0, period=0.15, duration=0.03)  # pushes on steps 11 and 12
    _, data = model_and_data(env)
    torso = env.unwrapped.model.body(TORSO_BODY).id
    zero = np.zeros(env.action_space.shape)

    def push_size() -> float:
        for _ in range(11):
            env.step(zero)
        return float(np.linalg.norm(data.xfrc_applied[torso, :3]))

    env.reset(seed=0)
    env.set_force(30.0)
    assert push_size() == pytest.approx(10.0)
    env.reset(seed=0)
    assert push_size() == pytest.approx(30.0)


@pytest.mark.slow  # worker processes: seconds
def test_randomised_training_environments_differ_and_repeat_with_the_seed() -> None:
    """Each training environment draws its own body; the same seed draws the same bodies again."""

    def bodies(seed: int) -> list[dict]:
        env = make_vec_env(4, 2, None, seed, randomization=PRESETS["suite"])
        try:
            env.reset()
            return env.get_attr("parameters")
        finally:
            env.close()

    first = bodies(7)
    masses = [tuple(p["mass_scale"]) for p in first]
    assert len(set(masses)) == 4 and len({p["friction_scale"] for p in first}) == 4
    assert bodies(7) == first and bodies(8) != first


def test_the_randomisation_widens_from_nominal_to_whole_over_the_stages() -> None:
    assert [stage_width(stage, 4) for stage in range(4)] == [0.0, 1 / 3, 2 / 3, 1.0]
    assert stage_width(0, 1) == 1.0  # one stage: the whole ranges
    widened = Randomization(mass=(0.8, 1.2), friction=(0.5, 1.5)).widened(0.5)
    assert widened.mass == pytest.approx((0.9, 1.1)) and widened.friction == pytest.approx((0.75, 1.25))


def test_a_new_width_applies_from_the_next_draw() -> None:
    """`set_width` mid-episode leaves the body as drawn; the next reset draws within the new width (0: nominal)."""
    env = DomainRandomization(make_env(), PRESETS["suite"], width=1.0)
    model, _ = model_and_data(env)
    nominal = model.body_mass.copy()
    env.reset(seed=0)
    drawn = model.body_mass.copy()
    assert not np.allclose(drawn, nominal)
    env.set_width(0.0)
    np.testing.assert_array_equal(model.body_mass, drawn)
    env.reset(seed=0)
    np.testing.assert_allclose(model.body_mass, nominal)


@pytest.mark.slow  # worker processes: seconds
def test_the_stage_sets_the_widened_shares_of_every_training_environment() -> None:
    """Each method the curriculum widens gets the stage's width times its value at the last stage, in every
    environment: at stage 1 of 3 half the latency and sensor-noise shares and half the randomisation."""
    env = make_vec_env(4, 2, 0.0, 0, randomization=PRESETS["suite"], width=0.0, latency=0.0, obs_noise=0.0)
    try:
        curriculum = PushCurriculum(
            [0.0, 10.0, 20.0], 0.8, 16, {"set_width": 1.0, "set_latency_share": 0.5, "set_noise_share": 0.3}
        )
        curriculum.stage = 1
        curriculum.apply(env)
        assert env.get_attr("next_force") == [10.0] * 4
        assert env.get_attr("width") == [0.5] * 4
        assert env.get_attr("latency_share") == [0.25] * 4
        assert env.get_attr("noise_share") == [0.15] * 4
    finally:
        env.close()
