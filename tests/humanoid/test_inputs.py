"""The "pending" inputs: odometry's, the command in flight under one step of latency, and the delay."""

from __future__ import annotations

import numpy as np
import pytest

from common.cli import UserError
from humanoid.conditions import ActionLatency
from humanoid.env import humanoid_model, make_env
from humanoid.episode import Episode, run_episode
from humanoid.expert import LQRExpert
from humanoid.inputs import INPUT_COLUMNS, PendingInputs, episode_inputs, input_names
from humanoid.learned import PolicyController
from humanoid.sensors import Proprioception
from policies.mlp import MLPPolicy, MLPSpec

STEPS = 50


def expert_episode(delay: int, seed: int) -> Episode:
    env = ActionLatency(make_env(STEPS), delay) if delay else make_env(STEPS)
    return run_episode(env, LQRExpert(delay=delay), seed, noise_std=0.05)


def test_training_inputs_are_what_the_live_policy_reads() -> None:
    """A delayed episode then an undelayed one: the inputs computed from their recorded frames equal, row for row,
    those `PendingInputs` gives live along the same observations and commands."""
    model = humanoid_model()
    sensed = Proprioception(model)
    episodes = [expert_episode(1, seed=0), expert_episode(0, seed=1)]
    recorded = np.concatenate([np.column_stack([[sensed(o) for o in e.observation], e.action]) for e in episodes])
    index = np.repeat([0, 1], [e.length for e in episodes])
    delays = np.repeat([1, 0], [e.length for e in episodes])
    trained = episode_inputs("pending", recorded, index, model, delays)
    live = PendingInputs(model)
    rows = []
    for delay, episode in zip((1, 0), episodes, strict=True):
        live.set_delay(delay)
        live.reset()
        for obs, action in zip(episode.observation, episode.action, strict=True):
            rows.append(live(obs))
            live.commanded(action)
    np.testing.assert_allclose(trained, np.array(rows), rtol=0, atol=1e-12)
    assert trained.shape[1] == len(input_names("pending", model))


def test_the_pending_command_is_the_previous_label_in_a_delayed_episode_only() -> None:
    """Known answer: zeros at the first step (the env executes zeros then) and throughout an undelayed episode."""
    model = humanoid_model()
    episode = expert_episode(1, seed=0)
    recorded = np.column_stack([[Proprioception(model)(o) for o in episode.observation], episode.action])
    index = np.zeros(episode.length, np.int64)
    pending = slice(-1 - model.nu, -1)
    delayed = episode_inputs("pending", recorded, index, model, np.ones(episode.length))
    np.testing.assert_array_equal(delayed[0, pending], 0.0)
    np.testing.assert_array_equal(delayed[1:, pending], episode.action[:-1])
    np.testing.assert_array_equal(delayed[:, -1], 1.0)
    undelayed = episode_inputs("pending", recorded, index, model, np.zeros(episode.length))
    np.testing.assert_array_equal(undelayed[:, pending.start :], 0.0)


@pytest.mark.parametrize("delay", [0, 1])
def test_a_policy_on_pending_inputs_is_told_the_delay_and_remembers_its_command(delay: int) -> None:
    env = ActionLatency(make_env(20), 1) if delay else make_env(20)
    spec = MLPSpec(INPUT_COLUMNS["pending"], len(input_names("pending", humanoid_model())), 17, (8,), inputs="pending")
    controller = PolicyController(MLPPolicy(spec, env.action_space.low, env.action_space.high), "pending", env)
    episode = run_episode(env, controller, seed=0)
    assert controller.features.delay == delay
    np.testing.assert_array_equal(controller.features.pending, episode.action[-1] if delay else 0.0)


def test_a_delay_beyond_one_step_is_refused_in_one_line() -> None:
    with pytest.raises(
        UserError,
        match=r"^a policy on the 'pending' inputs acts through at most 1 step of action "
        r"latency; this episode delays its actions by 2$",
    ):
        PendingInputs(humanoid_model()).set_delay(2)
