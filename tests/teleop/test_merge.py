"""`make merge`: shards recorded apart become the dataset one recorder writes for the same seeds, file for file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from support import SHORT_EPISODE, snapshot
from teleop import recordings
from teleop.merge import MergeConfig, cli, main
from teleop.record import STANDING, RecordConfig, record

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (several recordings)


def record_seeds(root: Path, episodes: int, seed: int, randomize: str = "none") -> Path:
    """`make record`'s session, its recordings.jsonl line included."""
    settings = {"max_steps": SHORT_EPISODE, "writer": "inline", "progress": False, "randomize": randomize}
    record(RecordConfig(dataset=root, episodes=episodes, seed=seed, **settings, **STANDING))
    return root


@pytest.fixture(scope="module")
def shards(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """Seeds 0..2 and 3..5 recorded apart (randomised bodies, so the drawn parameters travel too), and 0..5 at once."""
    root = tmp_path_factory.mktemp("shards")
    return (
        record_seeds(root / "shard_0", 3, 0, "suite"),
        record_seeds(root / "shard_1", 3, 3, "suite"),
        record_seeds(root / "whole", 6, 0, "suite"),
    )


def files(root: Path) -> dict[str, bytes]:
    """The dataset's files but recordings.jsonl, whose lines say who wrote them (a merge, a recording)."""
    return {name: content for name, content in snapshot(root).items() if name != recordings.RECORDINGS_FILE}


def merge(shards: list[Path], dataset: Path) -> int:
    return main(MergeConfig(shards=" ".join(map(str, shards)), dataset=dataset, progress=False))


def test_merged_shards_are_the_one_recorders_files(shards: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """Given in any order, the shards merge into every file of the one-go recording, byte for byte."""
    first, second, whole = shards
    assert merge([second, first], tmp_path / "merged") == 6
    assert files(tmp_path / "merged") == files(whole)


def test_the_merge_logs_itself_with_each_shards_sessions(shards: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """The merged dataset's recordings.jsonl: one line for the merge, holding each shard's own lines, so how its
    episodes were recorded travels with them."""
    first, second, _ = shards
    merge([second, first], tmp_path / "merged")
    (line,) = recordings.read(tmp_path / "merged")
    assert (line["made_by"], line["complete"], line["episodes"], line["seeds"]) == (
        "teleop.merge",
        True,
        [0, 5],
        [0, 5],
    )
    assert line[recordings.SESSIONS_KEY] == {str(shard): recordings.read(shard) for shard in (second, first)}
    assert [run["config"]["randomize"] for run in recordings.expanded([line])] == ["suite", "suite"]
    assert not (tmp_path / "merged" / recordings.RUN_FILE).exists()


def test_a_merge_cut_short_continues_where_it_stopped(shards: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """A merged dataset holding the first seeds only (a merge killed there) gets the rest, and nothing twice."""
    first, second, whole = shards
    merge([first], tmp_path / "merged")
    assert merge([first, second], tmp_path / "merged") == 3
    assert merge([first, second], tmp_path / "merged") == 0
    assert files(tmp_path / "merged") == files(whole)


@pytest.mark.parametrize(
    ("which", "message"),
    [
        ("overlapping", "are already in"),
        ("not a dataset", "is not a dataset"),
        ("other episodes", "holds other episodes than the first 3 of these shards' seeds: merge into a new DATASET"),
        ("twice", "names {first} twice: give each shard once"),
        ("itself", "a shard cannot be merged into itself"),
        ("no episode", "no episode was committed to it"),
        ("killed", "holds what a killed run left (its mark, .spool)"),
        ("cut-short info", "meta/info.json is not readable JSON"),
        ("missing MCAP", "lacks mcap/"),
    ],
)
def test_bad_shards_are_refused_in_one_line_and_nothing_changes(
    shards: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str, message: str
) -> None:
    first, second, whole = shards
    target = tmp_path / "merged"
    given = {
        "overlapping": [first, whole],
        "not a dataset": [first, tmp_path / "nothing"],
        "other episodes": [second],
        "itself": [first, target],
        "twice": [first, second, first],
        "no episode": [first, tmp_path / "opened"],  # what a first session refused or killed early leaves
        "killed": [first, tmp_path / "killed"],  # a parallel recording killed with an episode finished past a gap
        "cut-short info": [first, tmp_path / "copied"],  # copies between nodes cut short
        "missing MCAP": [first, tmp_path / "copied"],
    }[which]
    if which in ("cut-short info", "missing MCAP"):
        shutil.copytree(second, tmp_path / "copied")
        if which == "cut-short info":
            (tmp_path / "copied/meta/info.json").write_text('{"codebase_version": ')
        else:
            next((tmp_path / "copied/mcap").rglob("*.mcap")).unlink()
    if which == "killed":
        shutil.copytree(second, tmp_path / "killed")
        recordings.mark(tmp_path / "killed", "teleop.record", {}, episodes=3)
        (tmp_path / "killed/.spool").mkdir()
        (tmp_path / "killed/.spool/000000000007.npz").write_bytes(b"an episode")
    if which == "no episode":
        (tmp_path / "opened/meta").mkdir(parents=True)
        shutil.copy(first / "meta/info.json", tmp_path / "opened/meta/info.json")
    if which in ("other episodes", "itself"):
        merge([first], target)  # seeds 0..2, which shard_1 (3..5) does not start with
    before = snapshot(target) if target.exists() else None
    code = cli(["--shards", " ".join(map(str, given)), "--dataset", str(target), "--progress", "false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and message.format(first=first) in err[0], err
    assert (snapshot(target) if target.exists() else None) == before
