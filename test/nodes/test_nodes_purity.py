"""The nodes' policy and tables import neither rclpy nor a message package.

The planning service (and what it is built on) is tested without ROS and must stay so. Each
check runs in a fresh interpreter, as ``test/core/test_core_purity.py`` does for the core.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

#: The ROS-free modules of ``tocontrol_ros/nodes/``.
PURE = ("planning_service", "replan_policy", "warm_up", "requests", "replanning",
        "planner_config", "parameter_specs", "outcomes", "splice", "tracker_time",
        "jtc_interpolation", "memory_policy",
        "tracker_config", "trajectory_cdr")

#: Imports the given module and prints the ROS packages in ``sys.modules`` after it: rclpy,
#: rosidl and any message package (``*_msgs``, ``*_interfaces``).
PROBE = """
import importlib, json, sys
importlib.import_module(sys.argv[1])
top = {m.split(".")[0] for m in sys.modules}
print(json.dumps(sorted(m for m in top if m == "rclpy" or m.startswith("rosidl")
                        or m.endswith("_msgs") or m.endswith("_interfaces"))))
"""


def _ros_after_import(name: str) -> list[str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    result = subprocess.run([sys.executable, "-c", PROBE, name], capture_output=True,
                            text=True, cwd=REPO, env=env, timeout=120, check=False)
    assert result.returncode == 0, f"importing {name} failed:\n{result.stderr}"
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_the_probe_sees_ros():
    """Guards the test below: a node module does import rclpy and messages."""
    found = _ros_after_import("tocontrol_ros.nodes.planner")
    assert "rclpy" in found and "nav_msgs" in found


@pytest.mark.parametrize("module", PURE)
def test_module_imports_no_ros(module):
    assert _ros_after_import(f"tocontrol_ros.nodes.{module}") == []
