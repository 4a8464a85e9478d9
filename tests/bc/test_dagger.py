"""`make dagger`: policy rollouts labelled by the expert, appended as rounds, the demonstrations untouched."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import torch

from bc.dagger import (
    ROUNDS,
    SOURCE_FILE,
    DaggerConfig,
    DaggerResult,
    DAggerTrainer,
    check_settings,
    cli,
    expert_of,
    is_aggregate,
    main,
    recorded_conditions,
    resolved,
    rounds_of,
    settle_spool,
)
from bc.data import load_demonstrations
from bc.train import TrainConfig
from bc.train import main as train
from common import columns
from common.cli import DatasetError, UserError, config_dict
from humanoid.conditions import LATENCY_PARAMETER, NO_RANDOMIZATION, recording_condition
from humanoid.env import make_env
from policies import checkpoint
from policies.folder import CONFIG_FILE
from rollout.episode import injected_noise, run_episode
from students.inputs import INPUT_SETS, INPUTS
from support import committed_episodes, drawn_delay, join_observation, snapshot, wait_for_episodes
from teachers.expert import LQRExpert, SensedExpert
from teachers.registry import TEACHER, TEACHERS, WALKING_TEACHER
from teleop import recordings
from teleop.dataset_reader import fingerprint, read_episodes, read_frames, read_parameters
from teleop.merge import MergeConfig
from teleop.merge import main as merge_datasets
from teleop.parallel import RolloutSettings, Simulator
from teleop.record import RecordConfig, record
from teleop.spool import DAGGER_SPOOL, Spool
from teleop.store import CommittedEpisode, DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)


STANDING_DAGGER = {"inputs": "full", "expert": "expert", "noise": 0.0, "epochs": 30}
"""DAgger on the standing recipe's demonstrations (the `recorded` fixture): the full-state student, the expert told
the simulator's state labelling, no noise on the rollouts."""
ONE_ROUND = {"rounds": 1, "episodes": 2, "min_updates": 0, "eval_episodes": 0, "progress": False, **STANDING_DAGGER}
"""A tiny DAgger run: one round of 2 episodes, each training exactly its epochs, no final evaluation."""


@pytest.fixture(scope="module")
def dagger(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, DaggerResult, dict]:
    """One DAgger round of 2 episodes on a copy of the 3-episode recording, the student on the sensed features
    (the privileged expert teaching a proprioceptive student)."""
    folder = tmp_path_factory.mktemp("dagger")
    demonstrations = folder / "demonstrations"
    shutil.copytree(recorded, demonstrations)
    before = snapshot(demonstrations)
    output = folder / "aggregate"
    config = DaggerConfig(
        dataset=demonstrations, output=output, policy=folder / "policy", **{**ONE_ROUND, "inputs": "proprio"}
    )
    result = main(config)
    return demonstrations, output, result, before, config


def test_rounds_are_appended_after_the_demonstrations(dagger: tuple) -> None:
    """The aggregate holds the demonstrations (round 0) then the round's policy episodes, seeds continuing."""
    _, output, result, _, _ = dagger
    episodes = read_episodes(output).to_pylist()
    assert [e[columns.EPISODE_DAGGER_ROUND] for e in episodes] == [0, 0, 0, 1, 1]
    assert [e[columns.EPISODE_SEED] for e in episodes] == [0, 1, 2, 3, 4]
    assert [e[columns.EPISODE_LABELLER] for e in episodes] == ["expert"] * 5
    assert episodes[0][columns.EPISODE_CONTROLLER] == "expert"
    assert all(e[columns.EPISODE_CONTROLLER] != "expert" for e in episodes[3:])  # the policy drove
    assert [r.round for r in result.rounds] == [1]
    assert result.rounds[0].frames == sum(e["length"] for e in episodes[3:])


def assert_labelled_by(expert: LQRExpert | SensedExpert, frames: dict[str, np.ndarray], episodes: list[dict]) -> None:
    """Each episode's labels are `expert`'s actions along its stored observations, the expert reset at the
    episode's start as the rollout resets it (its landing plan and estimator run from there)."""
    for episode in episodes:
        rows = frames["episode_index"] == episode["episode_index"]
        expert.reset(episode[columns.EPISODE_SEED])
        observations = join_observation(frames[columns.OBS_STATE][rows], frames[columns.OBS_ENV_STATE][rows])
        labels = np.stack([expert.act(obs) for obs in observations])
        np.testing.assert_array_equal(frames[columns.ACTION][rows], labels)


def test_labels_are_the_experts_actions_in_the_policys_states(dagger: tuple) -> None:
    """Every DAgger frame's label is what the expert does in the stored state; what ran was the policy's action."""
    _, output, _, _, _ = dagger
    frames = read_frames(output)
    assert_labelled_by(LQRExpert(), frames, read_episodes(output).to_pylist()[3:])
    rows = frames["episode_index"] >= 3
    assert not np.array_equal(frames[columns.EXECUTED_ACTION][rows], frames[columns.ACTION][rows])


def sensed_run(dataset: Path, folder: Path, inputs: str) -> DaggerConfig:
    """ONE_ROUND on `dataset` into `folder`, labelled by the expert on leg odometry, the student on `inputs`."""
    return DaggerConfig(
        dataset=dataset,
        output=folder / "aggregate",
        policy=folder / "policy",
        **{**ONE_ROUND, "inputs": inputs, "expert": "expert-sensed"},
    )


@pytest.fixture(scope="module")
def sensed_dagger(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One round of 2 episodes labelled by the expert on leg odometry, a "proprio" student (the recording has no
    delay for "pending" to learn from): the aggregate."""
    config = sensed_run(recorded, tmp_path_factory.mktemp("sensed_dagger"), "proprio")
    main(config)
    return config.output


def test_the_sensed_expert_labels_each_episode_from_its_start(sensed_dagger: Path) -> None:
    """EXPERT=expert-sensed: each round episode's labels are the sensed expert's actions along it, its estimator
    reset at the episode's start; the labeller column names it."""
    episodes = read_episodes(sensed_dagger).to_pylist()
    assert [e[columns.EPISODE_LABELLER] for e in episodes] == ["expert"] * 3 + ["expert-sensed"] * 2
    assert_labelled_by(SensedExpert(), read_frames(sensed_dagger), episodes[3:])


def test_the_aggregate_loads_from_the_cache_as_computed(sensed_dagger: Path) -> None:
    """The run leaves its aggregate's rows (held in memory) in the decoded-frames cache: the next load as the student's
    inputs reads them from there, equal to the rows computed from the files."""
    cached = load_demonstrations(sensed_dagger, make_env(), inputs="proprio")
    computed = load_demonstrations(sensed_dagger, make_env(), cache=False, inputs="proprio")
    assert cached.from_cache and not computed.from_cache
    torch.testing.assert_close(cached.inputs, computed.inputs, rtol=0, atol=0)
    torch.testing.assert_close(cached.actions, computed.actions, rtol=0, atol=0)
    np.testing.assert_array_equal(cached.episode_index, computed.episode_index)


def test_demonstrations_are_left_unchanged_and_a_policy_is_saved(dagger: tuple) -> None:
    """DATASET is only read; the final policy is a loadable checkpoint trained on the aggregate, on the inputs asked."""
    demonstrations, output, result, before, _ = dagger
    assert snapshot(demonstrations) == before
    assert result.final.train_frames + result.final.val_frames == len(read_frames(output, ["index"])["index"])
    assert checkpoint.load(result.final.policy_dir).spec.inputs == "proprio"


AS_RECORDED = {"randomize": "none", "latency": 0.0}
"""The conditions the test recording ran under: DAgger's rollouts take them when RANDOMIZE and LATENCY are unset."""


def test_final_checkpoint_records_the_dagger_settings(dagger: tuple) -> None:
    """The final policy's config.json holds every DaggerConfig field beside its training's (the rollout conditions
    as resolved from the dataset), and who ran it."""
    *_, config = dagger
    training = json.loads((config.policy / CONFIG_FILE).read_text())["training"]
    assert training["dagger"] == {**config_dict(config), **AS_RECORDED} and training["made_by"] == "bc.dagger"


def test_the_aggregate_and_the_checkpoint_name_the_demonstrations_copied(dagger: tuple) -> None:
    """OUTPUT's demonstrations.json holds DATASET's path and fingerprint and who copied it; the checkpoint records the
    same fingerprint, which `make pipeline` compares with the dataset's before reusing either."""
    demonstrations, output, *_, config = dagger
    source = json.loads((output / SOURCE_FILE).read_text())
    assert source == {"path": str(demonstrations), "fingerprint": fingerprint(demonstrations), "made_by": "bc.dagger"}
    training = json.loads((config.policy / CONFIG_FILE).read_text())["training"]
    assert training["demonstrations"] == source["fingerprint"]


def test_another_training_seed_fits_other_policies_from_the_same_rollout_seeds(dagger: tuple, tmp_path: Path) -> None:
    """SEED is every fit's seed (initial weights, split, minibatches), not the rollouts': the same episode seeds, other
    weights."""
    demonstrations, output, result, _, config = dagger
    other = dataclasses.replace(config, output=tmp_path / "aggregate", policy=tmp_path / "policy", seed=1)
    weights = main(other).final.policy.state_dict()
    seeds = [columns.EPISODE_SEED]
    assert read_episodes(other.output, seeds).to_pylist() == read_episodes(output, seeds).to_pylist()
    assert any(not torch.equal(weights[name], value) for name, value in result.final.policy.state_dict().items())


def test_aggregate_logs_the_rounds_in_recordings_jsonl(dagger: tuple) -> None:
    """OUTPUT/recordings.jsonl ends with the DAgger run's line: its settings and the episodes the round added."""
    _, output, _, _, config = dagger
    line = recordings.read(output)[-1]
    assert (line["made_by"], line["config"], line["complete"]) == (
        "bc.dagger",
        {**config_dict(config), **AS_RECORDED},
        True,
    )
    assert (line["episodes"], line["seeds"], line["count"]) == ([3, 4], [3, 4], 2)


def test_output_equal_to_dataset_is_refused(recorded: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """DAgger never appends to the demonstrations themselves."""
    code = cli(["--dataset", str(recorded), "--output", str(recorded), "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "--output must differ from --dataset" in err[0]


@pytest.mark.parametrize("kind", ["folder", "file"])
def test_an_output_that_is_not_a_dataset_is_refused_and_left_alone(
    recorded: Path, tmp_path: Path, kind: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """An OUTPUT holding something else (a folder with a file, or a file): one line, and it stays as it was."""
    output = tmp_path / "mine"
    if kind == "folder":
        output.mkdir()
        (output / "notes.txt").write_text("keep")
    else:
        output.write_text("keep")
    before = snapshot(tmp_path)
    code = cli(
        ["--dataset", str(recorded), "--output", str(output), "--policy", str(tmp_path / "p"), "--progress", "false"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "holds no LeRobot dataset" in err[0]
    assert snapshot(tmp_path) == before and not (tmp_path / "p").exists()


def test_an_output_holding_a_dataset_dagger_did_not_copy_is_refused_and_left_alone(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """OUTPUT holding a recording of its own (no copy of DATASET, no round): one line, and it stays as it was; a
    resume would have appended the rounds to it."""
    output = tmp_path / "other"
    shutil.copytree(recorded, output)
    before = snapshot(tmp_path)
    code = cli(
        ["--dataset", str(recorded), "--output", str(output), "--policy", str(tmp_path / "p"), "--progress", "false"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "holds a dataset DAgger did not copy" in err[0], err
    assert snapshot(tmp_path) == before and not (tmp_path / "p").exists()


def test_an_aggregate_copied_before_its_source_file_existed_is_still_dagger_s(dagger: tuple, tmp_path: Path) -> None:
    """An aggregate with rounds but no demonstrations.json (copied by an earlier version) is DAgger's own: it resumes;
    its demonstrations alone, without the file, are a recording, and so is a merge of it."""
    _, output, _, _, _ = dagger
    older = tmp_path / "older"
    shutil.copytree(output, older)
    (older / SOURCE_FILE).unlink()
    assert is_aggregate(output) and is_aggregate(older) and not is_aggregate(tmp_path / "missing")
    copied = tmp_path / "copied"
    shutil.copytree(dagger[0], copied)
    assert not is_aggregate(copied)
    merged = tmp_path / "merged"  # a merge holding an aggregate's rounds: copied from no DATASET of a run
    merge_datasets(MergeConfig(shards=str(output), dataset=merged, progress=False))
    assert not is_aggregate(merged)


def test_the_final_policy_is_the_one_train_bc_fits_on_the_aggregate(dagger: tuple, tmp_path: Path) -> None:
    """The rounds' frames held in memory are the ones on disk: `make train-bc` on OUTPUT with the same settings gives
    the final policy's weights exactly."""
    _, output, result, _, config = dagger
    again = TrainConfig(
        dataset=output,
        policy=tmp_path / "again",
        inputs=config.inputs,
        epochs=config.epochs,
        min_updates=0,
        eval_episodes=0,
        progress=False,
        cache=False,
    )
    fitted = train(again).policy.state_dict()
    for name, weights in result.final.policy.state_dict().items():
        torch.testing.assert_close(weights, fitted[name], rtol=0, atol=0)


STEPS = 40
"""Steps of the delayed recording's episodes and of the rollouts on it."""


@pytest.fixture(scope="module")
def delayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """4 expert episodes (seeds 0..3: delayed, delayed, not, delayed) recorded with LATENCY=0.5."""
    root = tmp_path_factory.mktemp("delayed") / "dataset"
    record(RecordConfig(dataset=root, episodes=4, max_steps=STEPS, latency=0.5, writer="inline", progress=False))
    return root


def one_round(
    delayed: Path, root: Path, inputs: str, latency: float, expert: str, episodes: int, waiting: Sequence[int] = ()
) -> DAggerTrainer:
    """A copy of `delayed` at `root`, a policy on `inputs` fitted to it, and one round of `episodes` rollouts (seeds
    4 on) under `latency`, labelled by `expert`, appended to `root`; the seeds `waiting` rolled out beforehand and
    left in the spool, as a killed run leaves episodes it finished beyond one it had not."""
    shutil.copytree(delayed, root)
    condition = recording_condition("none", latency)
    env = condition.wrap(make_env(STEPS))
    training = TrainConfig(inputs=inputs, epochs=1, min_updates=0, progress=False)
    rollouts = RolloutSettings("dagger", 0.0, STEPS, condition, labeller=TEACHERS[expert])
    demos = load_demonstrations(root, env, cache=False, inputs=inputs)
    trainer = DAggerTrainer(demos, training, rollouts, env.action_space)
    store = EpisodeStore(root, DatasetSpec.from_env(env, (LATENCY_PARAMETER,)))
    try:
        trainer.train()
        simulator = Simulator(dataclasses.replace(trainer.rollouts, controller="dagger:round0", policy=trainer.policy))
        for seed in waiting:
            Spool(root, DAGGER_SPOOL).put(simulator.run(seed))
        trainer.collect(store, round_index=1, episodes=episodes)
    finally:
        trainer.close()
        store.close()
        env.close()
    return trainer


@pytest.mark.parametrize("inputs", INPUTS)
def test_round_frames_in_memory_equal_the_frames_read_back(delayed: Path, inputs: str, tmp_path: Path) -> None:
    """A round's episodes (seeds 4, 5: one delayed, one not) join the aggregate in memory exactly as
    `load_demonstrations` reads them from the dataset they were appended to, for every kind of input."""
    root = tmp_path / "aggregate"
    trainer = one_round(delayed, root, inputs, latency=0.5, expert="expert-sensed", episodes=2)
    delays = [drawn[LATENCY_PARAMETER] for drawn in read_parameters(root)[4:]]
    assert delays == [drawn_delay(4), drawn_delay(5)] and sorted(delays) == [0, 1]  # both kinds of episode
    read_back = load_demonstrations(root, make_env(), cache=False, inputs=inputs)
    np.testing.assert_array_equal(trainer.demos.episode_index, read_back.episode_index)
    torch.testing.assert_close(trainer.demos.inputs, read_back.inputs, rtol=0, atol=0)
    torch.testing.assert_close(trainer.demos.actions, read_back.actions, rtol=0, atol=0)


def test_an_episode_left_waiting_is_committed_in_its_turn(delayed: Path, tmp_path: Path) -> None:
    """A round's episode left in OUTPUT's spool beyond one not rolled out yet (seed 5, not 4) is committed in its
    seed's turn, not rolled out again: the aggregate, on disk and in memory, is the one of a round never broken."""
    unbroken = one_round(delayed, tmp_path / "unbroken", "pending", 0.5, "expert-sensed", episodes=2)
    resumed = one_round(delayed, tmp_path / "resumed", "pending", 0.5, "expert-sensed", episodes=2, waiting=[5])
    assert not (tmp_path / "resumed" / DAGGER_SPOOL).exists()
    names = [columns.EPISODE_SEED, "length", columns.EPISODE_RETURN, columns.EPISODE_CONTROLLER]
    episodes = [read_episodes(tmp_path / name, names).to_pylist() for name in ("unbroken", "resumed")]
    assert episodes[0] == episodes[1] and [e[columns.EPISODE_SEED] for e in episodes[1]] == [0, 1, 2, 3, 4, 5]
    for key in (columns.ACTION, columns.EXECUTED_ACTION, columns.OBS_STATE):
        np.testing.assert_array_equal(read_frames(tmp_path / "resumed")[key], read_frames(tmp_path / "unbroken")[key])
    torch.testing.assert_close(resumed.demos.inputs, unbroken.demos.inputs, rtol=0, atol=0)


def test_a_spool_no_killed_dagger_run_left_is_dropped(delayed: Path, tmp_path: Path) -> None:
    """Spooled episodes without the mark of a killed DAgger run (removed to go on with other settings) are no round
    of the next run: dropped."""
    root = tmp_path / "aggregate"
    shutil.copytree(delayed, root)
    Spool(root, DAGGER_SPOOL).put(run_episode(make_env(STEPS), LQRExpert(), seed=4))
    settle_spool(root, committed=4)
    assert not (root / DAGGER_SPOOL).exists()


def test_a_delayed_rounds_action_in_flight_is_what_the_policy_sent(delayed: Path, tmp_path: Path) -> None:
    """In a delayed round episode the "pending" inputs carry, at each step, the action the rolled-out policy sent the
    step before (`executed_action`: no rollout noise), as its inputs did live; not the expert's label."""
    root = tmp_path / "aggregate"
    trainer = one_round(delayed, root, "pending", latency=1.0, expert="expert", episodes=1)
    names = INPUT_SETS["pending"].input_names(make_env().unwrapped.model)
    in_flight = [i for i, name in enumerate(names) if name.startswith("pending.")]
    rows = trainer.demos.episode_index == 4
    pending = trainer.demos.inputs[rows][:, in_flight].numpy()
    frames = read_frames(root, [columns.ACTION, columns.EXECUTED_ACTION])
    episode = read_frames(root, ["episode_index"])["episode_index"] == 4
    sent, labels = frames[columns.EXECUTED_ACTION][episode], frames[columns.ACTION][episode]
    np.testing.assert_array_equal(pending[0], 0.0)  # as ActionLatency: nothing sent before the first step
    np.testing.assert_array_equal(pending[1:], sent[:-1])
    assert np.abs(sent - labels).max() > 1e-3  # the policy's actions are not the expert's


def test_rollouts_run_under_the_conditions_the_dataset_was_recorded_in(delayed: Path, tmp_path: Path) -> None:
    """Without RANDOMIZE and LATENCY, DAgger takes the recording's (recordings.jsonl): its rollouts draw their delays
    as `make record LATENCY=0.5` does, and the settings it logs say so."""
    config = sensed_run(delayed, tmp_path, "pending")
    main(config)
    seeds = read_episodes(config.output, [columns.EPISODE_SEED])[columns.EPISODE_SEED].to_pylist()
    delays = [drawn[LATENCY_PARAMETER] for drawn in read_parameters(config.output)]
    assert delays == [drawn_delay(seed) for seed in seeds] and len(seeds) > 4  # the round's rollouts too
    line = recordings.read(config.output)[-1]
    assert (line["config"]["randomize"], line["config"]["latency"]) == (NO_RANDOMIZATION, 0.5)


def test_rollouts_under_other_conditions_are_refused_before_anything_is_written(
    delayed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """LATENCY=0 on a dataset whose episodes draw their delay: one line, exit != 0, no OUTPUT."""
    output = tmp_path / "aggregate"
    code = cli(["--dataset", str(delayed), "--output", str(output), "--latency", "0", "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "give the conditions it was recorded in" in err[0]
    assert not output.exists()


def test_recordings_under_several_conditions_need_them_given(tmp_path: Path) -> None:
    """Known answers of `recorded_conditions`: a line from before LATENCY existed recorded none; two differing
    recordings are refused; a merge line (no conditions in its config) does not count."""
    root = tmp_path / "dataset"
    root.mkdir()
    recordings.append(root, "teleop.record", {"randomize": "mild"}, [CommittedEpisode(0, 0, 1, 0.0, False)], True)
    recordings.append(root, "teleop.merge", {"shards": ["a", "b"]}, [CommittedEpisode(1, 1, 1, 0.0, False)], True)
    assert recorded_conditions(root) == ("mild", 0.0)
    recordings.append(
        root, "teleop.record", {"randomize": "mild", "latency": 0.5}, [CommittedEpisode(2, 2, 1, 0.0, False)], True
    )
    with pytest.raises(DatasetError, match="several conditions"):
        recorded_conditions(root)


def test_conditions_given_stand_whatever_the_recordings_say(recorded: Path, tmp_path: Path) -> None:
    """RANDOMIZE and LATENCY given are not read from the recordings, which may hold several (a DAgger run under
    other settings drawing the same parameters): only the episodes' drawn parameters are checked against them."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    for index, randomize in enumerate(("mild", "suite")):  # both draw the same parameters
        episode = CommittedEpisode(3 + index, 3 + index, 1, 0.0, False)
        recordings.append(root, "teleop.record", {"randomize": randomize}, [episode], True)
    given = DaggerConfig(
        dataset=root, output=tmp_path / "out", randomize="none", latency=0.0, expert=TEACHER, rounds=ROUNDS
    )
    assert resolved(given) == given
    with pytest.raises(DatasetError, match="several conditions"):
        resolved(dataclasses.replace(given, latency=None))


def test_a_merged_dataset_is_read_by_its_shards_recordings(tmp_path: Path) -> None:
    """A merge's line carries each shard's lines: their conditions are the merged dataset's."""
    root = tmp_path / "dataset"
    root.mkdir()
    shard = {"made_by": "teleop.record", "config": {"randomize": "suite", "latency": 0.5}}
    sessions = {recordings.SESSIONS_KEY: {"a": [shard], "b": [shard]}}
    episode = CommittedEpisode(0, 0, 1, 0.0, False)
    recordings.append(root, "teleop.merge", {"shards": "a b"}, [episode], True, sessions)
    assert recorded_conditions(root) == ("suite", 0.5)


def test_rollout_noise_goes_with_each_round_episode(recorded: Path, tmp_path: Path) -> None:
    """NOISE: the round's episodes are rolled out with that noise on the executed actions, and say so: the first
    executed action of each is the same round policy's without noise plus the episode's drawn noise (clipped)."""
    first: dict[float, list[np.ndarray]] = {}
    for noise in (0.0, 0.05):
        config = DaggerConfig(dataset=recorded, output=tmp_path / f"aggregate{noise}", policy=tmp_path / f"p{noise}")
        main(dataclasses.replace(config, **{**ONE_ROUND, "noise": noise}))
        rounds = read_episodes(config.output).to_pylist()[3:]
        assert [e[columns.EPISODE_NOISE_STD] for e in rounds] == [noise, noise]
        frames = read_frames(config.output, [columns.EXECUTED_ACTION, "episode_index", "frame_index"])
        starts = (frames["frame_index"] == 0) & (frames["episode_index"] >= 3)
        first[noise] = list(frames[columns.EXECUTED_ACTION][starts])
    env = make_env()
    for episode, clean, noisy in zip(rounds, first[0.0], first[0.05], strict=True):
        drawn = injected_noise(episode[columns.EPISODE_SEED], 1, 0.05, clean.size)[0]
        expected = np.clip(clean + drawn, env.action_space.low, env.action_space.high)
        np.testing.assert_allclose(noisy, expected, atol=1e-6)
        assert np.abs(noisy - clean).max() > 0.02
    env.close()


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--noise", "-0.1"),
        ("--noise", "nan"),
        ("--noise", "inf"),
        ("--seed", "-1"),
        ("--seed", str(2**70)),
        ("--kick", "-0.4"),
        ("--latency", "1.5"),
        ("--randomize", "heavy"),
        ("--workers", "0"),
        ("--inputs", "pending"),  # learns to act through latency: the recording has none
        ("--inputs", "full+command"),  # learns to follow a command: the recording's never changes
        ("--inputs", "pending+walk"),  # learns to walk: the recording commands no walk
    ],
)
def test_bad_rollout_settings_are_refused(
    recorded: Path, tmp_path: Path, option: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    output = tmp_path / "aggregate"
    code = cli(["--dataset", str(recorded), "--output", str(output), option, value, "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and option in err[0]
    assert not output.exists()


def test_a_walking_student_is_labelled_by_the_walker_in_more_rounds_unless_told_otherwise() -> None:
    """No --expert: the teacher on leg odometry labels a posture student and the walker on it a walking student;
    --expert names who labels, and one that does not walk is refused for a walking student in one line. No --rounds:
    6 for a posture student, 12 for a walking one; --rounds stands."""
    assert rounds_of(DaggerConfig()) == ROUNDS == 6 and rounds_of(DaggerConfig(inputs="pending+gait")) == 12
    assert rounds_of(DaggerConfig(inputs="pending+gait", rounds=2)) == 2
    assert expert_of(DaggerConfig()) == TEACHER == "expert-sensed"
    assert expert_of(DaggerConfig(inputs="pending+gait")) == WALKING_TEACHER == "walker-sensed"
    assert expert_of(DaggerConfig(inputs="pending+walk")) == WALKING_TEACHER
    assert expert_of(DaggerConfig(inputs="pending+gait", expert="walker")) == "walker"
    with pytest.raises(UserError, match="--expert expert-sensed does not: give --expert"):
        check_settings(DaggerConfig(inputs="pending+gait", expert="expert-sensed"))


TWO_ROUNDS = {"rounds": 2, "episodes": 3, "min_updates": 0, "eval_episodes": 0, "progress": False, **STANDING_DAGGER}


def as_flags(config: DaggerConfig) -> list[str]:
    """The command line of `config`'s settings that differ from the defaults."""
    default = config_dict(DaggerConfig())
    return [
        part
        for name, value in config_dict(config).items()
        if value != default[name]
        for part in (f"--{name.replace('_', '-')}", str(value).lower() if isinstance(value, bool) else str(value))
    ]


def kill_in_round_one(config: DaggerConfig) -> None:
    """`python -m bc.dagger` of `config`, killed with SIGKILL once OUTPUT holds the recording's 3 episodes and a
    round-1 episode."""
    process = subprocess.Popen(
        [sys.executable, "-m", "bc.dagger", *as_flags(config)],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        wait_for_episodes(config.output, 4, process)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def test_a_run_killed_mid_round_and_run_again_ends_as_an_unbroken_run(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """kill -9 once the first round's first episode is on disk, then the same command: the aggregate holds the same
    episodes, frame for frame, and the final policy has the same weights as a run never interrupted. Run again with
    another NOISE first: one line naming the killed run's, exit != 0, OUTPUT as it was."""
    unbroken = DaggerConfig(dataset=recorded, output=tmp_path / "unbroken", policy=tmp_path / "p1", **TWO_ROUNDS)
    expected = main(unbroken).final.policy.state_dict()
    broken = dataclasses.replace(unbroken, output=tmp_path / "broken", policy=tmp_path / "p2")
    kill_in_round_one(broken)
    killed_at = committed_episodes(broken.output)
    assert killed_at < 3 + 2 * 3 and not broken.policy.exists()  # killed mid-way

    before = snapshot(broken.output)
    capsys.readouterr()
    code = cli([*as_flags(broken), "--noise", "0.05"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "killed with --noise 0.0" in err[0]
    assert snapshot(broken.output) == before

    resumed = main(broken).final.policy.state_dict()
    killed, finishing = recordings.read(broken.output)  # the killed run's episodes get their line too
    assert (killed["complete"], killed["episodes"], finishing["complete"]) == (False, [3, killed_at - 1], True)
    assert finishing["episodes"] == [killed_at, 3 + 2 * 3 - 1] and not (broken.output / recordings.RUN_FILE).exists()
    names = [columns.EPISODE_SEED, columns.EPISODE_DAGGER_ROUND, "length", columns.EPISODE_RETURN]
    assert read_episodes(broken.output, names).to_pylist() == read_episodes(unbroken.output, names).to_pylist()
    for key in (columns.ACTION, columns.EXECUTED_ACTION, columns.OBS_STATE):
        np.testing.assert_array_equal(read_frames(broken.output)[key], read_frames(unbroken.output)[key])
    for name, weights in expected.items():
        torch.testing.assert_close(resumed[name], weights, rtol=0, atol=0)
