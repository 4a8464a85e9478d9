"""`make finetune-rl`: PPO starts from the BC policy exactly, the warm-up spares the actor, bad input is refused.

That a run ends with the same weights however it runs (workers, Ray, threads, kills, a lost worker):
`test_finetune_workers.py` and `test_finetune_resume.py`. The small BC checkpoints PPO starts from: `conftest.py`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from common import paths
from common.cli import config_dict, write_json
from humanoid.env import make_env
from humanoid.perturbations import VelocityKick
from policies import checkpoint
from policies import folder as policy_files
from policies.folder import CONFIG_TAG, TENSORBOARD_DIR
from policies.mlp import MLPPolicy, MLPSpec
from rl.finetune import (
    EVAL_CONDITIONS,
    FinetuneConfig,
    cli,
    eval_conditions,
    learner,
    main,
    print_summary,
    vec_env,
    weights_digest,
)
from rl.guards import Guards
from rl.learner import training_env
from rl.validation import Validator, better, falls_back, holds_floor, selection_score
from rl.vec_env import WorkerGroupVecEnv
from students.learned import PolicyController
from support import TINY_PPO, snapshot, tensorboard_text
from teachers.expert import LQRExpert

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

# The plumbing tests run on the nominal task, unpushed (the curriculum and the randomisation have tests of their own).
PPO_ENV = functools.partial(training_env, None)  # a full actor's PPO environment: the observation, then its inputs


def ppo_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    code = cli(["--progress", "false", *args])
    return code, capsys.readouterr().err.strip().splitlines()


def test_step_zero_actions_equal_the_bc_policy(bc_policy: Path) -> None:
    """Before any update, PPO's deterministic actions are the BC policy's, bit for bit."""
    config = FinetuneConfig(bc_policy=bc_policy, **TINY_PPO)
    env = WorkerGroupVecEnv([PPO_ENV], workers=1)
    model = learner(config, env)
    bc = PolicyController(checkpoint.load(bc_policy), "bc")
    probe = PPO_ENV()  # the observation, then the actor's inputs: here the observation again
    for seed in range(3):
        obs, _ = probe.reset(seed=seed)
        for _ in range(20):
            action, _ = model.predict(obs, deterministic=True)
            np.testing.assert_array_equal(action, bc.act(obs[:348]))
            obs, *_ = probe.step(action)
    assert torch.exp(model.policy.log_std).allclose(torch.tensor(0.05))


def test_sampled_rollouts_are_what_the_policy_and_environments_give(bc_policy: Path) -> None:
    """A worker-sampled rollout holds the policy's values and log-probabilities, the steps and the scaled rewards."""
    config = FinetuneConfig(bc_policy=bc_policy, **TINY_PPO)
    env = vec_env(config)
    try:
        model = learner(config, env)
        _, callback = model._setup_learn(config.rollout_steps, callback=None)
        assert model.collect_rollouts(env, callback, model.rollout_buffer, model.n_steps)
    finally:
        env.close()
    buffer = model.rollout_buffer
    obs = torch.as_tensor(buffer.observations.reshape(-1, buffer.observations.shape[-1]))
    actions = torch.as_tensor(buffer.actions.reshape(-1, buffer.actions.shape[-1]))
    with torch.no_grad():
        values, log_probs, _ = model.policy.evaluate_actions(obs, actions)
        means = model.policy.get_distribution(obs).distribution.mean
    np.testing.assert_allclose(buffer.values.flatten(), values.flatten().numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(buffer.log_probs.flatten(), log_probs.numpy(), rtol=1e-5, atol=1e-4)
    assert 0.04 < float((actions - means).std()) < 0.06  # the exploration noise: std 0.05
    assert buffer.episode_starts[0].all()
    # Environment 0's first episode replayed on its own (seed = the run's seed + its index), clipped actions.
    replay = training_env(None)
    expected, _ = replay.reset(seed=config.seed)
    episode_steps = 1 + int(np.argmax(np.append(buffer.episode_starts[1:, 0], 1)))
    assert episode_steps > 5
    for step in range(episode_steps):
        np.testing.assert_array_equal(buffer.observations[step, 0], expected, err_msg=f"step {step}")
        expected, reward, *_ = replay.step(np.clip(buffer.actions[step, 0], -0.4, 0.4))
        assert buffer.rewards[step, 0] == pytest.approx(0.01 * reward, rel=1e-6), f"step {step}"


def test_kicked_training_episodes_are_kicked_once_at_their_seeds_step() -> None:
    """--kick: each training episode is kicked as the suite's kick condition kicks it (seed 0: step 277, by 0.4 m/s),
    and the run's validation adds that condition to those that choose the actor kept."""
    env = training_env(None, kick=0.4)
    kicker, expert = env, LQRExpert()
    while not isinstance(kicker, VelocityKick):
        kicker = kicker.env
    obs, _ = env.reset(seed=0)
    expert.reset(0)
    size = make_env().observation_space.shape[0]
    data = env.unwrapped.data
    for step in range(KICKED_AT + 1):
        before = data.qvel[:2].copy()
        obs, *_ = env.step(expert.act(obs[:size]))
        if step == KICKED_AT:
            assert np.linalg.norm(data.qvel[:2] - before) > 0.3  # the kick, on top of the step's own change
    assert [at for at, _ in kicker.pushes] == [KICKED_AT]
    assert eval_conditions(FinetuneConfig(kick=0.4)) == (*EVAL_CONDITIONS, "kick0.4")
    assert eval_conditions(FinetuneConfig()) == EVAL_CONDITIONS


KICKED_AT = 277  # seed 0's kick (humanoid.perturbations.VelocityKick's draw)


def test_training_episodes_are_logged_in_the_environments_units(bc_policy: Path) -> None:
    """Finished training episodes reach SB3's episode statistics (rollout/ep_rew_mean) unscaled: ~5 a step, not 0.05."""
    config = FinetuneConfig(bc_policy=bc_policy, **TINY_PPO)
    env = vec_env(config)
    try:
        model = learner(config, env)
        model.learn(total_timesteps=512)
    finally:
        env.close()
    assert model.ep_info_buffer
    for episode in model.ep_info_buffer:
        assert 2.5 < episode["r"] / episode["l"] < 10.0  # the alive bonus of 5, plus or minus motion and costs


def test_critic_learns_at_its_own_rate(bc_policy: Path) -> None:
    """The critic's parameters are updated at CRITIC_LEARNING_RATE, the actor's and log std's at LEARNING_RATE."""
    config = FinetuneConfig(bc_policy=bc_policy, learning_rate=2e-5, critic_learning_rate=1e-3, **TINY_PPO)
    model = learner(config, WorkerGroupVecEnv([PPO_ENV], workers=1))
    model._update_learning_rate(model.policy.optimizer)  # what every PPO update starts with
    rates = {id(p): group["lr"] for group in model.policy.optimizer.param_groups for p in group["params"]}
    actor = {id(p) for p in model.policy.actor_parameters()}
    assert len(rates) == len(list(model.policy.parameters()))
    assert {rate for key, rate in rates.items() if key in actor} == {2e-5}
    critic_rates = [rate for key, rate in rates.items() if key not in actor]
    assert critic_rates == pytest.approx([1e-3] * len(critic_rates)) and critic_rates


def test_critic_clips_inputs_far_from_the_demonstrations(bc_policy: Path) -> None:
    """Observations 20 and 1,000 standard deviations from the demonstrations' mean get the same value (a full
    actor's PPO observation is the observation twice: the privileged one, then the actor's inputs)."""
    config = FinetuneConfig(bc_policy=bc_policy, **TINY_PPO)
    policy = learner(config, WorkerGroupVecEnv([PPO_ENV], workers=1)).policy
    actor = policy.actor
    with torch.no_grad():
        mean, far, farther = (
            float(policy.predict_values(torch.cat([actor.input_mean + distance * actor.input_std] * 2)[None]))
            for distance in (0, 20, 1000)
        )
    assert far == pytest.approx(farther, rel=1e-6)
    assert abs(far - mean) > 1e-3


def test_critic_warmup_leaves_the_actor_unchanged(bc_policy: Path) -> None:
    """During the warm-up PPO updates the critic and leaves the actor's weights and log std as they were."""
    config = FinetuneConfig(bc_policy=bc_policy, learning_rate=1e-3, **TINY_PPO)
    model = learner(config, WorkerGroupVecEnv([PPO_ENV], workers=1))
    actor_before = {k: v.clone() for k, v in model.policy.actor.state_dict().items()}
    log_std_before = model.policy.log_std.detach().clone()
    critic_before = [p.detach().clone() for p in model.policy.mlp_extractor.critic.parameters()]
    model.learn(total_timesteps=512, callback=Guards(warmup=10_000))
    for name, value in model.policy.actor.state_dict().items():
        assert torch.equal(value, actor_before[name]), name
    assert torch.equal(model.policy.log_std, log_std_before)
    assert any(
        not torch.equal(p, q)
        for p, q in zip(model.policy.mlp_extractor.critic.parameters(), critic_before, strict=True)
    )


def test_actor_learns_once_the_warmup_is_over(bc_policy: Path) -> None:
    """With no warm-up the same updates do change the actor (the previous test is not vacuous)."""
    config = FinetuneConfig(bc_policy=bc_policy, learning_rate=1e-3, **TINY_PPO)
    model = learner(config, WorkerGroupVecEnv([PPO_ENV], workers=1))
    before = model.policy.actor.net[0].weight.detach().clone()
    model.learn(total_timesteps=512, callback=Guards(warmup=0))
    assert not torch.equal(model.policy.actor.net[0].weight, before)


@pytest.fixture(scope="module")
def tiny_run(bc_policy: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[FinetuneConfig, dict]:
    """A short fine-tuning run (768 steps, 4 evaluations) and its final evaluation."""
    config = FinetuneConfig(
        bc_policy=bc_policy,
        policy=tmp_path_factory.mktemp("tiny") / "ppo",
        timesteps=768,
        critic_warmup=256,
        **TINY_PPO,
    )
    return config, main(config)


def test_tiny_run_writes_a_loadable_checkpoint(bc_policy: Path, tiny_run: tuple[FinetuneConfig, dict]) -> None:
    """A short fine-tuning run saves the actor in the BC format, an eval.json and periodic checkpoints."""
    config, result = tiny_run
    loaded = checkpoint.load(config.policy)
    assert loaded.spec == checkpoint.load(bc_policy).spec
    assert [p["timesteps"] for p in result["training_curve"]] == [0, 256, 512, 768]
    assert (config.policy / policy_files.EVAL_FILE).is_file() and (config.policy / "learning_curve.png").is_file()
    assert len(list((config.policy / "checkpoints").iterdir())) == 4
    data = (config.policy / policy_files.DATASET_FILE).read_text()
    assert all(
        (step / policy_files.DATASET_FILE).read_text() == data for step in (config.policy / "checkpoints").iterdir()
    )
    assert result["episodes"] == 1 and 0.0 <= result["survival_rate"] <= 1.0


def test_every_evaluation_includes_the_robustness_conditions(tiny_run: tuple[FinetuneConfig, dict]) -> None:
    """Each point of the learning curve has the survival and return under each of --eval-conditions (push20,
    mass by default), beside the validation ones, for the figure's survival panel."""
    _, result = tiny_run
    assert len(result["training_curve"]) == 4
    for point in result["training_curve"]:
        assert 0.0 <= point["survival_rate"] <= 1.0 and point["mean_return"] > 0
        for name in ("push20", "mass"):
            assert 0.0 <= point[f"{name}_survival_rate"] <= 1.0 and point[f"{name}_mean_return"] > 0


def test_config_json_holds_every_setting_and_the_bc_policy(tiny_run: tuple[FinetuneConfig, dict]) -> None:
    """config.json's training record: every FinetuneConfig field as run, who ran it, the BC weights' digest."""
    config, _ = tiny_run
    training = json.loads((config.policy / policy_files.CONFIG_FILE).read_text())["training"]
    assert {name: training[name] for name in config_dict(config)} == config_dict(config)
    assert training["made_by"] == "rl.finetune" and training["bc_policy_sha256"] == weights_digest(config.bc_policy)


def test_tensorboard_holds_the_config_as_text(tiny_run: tuple[FinetuneConfig, dict]) -> None:
    """PPO's TensorBoard logs (SB3's) hold the run's settings as text, as config.json has them."""
    config, _ = tiny_run
    (events,) = {path.parent for path in (config.policy / TENSORBOARD_DIR).rglob("events.out.tfevents.*")}
    settings = json.loads(textwrap.dedent(tensorboard_text(events, CONFIG_TAG)))
    training = json.loads((config.policy / policy_files.CONFIG_FILE).read_text())["training"]
    assert settings == {name: training[name] for name in settings} and set(config_dict(config)) <= set(settings)


def test_the_curriculum_moves_on_at_rollout_ends_and_the_checkpoint_says_when(bc_policy: Path, tmp_path: Path) -> None:
    """With every episode counting (the tiny BC policy falls), the stage moves on after each rollout until the
    last; config.json records when each stage began, and the validation runs under the last stage's push."""
    config = FinetuneConfig(
        bc_policy=bc_policy,
        policy=tmp_path / "ppo",
        timesteps=1024,
        **{**TINY_PPO, "curriculum": "0,5,10", "curriculum_advance": 0.0, "curriculum_episodes": 1},
    )
    result = main(config)
    training = json.loads((config.policy / policy_files.CONFIG_FILE).read_text())["training"]
    assert training["curriculum_stages"] == [
        {"timesteps": 0, "stage": 0, "push": 0.0},
        {"timesteps": 256, "stage": 1, "push": 5.0},
        {"timesteps": 512, "stage": 2, "push": 10.0},
    ]
    assert result["pushed"]["push_newtons"] == 10.0


def test_evaluations_fall_between_updates(bc_policy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """With EVAL_FREQ shorter than a rollout, each actor is evaluated once; the last after the last whole rollout.
    Without a final evaluation (`make pipeline`'s), eval.json and the summary hold the training's figures only, and
    such a checkpoint can start another run."""
    config = FinetuneConfig(
        bc_policy=bc_policy,
        policy=tmp_path / "ppo",
        timesteps=300,
        critic_warmup=0,
        **{**TINY_PPO, "eval_freq": 100, "final_eval_episodes": 0},
    )
    result = main(config)
    assert [p["timesteps"] for p in result["training_curve"]] == [0, 256, 512]
    assert result["timesteps"] == 512
    assert json.loads((config.policy / policy_files.EVAL_FILE).read_text()) == json.loads(json.dumps(result))
    assert "seeds" not in result and "survival_rate" not in result
    print_summary(config, result)
    printed = capsys.readouterr().out
    assert f"kept step {result['kept']['timesteps']}" in printed and "final on" not in printed
    again = main(dataclasses.replace(config, bc_policy=config.policy, policy=tmp_path / "again", timesteps=256))
    assert again["bc_mean_return"] is None  # its start has no final evaluation to compare with


def test_the_saved_actor_is_the_checkpoint_of_the_evaluation_kept(tiny_run: tuple[FinetuneConfig, dict]) -> None:
    """By default (guarded) the last evaluation's actor unless its clean return fell below the floor."""
    config, result = tiny_run
    curve = result["training_curve"]
    assert result["kept"] == (curve[-1] if holds_floor(curve) else max(curve, key=selection_score))
    kept = checkpoint.load(config.policy / "checkpoints" / f"step_{result['kept']['timesteps']:08d}").state_dict()
    for name, value in checkpoint.load(config.policy).state_dict().items():
        assert torch.equal(value, kept[name]), name


def test_guarded_keeps_the_last_actor_unless_its_clean_return_fell_below_the_floor() -> None:
    start = {"timesteps": 0, "mean_return": 1000.0, "clean_mean_return": 4900.0}
    held = {"timesteps": 9, "mean_return": 900.0, "clean_mean_return": 0.9 * 4900.0}
    fell = {**held, "clean_mean_return": 0.89 * 4900.0}
    assert holds_floor([start, fell, held]) and not holds_floor([start, held, fell])
    # Without a clean evaluation the validation return stands in for it.
    assert not holds_floor([{"mean_return": 1000.0}, {"mean_return": 899.0}])
    # On commands the tracking score is held to the floor too.
    tracked = {**start, "tracking_score": 0.7}
    assert holds_floor([tracked, {**held, "tracking_score": 0.63}])
    assert not holds_floor([tracked, {**held, "tracking_score": 0.62}])


def test_the_clean_evaluation_which_holds_the_floor_runs_its_own_episodes(tmp_path: Path) -> None:
    """--floor-episodes for the clean condition (one fall in 5 episodes crossed the floor), in parts of at most
    --eval-episodes from the validation seed; --eval-episodes for the validation push and the other conditions."""
    validator = Validator(
        episodes=5, floor_episodes=12, seed=2000, push=40.0, freq=1, settings={}, folder=tmp_path, bar=None
    )
    clean = [(part["seed"], part["episodes"]) for part in validator.parts({"condition": "clean"})]
    assert clean == [(2000, 5), (2005, 5), (2010, 2)]
    assert [(part["seed"], part["episodes"]) for part in validator.parts({"push": 40.0})] == [(2000, 5)]
    assert [(part["seed"], part["episodes"]) for part in validator.parts({"condition": "mass"})] == [(2000, 5)]


def test_scratch_keeps_its_last_actor_where_fine_tuning_falls_back() -> None:
    """PPO from scratch has none of the guards: below its random start's return it still keeps its last actor."""
    start = {"timesteps": 0, "mean_return": 310.0, "clean_mean_return": 310.0}
    last = {"timesteps": 9, "mean_return": 230.0, "clean_mean_return": 230.0}
    assert falls_back([start, last], fresh=False) and not falls_back([start, last], fresh=True)
    assert not falls_back([start, start], fresh=False)


def test_the_actor_fallen_back_on_holds_the_floor_too() -> None:
    """A higher score that gave up the student's tracking (below 90 % of step 0's) does not replace the best."""
    start = {"timesteps": 0, "mean_return": 1000.0, "clean_mean_return": 4000.0, "tracking_score": 0.7}
    survives = {**start, "timesteps": 9, "mean_return": 1500.0, "clean_mean_return": 4900.0, "tracking_score": 0.5}
    tracks = {**survives, "mean_return": 1200.0, "tracking_score": 0.65}
    assert better(tracks, start, start) and not better(survives, start, start) and not better(survives, tracks, start)


def test_the_selection_score_is_the_mean_return_over_the_evaluated_conditions() -> None:
    """Validation return and each condition's return count alike; survival rates do not enter."""
    point = {"timesteps": 5, "mean_return": 1000.0, "survival_rate": 0.0, "clean_mean_return": 5000.0}
    point |= {"clean_survival_rate": 1.0, "mass_mean_return": 3000.0, "mass_survival_rate": 0.5}
    assert selection_score(point) == 3000.0
    # Higher under the validation push alone, lower over the conditions: not the one kept.
    assert selection_score({**point, "mean_return": 1200.0, "mass_mean_return": 2000.0}) < selection_score(point)
    assert selection_score({"timesteps": 0, "mean_return": 4944.0, "survival_rate": 1.0}) == 4944.0


def test_missing_bc_checkpoint_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """BC_POLICY naming nothing fails in one line and writes nothing."""
    code, err = ppo_cli(["--bc-policy", str(tmp_path / "none"), "--policy", str(tmp_path / "ppo")], capsys)
    assert code == 1 and len(err) == 1 and "no policy checkpoint" in err[0]
    assert not (tmp_path / "ppo").exists()


def test_missing_default_student_says_how_to_make_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`make finetune-rl` starts from the newest student (DAgger's or BC's) by default; where neither was made yet,
    its one line names both folders and the command that makes one."""
    monkeypatch.chdir(tmp_path)
    code, err = ppo_cli(["--policy", "ppo"], capsys)
    listed = f"{paths.DAGGER_POLICY}, {paths.BC_POLICY}"
    assert (code, err) == (
        1,
        [f"error: no policy checkpoint yet at {listed}: make train-bc (after make record) makes one"],
    )
    assert not (tmp_path / "ppo").exists()


def test_bc_checkpoint_for_other_sizes_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A checkpoint built for another observation or action size fails in one line."""
    folder = tmp_path / "small"
    spec = MLPSpec(("observation.state", "observation.environment_state"), 10, 3, hidden=(8,))
    checkpoint.save(MLPPolicy(spec), folder, {}, {"path": str(tmp_path)})
    code, err = ppo_cli(["--bc-policy", str(folder), "--policy", str(tmp_path / "ppo")], capsys)
    assert code == 1 and len(err) == 1 and "gives 348 and takes 17" in err[0]
    assert not (tmp_path / "ppo").exists()


def test_a_proprioceptive_actor_reads_the_sensed_features_its_env_appends(proprio_policy: Path) -> None:
    """Asymmetric actor-critic: the training env appends the sensed features to the observation; the actor's actions
    are the proprio BC policy's and change with no entry of the observation before them, the critic's value does."""
    config = FinetuneConfig(bc_policy=proprio_policy, **TINY_PPO)
    proprio_env = functools.partial(training_env, None, inputs="proprio")
    policy = learner(config, WorkerGroupVecEnv([proprio_env], workers=1)).policy
    bc = PolicyController(checkpoint.load(proprio_policy), "bc")
    env, rng, seen = proprio_env(), np.random.default_rng(0), []
    obs, _ = env.reset(seed=0)
    for _ in range(50):  # a body falling under random actions
        seen.append(obs)
        obs, _, terminated, _, _ = env.step(rng.uniform(-0.4, 0.4, 17))
        if terminated:
            obs, _ = env.reset()
    seen = np.array(seen, np.float32)
    assert seen.shape[1] == 348 + 48
    changed = seen.copy()
    changed[:, :348] += np.random.default_rng(1).normal(0, 5, (len(seen), 348))
    with torch.no_grad():
        actions = policy.get_distribution(torch.as_tensor(seen)).distribution.mean.numpy()
        actions_changed = policy.get_distribution(torch.as_tensor(changed)).distribution.mean.numpy()
        values = policy.predict_values(torch.as_tensor(seen)).numpy()
        values_changed = policy.predict_values(torch.as_tensor(changed)).numpy()
    np.testing.assert_array_equal(actions, actions_changed)
    np.testing.assert_allclose(actions, np.array([bc.act(o[:348].astype(np.float64)) for o in seen]), atol=1e-6)
    assert np.abs(values - values_changed).min() > 0


def test_a_pending_actor_reads_its_command_in_flight_and_the_delay(pending_policy: Path) -> None:
    """Under one step of latency the training env appends the estimate, the last action stepped and the delay;
    along an episode the actor's actions are the pending BC policy's (told the delay, remembering its commands)."""
    config = FinetuneConfig(bc_policy=pending_policy, **TINY_PPO)
    delayed_env = functools.partial(training_env, None, inputs="pending", latency=1.0)
    policy = learner(config, WorkerGroupVecEnv([delayed_env], workers=1)).policy
    env, seen = delayed_env(), []
    bc = PolicyController(checkpoint.load(pending_policy), "bc", env)
    obs, _ = env.reset(seed=0)
    bc.set_delay(1)
    bc.reset(0)
    expected = []
    for _ in range(40):
        seen.append(obs)
        action = bc.act(obs[:348])
        expected.append(action)
        obs, *_ = env.step(action)
    with torch.no_grad():
        actions = policy.get_distribution(torch.as_tensor(np.array(seen, np.float32))).distribution.mean.numpy()
    np.testing.assert_allclose(actions, np.array(expected), atol=1e-5)
    assert np.array(seen)[1:, -1].min() == 1.0 and np.abs(np.array(seen)[1:, -18:-1]).max() > 0


@pytest.mark.parametrize("bc_folder", ["proprio_policy", "pending_policy"])
def test_a_proprioceptive_run_saves_a_policy_on_the_same_inputs(
    bc_folder: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    """Fine-tuning a proprio or pending BC checkpoint ends with a checkpoint that reads what it read, which
    make eval runs."""
    bc_policy = request.getfixturevalue(bc_folder)
    result = main(FinetuneConfig(bc_policy=bc_policy, policy=tmp_path / "ppo", timesteps=256, **TINY_PPO))
    assert checkpoint.load(tmp_path / "ppo").spec == checkpoint.load(bc_policy).spec
    assert result["episodes"] == 1 and len(result["training_curve"]) == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["--timesteps", "0"], "--timesteps must be positive"),
        (["--timesteps", "-5"], "--timesteps must be positive"),
        (["--workers", "0"], "--workers must be positive"),
        (["--envs", "0"], "--envs must be positive"),
        (["--envs", "4", "--workers", "5"], "--workers (5) must not exceed --envs (4)"),
        (["--critic-learning-rate", "0"], "--critic-learning-rate must be positive"),
        (["--floor-episodes", "0"], "--floor-episodes must be positive"),
        (["--backend", "ray", "--ray-address", "6379"], "--ray-address must be HOST:PORT"),
        (["--curriculum", "20,10"], "forces must not decrease"),
        (["--curriculum", "10,x"], "give push forces in newtons"),
        (["--curriculum", "10,20", "--push", "20"], "give --push or --curriculum, not both"),
        (["--curriculum-advance", "1.5"], "--curriculum-advance must be in [0, 1]"),
        (["--latency-share", "-0.5"], "--latency-share must be in [0, 1]"),
        (["--obs-noise-share", "2"], "--obs-noise-share must be in [0, 1]"),
        (["--tracking-weight", "-1"], "--tracking-weight must be >= 0"),
        (["--clip-range", "0"], "--clip-range must be positive"),
        (["--curriculum-episodes", "0"], "--curriculum-episodes must be positive"),
        (["--gamma", "nan"], "--gamma must be in [0, 1]"),
        (["--gae-lambda", "-1"], "--gae-lambda must be in [0, 1]"),
        (["--batch-size", "1"], "--batch-size must be at least 2"),
        (["--seed", "-1"], "--seed must be a seed, at least 0 and below 2**32"),
        (["--batch-size", "100000"], "--batch-size (100000) must not exceed --rollout-steps"),
        (["--seed", str(2**70)], "--seed must be a seed"),
        (["--kick", "-0.4"], "--kick must be >= 0"),
        (["--kick", "0.3"], "--kick must be 0 or one of the suite's kick speeds (0.2, 0.4, 0.6 m/s), got 0.3"),
        (["--randomize", "wild"], "--randomize 'wild': unknown preset"),
        (["--randomize", "mass=1.2:0.8"], "mass range has low 1.2 > high 0.8"),
    ],
)
def test_bad_settings_are_refused(
    bc_policy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    """A non-positive budget or rate fails in one line before anything starts."""
    code, err = ppo_cli(["--bc-policy", str(bc_policy), "--policy", str(tmp_path / "ppo"), *args], capsys)
    assert code == 1 and len(err) == 1 and message in err[0]


def test_unwritable_policy_folder_is_refused(bc_policy: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """POLICY on a read-only file system fails in one line."""
    code, err = ppo_cli(["--bc-policy", str(bc_policy), "--policy", "/sys/fs/humanoid_bc_policy"], capsys)
    assert code == 1 and len(err) == 1 and "cannot write a checkpoint in /sys/fs" in err[0]


def test_existing_checkpoint_is_not_overwritten(
    bc_policy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An existing POLICY is left as it was without --overwrite; the BC checkpoint itself is refused as POLICY."""
    before = snapshot(bc_policy)
    code, err = ppo_cli(["--bc-policy", str(bc_policy), "--policy", str(bc_policy), "--overwrite", "true"], capsys)
    assert code == 1 and "--policy must differ from --bc-policy" in err[0]
    target = tmp_path / "existing"
    checkpoint.save(checkpoint.load(bc_policy), target, {}, {})
    existing = snapshot(target)
    code, err = ppo_cli(["--bc-policy", str(bc_policy), "--policy", str(target)], capsys)
    assert code == 1 and len(err) == 1 and "--overwrite" in err[0]
    assert snapshot(target) == existing and snapshot(bc_policy) == before


def test_a_run_killed_in_its_final_evaluation_is_finished_by_the_same_command(
    bc_policy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The weights and the training's figures are published together; killed during the final evaluation, the same
    command runs that evaluation alone, to the whole run's eval.json."""
    config = FinetuneConfig(bc_policy=bc_policy, policy=tmp_path / "ppo", timesteps=256, critic_warmup=0, **TINY_PPO)
    path = config.policy / policy_files.EVAL_FILE
    whole = json.loads(json.dumps(main(config), default=str))
    figures = (
        "timesteps",
        "seconds",
        "steps_per_s",
        "bc_mean_return",
        "expert_mean_return",
        "training_curve",
        "kept",
        "resumed_at",
    )
    write_json(path, {name: whole[name] for name in figures})  # what the kill leaves
    weights = (config.policy / policy_files.WEIGHTS_FILE).read_bytes()
    capsys.readouterr()
    assert json.loads(json.dumps(main(config), default=str)) == whole == json.loads(path.read_text())
    assert "already holds this run" in capsys.readouterr().err
    assert (config.policy / policy_files.WEIGHTS_FILE).read_bytes() == weights


def test_a_start_that_names_no_demonstrations_is_refused(
    bc_policy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Their data normalise the critic: a checkpoint whose dataset.json names none is refused in one line, before
    any worker starts."""
    start = tmp_path / "start"
    shutil.copytree(bc_policy, start)
    (start / policy_files.DATASET_FILE).write_text("{}")
    code, err = ppo_cli(["--bc-policy", str(start), "--policy", str(tmp_path / "ppo")], capsys)
    assert code == 1 and len(err) == 1 and "names no demonstrations" in err[0]
    assert not (tmp_path / "ppo").exists()
