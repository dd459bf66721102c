"""A memory hit with ``publish: first_then_optimum``: the stored motion moved, then the optimum.

The paper's arm with velocity limits that bind (a ``joint_limits`` file: the bounded
B-spline solve, as a real arm's memory holds), one motion stored with its serving state
(the node's own problem: its config, limits and defaults), then the planner node in process
with ``memory`` and ``publish: first_then_optimum``: a request 8 cm from the stored one is a
hit, and the node publishes first the stored motion moved onto the request's ends and
timed (``core/direct/shifted.py``, before the warm re-solve starts: a ``first`` status with
``memory: hit``, certified, slower than the optimum), then the converged
optimum (the final status, ``published: optimum``, with ``memory_first_T``); both
trajectories end on the target at rest. The optimum is the one the node serves with
``publish: optimum`` (the same ``T`` to the bit).
"""

from __future__ import annotations

import contextlib
from dataclasses import replace

import numpy as np
import pytest
from planner_harness import PAPER_START, PlannerClient
from rclpy.parameter import Parameter
from test_planner_node import NAMESPACE, Running

from tocontrol_ros.core import Planner, SolverOptions
from tocontrol_ros.core.memory.recall import open_memory, remember
from tocontrol_ros.core.memory.serve import convert
from tocontrol_ros.nodes.planner_config import (
    config_from_values,
    plan_problem,
    planner_limits,
    planner_model,
)

pytestmark = pytest.mark.ros
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 300.0
STORED, HIT = (2.2, 1.5), (2.28, 1.5)
LIMITS_YAML = """joint_limits:
  joint1: {has_position_limits: true, min_position: -2.5, max_position: 2.5,
           has_velocity_limits: true, max_velocity: 0.4}
  joint2: {has_velocity_limits: true, max_velocity: 1.0}
  joint3: {has_velocity_limits: true, max_velocity: 1.0}
"""


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    """The limits file and a memory of one stored motion with its 64-span serving state."""
    folder = tmp_path_factory.mktemp("memory_first")
    limits_file = folder / "joint_limits.yaml"
    limits_file.write_text(LIMITS_YAML)
    config = config_from_values({"joint_limits": str(limits_file)}, task_dim=2)
    model = planner_model(config)
    problem = plan_problem(config, model, planner_limits(config, model),
                           ("point", np.array(PAPER_START)), np.array(STORED))
    planner = Planner(model)
    options = SolverOptions(starts=4, candidates=2)
    stored = planner.plan(problem, options)
    assert stored.success and stored.method == "direct", stored.message
    path = folder / "m.sqlite"
    with open_memory(path, problem, create=True) as store:
        assert remember(store, stored, "test", 0.0)
        done = convert(store, planner, problem, replace(options, time_limit=HANG), 64)
        assert done.converted == 1, done.messages
    return limits_file, path


@contextlib.contextmanager
def planner(suffix: str, *params):
    ns = f"{NAMESPACE}_{suffix}"
    running = Running(list(params), namespace=ns)
    client = PlannerClient(f"{ns}/planner")
    try:
        client.wait_ready(HANG)
        assert running.node.ready.wait(HANG)
        yield running, client
    finally:
        client.close()
        running.stop()


# A memory built and a node run (20 s under load): with the slow tests. The default run keeps
# a hit's moved stored motion and first certified iterate (test/memory/test_shifted.py,
# test_early.py), the node's first motion then
# the optimum (test_planner_node.py::test_first_then_optimum_publishes_both_in_order) and
# a memory hit through the planner process (test/e2e/test_memory_node.py).
@pytest.mark.slow
def test_a_hit_publishes_its_stored_motion_moved_then_the_optimum(memory):
    limits_file, path = memory
    common = [Parameter("joint_limits", value=str(limits_file)),
              Parameter("memory", value=str(path)), Parameter("warm_start", value=False)]
    with planner("memfirst", *common,
                 Parameter("publish", value="first_then_optimum")) as (running, client):
        since = len(client.status_list())
        _, status, _ = client.call_plan(PAPER_START, HIT, timeout=HANG)
        assert status.event == "solved", status.message
        assert status.values["memory"] == "hit", status.values
        assert status.values["published"] == "optimum"
        firsts = [s for s in client.status_list()[since:] if s.event == "first"]
        assert len(firsts) == 1, [s.message for s in firsts]
        first = firsts[0]
        assert first.values["published"] == "first" and first.values["memory"] == "hit"
        assert first.values["certified"] == "true" and first.values["method"] == "direct"
        assert "route: shifted" in first.message, first.message
        T_first, T_opt = float(first.values["T"]), float(status.values["T"])
        assert T_first >= T_opt * (1 - 1e-4), (T_first, T_opt)
        assert float(status.values["memory_first_T"]) == T_first
        assert int(status.values["memory_first_iteration"]) == 0 \
            < int(status.values["memory_iterations"])  # before IPOPT's first iteration
        assert first.received <= status.received
        published = running.node.last_result
        model = running.node.model
        assert published.T == pytest.approx(T_opt, rel=1e-9)
        exact = published.T
        np.testing.assert_allclose(model.point(published.trajectory.sample(0.01).q[-1]), HIT,
                                   atol=1e-6)
    # The same request with publish: optimum: the same optimum, no first motion.
    with planner("memopt", *common) as (running, client):
        since = len(client.status_list())
        _, plain, _ = client.call_plan(PAPER_START, HIT, timeout=HANG)
        assert plain.values["memory"] == "hit" and plain.event == "solved", plain.message
        assert not [s for s in client.status_list()[since:] if s.event == "first"]
        assert "memory_first_T" not in plain.values
        assert running.node.last_result.T == exact  # to the bit
