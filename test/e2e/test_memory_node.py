"""The planner process with a memory of optimal motions (its installed executable).

A memory of the paper's arm is made in the test (motions planned and stored as the node's
own defaults would: k = 4, reserve = 0.1, the URDF's limits); the planner is started with
``memory`` set and called over ``~/plan`` from this process: a near request is a ``hit``
(a certified motion, ``T`` as the cold plan's), a far one a ``miss`` planned as usual; a
corrupt file set at run time is a WARN and the request is still solved; with
``memory_learn`` a plan lands in a new file and the next near request hits it.
"""

import os
import time
from pathlib import Path

import pytest
from planner_harness import PAPER_START, PlannerClient, path_end
from test_planner_process import PlannerProcess

from tocontrol_ros.core import Planner, Problem, SolverOptions, load_robot, point
from tocontrol_ros.core.memory.recall import open_memory, remember
from tocontrol_ros.core.memory.store import MemoryFileError, MotionStore
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import default_urdf_path

pytestmark = pytest.mark.ros
#: A wait that only catches a hang (s).
HANG = 120.0
STORED = ((2.2, 1.5), (2.0, 1.8))


@pytest.fixture(scope="module")
def memory_file(tmp_path_factory):
    model = load_robot(default_urdf_path())
    limits = JointLimits.from_model(model)
    planner = Planner(model)
    path = tmp_path_factory.mktemp("memory") / "paper.sqlite"
    store = None
    for target in STORED:
        problem = Problem(model, point(PAPER_START), point(target), k=4.0, reserve=0.1,
                          limits=limits)
        res = planner.plan(problem, SolverOptions())
        assert res.success, res.message
        store = store or open_memory(path, problem, create=True)
        assert remember(store, res, "test", 0.0)
    store.close()
    return path


@pytest.fixture(scope="module")
def node(tmp_path_factory, memory_file):
    proc = PlannerProcess(tmp_path_factory.mktemp("e2e_memory"), f"/e2e_memory_{os.getpid()}",
                          {"memory": str(memory_file)})
    proc.memory = memory_file
    client = PlannerClient(proc.name)
    try:
        client.wait_ready(HANG)
    except AssertionError:
        raise AssertionError(f"planner did not come up; its log:\n{proc.log()}") from None
    yield proc, client
    client.close()
    code, _ = proc.stop()
    assert code == 0, proc.log()


def test_a_near_request_is_a_hit_and_a_far_one_a_miss(node):
    proc, client = node
    _, hit, _ = client.call_plan(PAPER_START, (2.23, 1.48), timeout=HANG)
    assert hit.event == "solved", hit.message
    assert hit.values["memory"] == "hit", (hit.values, proc.log())
    assert 0.0 <= float(hit.values["memory_distance"]) <= 1.0
    assert "; certified" in hit.message, hit.message
    # The same request cold (memory off): the same basin, T within 1e-6 relative.
    assert client.set_parameters(memory="")[0].successful
    _, cold, _ = client.call_plan(PAPER_START, (2.23, 1.48), timeout=HANG)
    assert cold.values["memory"] == "off"
    assert float(hit.values["T"]) <= float(cold.values["T"]) * (1 + 1e-6)
    assert client.set_parameters(memory=str(proc_memory(proc)))[0].successful
    path, miss, _ = client.call_plan(PAPER_START, (3.0, -1.0), timeout=HANG)
    assert miss.event == "solved" and miss.values["memory"] == "miss", miss.values
    assert float(miss.values["memory_distance"]) > 1.0
    assert path_end(path)[:2] == pytest.approx((3.0, -1.0), abs=1e-6)


def proc_memory(proc) -> Path:
    return Path(proc.memory)


def test_a_corrupt_memory_is_a_warning_and_the_plan_goes_on(node, tmp_path):
    _, client = node
    bad = tmp_path / "corrupt.sqlite"
    bad.write_bytes(b"not a database" * 200)
    assert client.set_parameters(memory=str(bad))[0].successful
    since = len(client.status_list())
    path, status, _ = client.call_plan(PAPER_START, (2.2, 1.5), timeout=HANG)
    assert status.event == "solved" and status.values["memory"] == "unavailable"
    assert "corrupt or not a database" in status.values["memory_error"]
    warned = [s for s in client.status_list()[since:] if s.event == "memory"]
    assert warned and "planning without it" in warned[0].message and warned[0].level == 1
    assert path_end(path)[:2] == pytest.approx((2.2, 1.5), abs=1e-6)


def _stored_count(path, at_least: int) -> int:
    """The motions stored in ``path`` once there are ``at_least`` (or HANG s have passed)."""
    deadline = time.monotonic() + HANG
    count = 0
    while time.monotonic() < deadline:
        if path.exists():
            try:
                with MotionStore(path) as store:
                    count = store.count()
            except MemoryFileError:  # created but its schema not yet written
                count = 0
            if count >= at_least:
                return count
        time.sleep(0.05)
    return count


def test_a_node_that_learns_fills_a_new_memory(node, tmp_path):
    _, client = node
    new = tmp_path / "learnt.sqlite"
    assert client.set_parameters(memory=str(new), memory_learn=True)[0].successful
    _, first, _ = client.call_plan(PAPER_START, (1.8, 2.0), timeout=HANG)
    assert first.event == "solved" and first.values["memory"] == "unavailable"
    # The plan is published before it is stored: wait for the row, not the file.
    assert _stored_count(new, at_least=1) == 1
    _, second, _ = client.call_plan(PAPER_START, (1.82, 1.98), timeout=HANG)
    assert second.values["memory"] == "hit", second.values
    assert client.set_parameters(memory_learn=False)[0].successful
