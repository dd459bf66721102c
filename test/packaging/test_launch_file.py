"""The launch file (not runnable here: `launch` is not installable from the registry).

Checked statically: it parses, every Node it starts is a registered executable of this
package, every parameter file it names exists in config/, and package.xml declares the
launch packages it imports.
"""

import ast
import re
from pathlib import Path

from launch_stubs import launched_nodes, load_launch_file

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



def _started(module, **arguments):
    return {node["executable"]: node["parameters"]
            for node in launched_nodes(module, **arguments)}

def test_launch_arguments_reach_the_nodes(monkeypatch):
    module = load_launch_file(monkeypatch)
    names = [entry[1] for entry in module.generate_launch_description()[:-1]]
    assert names == ["robot", "params_file", "use_sim_time", "controller_action", "simulate",
                     "record", "output", "namespace"]
    nodes = _started(module)  # defaults: the robot from /robot_description, the topic route
    assert list(nodes) == ["planner", "tracker", "recorder"]
    planner, tracker = nodes["planner"][1], nodes["tracker"][1]
    # Relative: in the launch's namespace (issue 52), /robot_description without one.
    assert planner["robot_description_topic"] == tracker["robot_description_topic"] == \
        "robot_description"
    assert planner["controller_action"] == "" and \
        tracker["trajectory_topic"] == "planner/trajectory"
    assert all(n["namespace"] == "" for n in launched_nodes(module))
    assert {n["namespace"] for n in launched_nodes(module, namespace="arm1")} == {"arm1"}
    assert nodes["planner"][0] == "/prefix/share/tocontrol_ros/config/planner.yaml"

    nodes = _started(module, robot="/arm.urdf", params_file="/mine.yaml", use_sim_time="true",
                     controller_action="/arm_controller/follow_joint_trajectory",
                     simulate="false", record="false")
    assert list(nodes) == ["planner"]
    planner = nodes["planner"]
    assert planner[1]["robot_description_file"] == "/arm.urdf"
    assert "robot_description_topic" not in planner[1]
    assert planner[1]["use_sim_time"] is True
    assert planner[1]["controller_action"] == "/arm_controller/follow_joint_trajectory"
    assert planner[-1] == "/mine.yaml"  # after the defaults: it wins

    tracker = _started(module, controller_action="/tracker/follow_joint_trajectory")["tracker"]
    assert tracker[1]["trajectory_topic"] == "~/unused"  # goals only, not the plan twice
