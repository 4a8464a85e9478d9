"""`make record RANDOMIZE=...`: each episode's physical parameters drawn from its seed, stored in both formats."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from common import columns
from humanoid.conditions import PRESETS, DomainRandomization
from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import run_episode
from support import STANDING_FLAGS, mcap_parameters, read_mcap_episode, record_short, snapshot
from teleop import recordings
from teleop.dataset_reader import read_episodes, read_frames, read_parameters
from teleop.inspect_dataset import InspectConfig
from teleop.inspect_dataset import main as inspect
from teleop.record import DART_NOISE, STANDING, RecordConfig, cli, record
from teleop.spool import Spool
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

STEPS = 60
SUITE = PRESETS["suite"]


def record_here(root: Path, **settings: object) -> None:
    """A short in-process recording of 2 episodes with the suite's randomisation unless told otherwise."""
    record_short(root, **{"episodes": 2, "max_steps": STEPS, "randomize": "suite", **settings})


@pytest.fixture(scope="module")
def randomized(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 episodes (seeds 0, 1) recorded with RANDOMIZE=suite through the writer process, as `make record` does."""
    root = tmp_path_factory.mktemp("randomized") / "dataset"
    record(RecordConfig(dataset=root, episodes=2, max_steps=STEPS, randomize="suite", progress=False, **STANDING))
    return root


def wrapper_draw(seed: int) -> dict:
    """What `DomainRandomization` draws for `seed` with the suite's ranges, outside any recording."""
    env = DomainRandomization(make_env(STEPS), SUITE)
    try:
        return env.reset(seed=seed)[1]["parameters"]
    finally:
        env.close()


def test_the_same_seed_gives_the_same_draw(randomized: Path, tmp_path: Path) -> None:
    """Recording seeds 0 and 1 again stores the same draws: the wrapper's for each seed, different per seed."""
    record_here(tmp_path / "again")
    stored, again = read_parameters(randomized), read_parameters(tmp_path / "again")
    assert stored == again == [wrapper_draw(0), wrapper_draw(1)]
    assert stored[0] != stored[1]


def test_the_draw_round_trips_through_parquet_mcap_and_lerobot(randomized: Path) -> None:
    """Every episode's draw reads back the same from its episode columns, its MCAP metadata and LeRobot's loader."""
    drawn = read_parameters(randomized)
    assert [set(parameters) for parameters in drawn] == [{"mass_scale", "friction_scale", "strength_scale"}] * 2
    assert all(len(p["mass_scale"]) == 13 and len(p["strength_scale"]) == 17 for p in drawn)
    assert all(isinstance(p["friction_scale"], float) for p in drawn)
    rows = read_episodes(randomized).to_pylist()
    assert [mcap_parameters(randomized / row[columns.EPISODE_MCAP]) for row in rows] == drawn
    loaded = LeRobotDataset("local/randomized", root=randomized)
    for name in drawn[0]:
        assert list(loaded.meta.episodes[columns.RANDOMIZATION_PREFIX + name]) == [p[name] for p in drawn]
    assert len(loaded) == len(read_frames(randomized, ["index"])["index"])


def test_the_recorded_episode_is_the_rollout_in_the_randomised_body(randomized: Path) -> None:
    """The stored frames are those of the expert under `DomainRandomization`, and differ from the nominal body's."""
    frames = read_frames(randomized, [columns.ACTION, "episode_index"])
    stored = frames[columns.ACTION][frames["episode_index"] == 0]
    env = DomainRandomization(make_env(STEPS), SUITE)
    episode = run_episode(env, make_controller("expert", env), seed=0, noise_std=DART_NOISE)
    np.testing.assert_array_equal(stored, episode.action)
    nominal_env = make_env(STEPS)
    nominal = run_episode(nominal_env, make_controller("expert", nominal_env), seed=0, noise_std=DART_NOISE)
    steps = min(len(stored), nominal.length)
    assert not np.array_equal(stored[:steps], nominal.action[:steps])


def test_a_plain_recording_gains_no_column_nor_metadata(recorded: Path) -> None:
    """RANDOMIZE=none (the default): no randomization.* column, no such MCAP metadata key."""
    rows = read_episodes(recorded).to_pylist()
    assert not [name for name in rows[0] if name.startswith(columns.RANDOMIZATION_PREFIX)]
    metadata = read_mcap_episode(recorded / rows[0][columns.EPISODE_MCAP]).metadata
    assert not [name for name in metadata if name.startswith(columns.RANDOMIZATION_PREFIX)]
    assert read_parameters(recorded) == [{}, {}, {}]


def test_the_spool_keeps_the_draw(tmp_path: Path) -> None:
    """A randomised episode left in the spool by a killed parallel recording is committed with its draw."""
    root = tmp_path / "dataset"
    root.mkdir()
    env = DomainRandomization(make_env(STEPS), SUITE)
    episode = run_episode(env, make_controller("expert", env), seed=4)
    Spool(root).put(episode)
    EpisodeStore(root, DatasetSpec.from_env(env, SUITE.parameters)).close()
    assert read_parameters(root) == [episode.parameters] == [wrapper_draw(4)]
    assert not (root / ".spool").exists()


@pytest.mark.parametrize(
    "first, then, message",
    [
        ("none", "suite", "holds episodes without domain randomisation, these would be with mass, friction, strength"),
        ("suite", "none", "holds episodes with mass, friction, strength randomised, these would be without"),
        ("suite", "mass=0.9:1.1", "these would be with mass randomised: a dataset does not mix them"),
    ],
)
def test_a_dataset_does_not_mix_randomised_and_plain_episodes(
    first: str, then: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Appending with other randomised parameters than the dataset's: one line, exit 1, the dataset unchanged."""
    root = tmp_path / "dataset"
    record_here(root, episodes=1, randomize=first)
    before = snapshot(root)
    args = ["--dataset", str(root), "--max-steps", str(STEPS), "--randomize", then, "--progress", "false"]
    code = cli([*args, *STANDING_FLAGS])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and message in err[0], err
    assert snapshot(root) == before


def test_other_ranges_of_the_same_parameters_append(randomized: Path, tmp_path: Path) -> None:
    """The columns stay the same with other ranges: `mild` appends to a `suite` dataset, drawing inside its own."""
    root = tmp_path / "dataset"
    shutil.copytree(randomized, root)
    record_here(root, episodes=1, randomize="mild")
    added = read_parameters(root)[-1]
    assert len(read_parameters(root)) == 3
    assert 0.7 <= added["friction_scale"] <= 1.3 and all(0.9 <= s <= 1.1 for s in added["mass_scale"])


@pytest.mark.parametrize(
    "text, message",
    [
        ("wild", "--randomize 'wild': unknown preset; presets: none, mild, suite"),
        ("gravity=0.9:1.1", "--randomize 'gravity=0.9:1.1': unknown parameter 'gravity'"),
        ("mass=1.2:0.8", "--randomize 'mass=1.2:0.8': mass range has low 1.2 > high 0.8"),
        ("friction=-0.5:1.5", "--randomize 'friction=-0.5:1.5': friction scales must be >= 0, got -0.5"),
        ("mass=0.8-1.2", "--randomize 'mass=0.8-1.2': 'mass=0.8-1.2' is not NAME=LOW:HIGH"),
    ],
)
def test_bad_randomize_is_refused_before_touching_the_disk(
    text: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An unknown preset or parameter, low > high, a negative scale, malformed text: one line, exit 1, no folder."""
    code = cli(["--dataset", str(tmp_path / "new"), "--randomize", text, "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and err[0].startswith(f"error: {message}"), err
    assert not (tmp_path / "new").exists()


def test_the_keyboard_is_refused_with_randomisation(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Teleoperation solves its postures on the live model: it records the nominal body only."""
    code = cli(["--dataset", str(tmp_path / "new"), "--controller", "keyboard", "--randomize", "mild"])
    assert code == 1
    message = "error: --controller keyboard records the nominal body: --randomize must be none"
    assert capsys.readouterr().err.strip() == message
    assert not (tmp_path / "new").exists()


def test_the_run_log_holds_the_setting_and_its_ranges(randomized: Path) -> None:
    """recordings.jsonl: the --randomize text in the config, and the ranges it stood for."""
    (line,) = recordings.read(randomized)
    assert line["config"]["randomize"] == "suite"
    assert line["randomization"] == {"mass": [0.8, 1.2], "friction": [0.5, 1.5], "strength": [0.8, 1.2]}


def test_inspect_shows_the_ranges_drawn(randomized: Path) -> None:
    """`make inspect` lists each drawn parameter with the smallest and largest value over the episodes."""
    report = inspect(InspectConfig(dataset=randomized, lerobot=False))
    drawn = read_parameters(randomized)
    friction = [p["friction_scale"] for p in drawn]
    mass = np.concatenate([p["mass_scale"] for p in drawn])
    strength = np.concatenate([p["strength_scale"] for p in drawn])
    assert report.randomized == {
        "mass_scale": f"{mass.min():.3f}..{mass.max():.3f} (13 per episode)",
        "friction_scale": f"{min(friction):.3f}..{max(friction):.3f}",
        "strength_scale": f"{strength.min():.3f}..{strength.max():.3f} (17 per episode)",
    }
    assert "randomised  mass_scale: " in report.summary()
