"""The launch file without `launch`: stand-ins for `launch` and `launch_ros` (not installable
from the registry), so that tests can read which nodes it starts with which parameters, and
start them as processes the way `ros2 launch` would.

Importable as ``launch_stubs`` (test/ is on sys.path, as for ``planner_harness``).
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

LAUNCH = Path(__file__).resolve().parents[1] / "launch" / "tocontrol.launch.py"


def load_launch_file(monkeypatch, share: str = "/prefix/share"):
    """The launch file as a module; its ``Node(...)`` calls return their keyword arguments.

    ``FindPackageShare(pkg)`` resolves to ``<share>/<pkg>``.
    """
    stubs = {name: types.ModuleType(name) for name in (
        "launch", "launch.actions", "launch_ros", "launch_ros.actions",
        "launch_ros.substitutions")}
    stubs["launch"].LaunchDescription = list
    stubs["launch.actions"].DeclareLaunchArgument = lambda name, **kw: ("arg", name, kw)
    stubs["launch.actions"].OpaqueFunction = lambda function: ("opaque", function)
    stubs["launch_ros.actions"].Node = lambda **kw: kw
    stubs["launch_ros.substitutions"].FindPackageShare = lambda pkg: types.SimpleNamespace(
        perform=lambda context: f"{share}/{pkg}")
    for name, module in stubs.items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("tocontrol_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def launched_nodes(module, **arguments) -> list[dict]:
    """The ``Node`` keyword arguments the launch file gives for these launch arguments."""
    context = types.SimpleNamespace(launch_configurations=dict(arguments))
    return module._nodes(context)


def ros_args(node: dict) -> list[str]:
    """The command-line ROS arguments that give a process what ``Node(**node)`` gives it."""
    args = ["--ros-args", "-r", f"__node:={node['name']}"]
    if node.get("namespace"):
        args += ["-r", f"__ns:=/{node['namespace'].strip('/')}"]
    for entry in node["parameters"]:
        if isinstance(entry, str):
            args += ["--params-file", entry]
        else:
            for key, value in entry.items():
                text = str(value).lower() if isinstance(value, bool) else str(value)
                args += ["-p", f"{key}:={text}" if text != "" else f"{key}:=''"]
    return args
