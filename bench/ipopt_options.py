"""IPOPT option sets for the direct method's guess, compared in one process.

Usage::

    scripts/dev bench ipopt_options.py '{"ipopt.mu_oracle": "probing"}' ...

Each argument is a dict literal of extra ``nlpsol`` options, applied on top of
:class:`~tocontrol_ros.core.direct.collocation.DirectCollocation`'s own (12 intervals, the
paper's arm);
the first row is the project's setting. The guesses are the ones a multistart solves: the
paper's example and 20 seeded random pairs, 4 seed pairs each (84 solves). Every solve runs
with every option set, interleaved and twice (the faster kept), so that the machine's drift
hits all sets alike. Printed per set: solves that succeeded, those that reach the same T as
the first set (to 1e-7, relative), mean IPOPT iterations, median time, and the median and the
sum of the time ratios against the first set.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

# `python -P` (as scripts/dev bench runs it) does not put the repository on sys.path.
sys.path.append(str(Path(__file__).resolve().parents[1]))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from bench.common import START, TARGET, paper_model  # noqa: E402
from bench.random_pairs import draw_pairs  # noqa: E402
from tocontrol_ros.core.direct import collocation as direct_module  # noqa: E402
from tocontrol_ros.core.direct.collocation import DirectCollocation, initial_path  # noqa: E402
from tocontrol_ros.core.methods.seeding import seed_pairs  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, point  # noqa: E402


def build(model, extra: dict) -> DirectCollocation:
    """A DirectCollocation whose nlpsol gets ``extra`` on top of its own options."""
    original = ca.nlpsol

    def nlpsol(name, plugin, nlp, opts):
        return original(name, plugin, nlp, {**opts, **extra})

    direct_module.ca.nlpsol = nlpsol
    try:
        return DirectCollocation(model, 12)
    finally:
        direct_module.ca.nlpsol = original


def main() -> None:
    model = paper_model()
    sets = [{}] + [eval(a) for a in sys.argv[1:]]  # noqa: S307 - a dev tool
    solvers = [build(model, extra) for extra in sets]
    cases = []
    for a, b in [(np.array(START), np.array(TARGET))] + list(draw_pairs(model, 20)):
        problem = Problem(model, point(a), point(b), k=4.0)
        for qa, qb in seed_pairs(problem, SolverOptions(starts=4)):
            cases.append((problem, initial_path(model, qa, qb, 12, 1.0)))
    shape = (len(sets), len(cases))
    times, iters, t_final = np.full(shape, np.inf), np.zeros(shape), np.full(shape, np.nan)
    for rep in range(2):
        for j, (problem, (tg, xg, ug)) in enumerate(cases):
            order = range(len(sets)) if (j + rep) % 2 == 0 else reversed(range(len(sets)))
            for i in order:
                t0 = time.perf_counter()
                res = solvers[i].solve(problem.start.value, problem.target.value, 1.0, tg, xg,
                                       ug)
                times[i, j] = min(times[i, j], time.perf_counter() - t0)
                iters[i, j] = res.iterations
                t_final[i, j] = res.T if res.success else np.nan
    for i, extra in enumerate(sets):
        same = int(np.sum(np.abs(t_final[i] - t_final[0]) <= 1e-7 * t_final[0]))
        ratio = times[i] / times[0]
        print(f"{extra or 'project setting'}: {int(np.isfinite(t_final[i]).sum())}/{len(cases)} "
              f"solved, same T {same}, {iters[i].mean():.1f} iterations, median "
              f"{1e3 * np.median(times[i]):.2f} ms, ratio median {np.median(ratio):.3f}, "
              f"sum {times[i].sum() / times[0].sum():.3f}")


if __name__ == "__main__":
    main()
