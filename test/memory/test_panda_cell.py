"""A small Panda cell built with the ``memory`` tool, then recalled (slow: minutes).

The Panda of example-robot-data with its URDF limits (which bind: the bounded solve's warm
state), one station and three targets 10 cm apart, built on one worker; a request between two
stored targets is recalled: certified, and its T within 1e-3 of the cold default plan's.
"""

from __future__ import annotations

import io

import pytest
import yaml
from skip_policy import missing

from tocontrol_ros.core import Planner, SolverOptions
from tocontrol_ros.core.memory.recall import recall
from tocontrol_ros.core.memory.store import MotionStore
from tocontrol_ros.memory import cli
from tocontrol_ros.memory.cell import example_robot_data_urdf, load_cell, task_problem

pytestmark = pytest.mark.slow


def test_a_small_panda_cell_is_built_and_recalled(tmp_path):
    try:
        example_robot_data_urdf("panda")
    except Exception:  # noqa: BLE001
        missing("example-robot-data (pip install example-robot-data)")
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text(yaml.safe_dump({
        "robot": {"urdf": "example-robot-data:panda", "tip_link": "panda_hand"},
        "k": 4, "reserve": 0.1,
        "starts": {"stations": {"home": {"point": [0.3, 0.0, 0.65]}}},
        "targets": {"points": [[0.5, 0.0, 0.3], [0.5, 0.1, 0.3], [0.5, -0.1, 0.3]]}}))
    memory = tmp_path / "cell.sqlite"
    err = io.StringIO()
    args = cli.build_parser().parse_args(["build", str(cell_file), str(memory), "-j", "1"])
    assert cli.run(args, err) == 0, err.getvalue()
    cell = load_cell(cell_file)
    near = task_problem(cell.model, cell.limits, cell.tasks[0])
    from dataclasses import replace

    from tocontrol_ros.core.types.problem import point

    near = replace(near, target=point([0.5, 0.05, 0.32]))
    planner = Planner(cell.model)
    with MotionStore(memory) as store:
        assert store.count() == 3
        found = recall(planner, near, SolverOptions(), store)
    assert found.hit and found.result is not None, found.messages
    res = found.result
    assert res.success and res.method == "direct" and res.certificate.passed
    cold = planner.plan(near, SolverOptions())
    assert cold.success
    assert res.T <= cold.T * (1 + 1e-3), (res.T, cold.T)
