"""The nodes' modules use each other's public names only (issue 48).

An attribute with a leading underscore is read only on ``self`` or ``cls``: a module never
reaches into another object's private state (the tracker's action server once read the
node's ``_epoch`` and ``_status``; the planner's mixin twelve of its host's privates).
"""

from __future__ import annotations

import ast
from pathlib import Path

NODES = Path(__file__).resolve().parents[2] / "tocontrol_ros" / "nodes"

#: Underscore names that are public API: a NamedTuple's.
PUBLIC = {"_replace", "_asdict", "_fields", "_make"}
#: The one use of rclpy's private API, isolated in a function that says why
#: (follow_action._enter_canceling: rclpy has no public way to preempt a goal CANCELED).
ALLOWED = {("follow_action.py", "handle._update_state")}


def _private_uses(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") \
                or node.attr.startswith("__") or node.attr in PUBLIC:
            continue
        if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            continue
        if (path.name, ast.unparse(node)) not in ALLOWED:
            found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_check_finds_a_private_use(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f(node):\n    return node._epoch + node.t._replace()\n")
    assert _private_uses(probe) == ["probe.py:2: node._epoch"]


def test_no_node_module_reads_another_objects_private_names():
    modules = sorted(NODES.glob("*.py"))
    assert len(modules) > 10
    assert [use for path in modules for use in _private_uses(path)] == []


def test_no_node_module_imports_a_private_name():
    imported = []
    for path in sorted(NODES.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module \
                    and node.module.startswith("tocontrol_ros"):
                imported += [f"{path.name}: {a.name}" for a in node.names
                             if a.name.startswith("_")]
    assert imported == []


#: The longest a node class may be (lines, docstring included): a node wires, the policy
#: lives in ROS-free modules (issue 48).
MAX_NODE_CLASS = 300


def test_node_classes_are_thin():
    sizes = {}
    for path in sorted(NODES.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                    isinstance(b, ast.Name) and b.id == "Node" for b in node.bases):
                sizes[node.name] = node.end_lineno - node.lineno + 1
    assert {"PlannerNode", "TrackerNode"} <= set(sizes)
    assert {name: n for name, n in sizes.items() if n > MAX_NODE_CLASS} == {}
