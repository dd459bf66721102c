"""The numerical core imports neither ROS nor plotting libraries.

Each check runs in a fresh interpreter: in this one, pytest plugins or other tests may have
imported anything already.
"""

from __future__ import annotations

import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import tocontrol_ros.core

REPO = Path(__file__).resolve().parents[2]
FORBIDDEN = ("rclpy", "matplotlib")

#: Imports the given modules in turn and reports, for each, the forbidden top-level
#: packages that are in ``sys.modules`` after it (cumulative, in import order).
PROBE = """
import importlib, json, sys
forbidden, names = sys.argv[1].split(","), sys.argv[2:]
report = {}
for name in names:
    importlib.import_module(name)
    report[name] = sorted({m.split(".")[0] for m in sys.modules} & set(forbidden))
print(json.dumps(report))
"""


def _core_modules() -> list[str]:
    return sorted(info.name for info in pkgutil.walk_packages(
        tocontrol_ros.core.__path__, prefix="tocontrol_ros.core."))


def _probe(names: list[str]) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    result = subprocess.run(
        [sys.executable, "-c", PROBE, ",".join(FORBIDDEN), *names],
        capture_output=True, text=True, cwd=REPO, env=env, timeout=120, check=False)
    assert result.returncode == 0, f"importing {names} failed:\n{result.stderr}"
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_core_modules_are_found():
    """Guards the test below against an empty package walk."""
    assert "tocontrol_ros.core.robot.model" in _core_modules()
    assert "tocontrol_ros.core.errors" in _core_modules()


def test_model_alone_imports_no_ros_nor_matplotlib():
    assert _probe(["tocontrol_ros.core.robot.model"]) == {"tocontrol_ros.core.robot.model": []}


def test_every_core_module_imports_no_ros_nor_matplotlib():
    names = ["tocontrol_ros.core", *_core_modules()]
    report = _probe(names)
    culprits = {name: found for name, found in report.items() if found}
    # The first module listed is the one that pulled the package in.
    assert not culprits, f"core modules importing {FORBIDDEN}: {culprits}"


@pytest.mark.parametrize("package", FORBIDDEN)
def test_probe_detects_a_forbidden_import(package, tmp_path):
    """The probe itself works: a stub ``rclpy``/``matplotlib`` on the path is reported."""
    (tmp_path / f"{package}.py").write_text("")
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    code = PROBE.replace("importlib.import_module(name)",
                         "importlib.import_module(name); importlib.import_module("
                         f"{package!r})")
    result = subprocess.run([sys.executable, "-c", code, ",".join(FORBIDDEN), "json"],
                            capture_output=True, text=True, env=env, timeout=60, check=True)
    assert json.loads(result.stdout) == {"json": [package]}
