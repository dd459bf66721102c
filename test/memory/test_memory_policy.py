"""The planner's memory policy without ROS: off, unavailable with one warning, learning.

:class:`~tocontrol_ros.nodes.memory_policy.MemoryPolicy` with the node's config: a missing,
corrupt or other robot's file gives ``memory: unavailable`` with the reason (and one warning
per file, not one per request), and never an exception; with ``memory_learn`` a published
plan is stored in a new file, which the next lookup uses.
"""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core import Planner, Problem, SolverOptions, load_robot, point
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.memory.recall import open_memory
from tocontrol_ros.core.memory.store import MotionStore
from tocontrol_ros.core.robot.model import default_urdf_path
from tocontrol_ros.nodes.memory_policy import HIT, MISS, OFF, UNAVAILABLE, MemoryPolicy
from tocontrol_ros.nodes.planner_config import config_from_values

MODEL = load_robot(default_urdf_path())
OPTIONS = SolverOptions(starts=4, candidates=2)


def config(**values):
    return config_from_values(values, task_dim=MODEL.m)


def problem(target, model=MODEL):
    return Problem(model, point(PAPER_START), point(target), k=4.0, reserve=0.1)


@pytest.fixture(scope="module")
def planner():
    return Planner(MODEL)


def test_no_memory_is_off(planner):
    found, values = MemoryPolicy(lambda m: None).lookup(config(), planner,
                                                        problem([2.2, 1.5]), OPTIONS, None)
    assert found is None and values == {"memory": OFF}


@pytest.mark.parametrize("content, reason", [
    (None, "no such file"),
    (b"\x00garbage" * 300, "corrupt or not a database"),
])
def test_an_unusable_file_warns_once_and_says_why(tmp_path, planner, content, reason):
    path = tmp_path / "m.sqlite"
    if content is not None:
        path.write_bytes(content)
    warnings = []
    policy = MemoryPolicy(warnings.append)
    for target in ([2.2, 1.5], [2.0, 1.8]):
        found, values = policy.lookup(config(memory=str(path)), planner, problem(target),
                                      OPTIONS, None)
        assert found is None and values["memory"] == UNAVAILABLE
        assert reason in values["memory_error"] and str(path) in values["memory_error"]
    assert len(warnings) == 1 and "planning without it" in warnings[0]


def test_another_robots_memory_is_unavailable(tmp_path, planner):
    other = load_robot(default_urdf_path(), gravity=(0.0, -9.81, 0.0))
    path = tmp_path / "m.sqlite"
    open_memory(path, problem([2.2, 1.5], other), create=True).close()
    warnings = []
    _, values = MemoryPolicy(warnings.append).lookup(
        config(memory=str(path)), planner, problem([2.2, 1.5]), OPTIONS, None)
    assert values["memory"] == UNAVAILABLE and "another robot" in values["memory_error"]
    assert warnings and "another robot" in warnings[0]


def test_a_learning_policy_stores_a_plan_and_hits_it_next(tmp_path, planner):
    path = tmp_path / "learnt.sqlite"
    cfg = config(memory=str(path), memory_learn=True)
    policy = MemoryPolicy(lambda m: None)
    first = planner.plan(problem([2.2, 1.5]), OPTIONS)
    assert first.success
    assert policy.learn(cfg, first, 1.0)
    assert not policy.learn(config(memory=str(path)), first, 1.0), "learning is off"
    with MotionStore(path) as store:
        assert store.count() == 1 and store.summary()[0]["source"] == "planner"
    found, values = policy.lookup(cfg, planner, problem([2.21, 1.52]), OPTIONS, None)
    assert values["memory"] == HIT and found.result.success
    assert values["memory_entries"] == [1] and 0 < values["memory_distance"] <= 1
    far, values = policy.lookup(cfg, planner, problem([3.0, -1.0]), OPTIONS, None)
    assert values["memory"] == MISS and far.result is None
    assert values["memory_distance"] > 1 and "memory_entries" not in values
    # Another k is another problem class: that file is not this class's memory.
    _, values = policy.lookup(cfg, planner, Problem(MODEL, point(PAPER_START),
                                                    point([2.2, 1.5]), k=8.0, reserve=0.1),
                              OPTIONS, None)
    assert values["memory"] == UNAVAILABLE and "another options" in values["memory_error"]
    policy.close()
    assert np.isfinite(first.T)
