"""`python -m teleop.inspect_dataset`: the summary, the PNG, and the first problem of a damaged dataset."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from matplotlib import image

from common import columns
from humanoid.env import make_env
from rollout.episode import run_episode
from support import snapshot
from teachers.expert import LQRExpert
from teleop.dataset_reader import read_episodes, read_info
from teleop.inspect_dataset import PLOT_NAME, cli
from teleop.lerobot_io.format import INFO_PATH
from teleop.record import STANDING, RecordConfig, record
from teleop.spool import DAGGER_SPOOL, SPOOL_DIR, Spool

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class Run:
    """One command-line inspection: its exit code, stdout and stderr."""

    code: int
    out: str
    err: str


def inspect(*argv: str | Path) -> Run:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli([str(arg) for arg in argv])
    return Run(code, out.getvalue(), err.getvalue())


@dataclass(frozen=True)
class CleanRun:
    root: Path
    run: Run
    before: dict[str, bytes]
    after: dict[str, bytes]


@pytest.fixture(scope="module")
def clean(recorded: Path, tmp_path_factory: pytest.TempPathFactory) -> CleanRun:
    """The whole inspection (LeRobot's loader and the PNG included) of an undamaged copy, run once."""
    root = tmp_path_factory.mktemp("inspect") / "dataset"
    shutil.copytree(recorded, root)
    before = snapshot(root)
    run = inspect("--dataset", root, "--plot", "true")
    return CleanRun(root, run, before, snapshot(root))


@pytest.fixture
def copy(recorded: Path, tmp_path: Path) -> Path:
    """A copy of the recorded dataset, to damage."""
    root = tmp_path / "dataset"
    shutil.copytree(recorded, root)
    return root


def assert_fails(run: Run, *fragments: str) -> None:
    assert run.code != 0, run.out
    lines = run.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), run.err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def data_file(root: Path, episode: int) -> Path:
    row = read_episodes(root, ["data/chunk_index", "data/file_index"]).to_pylist()[episode]
    return root / read_info(root)["data_path"].format(
        chunk_index=row["data/chunk_index"], file_index=row["data/file_index"]
    )


def rewrite_column(path: Path, column: str, change: Callable[[np.ndarray], None]) -> None:
    """Apply `change` to a NumPy copy of `column` (rows, or rows x n) and write the parquet file back."""
    table = pq.read_table(path)
    array = table[column].combine_chunks()
    if pa.types.is_fixed_size_list(array.type):
        values = array.flatten().to_numpy().reshape(len(array), array.type.list_size).copy()
        change(values)
        new = pa.FixedSizeListArray.from_arrays(
            pa.array(values.reshape(-1), array.type.value_type), array.type.list_size
        )
    else:
        values = array.to_numpy().copy()
        change(values)
        new = pa.array(values, array.type)
    pq.write_table(table.set_column(table.schema.get_field_index(column), column, new), path)


def test_clean_dataset_passes_with_a_summary(clean: CleanRun) -> None:
    """An undamaged recording exits 0 and its summary names the episodes, frames and features."""
    assert clean.run.code == 0, clean.run.err
    out = clean.run.out
    assert "episodes    3 (seeds 0..2)" in out
    assert f"frames      {read_info(clean.root)['total_frames']:,}" in out
    for feature in (columns.OBS_STATE, columns.OBS_ENV_STATE, columns.ACTION, columns.EXECUTED_ACTION, columns.REWARD):
        assert feature in out
    assert "LeRobot loads it" in out and "3/3 files readable" in out


def test_plot_writes_a_png(clean: CleanRun) -> None:
    """--plot true writes DATASET/inspect.png: a PNG that decodes to a non-blank image."""
    path = clean.root / PLOT_NAME
    assert str(path) in clean.run.out
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    pixels = image.imread(path)
    assert pixels.shape[0] > 300 and pixels.shape[1] > 300 and pixels.std() > 0.05


def test_a_plot_path_that_cannot_be_written_is_refused_in_one_line(recorded: Path, tmp_path: Path) -> None:
    """--plot-path through a file: one line naming the path, a non-zero exit, no traceback."""
    (tmp_path / "a_file").write_text("")
    path = tmp_path / "a_file/x.png"
    run = inspect("--dataset", recorded, "--lerobot", "false", "--plot", "true", "--plot-path", path)
    err = run.err.strip().splitlines()
    assert run.code != 0 and len(err) == 1 and err[0].startswith(f"error: cannot write {path}: ")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--plot-path", "{tmp}/x.png"], "--plot-path names where --plot true draws: give --plot true too"),
        (["--plot", "true", "--plot-path", "{tmp}/x.txt"], "--plot-path must be a .png file's path"),
        (["--plot", "true", "--plot-path", "{tmp}"], "--plot-path must be a .png file's path"),
    ],
)
def test_a_plot_path_the_plot_cannot_take_is_refused_before_the_inspection(
    recorded: Path, tmp_path: Path, args: list[str], message: str
) -> None:
    run = inspect("--dataset", recorded, "--lerobot", "false", *(arg.format(tmp=tmp_path) for arg in args))
    err = run.err.strip().splitlines()
    assert run.code == 1 and err == [f"error: {message}, got {args[-1].format(tmp=tmp_path)}"] and not run.out.strip()
    assert not any(tmp_path.iterdir())


def test_inspection_writes_nothing_but_the_png(clean: CleanRun) -> None:
    """Every file of the dataset is left byte for byte as it was; the PNG is the only new one."""
    assert set(clean.after) - set(clean.before) == {PLOT_NAME}
    assert {name: clean.after[name] for name in clean.before} == clean.before


def test_recording_sessions_are_listed(tmp_path: Path) -> None:
    """The summary lists each session of recordings.jsonl: who recorded which episodes (and the dataset passes)."""
    root = tmp_path / "logged"
    for episodes in (2, 1):
        record(RecordConfig(dataset=root, episodes=episodes, max_steps=30, writer="inline", progress=False, **STANDING))
    run = inspect("--dataset", root, "--lerobot", "false")
    sessions = [line for line in run.out.splitlines() if "teleop.record at " in line]
    assert run.code == 0 and len(sessions) == 2 and sessions[0].startswith("sessions    ")
    assert sessions[0].endswith(": episodes 0..1") and sessions[1].endswith(": episodes 2..2")


def test_each_spool_is_named_with_what_the_next_run_makes_of_it(copy: Path) -> None:
    """Episodes a killed DAgger round left in its spool are named as its, not counted among the recorder's leftovers:
    only `make dagger` commits them (`teleop.spool.DAGGER_SPOOL`)."""
    spool = Spool(copy, DAGGER_SPOOL)
    spool.put(run_episode(make_env(20), LQRExpert(), seed=7))
    (spool.folder / "000000000008.npz.partial").write_bytes(b"cut short")
    run = inspect("--dataset", copy, "--lerobot", "false")
    assert run.code == 0, run.err
    assert f"{DAGGER_SPOOL} holds 1 finished episodes and 1 partial files (the next `make dagger`" in run.out
    assert "interrupted recording" not in run.out and f"{SPOOL_DIR} holds" not in run.out


def test_nan_in_a_frame_is_named(copy: Path) -> None:
    """A NaN in one frame's observation.state fails, naming the episode, frame and column."""
    rewrite_column(data_file(copy, 1), columns.OBS_STATE, lambda values: values.__setitem__((5, 3), np.nan))
    assert_fails(inspect("--dataset", copy), "episode 1, frame 5", "observation.state[3]", "nan")


def test_failure_still_prints_the_summary(copy: Path) -> None:
    """The summary goes to stdout before the problem, so the user sees both."""
    rewrite_column(data_file(copy, 0), columns.ACTION, lambda values: values.__setitem__((0, 0), np.inf))
    run = inspect("--dataset", copy)
    assert_fails(run, "episode 0, frame 0", "action[0]", "inf")
    assert "episodes    3" in run.out and "verified" not in run.out


def test_deleted_mcap_file_is_named(copy: Path) -> None:
    """A missing MCAP file fails, naming the episode and the file."""
    (copy / "mcap" / "episode_000002.mcap").unlink()
    assert_fails(inspect("--dataset", copy), "episode 2", "mcap/episode_000002.mcap", "missing")


def test_truncated_mcap_file_is_named(copy: Path) -> None:
    """An MCAP file cut in half (a copy interrupted) fails as truncated."""
    path = copy / "mcap" / "episode_000001.mcap"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert_fails(inspect("--dataset", copy), "episode 1", "mcap/episode_000001.mcap", "truncated")


def test_total_frames_off_by_one_is_named(copy: Path) -> None:
    """info.json counting one frame more than the episodes hold fails on total_frames."""
    info = json.loads((copy / INFO_PATH).read_text())
    info["total_frames"] += 1
    (copy / INFO_PATH).write_text(json.dumps(info, indent=4))
    assert_fails(inspect("--dataset", copy), "total_frames", str(info["total_frames"]))


def test_parquet_reward_differing_from_mcap_is_named(copy: Path) -> None:
    """One reward moved by one ulp in parquet (the episode's return still agrees) fails on the exact MCAP comparison."""
    rewrite_column(
        data_file(copy, 0), columns.REWARD, lambda values: values.__setitem__(10, np.nextafter(values[10], np.inf))
    )
    assert_fails(
        inspect("--dataset", copy), "episode 0", "mcap/episode_000000.mcap", "/step.reward", columns.REWARD, "frame 10"
    )


def test_missing_dataset_is_one_line(tmp_path: Path) -> None:
    """A folder that does not exist fails with one line, and nothing is created."""
    missing = tmp_path / "nothing-here"
    run = inspect("--dataset", missing)
    assert_fails(run, str(missing), "does not exist")
    assert run.out == "" and not missing.exists()
