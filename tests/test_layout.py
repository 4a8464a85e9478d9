"""The project's own imports go one way: no cycle between modules or between top-level packages.

Function-level imports count too: deferring an import hides a cycle from Python, not from a reader.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from common.digest import imported_names

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = (
    "common",
    "policies",
    "humanoid",
    "task",
    "teachers",
    "students",
    "rollout",
    "teleop",
    "evaluation",
    "bc",
    "rl",
    "pipeline",
    "bench",
    "tests",
)
"""Bottom to top: a package may import only those before it (and itself): the body, the task, the teachers, the
students' inputs, the rollout that runs any of them, then the stages."""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules() -> dict[str, Path]:
    return {module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


def imported(path: Path, modules: dict[str, Path]) -> set[str]:
    """The project modules `path` imports anywhere in its body (module level, functions, TYPE_CHECKING)."""
    return {name for name in imported_names(path) if name in modules}


def import_graph() -> dict[str, set[str]]:
    modules = project_modules()
    return {name: imported(path, modules) - {name} for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of `graph` as a list of nodes (first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for succ in sorted(graph.get(node, ())):
            if state.get(succ) == 1:
                return path[path.index(succ) :] + [succ]
            if succ not in state and (cycle := visit(succ)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_find_cycle_finds_a_known_cycle() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_cycle_between_modules() -> None:
    assert find_cycle(import_graph()) is None


def test_packages_import_only_those_below() -> None:
    wrong = [
        f"{name} imports {target}"
        for name, targets in import_graph().items()
        for target in targets
        if PACKAGES.index(target.split(".")[0]) > PACKAGES.index(name.split(".")[0])
    ]
    assert wrong == []


def test_the_students_inputs_import_no_teacher() -> None:
    """What a student computes (its inputs, the hand-over flag among them) lives below the teachers: a student reads
    the rule its teacher runs (`task.handover`), never a teacher's internals."""
    graph = import_graph()
    assert {t for name, targets in graph.items() if name.startswith("students") for t in targets} & {
        name for name in graph if name.startswith("teachers")
    } == set()


def test_common_imports_nothing_of_ours() -> None:
    graph = import_graph()
    assert {
        t for name, targets in graph.items() if name.startswith("common") for t in targets if not t.startswith("common")
    } == set()


def test_every_module_parses_with_the_python_3_11_grammar() -> None:
    """The workplace's own checks (an import-cycle check among them) read the code with Python 3.11's parser."""
    newer = []
    for path in project_modules().values():
        try:
            ast.parse(path.read_text(), str(path), feature_version=(3, 11))
        except SyntaxError as error:
            newer.append(f"{path.relative_to(ROOT)}:{error.lineno}: {error.msg}")
    assert newer == []


def test_datasets_folder_is_not_a_package() -> None:
    """`import datasets` must stay HuggingFace's: the data folder holds no Python."""
    assert not list((ROOT / "datasets").glob("*.py"))
    result = subprocess.run(
        [sys.executable, "-c", "import datasets; print(datasets.__file__)"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    assert "site-packages" in result.stdout


def test_recorder_and_writer_start_without_torch() -> None:
    """Checking a recording, building the random controller and the writer process's modules leave torch unimported."""
    code = (
        "import sys; from teleop.record import validate, RecordConfig; import teleop.writer_process; "
        "from rollout.controllers import make_controller; from humanoid.env import make_env; "
        "validate(RecordConfig()); make_controller('random', make_env()); print('torch' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
