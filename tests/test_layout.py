"""The package's shape (docs/architecture.md): small modules, no import cycle, the CLI on top,
and ``baselines`` entered through one door."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tacbench", "baselines")
MAX_LINES = 400


def _modules() -> dict[str, Path]:
    """Every module of the packages, by dotted name (a package by its ``__init__``)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


MODULES = _modules()


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """Every node of ``tree`` but those under ``if TYPE_CHECKING:``."""
    nodes, stack = [], [tree]
    while stack:
        node = stack.pop()
        nodes.append(node)
        if isinstance(node, ast.If) and ast.unparse(node.test).endswith("TYPE_CHECKING"):
            stack.extend(node.orelse)
        else:
            stack.extend(ast.iter_child_nodes(node))
    return nodes


def _imports(name: str, path: Path) -> set[str]:
    """The project modules ``name`` imports at run time, anywhere in its body (lazy imports
    included, ``if TYPE_CHECKING:`` blocks not)."""
    found = set()
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert not node.level, f"{path}: a relative import; the project imports absolutely"
            module = node.module or ""
            targets = [f"{module}.{alias.name}" for alias in node.names] + [module]
        else:
            continue
        found |= {t for t in targets if t in MODULES and t != name}
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _enclosing_packages(name: str) -> set[str]:
    parts = name.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts))}


def test_no_module_is_over_the_line_limit() -> None:
    sizes = {name: len(path.read_text().splitlines()) for name, path in MODULES.items()}
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}, "split them by job"


def test_no_import_cycle() -> None:
    """A module importing its own package's ``__init__`` is how a package exposes its parts,
    not a cycle; any other loop in the import graph is."""
    state: dict[str, str] = {}

    def visit(name: str, trail: list[str]) -> None:
        state[name] = "open"
        for target in sorted(GRAPH[name] - _enclosing_packages(name)):
            if state.get(target) == "open":
                cycle = [*trail[trail.index(target) :], target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target, [*trail, target])
        state[name] = "done"

    for name in sorted(GRAPH):
        if name not in state:
            visit(name, [name])


def test_nothing_below_the_cli_imports_it() -> None:
    importers = sorted(
        name
        for name, targets in GRAPH.items()
        if not name.startswith(("tacbench.cli", "tacbench.__main__"))
        and any(t == "tacbench.cli" or t.startswith("tacbench.cli.") for t in targets)
    )
    assert importers == []


def test_baselines_is_imported_from_one_place_in_tacbench() -> None:
    importers = sorted(
        name
        for name, targets in GRAPH.items()
        if name.startswith("tacbench")
        and any(t == "baselines" or t.startswith("baselines.") for t in targets)
    )
    assert importers == ["tacbench.trainers"]
