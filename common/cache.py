"""Arrays computed once and kept on disk: `load_or_build` (the LQR gains, the landing plan, the standing pose).

A file per kind and key under `common.paths.cache_dir`; the key says everything the arrays depend on (the model, the
settings, the library versions and BLAS kernels), so a stale file is never read: it is rebuilt and replaced.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import tempfile
import zipfile
from collections.abc import Callable
from typing import TypeVar

import numpy as np

from common.paths import cache_dir

log = logging.getLogger(__name__)

T = TypeVar("T")  # what load_or_build caches (a TypeVar, not 3.12's syntax: tests/test_layout.py says why)


def load_or_build(kind: str, key: str, cls: type[T], build: Callable[[], T]) -> T:
    """The dataclass of arrays ``cls`` cached under ``key`` (a file per kind and key), or ``build()`` written there."""
    path = cache_dir() / f"{kind}-{key[:16]}.npz"
    fields = [f.name for f in dataclasses.fields(cls)]
    try:
        with np.load(path) as cached:
            if str(cached["key"]) == key:
                return cls(**{name: cached[name] for name in fields})
    # Missing, truncated, or written by an older format:
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as error:
        log.debug("no usable cache at %s: %s", path, error)

    built = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Write-then-rename, so concurrent processes never read a half-written file.
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as tmp:
            np.savez(tmp, key=key, **dataclasses.asdict(built))
        os.replace(tmp.name, path)
    except OSError as error:
        log.warning("could not cache %s at %s: %s", kind, path, error)
    return built
