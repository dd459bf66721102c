"""Fixtures shared by the packaging tests: the source tree, setup.py's declarations and
the install prefix of the running interpreter."""

import ast
import os
import sys
from pathlib import Path

import pytest

PACKAGE = "tocontrol_ros"
REPO = Path(__file__).resolve().parents[2]


def _setup_assignments():
    """Literal top-level assignments and setup() keywords of setup.py, without running it."""
    tree = ast.parse((REPO / "setup.py").read_text(), filename="setup.py")
    names = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name):
                try:
                    names[target.id] = ast.literal_eval(node.value)
                except ValueError:
                    pass
    keywords = {}
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "setup"
        ):
            for kw in node.keywords:
                try:
                    keywords[kw.arg] = ast.literal_eval(kw.value)
                except ValueError:
                    pass
    return names, keywords


@pytest.fixture(scope="session")
def repo():
    return REPO


@pytest.fixture(scope="session")
def setup_names():
    return _setup_assignments()[0]


@pytest.fixture(scope="session")
def setup_keywords():
    return _setup_assignments()[1]


@pytest.fixture(scope="session")
def executables(setup_names):
    """setup.py's EXECUTABLES: ros2-run name -> module."""
    return setup_names["EXECUTABLES"]


@pytest.fixture(scope="session")
def prefix():
    """Install prefix of the running interpreter, holding an installed tocontrol_ros.

    Under scripts/dev (TOCONTROL_DEV_VENV set) a missing install is a failure; elsewhere
    (say, a bare pytest in a venv without the project) the install tests are skipped.
    """
    prefix = Path(sys.prefix)
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    if not marker.exists() and not os.environ.get("TOCONTROL_DEV_VENV"):
        pytest.skip(f"tocontrol_ros is not pip-installed in {prefix}; run scripts/dev test")
    return prefix
