"""`common.files.write_atomically`: a write that fails part-way leaves the old file whole and deletes its partial file
(a kill leaves that file, which the next run deletes)."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from common.files import PARTIAL_SUFFIX, write_atomically


def test_a_write_that_fails_leaves_the_old_file_and_no_partial_one(tmp_path: Path) -> None:
    path = tmp_path / "info.json"
    path.write_text("old")

    def cut_short(partial: Path) -> None:
        partial.write_text("ne")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomically(path, cut_short)
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["info.json"]


def test_a_whole_write_replaces_the_file_in_a_new_folder(tmp_path: Path) -> None:
    path = tmp_path / "meta" / "info.json"
    write_atomically(path, lambda partial: partial.write_text("new"))
    assert path.read_text() == "new" and [p.name for p in path.parent.iterdir()] == ["info.json"]


def test_a_full_disk_names_the_file_being_written(tmp_path: Path) -> None:
    """The disk's "no space left" names no file; the error raised names the one being written, for the one line."""

    def full(partial: Path) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError) as raised:
        write_atomically(tmp_path / "stats.json", full)
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == str(tmp_path / f"stats.json{PARTIAL_SUFFIX}")
