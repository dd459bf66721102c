"""Fingerprint of a source tree's solves, to show that a refactoring changed no number.

Usage::

    scripts/dev run python bench/fingerprint.py TREE > a.txt
    scripts/dev run python bench/fingerprint.py OTHER_TREE > b.txt && diff a.txt b.txt

Imports ``tocontrol_ros`` and ``bench`` from ``TREE`` (as ``bench/ab_trees.py`` does) and
prints, one line per solve, the status, ``repr(T)`` (every digit), Newton iterations,
intervals, the final smoothing, the continuation's length, the re-integrated end-point error
and the warnings: the paper's example cold and warm (target moved 5 cm) at k = 1, 2, 4, 16
with one start, the multistart at k = 4 with every start's ``T``, a torque reserve of 0.2, a
moving start, and the uniform mesh (no switch nodes). Two trees that print the same lines
take the same numerical path.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()))

import numpy as np  # noqa: E402

from bench.common import MOVED_TARGET, START, TARGET, paper_model  # noqa: E402
from tocontrol_ros.core.problem import Problem, joint_state, point  # noqa: E402
from tocontrol_ros.core.solver import SolverOptions, plan  # noqa: E402


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
    for row in rows:
        print(row)


if __name__ == "__main__":
    main()
