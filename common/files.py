"""Files written whole: a reader, or a run that a kill -9 stopped mid-write, finds the old file or the new one.

Every file a later run trusts (a dataset's parquet and info, an episode's MCAP, a spooled episode, a run's mark, a
checkpoint's JSON, a tuning run's state) is written here, so that there is one rule for what a kill leaves: at most a
`PARTIAL_SUFFIX` file beside it, which the next run may delete.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

PARTIAL_SUFFIX = ".partial"
"""What a file being written is called until it is complete: its final name and this."""


def write_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """Call `write` on a sibling of `path` named with `PARTIAL_SUFFIX`, then rename it over `path`; if `write` fails,
    the sibling is deleted and `path` is left as it was."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + PARTIAL_SUFFIX)
    try:
        write(partial)
    except BaseException as error:
        partial.unlink(missing_ok=True)  # what a kill leaves, the next run deletes; an error's, this one
        if isinstance(error, OSError) and error.filename is None and error.errno is not None:
            raise OSError(error.errno, error.strerror, str(partial)) from error  # a full disk names no file
        raise
    os.replace(partial, path)
