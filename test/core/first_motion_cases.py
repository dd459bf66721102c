"""Problems shared by the first-motion tests (a helper module, not a test module)."""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.types.problem import Problem, joint_state, point


def panda_problem(panda, moving: bool) -> Problem:
    """The Panda with its URDF limits, between two drawn configurations' points.

    Parameters
    ----------
    panda : RobotModel
    moving : bool
        Start with drawn joint velocities (up to 0.3 of the limits) instead of at rest.

    Returns
    -------
    Problem
        A point target, k = 4, the same draw every call (seed 32).
    """
    limits = JointLimits.from_model(panda)
    rng = np.random.default_rng(32)
    centre = 0.5 * (limits.lower + limits.upper)
    half = 0.4 * (limits.upper - limits.lower)
    q0, q1 = (centre + rng.uniform(-1, 1, 7) * half for _ in range(2))
    qd0 = rng.uniform(-0.3, 0.3, 7) * limits.velocity if moving else np.zeros(7)
    return Problem(panda, joint_state(q0, qd0), point(panda.point(q1)), k=4.0, limits=limits)
