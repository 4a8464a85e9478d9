"""Writing a figure where a user asked for it: one line, not a traceback, when the path cannot be written."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from common.cli import UserError


def save_figure(figure: Any, path: Path, dpi: int = 100) -> None:
    """Write matplotlib `figure` to `path`, its folder made first; UserError in one line if it cannot be written
    (a read-only folder, a path through a file)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, dpi=dpi)
    except OSError as error:
        raise UserError(f"cannot write {path}: {error.strerror or error}") from None
