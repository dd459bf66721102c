"""The package's import graph: no cycle, the methods below the orchestration, short modules.

Every module of the installed package is parsed with :mod:`ast` (nothing is imported), and
each ``import`` / ``from ... import`` that names a module of the package is an edge. Edges
count wherever the statement is: at the top, inside a function (a deferred import is still
a dependency) or under ``if TYPE_CHECKING:`` (an annotation that needs the other module is
a dependency too; a cycle hidden there is the one issue 31 removed between the solver and
the bounded solve). ``from package import name`` is an edge to ``package.name`` when that is
a module, else to ``package``. Importing ``a.b.c`` also runs ``a/__init__`` and
``a/b/__init__`` first; those implicit edges are left out, as a package's ``__init__``
may name its children (``tocontrol_ros.core`` re-exports ``plan`` lazily) without that
being a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import tocontrol_ros

PACKAGE = "tocontrol_ros"
ROOT = Path(tocontrol_ros.__file__).resolve().parent

#: Longest module, in lines (issue 31): a module longer than this holds more than one job.
MAX_LINES = 600

#: The methods and the robot below them never import the orchestration that chooses
#: between them (:mod:`tocontrol_ros.core.solver`).
BELOW_ORCHESTRATION = ("tocontrol_ros.core.robot", "tocontrol_ros.core.indirect",
                       "tocontrol_ros.core.direct", "tocontrol_ros.core.sim")


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = (PACKAGE,) + path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The package's modules that module ``name`` imports (see the module docstring)."""
    is_package = path.name == "__init__.py"
    here = name if is_package else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")
                base = base[: len(base) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:
                child = f"{source}.{alias.name}"
                found.add(child if child in MODULES else source)
    return {target for target in found if target in MODULES and target != name}


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` as a list of modules, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)):
            return found
    return None


def test_the_graph_sees_the_package():
    assert len(MODULES) > 40
    assert "tocontrol_ros.core.direct.limited" in GRAPH["tocontrol_ros.core.solver"]


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = _cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


@pytest.mark.parametrize("layer", BELOW_ORCHESTRATION)
def test_the_methods_never_import_the_orchestration(layer):
    offenders = sorted(name for name, targets in GRAPH.items()
                       if name.startswith(layer) and "tocontrol_ros.core.solver" in targets)
    assert not offenders, offenders


def test_the_core_never_imports_the_nodes():
    offenders = sorted(
        (name, target) for name, targets in GRAPH.items() if name.startswith("tocontrol_ros.core")
        for target in targets if not target.startswith("tocontrol_ros.core"))
    assert not offenders, offenders


def test_no_module_is_longer_than_the_limit():
    lengths = {name: len(path.read_text().splitlines()) for name, path in MODULES.items()}
    long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"
