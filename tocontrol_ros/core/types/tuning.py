"""When a previous solution may warm-start a new problem (read by the result type).

:meth:`~tocontrol_ros.core.types.result.PlanResult.can_warm_start` and the default of
``SolverOptions.warm_joint_radius``; each constant with why it has its value. This module
imports nothing.
"""

__all__ = ["WARM_RADIUS", "WARM_JOINT_RADIUS"]


# ----------------------------------------- the warm start (result.py, solver.py)
#: A previous solution warm-starts a problem only when each end point moved by at most this
#: (m): farther, the warm solution often lands in another (worse) basin than the multistart
#: (measured on the paper's arm, bench/optimum.py and docs/seeding.md).
WARM_RADIUS = 0.1

#: ...and each joint-state end by at most this (max-norm of positions and velocities, rad
#: and rad/s).
WARM_JOINT_RADIUS = 0.05
