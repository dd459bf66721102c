"""The paper's arm with velocity limits that bind, shared by the memory tests.

Its velocity limits at 0.4 and 1 rad/s (as the benchmark's ``3R-limited``) make the planner
take the bounded B-spline transcription (``method`` ``direct``), whose warm state is what a
memory of a real arm holds: test_bounded.py, test_serve.py, test_follow.py, test_early.py
and test_shifted.py store and recall its motions (:func:`served_memory`).
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core import Problem, SolverOptions, load_robot, point
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import default_urdf_path

MODEL = load_robot(default_urdf_path())
BASE = JointLimits.from_model(MODEL)
LIMITS = JointLimits(BASE.names, np.array([-2.5, -np.inf, -np.inf]),
                     np.array([2.5, np.inf, np.inf]), np.array([0.4, 1.0, 1.0]))
#: A small multistart: the tests compare against it, not against the default's basin.
OPTIONS = SolverOptions(starts=4, candidates=2)
#: The serving mesh of these tests' stored motions.
SPANS = 64


def problem(target) -> Problem:
    """From the paper's start point to ``target`` (m, shape (2,)), k = 4, :data:`LIMITS`."""
    return Problem(MODEL, point(PAPER_START), point(target), k=4, limits=LIMITS)


def served_memory(path, target):
    """A planner and a memory at ``path`` holding the motion to ``target`` with its serving
    state on :data:`SPANS` spans: ``(planner, store)``; the caller closes the store."""
    from dataclasses import replace

    from tocontrol_ros.core import Planner
    from tocontrol_ros.core.memory.recall import open_memory, remember
    from tocontrol_ros.core.memory.serve import convert

    planner = Planner(MODEL)
    stored = planner.plan(problem(target), OPTIONS)
    assert stored.success and stored.method == "direct", stored.message
    store = open_memory(path, stored.problem, create=True)
    assert remember(store, stored, "test", 0.0)
    done = convert(store, planner, stored.problem, replace(OPTIONS, time_limit=600.0), SPANS)
    assert done.converted == 1, done.messages
    return planner, store


def check_motion(result, target) -> None:
    """A motion of :func:`problem` checked independently of its certificate, along a fine
    sampling: from the paper's start to ``target`` at rest, inside the velocity limits and
    the torque set."""
    s = result.trajectory.sample(1e-3)
    np.testing.assert_allclose(MODEL.point(s.q[0]), PAPER_START, atol=1e-6)
    np.testing.assert_allclose(MODEL.point(s.q[-1]), target, atol=1e-5)
    np.testing.assert_allclose(s.qd[[0, -1]], 0.0, atol=1e-5)
    assert np.all(np.abs(s.qd) <= LIMITS.velocity * (1 + 1e-6) + 1e-9)
    assert np.max(np.sum(np.abs(s.u) ** (2 * result.k), axis=1)) <= 1.0 + 1e-6
