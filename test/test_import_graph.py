"""The package's import graph: no cycle, layers that point down only, no private names used.

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

import tocontrol_ros

PACKAGE = "tocontrol_ros"
ROOT = Path(tocontrol_ros.__file__).resolve().parent

#: A generous guard, not a target: rooms are cut to jobs (issue 48), and a module this long
#: certainly holds more than one.
MAX_LINES = 900

#: The layers of the package, bottom first (docs/architecture.md): a module may import its
#: own layer's modules and those of the layers below, never one above. Folders are layers;
#: the peers of one layer (``direct`` and ``indirect``) are listed as layers of their own in
#: the order in which they may import each other (the maximum principle starts from the
#: direct method's guess). Each entry is a module or a package prefix; the longest prefix
#: that matches a module decides its layer (the package itself, ``tocontrol_ros``, matches
#: only its ``__init__``).
LAYERS = (
    ("foundation", ("tocontrol_ros", "tocontrol_ros.core.errors", "tocontrol_ros.core.validate",
                    "tocontrol_ros.core.examples", "tocontrol_ros.core.memo")),
    ("robot", ("tocontrol_ros.core.robot",)),
    ("geometry", ("tocontrol_ros.core.geometry",)),
    ("types", ("tocontrol_ros.core.types",)),
    ("simulation", ("tocontrol_ros.core.sim",)),
    ("checks", ("tocontrol_ros.core.checks",)),
    ("method contract", ("tocontrol_ros.core.methods",)),
    ("direct methods", ("tocontrol_ros.core.direct",)),
    ("indirect method", ("tocontrol_ros.core.indirect",)),
    ("planning", ("tocontrol_ros.core.planning",)),
    ("memory", ("tocontrol_ros.core.memory",)),
    ("core's face", ("tocontrol_ros.core",)),
    ("nodes", ("tocontrol_ros.nodes",)),
    ("recording", ("tocontrol_ros.recording",)),
    ("batch", ("tocontrol_ros.batch",)),
    ("memory tools", ("tocontrol_ros.memory",)),
    ("entry points", ("tocontrol_ros.demo", "tocontrol_ros.planner", "tocontrol_ros.tracker",
                      "tocontrol_ros.recorder", "tocontrol_ros.replay", "tocontrol_ros.report",
                      "tocontrol_ros.figures", "tocontrol_ros.reindex",
                      "tocontrol_ros.single_blas")),
)


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


def _layer(name: str) -> int:
    """Index in :data:`LAYERS` of the layer that holds module ``name``."""
    best, index = "", -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            inside = prefix != PACKAGE and name.startswith(prefix + ".")
            if (name == prefix or inside) and len(prefix) > len(best):
                best, index = prefix, i
    return index


def test_the_graph_sees_the_package():
    assert len(MODULES) > 40
    assert "tocontrol_ros.core.methods.contract" in GRAPH["tocontrol_ros.core.planning.solver"]


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = _cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_every_module_has_a_layer():
    assert not [name for name in MODULES if _layer(name) < 0]
    assert _layer("tocontrol_ros.core.indirect.pmp") > _layer("tocontrol_ros.core.direct.flat")
    assert _layer("tocontrol_ros.core") > _layer("tocontrol_ros.core.planning.solver")


def test_no_module_imports_a_layer_above_its_own():
    upward = sorted(
        f"{name} ({LAYERS[_layer(name)][0]}) -> {target} ({LAYERS[_layer(target)][0]})"
        for name, targets in GRAPH.items() for target in targets
        if _layer(target) > _layer(name))
    assert not upward, "imports that run up a layer:\n" + "\n".join(upward)


def test_the_core_never_imports_the_nodes():
    offenders = sorted(
        (name, target) for name, targets in GRAPH.items() if name.startswith("tocontrol_ros.core")
        for target in targets if not target.startswith("tocontrol_ros.core"))
    assert not offenders, offenders


def test_no_module_is_longer_than_the_limit():
    lengths = {name: len(path.read_text().splitlines()) for name, path in MODULES.items()}
    long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def _private_definitions(tree: ast.AST) -> set[str]:
    """Private names a module defines: ``def _f``, ``class _C``, ``_x = ...``, ``self._a``."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
    return {name for name in names if name.startswith("_") and not name.startswith("__")}


TREES = {name: ast.parse(path.read_text(), str(path)) for name, path in MODULES.items()}
PRIVATE = {name: _private_definitions(tree) for name, tree in TREES.items()}


def _private_uses(name: str, tree: ast.AST) -> list[str]:
    """Another package module's private names that module ``name`` uses.

    Imported (``from m import _x``), read off an imported module (``m._x``), or read off an
    object (``obj._x``, ``self.node._x``) when ``_x`` is defined by another module of the
    package and not by this one (a class's privates are used in its own module only). Names
    the package does not define (``os._exit``, a namedtuple's ``_replace``) are not its.
    """
    elsewhere = set().union(*(p for other, p in PRIVATE.items() if other != name))
    own = PRIVATE[name]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(PACKAGE):
            found += [f"from {node.module} import {alias.name}" for alias in node.names
                      if alias.name.startswith("_") and not alias.name.startswith("__")]
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                continue
            if node.attr in elsewhere and node.attr not in own:
                found.append(f"line {node.lineno}: .{node.attr}")
    return found


def test_the_private_name_scan_finds_what_it_names():
    tree = ast.parse("from tocontrol_ros.core.planning.solver import _PLANNERS\n"
                     "x = self.node._collect\n"
                     "y = self._collect\n"
                     "os._exit(0)\n")
    PRIVATE["probe"] = set()
    try:
        uses = _private_uses("probe", tree)
    finally:
        del PRIVATE["probe"]
    assert any("_collect" in p for p in PRIVATE.values())  # the pool's, elsewhere
    assert uses == ["from tocontrol_ros.core.planning.solver import _PLANNERS",
                    "line 2: ._collect"]


def test_no_module_uses_a_private_name_of_another():
    offenders = {name: uses for name, tree in TREES.items()
                 if (uses := _private_uses(name, tree))}
    assert not offenders, offenders
