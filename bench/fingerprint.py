"""Fingerprint of a source tree's solves, to show that a refactoring changed no number.

Usage::

    scripts/dev run python bench/fingerprint.py TREE > a.txt
    scripts/dev run python bench/fingerprint.py OTHER_TREE > b.txt && diff a.txt b.txt

Imports ``tocontrol_ros`` and ``bench`` from ``TREE`` (as ``bench/ab_trees.py`` does) and
prints, one line per solve, the status, ``repr(T)`` (every digit), Newton iterations,
intervals, the final smoothing, the continuation's length, the re-integrated end-point error
and the warnings: the paper's example cold and warm (target moved 5 cm) at k = 1, 2, 4, 16
with one start, the multistart at k = 4 with every start's ``T``, a torque reserve of 0.2, a
moving start, the uniform mesh (no switch nodes), and the Panda with its joint limits (the
bounded B-spline solve; skipped with a line saying so when example-robot-data is missing).
Two trees that print the same lines take the same numerical path. The imports try the
package's top-level names (``tocontrol_ros.core``) first and fall back to the module paths
of older trees, so the script runs on both sides of a restructuring.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()))

import numpy as np  # noqa: E402

from bench.common import MOVED_TARGET, START, TARGET, panda_urdf, paper_model  # noqa: E402

try:  # the re-exports of tocontrol_ros.core (issue 31 onwards)
    from tocontrol_ros.core import (  # noqa: E402
        Problem,
        SolverOptions,
        joint_state,
        load_robot,
        plan,
        point,
    )
except ImportError:  # older trees: the module paths
    from tocontrol_ros.core.model import load_robot  # noqa: E402
    from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
    from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

# The Panda case of test/core/plan_probe.py: from rest at PANDA_Q0 to the tip at PANDA_Q1.
PANDA_Q0 = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
PANDA_Q1 = np.array([1.2, -0.3, 0.4, -1.6, -0.5, 2.2, 0.2])


def main() -> None:
    model = paper_model()
    one = SolverOptions(starts=1, candidates=1)
    rows = []
    for k in (1.0, 2.0, 4.0, 16.0):
        cold = plan(Problem(model, point(START), point(TARGET), k=k), one)
        warm = plan(Problem(model, point(START), point(MOVED_TARGET), k=k), one,
                    warm_start=cold)
        for name, r in (("cold", cold), ("warm", warm)):
            rows.append((k, name, r.status.name, repr(r.T), r.iterations, r.intervals,
                         r.delta, len(r.continuation),
                         repr(r.verification.get("point_error")), r.warnings))
    multi = plan(Problem(model, point(START), point(TARGET), k=4.0), SolverOptions())
    rows.append(("multi", multi.status.name, repr(multi.T), multi.iterations, multi.intervals,
                 [(s.index, repr(s.T), s.status) for s in multi.starts]))
    res = plan(Problem(model, point(START), point(TARGET), k=4.0, reserve=0.2), one)
    rows.append(("reserve", res.status.name, repr(res.T), res.iterations, res.intervals))
    q0 = np.array([0.3, -0.4, 0.2])
    res = plan(Problem(model, joint_state(q0, [0.1, 0.0, -0.2]), point(TARGET), k=4), one)
    rows.append(("state", res.status.name, repr(res.T), res.iterations, res.intervals))
    res = plan(Problem(model, point(START), point(TARGET), k=4.0),
               SolverOptions(starts=1, candidates=1, switch_nodes=False))
    rows.append(("uniform", res.status.name, repr(res.T), res.iterations, res.intervals))
    rows.append(panda_row())
    for row in rows:
        print(row)


def panda_row() -> tuple:
    """The Panda with its URDF joint limits (the bounded solve), or why it was skipped."""
    urdf = panda_urdf()
    if urdf is None:
        return ("panda", "skipped: example-robot-data not installed")
    model = load_robot(str(urdf), tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    problem = Problem(model, joint_state(PANDA_Q0), point(model.point(PANDA_Q1)), k=4.0)
    res = plan(problem, SolverOptions(starts=2, candidates=2))
    return ("panda", res.status.name, repr(res.T), res.iterations, res.intervals, res.method)


if __name__ == "__main__":
    main()
