"""`make tutorial-rl`: the seed tutorial's learners, trained for real on Humanoid-v5 and run by the project's tools."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from evaluation.evaluate import evaluate
from humanoid.env import make_env
from policies import checkpoint
from policies.folder import CONFIG_FILE, CONFIG_TAG, EVAL_FILE, SB3_FILE, TENSORBOARD_DIR
from rl.tutorial import PreferredActionLearner, TutorialConfig, cli, main
from rollout.controllers import make_controller
from students.learned import SB3Controller
from support import scalars, snapshot, tensorboard_text

LOW, HIGH = -0.4 * np.ones(17), 0.4 * np.ones(17)


def learner(**changes: float) -> PreferredActionLearner:
    settings = {"step_size": 0.5, "noise_start": 0.2, "noise_end": 0.01, "timesteps": 100, "seed": 0, **changes}
    return PreferredActionLearner(LOW, HIGH, **settings)


def test_a_rewarded_action_pulls_the_mean_by_the_step_size() -> None:
    preferred = learner()
    action = np.full(17, 0.2)
    preferred.learn(action, reward=1.0)
    np.testing.assert_allclose(preferred.mean, 0.1)  # halfway from 0 to 0.2
    preferred.learn(np.full(17, -0.4), reward=-3.0)  # not rewarded: the mean stays
    np.testing.assert_allclose(preferred.mean, 0.1)


def test_the_noise_decays_from_its_start_to_its_end_over_the_run() -> None:
    """Geometrically: 0.2 at the start, the geometric mean of start and end halfway (0.045), 0.01 at the end."""
    preferred = learner()
    seen = [preferred.noise]
    for _ in range(100):
        preferred.learn(np.zeros(17), reward=0.0)
        seen.append(preferred.noise)
    assert seen[0] == 0.2 and seen[50] == pytest.approx(0.2**0.5 * 0.01**0.5) and seen[100] == pytest.approx(0.01)


def test_the_saved_policy_outputs_the_mean_action_for_any_observation(tmp_path: Path) -> None:
    """The constant policy, as a checkpoint, acts with the learned mean whatever it observes."""
    preferred = learner()
    preferred.mean = np.linspace(-0.3, 0.39, 17)
    checkpoint.save(preferred.policy(), tmp_path / "p", {}, {})
    env = make_env()
    controller = make_controller(str(tmp_path / "p"), env)
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_allclose(controller.act(obs), preferred.mean, atol=1e-5)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[TutorialConfig, dict]:
    folder = tmp_path_factory.mktemp("tutorial")
    config = TutorialConfig(
        preferred_policy=folder / "preferred",
        ppo_policy=folder / "ppo",
        timesteps=300,
        final_eval_episodes=2,
        progress=False,
    )
    return config, main(config)


def test_both_learners_train_and_are_evaluated_on_the_test_seeds(trained: tuple[TutorialConfig, dict]) -> None:
    config, results = trained
    assert set(results) == {"preferred", "ppo"}
    for folder, result in ((config.preferred_policy, results["preferred"]), (config.ppo_policy, results["ppo"])):
        assert json.loads((folder / EVAL_FILE).read_text()) == result
        assert result["seeds"] == [1000, 1001] and result["timesteps"] == 300
    training = json.loads((config.preferred_policy / CONFIG_FILE).read_text())["training"]
    assert len(training["mean_action"]) == 17 and 0 < training["positive_reward_share"] <= 1


def test_the_tutorial_ppo_runs_as_sb3_saved_it(trained: tuple[TutorialConfig, dict]) -> None:
    """The SB3 folder is a controller the evaluator runs: its deterministic actions are SB3's `predict`'s."""
    config, results = trained
    assert (config.ppo_policy / SB3_FILE).is_file()
    controller = make_controller(str(config.ppo_policy), make_env())
    assert isinstance(controller, SB3Controller)
    obs, _ = make_env().reset(seed=3)
    expected, _ = PPO.load(config.ppo_policy / SB3_FILE, device="cpu").predict(obs, deterministic=True)
    np.testing.assert_array_equal(controller.act(obs), expected)
    assert evaluate(str(config.ppo_policy), episodes=2)["returns"] == results["ppo"]["returns"]


@pytest.mark.parametrize("learner", ["preferred", "ppo"])
def test_each_learner_leaves_its_curves_and_settings_in_tensorboard(
    trained: tuple[TutorialConfig, dict], learner: str
) -> None:
    """Inside its checkpoint folder (SB3 would otherwise make an empty folder under /tmp): episode returns by step,
    and the run's settings as text."""
    config, _ = trained
    folder = config.preferred_policy if learner == "preferred" else config.ppo_policy
    (events,) = {path.parent for path in (folder / TENSORBOARD_DIR).rglob("events.out.tfevents.*")}
    settings = json.loads(textwrap.dedent(tensorboard_text(events, CONFIG_TAG)))
    assert settings["timesteps"] == 300 and settings["learning_rate"] == config.learning_rate
    returns = scalars(events, "rollout/ep_rew_mean")
    assert returns and all(0 < step <= 2048 and value > 0 for step, value in returns)


def test_a_finished_run_is_reused(trained: tuple[TutorialConfig, dict], capsys: pytest.CaptureFixture[str]) -> None:
    config, results = trained
    before = snapshot(config.preferred_policy.parent)
    assert main(config) == results
    assert snapshot(config.preferred_policy.parent) == before
    assert capsys.readouterr().err.count("not run again") == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["--learners", "preferred,dqn"], "--learners 'preferred,dqn': choose from preferred, ppo"),
        (["--timesteps", "0"], "--timesteps must be positive"),
        (["--learning-rate", "-1"], "--learning-rate must be positive"),
        (["--seed", "-1"], "--seed must be a seed, at least 0 and below 2**32"),
        (["--seed", str(2**70)], "--seed must be a seed"),
    ],
)
def test_bad_settings_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code = cli(["--progress", "false", "--preferred-policy", str(tmp_path / "p"), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "p").exists()
