"""The benchmarks' tests: the Panda of example-robot-data with its URDF limits."""

import sys
from pathlib import Path

import pytest
from skip_policy import missing

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))


@pytest.fixture(scope="module")
def panda():
    """(model, limits) of the Panda, or the test is skipped without example-robot-data."""
    from bench.limits import robots

    found = robots().get("Panda")
    if found is None:
        missing("example-robot-data (pip install '.[test]')")
    return found
