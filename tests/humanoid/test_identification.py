"""Identifying the body from the landing (`humanoid.identification`) and the expert that uses it (real MuJoCo)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from humanoid.conditions import DomainRandomization, Randomization
from humanoid.controllers import make_controller
from humanoid.env import humanoid_model, make_env
from humanoid.expert import LQRExpert, SensedExpert
from humanoid.identification import IdentificationDesign, IdentifierWeights, acted_scales, collect, fit, scaled_body
from humanoid.lqr import LQRGains
from humanoid.posture import body_gains


@pytest.fixture(scope="module")
def adaptive() -> SensedExpert:
    """The sensed expert that identifies its body (fitted once per test session: about a minute)."""
    return SensedExpert(identify=True)


def test_a_scaled_body_has_each_mass_and_inertia_scaled_and_its_subtrees_recomputed() -> None:
    model = humanoid_model()
    scales = np.linspace(0.8, 1.2, model.nbody - 1)
    body = scaled_body(model, scales)
    assert np.allclose(body.body_mass[1:], model.body_mass[1:] * scales)
    assert np.allclose(body.body_inertia[1:], model.body_inertia[1:] * scales[:, None])
    assert np.isclose(body.body_subtreemass[1], body.body_mass[1:].sum())  # the torso carries every body
    assert np.isclose(model.body_subtreemass[1], model.body_mass[1:].sum())  # the nominal model is untouched


def test_the_acted_on_estimate_is_shrunk_and_clipped() -> None:
    """Scales are 1 + shrink * estimate, within 1 +- clip: here the estimate is 0.2 and 2.0 above 1."""
    weights = IdentifierWeights(mean=np.zeros(1), std=np.ones(1), weights=np.array([[0.2, 2.0]]))
    design = IdentificationDesign(shrink=0.5, clip=0.3)
    assert np.allclose(acted_scales(weights, design, np.ones(1)), [1.1, 1.3])


def test_ridge_fit_recovers_a_linear_map() -> None:
    rng = np.random.default_rng(0)
    features = rng.normal(3.0, 2.0, (500, 4))
    true = np.array([[0.1, -0.2], [0.0, 0.3], [0.05, 0.0], [-0.1, 0.1]])
    targets = 1.0 + ((features - features.mean(0)) / features.std(0)) @ true
    weights = fit(features, targets, ridge=1e-6)
    assert np.allclose(weights.weights, true, atol=1e-4)


@pytest.mark.slow
def test_the_landing_tells_drawn_masses_better_than_the_prior(adaptive: SensedExpert) -> None:
    """On episodes no fit used, the estimate (before shrinking) errs well below the nominal masses' error."""
    assert adaptive.identifier is not None
    design = dataclasses.replace(adaptive.identifier.design, first_seed=90000, episodes=120, shrink=1.0, clip=1.0)
    features, targets = collect(lambda model, delay: SensedExpert(model, delay), design)
    estimate = np.array([acted_scales(adaptive.identifier.weights, design, row) for row in features])
    assert len(features) > 100  # few fall within the first 20 steps
    assert np.abs(estimate - targets).mean() < 0.8 * np.abs(targets - 1.0).mean()


@pytest.mark.slow
def test_the_adaptive_expert_moves_to_the_identified_body_then_starts_over(adaptive: SensedExpert) -> None:
    """After its `steps` of landing the expert blends into the stance and gain of the body it estimated; each
    reset starts again from the design's."""
    assert adaptive.identifier is not None
    env = DomainRandomization(make_env(), Randomization(mass=(0.8, 1.2)))
    design = adaptive.expert.gains
    steps = adaptive.identifier.design.steps
    obs, _ = env.reset(seed=1003)
    adaptive.reset(1003)
    for _ in range(steps):
        assert np.array_equal(adaptive.expert.qpos_ref, design.qpos_ref)
        obs, *_ = env.step(adaptive.act(obs))
    target = body_gains(adaptive.identifier.body(), adaptive.expert.design, design.qpos_ref)
    for _ in range(steps):
        obs, *_ = env.step(adaptive.act(obs))
    assert np.allclose(adaptive.expert.qpos_ref, target.qpos_ref)
    assert np.allclose(adaptive.expert.gain, target.gain)
    assert not np.allclose(target.qpos_ref, design.qpos_ref)
    adaptive.reset(1004)
    assert np.array_equal(adaptive.expert.qpos_ref, design.qpos_ref) and adaptive.expert.gain is design.gain
    env.close()


def test_blend_to_moves_the_setpoint_linearly_and_never_writes_the_designs_gain() -> None:
    expert = LQRExpert(landing=False)  # the steady law from the first step: the blend acts there
    design = expert.gains
    saved = design.gain.copy()
    target = LQRGains(qpos_ref=design.qpos_ref + 0.1, ctrl_ff=design.ctrl_ff - 0.01, gain=2 * design.gain)
    obs, _ = (env := make_env()).reset(seed=0)
    expert.reset(0)
    expert.blend_to(target, 4)
    expert.act(obs)
    assert np.allclose(expert.qpos_ref, design.qpos_ref + 0.025)
    for _ in range(3):
        expert.act(obs)
    assert np.allclose(expert.qpos_ref, target.qpos_ref) and np.allclose(expert.gain, target.gain)
    expert.act(obs)
    assert np.allclose(expert.ctrl_ff, target.ctrl_ff)  # it stays there
    assert np.array_equal(design.gain, saved)
    env.close()


@pytest.mark.slow
def test_expert_adaptive_is_a_registered_controller(adaptive: SensedExpert) -> None:
    """Built from the cache the fixture filled: the same fitted map."""
    controller = make_controller("expert-adaptive", make_env())
    assert controller.name == "expert-adaptive" and controller.identifier is not None
    assert adaptive.identifier is not None
    assert np.array_equal(controller.identifier.weights.weights, adaptive.identifier.weights.weights)
