"""The robustness conditions change exactly what they name, repeat with the seed, and restore the model."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest

from bc import dagger
from evaluation.evaluate import evaluated_condition
from humanoid.conditions import (
    LATENCY_PARAMETER,
    OBS_NOISE_STD,
    SUITE,
    ActionLatency,
    Condition,
    DomainRandomization,
    ObservationNoise,
    Randomization,
    action_delay,
    condition,
    parse_randomization,
)
from humanoid.env import QPOS_OBS, QVEL_OBS, make_env, model_and_data
from rl.learner import training_condition
from teleop import record

MODEL_FIELDS = ("body_mass", "body_inertia", "body_subtreemass", "geom_friction", "actuator_gear", "dof_damping")


def model_values(env: gym.Env) -> dict[str, np.ndarray]:
    model, _ = model_and_data(env)
    return {name: getattr(model, name).copy() for name in MODEL_FIELDS}


def changed_fields(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> set[str]:
    return {name for name in MODEL_FIELDS if not np.array_equal(before[name], after[name])}


@pytest.mark.parametrize(
    "name, fields",
    [
        ("mass", {"body_mass", "body_inertia", "body_subtreemass"}),
        ("friction", {"geom_friction"}),
        ("strength", {"actuator_gear"}),
    ],
)
def test_randomization_changes_only_what_it_names_and_close_restores(name: str, fields: set[str]) -> None:
    env = condition(name).wrap(make_env())
    nominal = model_values(env)
    env.reset(seed=3)
    assert changed_fields(nominal, model_values(env)) == fields
    env.close()
    assert changed_fields(nominal, model_values(env)) == set()


def test_drawn_scales_are_within_their_ranges_and_applied() -> None:
    env = DomainRandomization(make_env(), Randomization(mass=(0.8, 1.2), friction=(0.5, 1.5), strength=(0.8, 1.2)))
    nominal = model_values(env)
    _, info = env.reset(seed=11)
    drawn, now = info["parameters"], model_values(env)
    mass = np.array(drawn["mass_scale"])
    assert mass.shape == (13,) and np.all((0.8 <= mass) & (mass <= 1.2))
    np.testing.assert_allclose(now["body_mass"][1:], nominal["body_mass"][1:] * mass, rtol=1e-5)
    np.testing.assert_allclose(now["body_subtreemass"][0], now["body_mass"].sum())
    assert 0.5 <= drawn["friction_scale"] <= 1.5
    np.testing.assert_allclose(now["geom_friction"][:, 0], nominal["geom_friction"][:, 0] * drawn["friction_scale"])
    np.testing.assert_array_equal(now["geom_friction"][:, 1:], nominal["geom_friction"][:, 1:])
    strength = np.array(drawn["strength_scale"])
    np.testing.assert_allclose(now["actuator_gear"][:, 0], nominal["actuator_gear"][:, 0] * strength, rtol=1e-5)


def test_the_same_seed_gives_the_same_draw_and_another_seed_another() -> None:
    env = condition("mass").wrap(make_env())
    first = env.reset(seed=5)[1]["parameters"]
    other = env.reset(seed=6)[1]["parameters"]
    again = env.reset(seed=5)[1]["parameters"]
    assert first == again and first != other


def test_a_new_draw_starts_from_the_nominal_model() -> None:
    """Draws do not compound: after many resets the masses are still nominal times the last draw."""
    env = DomainRandomization(make_env(), Randomization(mass=(0.8, 1.2)))
    nominal = model_values(env)["body_mass"]
    for seed in range(5):
        drawn = env.reset(seed=seed)[1]["parameters"]
    np.testing.assert_allclose(model_values(env)["body_mass"][1:], nominal[1:] * drawn["mass_scale"], rtol=1e-5)


def test_latency_executes_the_previous_action() -> None:
    env = ActionLatency(make_env(), steps=1)
    _, data = model_and_data(env)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-0.4, 0.4, (4, 17)).astype(np.float32)
    executed = []
    for action in actions:
        env.step(action)
        executed.append(data.ctrl.copy())
    np.testing.assert_array_equal(executed[0], 0.0)
    np.testing.assert_allclose(executed[1:], actions[:-1])


def test_observation_noise_touches_only_the_sensed_parts_with_the_documented_std() -> None:
    clean, noisy = make_env(), ObservationNoise(make_env())
    differences = np.array([noisy.reset(seed=s)[0] - clean.reset(seed=s)[0] for s in range(400)])
    np.testing.assert_array_equal(differences[:, QVEL_OBS.stop :], 0.0)
    assert differences[:, QPOS_OBS].std() == pytest.approx(OBS_NOISE_STD["qpos"], rel=0.05)
    assert differences[:, QVEL_OBS].std() == pytest.approx(OBS_NOISE_STD["qvel"], rel=0.05)


def executed_first(env: gym.Env, seed: int) -> np.ndarray:
    """What the environment executed at the first step of episode `seed`, given an action of ones."""
    _, data = model_and_data(env)
    env.reset(seed=seed)
    env.step(np.ones(env.action_space.shape, np.float32))
    return data.ctrl.copy()


def test_a_share_of_the_episodes_is_delayed_and_the_draw_repeats_with_the_seed() -> None:
    """share 0.5: some episodes execute the previous action (zeros at first), the others the action given."""
    env = ActionLatency(make_env(), steps=1, share=0.5)
    delays = {seed: float(executed_first(env, seed)[0]) == 0.0 for seed in range(40)}
    assert 10 <= sum(delays.values()) <= 30
    assert {seed: float(executed_first(env, seed)[0]) == 0.0 for seed in reversed(range(40))} == delays
    for seed, delayed in delays.items():
        _, info = env.reset(seed=seed)
        assert env.delay == action_delay(env) == info["parameters"][LATENCY_PARAMETER] == int(delayed)


def test_a_share_of_the_episodes_is_noisy_and_the_others_read_exactly() -> None:
    clean, noisy = make_env(), ObservationNoise(make_env(), share=0.5)
    differs = [not np.array_equal(noisy.reset(seed=s)[0], clean.reset(seed=s)[0]) for s in range(40)]
    assert 10 <= sum(differs) <= 30
    assert differs == [not np.array_equal(noisy.reset(seed=s)[0], clean.reset(seed=s)[0]) for s in range(40)]


def test_a_new_share_applies_from_the_next_reset() -> None:
    """As a curriculum changes it: the episode in progress keeps its delay and its noise; the next draws anew."""
    latency, noise = ActionLatency(make_env(), share=1.0), ObservationNoise(make_env(), share=1.0)
    latency.reset(seed=0)
    noise.reset(seed=0)
    latency.set_latency_share(0.0)
    noise.set_noise_share(0.0)
    assert latency.delay == 1 and noise.noisy
    latency.reset(seed=0)
    noise.reset(seed=0)
    assert latency.delay == 0 and not noise.noisy


@pytest.mark.parametrize("share", [-0.1, 1.5])
def test_a_share_outside_0_to_1_is_refused(share: float) -> None:
    with pytest.raises(ValueError, match="share must be in"):
        ActionLatency(make_env(), share=share)
    with pytest.raises(ValueError, match="share must be in"):
        ObservationNoise(make_env(), share=share)


@pytest.mark.parametrize(
    "bounds, message",
    [
        ((1.2, 0.8), "mass range has low 1.2 > high 0.8"),
        ((-0.1, 1.0), "mass scales must be >= 0, got -0.1"),
        ((0.5, float("inf")), "mass scales must be finite, got 0.5:inf"),
    ],
)
def test_bad_ranges_are_refused(bounds: tuple[float, float], message: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        Randomization(mass=bounds)


def test_unknown_condition_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="known: clean, noise"):
        condition("gravity")


def test_suite_has_the_conditions_the_issue_names() -> None:
    names = {"clean", "noise", "push10", "push20", "push40", "mass", "friction", "strength", "latency", "obs_noise"}
    assert names <= set(SUITE)


def test_randomize_presets_and_lists_parse_into_ranges() -> None:
    """`none` randomises nothing, `suite` is the suite's three ranges at once, a list sets what it names."""
    assert not parse_randomization("none").active
    suite = [SUITE[name].randomization for name in ("mass", "friction", "strength")]
    assert parse_randomization("suite") == Randomization(suite[0].mass, suite[1].friction, suite[2].strength)
    listed = parse_randomization(" mass=0.8:1.2, friction = 0.5:1.5")
    assert listed == Randomization(mass=(0.8, 1.2), friction=(0.5, 1.5))
    assert parse_randomization("strength=1:1").parameters == ("strength_scale",)


@pytest.mark.parametrize(
    "text, problem",
    [
        ("wild", "unknown preset"),
        ("gravity=1:2", "unknown parameter 'gravity'"),
        ("mass=1.2:0.8", "low 1.2 > high 0.8"),
        ("mass=-0.2:1", "mass scales must be >= 0, got -0.2"),
        ("mass=nan:1", "mass scales must be finite"),
        ("mass=0.9:1.1,mass=1:1", "mass is given twice"),
        ("mass=0.9", "is not NAME=LOW:HIGH"),
        ("mass=0.9:1.1,", "'' is not NAME=LOW:HIGH"),
    ],
)
def test_bad_randomize_text_is_one_line_naming_the_flag(text: str, problem: str) -> None:
    with pytest.raises(ValueError) as error:
        parse_randomization(text)
    message = str(error.value)
    assert message.startswith(f"--randomize {text!r}: ") and problem in message and "\n" not in message


def stack(env: gym.Env) -> list[tuple[str, tuple]]:
    """The wrappers around `make_env`'s Humanoid-v5 (gymnasium's own left out), outermost first, each with what it
    changes."""
    layers = []
    while isinstance(env, gym.Wrapper) and not isinstance(env, gym.wrappers.TimeLimit):
        settings = {
            "DomainRandomization": lambda w: (tuple(w.randomization.ranges.items()), w.width),
            "TorsoPushes": lambda w: (w.force,),
            "VelocityKick": lambda w: (w.speed, w.window),
            "ActionLatency": lambda w: (w.steps, w.latency_share),
            "ObservationNoise": lambda w: (tuple(w.std), w.noise_share),
        }.get(type(env).__name__, lambda w: ())
        layers.append((type(env).__name__, settings(env)))
        env = env.env
    return layers


def stacks(conditions: dict[str, Condition]) -> dict[str, list[tuple[str, tuple]]]:
    built = {}
    for stage, changed in conditions.items():
        env = changed.wrap(make_env())
        built[stage] = stack(env)
        env.close()
    return built


def test_one_condition_builds_one_stack_in_every_stage() -> None:
    """Recording, DAgger's rollouts, evaluation, the robustness suite and PPO's training build a condition's
    environment with the one builder (`Condition.wrap`), in one order: a kick alone, and a kick on a drawn body whose
    every episode is delayed, give the same wrappers in each stage that can express them."""
    kicked = stacks(
        {
            "record": record.condition(record.RecordConfig(kick=0.4, latency=0.0)),
            "dagger": dagger.condition(dagger.DaggerConfig(kick=0.4, latency=0.0, randomize="none")),
            "eval": evaluated_condition("clean", kick=0.4),
            "robustness": evaluated_condition("kick0.4"),
            "ppo": training_condition(None, kick=0.4),
        }
    )
    assert kicked["record"] == [("VelocityKick", (0.4, (4.0, 8.0)))]
    assert all(layers == kicked["record"] for layers in kicked.values()), kicked

    drawn = Randomization(mass=(0.8, 1.2))
    combined = stacks(
        {
            "record": record.condition(record.RecordConfig(kick=0.4, latency=1.0, randomize="mass=0.8:1.2")),
            "dagger": dagger.condition(dagger.DaggerConfig(kick=0.4, latency=1.0, randomize="mass=0.8:1.2")),
            "ppo": training_condition(None, drawn, latency=1.0, kick=0.4),
        }
    )
    names = [name for name, _ in combined["record"]]
    assert names == ["ActionLatency", "VelocityKick", "DomainRandomization"]
    assert all(layers == combined["record"] for layers in combined.values()), combined
    assert stacks({"suite": SUITE["latency"]})["suite"] == [("ActionLatency", (1, 1.0))]
