"""Stages of the solve: smoothing, its stopping rule, the k = 1 retry."""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.problem import Problem, point
from tocontrol_ros.core.solver import SolverOptions, plan

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)


def test_settled_stops_only_on_a_geometric_tail_below_tol():
    from tocontrol_ros.core.solver import _settled

    # T changes of the paper's example at k = 4 for delta = 1e-3 -> 1e-4 -> 1e-5: a ratio of
    # about 1/87, so the rest of the series is ~2e-10, below 1e-8 * T.
    assert _settled([1.33e-6, 1.52e-8], 5.4e-9)
    assert not _settled([1.52e-8], 5.4e-9)               # one change says nothing
    assert not _settled([1e-6, 6e-7], 1e-6)              # shrinking, but not by half
    assert not _settled([1e-3, 1e-5], 5.4e-9)            # geometric, but the tail 1e-7
    assert not _settled([0.0, 1e-9], 5.4e-9)


def test_final_smoothing_is_confirmed_on_the_refined_mesh(galicki):
    """Stopping the coarse schedule early still ends with a solve at the next smaller
    delta on the final mesh that changes T by less than smoothing_tol."""
    opts = SolverOptions(starts=1, candidates=1, verify=False)
    res = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4.0), opts)
    assert res.success
    (k_a, d_a, t_a, *_), (k_b, d_b, t_b, *_) = res.continuation[-2:]
    assert k_a == k_b == 4.0 and d_b < d_a
    assert abs(t_b - t_a) <= opts.smoothing_tol * t_b
    assert res.delta == d_b


def test_k1_newton_is_retried_on_twice_the_intervals(galicki, monkeypatch):
    """A k = 1 Newton failure on `intervals` intervals is retried once on twice as many
    (planar 8R in bench/scaling.py: initial residual 18 on 12 intervals, stall; converges
    on 24); a failure on both is reported as NEWTON_FAILED."""
    from tocontrol_ros.core import context, solver

    sizes = []
    real = context.newton_solve

    def fail_on(bad):
        def newton(grid, *args, **kwargs):
            sizes.append(grid.N)
            if grid.N in bad:
                return solver.NewtonReport(False, args[0], 1.0, 1, "stalled (forced)")
            return real(grid, *args, **kwargs)
        return newton

    problem = Problem(galicki, point(P_START), point(P_TARGET), k=1.0)
    opts = SolverOptions(starts=1, candidates=1, verify=False, intervals=6)
    monkeypatch.setattr(context, "newton_solve", fail_on({6}))
    res = plan(problem, opts)
    assert res.success and sizes[:2] == [6, 12]
    sizes.clear()
    monkeypatch.setattr(context, "newton_solve", fail_on({6, 12}))
    res = plan(problem, opts)
    assert res.status is solver.Status.NEWTON_FAILED and sizes == [6, 12]
    assert "forced" in res.message
