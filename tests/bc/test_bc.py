"""`make train-bc`: a tiny training learns, the checkpoint rebuilds the same policy, bad input is refused."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
import subprocess
import textwrap
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from bc import train as bc_train
from bc.data import Demonstrations, episode_delays, load_demonstrations, split_by_episode
from bc.train import (
    TrainConfig,
    TrainResult,
    cli,
    lr_factor,
    main,
    planned_epochs,
    teacher_of,
)
from common import columns
from common.cli import UserError, config_dict
from evaluation.evaluate import evaluate
from humanoid.env import observation_names
from policies import checkpoint
from policies import folder as policy_files
from policies.folder import CONFIG_TAG, TENSORBOARD_DIR
from policies.mlp import STD_FLOOR
from rollout.controllers import make_controller
from students.inputs import FullInputs
from students.learned import PolicyController
from support import join_observation, one_core, record_short, snapshot, tensorboard_text
from teleop.dataset_reader import fingerprint, read_frames
from teleop.record import STANDING, STANDING_NOISE, TEACHER, RecordConfig, validate
from teleop.record import main as record

TINY = {
    "inputs": "full",
    "hidden": 32,
    "epochs": 40,
    "min_updates": 0,
    "batch_size": 32,
    "eval_episodes": 0,
    "progress": False,
}


@pytest.fixture(scope="module")
def env() -> gym.Env:
    """A Humanoid-v5 environment for dimensions and bounds."""
    return gym.make("Humanoid-v5")


@pytest.fixture(scope="module")
def trained(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """A small MLP trained on the 3-episode recording, saved with its TensorBoard logs."""
    folder = tmp_path_factory.mktemp("policies") / "tiny"
    return main(TrainConfig(dataset=recorded, policy=folder, **TINY))


def train_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """Exit code and stderr lines of `python -m bc.train ARGS` with tiny settings."""
    tiny = ["--hidden", "8", "--epochs", "1", "--min-updates", "0", "--eval-episodes", "0", "--progress", "false"]
    tiny += ["--inputs", "full"]
    code = cli([*tiny, *args])
    return code, capsys.readouterr().err.strip().splitlines()


def test_tiny_training_lowers_the_validation_loss(trained: TrainResult) -> None:
    """On held-out episodes the kept epoch's loss is under 3/4 of the untrained policy's (0.50 measured)."""
    curves = trained.curves
    assert curves.best_val_loss < 0.75 * curves.initial_val_loss
    assert curves.train_loss[-1] < curves.train_loss[0]


@pytest.mark.slow
def test_default_recipe_clones_the_expert_from_five_demonstrations(tmp_path: Path) -> None:
    """The standing recipe's known answer: with ReLU units this data stood on no unseen seed
    (docs/decisions/activation.md).

    Trained on one core (`support.one_core`): this test's 5,000 Adam steps."""
    data = tmp_path / "five"
    record(
        RecordConfig(
            dataset=data, episodes=5, seed=0, noise=STANDING_NOISE, writer="inline", progress=False, **STANDING
        )
    )
    cfg = TrainConfig(dataset=data, policy=tmp_path / "policy", inputs="full", eval_episodes=0, progress=False)
    with one_core():
        result = main(cfg)
    evaluation = evaluate(PolicyController(result.policy, "five"), episodes=5, seed=1000)
    assert evaluation["survivals"] == [True] * 5, evaluation["lengths"]


def test_min_updates_give_a_small_dataset_more_epochs() -> None:
    """Known answers: 1,000 frames in batches of 256 are 4 steps a pass, so 5,000 steps take 1,250 passes;
    44,085 frames (50 demonstrations) are 173 steps a pass, and 30 passes already exceed 5,000 steps."""
    assert planned_epochs(1000, TrainConfig(epochs=30, min_updates=5000, batch_size=256)) == 1250
    assert planned_epochs(44_085, TrainConfig(epochs=30, min_updates=5000, batch_size=256)) == 30
    assert planned_epochs(1000, TrainConfig(epochs=30, min_updates=0, batch_size=256)) == 30


def test_cosine_schedule_known_answers() -> None:
    """Half way through the rate is half of LR, after the last step 0 (and past it)."""
    assert lr_factor(0, 100) == 1.0
    assert lr_factor(50, 100) == pytest.approx(0.5)
    assert lr_factor(100, 100) == pytest.approx(0.0, abs=1e-12)
    assert lr_factor(150, 100) == pytest.approx(0.0, abs=1e-12)


def test_default_training_anneals_the_rate_to_zero_by_its_last_step(trained: TrainResult) -> None:
    """Adam's rate falls every epoch and is 0 once the last minibatch has been learnt from."""
    rates = trained.curves.learning_rate
    assert len(rates) == len(trained.curves.val_loss) == TINY["epochs"]
    assert all(earlier > later for earlier, later in pairwise(rates))
    assert rates[-1] == pytest.approx(0.0, abs=1e-12)


def test_training_runs_the_passes_min_updates_need(recorded: Path, tmp_path: Path) -> None:
    """One epoch asked for, but at least 20 Adam steps in batches of 32: the run makes ceil(20 / steps a pass)."""
    config = TrainConfig(dataset=recorded, policy=tmp_path / "policy", **{**TINY, "epochs": 1, "min_updates": 20})
    result = main(config)
    steps_per_pass = -(-result.train_frames // 32)
    assert len(result.curves.val_loss) == -(-20 // steps_per_pass) > 1


def test_split_holds_out_whole_episodes(trained: TrainResult, recorded: Path, env: gym.Env) -> None:
    """Training and validation episodes are disjoint, cover the dataset, and the frame counts follow them."""
    demos = load_demonstrations(recorded, env)
    assert set(trained.train_episodes).isdisjoint(trained.val_episodes)
    assert sorted(trained.train_episodes + trained.val_episodes) == demos.episodes
    assert trained.val_frames == int(np.isin(demos.episode_index, trained.val_episodes).sum())
    assert split_by_episode(list(range(50)), 0.1, seed=3) == split_by_episode(list(range(50)), 0.1, seed=3)
    assert len(split_by_episode(list(range(50)), 0.1, seed=3)[1]) == 5


def test_checkpoint_round_trip_gives_identical_actions(trained: TrainResult, recorded: Path, env: gym.Env) -> None:
    """`checkpoint.load` rebuilds a policy whose actions equal the trained one's bit for bit."""
    inputs = load_demonstrations(recorded, env).inputs
    loaded = checkpoint.load(trained.policy_dir)
    with torch.no_grad():
        assert torch.equal(loaded(inputs), trained.policy(inputs))


def test_normalisation_is_in_the_state_dict(trained: TrainResult, recorded: Path, env: gym.Env) -> None:
    """The training frames' mean and floored std are buffers saved with the weights; constant inputs get the floor."""
    weights = load_file(trained.policy_dir / policy_files.WEIGHTS_FILE)
    demos = load_demonstrations(recorded, env)
    train_inputs = demos.inputs[torch.from_numpy(np.isin(demos.episode_index, trained.train_episodes))].double()
    torch.testing.assert_close(weights["input_mean"], train_inputs.mean(0).float())
    std = train_inputs.std(0, correction=0)
    torch.testing.assert_close(weights["input_std"], std.clamp_min(STD_FLOOR).float())
    assert bool((weights["input_std"][std == 0] == STD_FLOOR).all()) and bool((std == 0).any())
    assert torch.equal(weights["action_half_range"], torch.full((17,), 0.4))


def test_checkpoint_records_config_dataset_and_curves(trained: TrainResult, recorded: Path) -> None:
    """config.json has the resolved settings, dataset.json the data's identity; curve and logs are there."""
    folder = trained.policy_dir
    config = json.loads((folder / policy_files.CONFIG_FILE).read_text())
    assert config["policy"]["hidden"] == [32, 32] and config["policy"]["input_keys"] == list(FullInputs.columns)
    assert config["training"]["dataset"] == str(recorded) and config["training"]["lr"] == 1e-3
    dataset = json.loads((folder / policy_files.DATASET_FILE).read_text())
    assert dataset["path"] == str(recorded.resolve()) and dataset["episodes"] == 3
    assert dataset["frames"] == trained.train_frames + trained.val_frames
    assert (folder / policy_files.LEARNING_CURVE_FILE).stat().st_size > 0
    assert list((folder / TENSORBOARD_DIR).glob("events.out.tfevents.*"))


def test_config_json_holds_every_setting_and_the_datasets_fingerprint(trained: TrainResult, recorded: Path) -> None:
    """config.json's training record has every TrainConfig field as run, and who ran it; dataset.json the digest."""
    folder = trained.policy_dir
    training = json.loads((folder / policy_files.CONFIG_FILE).read_text())["training"]
    config = TrainConfig(dataset=recorded, policy=folder, **TINY)
    assert {name: training[name] for name in config_dict(config)} == config_dict(config)
    assert training["made_by"] == "bc.train"
    assert json.loads((folder / policy_files.DATASET_FILE).read_text())["fingerprint"] == fingerprint(recorded)


def test_a_finished_run_is_known_by_its_recorded_settings(trained: TrainResult, tmp_path: Path) -> None:
    """`finished_with`, which every stage that reuses a run asks: the settings recorded, those ignored aside, and the
    evaluation written; a config.json cut short reads as no settings."""
    folder = tmp_path / "policy"
    shutil.copytree(trained.policy_dir, folder)
    settings = policy_files.training_settings(folder)
    assert settings["lr"] == 1e-3 and settings["made_by"] == "bc.train"
    assert not policy_files.finished_with(folder, settings)  # no eval.json: not finished
    (folder / policy_files.EVAL_FILE).write_text("{}")
    assert policy_files.finished_with(folder, settings)
    assert not policy_files.finished_with(folder, {**settings, "lr": 3e-4})
    assert policy_files.finished_with(folder, {**settings, "lr": 3e-4}, ignored={"lr"})
    (folder / policy_files.CONFIG_FILE).write_text('{"training": {"lr"')
    assert policy_files.training_settings(folder) == {}
    assert not policy_files.finished_with(folder, {"lr": 1e-3})


def test_tensorboard_holds_the_config_as_text(trained: TrainResult) -> None:
    """The run's settings are in its TensorBoard logs as text: the JSON of config.json's settings."""
    settings = json.loads(textwrap.dedent(tensorboard_text(trained.policy_dir / TENSORBOARD_DIR, CONFIG_TAG)))
    training = json.loads((trained.policy_dir / policy_files.CONFIG_FILE).read_text())["training"]
    assert settings == {name: training[name] for name in settings}
    assert set(settings) >= {field.name for field in dataclasses.fields(TrainConfig)} | {"made_by"}


def test_saved_policy_is_a_controller(trained: TrainResult, env: gym.Env) -> None:
    """The controller registry builds a checkpoint folder into a controller giving float32 actions within bounds."""
    controller = make_controller(str(trained.policy_dir), env)
    assert isinstance(controller, PolicyController)
    action = controller.act(env.reset(seed=0)[0])
    assert action.dtype == np.float32 and action.shape == (17,) and np.abs(action).max() <= 0.4
    validate(RecordConfig(controller=str(trained.policy_dir)))  # the recorder accepts it too
    with pytest.raises(UserError, match="not a policy checkpoint"):
        validate(RecordConfig(controller=str(trained.policy_dir / TENSORBOARD_DIR)))


def test_failed_save_keeps_the_old_checkpoint(trained: TrainResult, tmp_path: Path) -> None:
    """An error while writing a replacement leaves the old checkpoint and no staging folder."""
    folder = tmp_path / "policy"
    shutil.copytree(trained.policy_dir, folder)
    before = snapshot(folder)
    with pytest.raises(RuntimeError), checkpoint.staged(folder, overwrite=True) as staging:
        checkpoint.save(trained.policy, staging, {}, {})
        raise RuntimeError("interrupted")
    assert snapshot(folder) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy"]


def test_a_kill_between_the_replacements_renames_loses_no_checkpoint(trained: TrainResult, tmp_path: Path) -> None:
    """Killed after moving the old checkpoint aside and before the new one took its place: the next run finds the old
    one back where it was (refused without --overwrite, replaced with it), and nothing left aside."""
    folder = tmp_path / "policy"
    shutil.copytree(trained.policy_dir, folder)
    before = snapshot(folder)
    folder.rename(tmp_path / ".policy.replaced")  # what the kill leaves
    with pytest.raises(checkpoint.CheckpointError, match="already holds a checkpoint"):
        with checkpoint.staged(folder, overwrite=False):
            pass
    assert snapshot(folder) == before
    folder.rename(tmp_path / ".policy.replaced")
    with checkpoint.staged(folder, overwrite=True) as staging:
        checkpoint.save(trained.policy, staging, {"new": True}, {})
    assert json.loads((folder / policy_files.CONFIG_FILE).read_text())["training"] == {"new": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy"]


def test_a_run_stopped_in_its_evaluation_publishes_nothing(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The evaluation runs before the checkpoint is published: stopped there, no checkpoint without its eval.json."""

    def stopped(*_: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(bc_train, "evaluation_of", stopped)
    with pytest.raises(KeyboardInterrupt):
        main(TrainConfig(dataset=recorded, policy=tmp_path / "policy", **{**TINY, "epochs": 1, "eval_episodes": 1}))
    assert list(tmp_path.iterdir()) == []


def test_a_killed_runs_staging_folder_is_removed_by_the_next_run(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The hidden folder a run killed mid-save leaves goes with the next run for the same checkpoint; a live run's,
    another machine's and another checkpoint's stay."""
    ended = subprocess.Popen(["true"])
    ended.wait()  # a process of this machine that no longer runs
    host = socket.gethostname()
    abandoned = tmp_path / f".policy.{host}-{ended.pid}.0badf00d.partial"
    kept = [
        tmp_path / f".policy.{host}-{os.getpid()}.0badf00d.partial",  # a live run
        tmp_path / f".policy.elsewhere-{ended.pid}.0badf00d.partial",  # another machine's
        tmp_path / f".policy.b.{host}-{ended.pid}.0badf00d.partial",  # checkpoint policy.b's
    ]
    for folder in [abandoned, *kept]:
        folder.mkdir()
        (folder / "model.safetensors").write_bytes(b"half")
    code, _ = train_cli(["--dataset", str(recorded), "--policy", str(tmp_path / "policy")], capsys)
    assert code == 0 and (tmp_path / "policy").is_dir() and not abandoned.exists()
    assert all((folder / "model.safetensors").read_bytes() == b"half" for folder in kept)


def test_existing_checkpoint_is_kept_without_overwrite(
    trained: TrainResult, recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Training into an existing checkpoint fails in one line and leaves it as it was; --overwrite replaces it."""
    folder = tmp_path / "policy"
    shutil.copytree(trained.policy_dir, folder)
    before = snapshot(folder)
    code, err = train_cli(["--dataset", str(recorded), "--policy", str(folder)], capsys)
    assert code == 1 and len(err) == 1 and "--overwrite" in err[0]
    assert snapshot(folder) == before
    code, err = train_cli(["--dataset", str(recorded), "--policy", str(folder), "--overwrite", "true"], capsys)
    assert code == 0
    assert json.loads((folder / policy_files.CONFIG_FILE).read_text())["policy"]["hidden"] == [8, 8]


def test_folder_that_is_not_a_checkpoint_is_never_replaced(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """POLICY naming some other folder is refused even with --overwrite, and the folder is untouched."""
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "todo.txt").write_text("keep me")
    code, err = train_cli(["--dataset", str(recorded), "--policy", str(folder), "--overwrite", "true"], capsys)
    assert code == 1 and len(err) == 1 and "not a policy checkpoint" in err[0]
    assert snapshot(folder) == {"todo.txt": b"keep me"}


def edited_copy(recorded: Path, tmp_path: Path, edit: Callable[[dict], object]) -> Path:
    """A copy of the recording whose info.json went through `edit`."""
    root = tmp_path / "edited"
    shutil.copytree(recorded, root)
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    edit(info)
    info_path.write_text(json.dumps(info))
    return root


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda info: info["features"]["action"].update(shape=[12]), "action dimensions"),
        (lambda info: info["features"].pop("observation.environment_state"), "no observation.environment_state"),
        (lambda info: info.update(codebase_version="v2.1"), "LeRobot v2.1 dataset"),
        (lambda info: info.update(total_episodes=1), "at least 2"),
    ],
)
def test_incompatible_dataset_is_refused(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], edit: Callable[[dict], object], message: str
) -> None:
    """A dataset that cannot train a Humanoid-v5 policy fails in one line, and no checkpoint appears."""
    root = edited_copy(recorded, tmp_path, edit)
    code, err = train_cli(["--dataset", str(root), "--policy", str(tmp_path / "policy")], capsys)
    assert code == 1 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "policy").exists()


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("min-updates", "-1", "must be >= 0, got -1"),
        ("seed", "-1", "must be a seed, at least 0 and below 2**32, got -1"),
        ("seed", str(2**70), f"must be a seed, at least 0 and below 2**32, got {2**70}"),  # torch would overflow
    ],
)
def test_counts_and_seeds_out_of_range_are_refused(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, value: str, message: str
) -> None:
    code, err = train_cli(["--dataset", str(recorded), "--policy", str(tmp_path / "p"), f"--{name}", value], capsys)
    assert (code, err) == (1, [f"error: --{name} {message}"])
    assert not (tmp_path / "p").exists()


def test_missing_dataset_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A dataset path with nothing there fails in one line naming it."""
    code, err = train_cli(["--dataset", str(tmp_path / "none"), "--policy", str(tmp_path / "policy")], capsys)
    assert code == 1 and len(err) == 1 and "no LeRobot dataset" in err[0]
    assert not (tmp_path / "policy").exists()


@pytest.fixture(scope="module")
def proprio(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """A small MLP trained on the sensed features of the 3-episode recording."""
    folder = tmp_path_factory.mktemp("policies") / "proprio"
    return main(TrainConfig(dataset=recorded, policy=folder, **{**TINY, "inputs": "proprio"}))


def test_proprio_checkpoint_records_what_it_reads(proprio: TrainResult) -> None:
    config = json.loads((proprio.policy_dir / policy_files.CONFIG_FILE).read_text())
    assert config["policy"]["inputs"] == "proprio" and config["training"]["inputs"] == "proprio"
    assert config["policy"]["input_keys"] == ["observation.state"] and config["policy"]["input_dim"] == 48


def test_proprio_controller_computes_the_recorded_features(proprio: TrainResult, recorded: Path, env: gym.Env) -> None:
    """Run on the gymnasium observation, the controller acts as the policy does on the stored observation.state:
    what the recorder stored is what the controller computes."""
    frames = read_frames(recorded, [columns.OBS_STATE, columns.OBS_ENV_STATE])
    observations = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    controller = make_controller(str(proprio.policy_dir), env)
    with torch.no_grad():
        expected = proprio.policy(torch.from_numpy(frames[columns.OBS_STATE]).float()).numpy()
    sensed = np.array(
        [controller.input_set(controller.input_set.observe(obs, controller.command)) for obs in observations]
    )
    np.testing.assert_array_equal(sensed, frames[columns.OBS_STATE])
    # One row at a time against a batch: float32 matmuls may differ in the last bits.
    actions = np.array([controller.act(obs) for obs in observations[::20]])
    np.testing.assert_allclose(actions, expected[::20], rtol=0, atol=1e-6)


@pytest.fixture(scope="module")
def delayed_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 short expert episodes, every one under a step of action latency: what the "pending" inputs learn from."""
    root = tmp_path_factory.mktemp("delayed") / "dataset"
    record(RecordConfig(dataset=root, episodes=3, max_steps=60, latency=1.0, writer="inline", progress=False))
    return root


@pytest.fixture(scope="module")
def pending(delayed_recording: Path, tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """A small MLP trained on the "pending" inputs (leg odometry, the command in flight, the delay) of the delayed
    recording."""
    folder = tmp_path_factory.mktemp("policies") / "pending"
    return main(TrainConfig(dataset=delayed_recording, policy=folder, **{**TINY, "inputs": "pending"}))


def test_pending_inputs_in_training_are_what_the_controller_computes_live(
    pending: TrainResult, delayed_recording: Path, env: gym.Env
) -> None:
    """The inputs training loads are the ones the saved policy's controller computes step by step out of the
    gymnasium observations, told each episode's delay and each command sent (float32 rows against float64)."""
    config = json.loads((pending.policy_dir / policy_files.CONFIG_FILE).read_text())
    # The sensed features but the forces (42), the estimated height and velocity (4), the inertias (130), the command
    # in flight (17), the delay (1).
    assert config["policy"]["inputs"] == "pending" and config["policy"]["input_dim"] == 42 + 4 + 130 + 17 + 1
    frames = read_frames(delayed_recording, [columns.OBS_STATE, columns.OBS_ENV_STATE, columns.ACTION, "episode_index"])
    observations = join_observation(frames[columns.OBS_STATE], frames[columns.OBS_ENV_STATE])
    delays = episode_delays(delayed_recording)
    assert delays.tolist() == [1, 1, 1]
    trained = load_demonstrations(delayed_recording, env, cache=False, inputs="pending").inputs.numpy()
    controller = make_controller(str(pending.policy_dir), env)
    live = []
    for row, obs in enumerate(observations):
        episode = frames["episode_index"][row]
        if row == 0 or episode != frames["episode_index"][row - 1]:
            controller.set_delay(int(delays[episode]))
            controller.reset()
        live.append(controller.input_set(controller.input_set.observe(obs, controller.command)))
        controller.input_set.sent(frames[columns.ACTION][row])
    live = np.array(live)
    assert np.abs(live[:, -18:-1]).max() > 0  # the command in flight is there, not zeros
    np.testing.assert_allclose(trained, live, rtol=0, atol=1e-4)
    assert np.abs(trained[:, 42 + 1 : 42 + 4]).max() > 0.1  # the estimated velocity moves (the drop from reset)


def test_each_input_set_keeps_its_own_cache(delayed_recording: Path, env: gym.Env) -> None:
    """Two input sets of one dataset read in turn (as PPO's critic does) both come from the cache the second time,
    the same rows as computed."""
    first = {inputs: load_demonstrations(delayed_recording, env, inputs=inputs) for inputs in ("full", "pending")}
    for inputs, loaded in first.items():
        again = load_demonstrations(delayed_recording, env, inputs=inputs)
        assert again.from_cache
        assert torch.equal(again.inputs, loaded.inputs)


def test_dataset_recorded_before_the_sensed_state_is_refused_for_proprio(
    recorded: Path, tmp_path: Path, env: gym.Env, capsys: pytest.CaptureFixture[str]
) -> None:
    """A dataset whose observation.state is qpos[2:] and qvel (45, the earlier layout) cannot train on proprio:
    one line saying so, exit 1, no checkpoint."""
    legacy = observation_names(env.unwrapped.model)[:45]
    root = edited_copy(
        recorded, tmp_path, lambda info: info["features"]["observation.state"].update(shape=[45], names=legacy)
    )
    before = snapshot(root)
    code, err = train_cli(["--dataset", str(root), "--policy", str(tmp_path / "policy"), "--inputs", "proprio"], capsys)
    assert code == 1 and len(err) == 1 and "recorded before" in err[0] and "INPUTS=full" in err[0]
    assert not (tmp_path / "policy").exists() and snapshot(root) == before


def test_unknown_inputs_are_refused_in_one_line(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err = train_cli(
        ["--dataset", str(recorded), "--policy", str(tmp_path / "policy"), "--inputs", "camera"], capsys
    )
    assert code == 1 and len(err) == 1 and "'camera'" in err[0]
    assert not (tmp_path / "policy").exists()


def test_pending_inputs_on_a_dataset_without_latency_are_refused(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """INPUTS=pending on episodes none of which was delayed: one line saying to record with latency, no checkpoint."""
    code, err = train_cli(
        ["--dataset", str(recorded), "--policy", str(tmp_path / "policy"), "--inputs", "pending"], capsys
    )
    assert code == 1 and len(err) == 1 and "LATENCY>0" in err[0]
    assert not (tmp_path / "policy").exists()


def small_demos() -> Demonstrations:
    """Episodes 0 and 2, two frames each, row r holding the value r."""
    rows = torch.arange(4, dtype=torch.float32)[:, None]
    return Demonstrations(Path("demos"), rows, rows, np.array([0, 0, 2, 2]), {}, 0.0, False)


def test_demonstrations_keep_the_frames_of_the_episodes_asked_in_order() -> None:
    demos = small_demos().only([2])
    assert demos.inputs.flatten().tolist() == [2.0, 3.0] and demos.episode_index.tolist() == [2, 2]
    assert small_demos().only([0, 2]).frames == 4


def test_episodes_join_the_demonstrations_after_the_last_one_only() -> None:
    """Rows in memory stay in episode order, as a dataset's are: an index at or before the one before is refused."""
    three, one = np.full((3, 1), 7.0, np.float32), np.full((1, 1), 8.0, np.float32)
    grown = small_demos().with_episodes([(three, three, 3), (one, one, 5)])
    assert grown.episode_index.tolist() == [0, 0, 2, 2, 3, 3, 3, 5] and grown.actions[-4:].flatten().tolist() == [
        7,
        7,
        7,
        8,
    ]
    with pytest.raises(ValueError, match="does not come after"):
        small_demos().with_episodes([(three, three, 2)])
    with pytest.raises(ValueError, match="episode 4 does not come after episode 4"):
        small_demos().with_episodes([(three, three, 4), (one, one, 4)])


def test_a_dataset_several_teachers_labelled_names_them_and_the_one_compared_with(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The student is compared with its teacher; where several labelled the dataset, one line names each (with its
    frames) and the one compared with, the one that labelled the most; where no registered teacher did, the default
    teacher, said the same way. One teacher: no line."""
    mixed = tmp_path / "mixed"
    record_short(mixed, controller="expert", episodes=2, max_steps=20)
    record_short(mixed, controller="expert-sensed", episodes=1, max_steps=20)
    capsys.readouterr()
    assert teacher_of(mixed) == "expert"
    (line,) = capsys.readouterr().err.splitlines()
    assert line == (
        f"note: {mixed} was labelled by expert (40 frames), expert-sensed (20 frames): the student is compared with "
        "expert"
    )
    randomly = tmp_path / "random"
    record_short(randomly, controller="random", episodes=1, max_steps=20)
    capsys.readouterr()
    assert teacher_of(randomly) == TEACHER
    assert capsys.readouterr().err.splitlines()[0].endswith(f"the student is compared with {TEACHER}")
    single = tmp_path / "single"
    record_short(single, controller="expert-sensed", episodes=1, max_steps=20)
    capsys.readouterr()
    assert teacher_of(single) == "expert-sensed" and capsys.readouterr().err == ""
