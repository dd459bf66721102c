"""Deterministic work of the shooting solver: RK4 step-equivalents per solve.

Usage::

    scripts/dev run python bench/work_counts.py [tree] [options]

``tree`` (default ``.``) is the source tree to import, ``options`` a Python dict literal of
:class:`~tocontrol_ros.core.SolverOptions` fields (default ``{}``). Counts every RK4
step the shooting residuals and the mesh error estimates take, a step with its Jacobian
weighted 5.7 (its measured cost against a plain step), by wrapping
``ShootingGrid.residual`` and ``mesh.interval_errors`` (``solver._interval_errors`` in trees
before the solver's split). Unlike wall time, the count does
not drift with the machine, so two trees or two option sets compare exactly. Printed: the
paper's example at k = 2, 4, 8, 16 (one-start cold solve, then the warm re-solve to the
target moved by 5 cm from it) and the total over 30 seeded random pairs at k = 4 (one start).
"""

from __future__ import annotations

import collections
import sys
from pathlib import Path

sys.path.insert(0, str(Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()))

from bench.common import MOVED_TARGET, START, TARGET, paper_model  # noqa: E402
from bench.random_pairs import draw_pairs  # noqa: E402
from tocontrol_ros.core.indirect import mesh as _estimates  # noqa: E402
from tocontrol_ros.core.indirect import shooting  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, point  # noqa: E402

_ESTIMATE = "interval_errors"

#: Cost of an RK4 step with its 12 x 12 Jacobian against a plain step (paper's arm).
JACOBIAN_WEIGHT = 5.7

COUNT: collections.Counter = collections.Counter()


def _count_residual(orig):
    def residual(self, w, values, par, jacobian=True):
        COUNT["steps"] += self.N * self.steps * (JACOBIAN_WEIGHT if jacobian else 1)
        return orig(self, w, values, par, jacobian)
    return residual


def _count_errors(orig):
    def interval_errors(owner, starts, lengths, steps, t_final, par, kinds=None, ends=None):
        # steps and 2 * steps per interval, or only the doubled ones when ends are given
        COUNT["steps"] += len(lengths) * steps * (2 if ends is not None else 3)
        return orig(owner, starts, lengths, steps, t_final, par, kinds, ends)
    return interval_errors


def main() -> None:
    options = eval(sys.argv[2]) if len(sys.argv) > 2 else {}  # noqa: S307 - a dev tool
    shooting.ShootingGrid.residual = _count_residual(shooting.ShootingGrid.residual)
    setattr(_estimates, _ESTIMATE, _count_errors(getattr(_estimates, _ESTIMATE)))
    model = paper_model()
    rows = []
    for k in (2.0, 4.0, 8.0, 16.0):
        COUNT.clear()
        cold = plan(Problem(model, point(START), point(TARGET), k=k),
                    SolverOptions(starts=1, candidates=1, verify=False, **options))
        n_cold = COUNT["steps"]
        COUNT.clear()
        plan(Problem(model, point(START), point(MOVED_TARGET), k=k),
             SolverOptions(verify=False, **options), warm_start=cold)
        rows.append(f"k = {k:g}: cold {n_cold / 1e3:.1f}k, warm {COUNT['steps'] / 1e3:.1f}k "
                    f"(T {cold.T:.9f} s, {cold.intervals} intervals)")
    total = ok = 0
    for a, b in draw_pairs(model, 30):
        COUNT.clear()
        res = plan(Problem(model, point(a), point(b), k=4.0),
                   SolverOptions(starts=1, candidates=1, verify=False, time_limit=30,
                                 **options))
        total += COUNT["steps"]
        ok += res.success
    print(f"options {options}")
    print("paper's example, one start:\n  " + "\n  ".join(rows))
    print(f"30 random pairs, k = 4, one start: {ok} solved, {total / 1e3:.0f}k steps in all")


if __name__ == "__main__":
    main()
