"""The paper's arm with velocity limits that bind, shared by the memory tests.

Its velocity limits at 0.4 and 1 rad/s (as the benchmark's ``3R-limited``) make the planner
take the bounded B-spline transcription (``method`` ``direct``), whose warm state is what a
memory of a real arm holds: test_bounded.py, test_serve.py and test_follow.py store and
recall its motions.
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
