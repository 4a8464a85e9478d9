"""What a computation's code is: the source of a module and of every project module it imports, at any depth.

A cache of computed results is keyed by it (`students.inputs.computation_digest`: the inputs computed from recorded
frames), so that changing any code the computation runs, a threshold in a module three imports away included, misses
the cache; a hand-kept list of modules went stale once (a trigger's module was missing from it). The imports are read
from the source (function-level ones too), as `tests/test_layout.py` reads them.
"""

from __future__ import annotations

import ast
import hashlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
"""The checkout: the project's packages are its folders."""


def module_file(module: str, root: Path = ROOT) -> Path | None:
    """The source file of `module` under `root` (a package's `__init__.py`), None if it is not the project's."""
    path = root.joinpath(*module.split("."))
    for candidate in (path / "__init__.py", path.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def imported_names(path: Path) -> set[str]:
    """Every module name `path` imports anywhere in its body (module level, functions, TYPE_CHECKING): `import a.b`
    names a.b, `from a import b` names a and a.b (b may be a module)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names |= {f"{node.module}.{alias.name}" for alias in node.names} | {node.module}
    return names


def source_closure(module: str, root: Path = ROOT) -> dict[str, Path]:
    """`module` and every project module it imports, directly or through others: name -> source file."""
    found: dict[str, Path] = {}
    pending = [module]
    while pending:
        name = pending.pop()
        if name in found or (path := module_file(name, root)) is None:
            continue
        found[name] = path
        pending += sorted(imported_names(path))
    return found


def source_digest(module: str, root: Path = ROOT) -> str:
    """A digest of the source of `module` and of every project module it imports at any depth (`source_closure`)."""
    digest = hashlib.sha256()
    for name, path in sorted(source_closure(module, root).items()):
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]
