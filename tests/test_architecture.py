"""The code's shape: no import cycles between lidarfuzz's modules, none between its packages.

Every ``import`` counts, the function-local ones included (a cycle hidden inside a function is
still a cycle: the two modules cannot be understood or changed apart). Imports under
``if TYPE_CHECKING:`` do not run and are left out. The graph is read from the source with
:mod:`ast`, so nothing is imported.
"""

from __future__ import annotations

import ast
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "lidarfuzz"


def _modules() -> dict[str, Path]:
    found = {}
    for path in sorted((SRC / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes inside ``if TYPE_CHECKING:`` blocks."""
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skipped.update(id(inner) for stmt in node.body for inner in ast.walk(stmt))
    return skipped


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The lidarfuzz modules that module ``name`` imports (anywhere in it)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = _type_checking_only(tree)
    targets: list[str] = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            targets += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            targets += [f"{module}.{a.name}" if f"{module}.{a.name}" in modules else module for a in node.names]
    out = set()
    for target in targets:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target.startswith(PACKAGE) and target != name:
            out.add(target)
    return out


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imported(name, path, modules) for name, path in modules.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    try:
        tuple(TopologicalSorter(graph).static_order())
    except CycleError as exc:
        return list(exc.args[1])
    return None


def test_the_graph_is_read():
    graph = import_graph()
    # a known edge, so that an empty or broken graph cannot pass the checks below
    assert "lidarfuzz.scene.boxes" in graph["lidarfuzz.scene.scene"]
    assert len(graph) > 100


def test_no_import_cycle_between_modules():
    cycle = _cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_no_import_cycle_between_packages():
    def package(module: str) -> str:
        parts = module.split(".")
        return ".".join(parts[:2])

    graph: dict[str, set[str]] = {}
    for module, targets in import_graph().items():
        graph.setdefault(package(module), set()).update(
            package(t) for t in targets if package(t) != package(module) and package(t) != PACKAGE)
    cycle = _cycle(graph)
    assert cycle is None, "packages import each other: " + " -> ".join(cycle or [])


@pytest.mark.parametrize("source, expected", [
    ("import lidarfuzz.scene.boxes\n", {"lidarfuzz.scene.boxes"}),
    ("def f():\n    from lidarfuzz.scene import boxes\n", {"lidarfuzz.scene.boxes"}),
    ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from lidarfuzz.scene import boxes\n", set()),
    ("from .boxes import Boxes3D\n", {"lidarfuzz.scene.boxes"}),
])
def test_imports_are_found_where_they_hide(tmp_path, source, expected):
    path = tmp_path / "probe.py"
    path.write_text(source)
    assert _imported("lidarfuzz.scene.probe", path, _modules()) == expected
