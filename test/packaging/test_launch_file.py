"""The launch file (not runnable here: `launch` is not installable from the registry).

Checked statically: it parses, every Node it starts is a registered executable of this
package, every parameter file it names exists in config/, and package.xml declares the
launch packages it imports.
"""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / "launch" / "tocontrol.launch.py"


def _executables() -> set[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "EXECUTABLES" for t in node.targets):
            return {k.value for k in node.value.keys}
    raise AssertionError("EXECUTABLES not found in setup.py")


def test_launch_file_nodes_are_registered_executables():
    tree = ast.parse(LAUNCH.read_text())
    started = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Node":
            kw = {k.arg: k.value for k in node.keywords}
            started.append(kw["executable"].value)
    assert started == ["planner", "tracker", "recorder"]
    assert set(started) <= _executables()


def test_launch_file_parameter_files_exist():
    names = re.findall(r'"(\w+\.yaml)"', LAUNCH.read_text())
    assert names == ["planner.yaml", "tracker.yaml", "recorder.yaml"]
    for name in names:
        assert (ROOT / "config" / name).is_file(), name


def test_package_xml_declares_launch_dependencies():
    xml = (ROOT / "package.xml").read_text()
    tree = ast.parse(LAUNCH.read_text())
    roots = {alias.name.split(".")[0] for node in ast.walk(tree)
             if isinstance(node, ast.ImportFrom) for alias in [ast.alias(node.module)]}
    assert roots == {"launch", "launch_ros"}
    for pkg in roots:
        assert f"<exec_depend>{pkg}</exec_depend>" in xml, pkg
