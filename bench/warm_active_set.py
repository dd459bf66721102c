"""Tried for issue 47 and not kept: a warm re-solve by SQP on a working set (an experiment).

Kept in bench/ (not in the package) so that the figures of docs/limits.md ("Warm re-solves
by the parametric step", the active-set route) can be reproduced: bench/warm_resolve.py
runs it beside the package's routes (its *active set* column). Measured there: it
converges on few of the 20 moves and is slower than the barrier step where both converge;
the planner does not use it.

The warm re-solve's route where the move changes the active set (issue 47): the barrier
step of :mod:`~tocontrol_ros.core.direct.sensitivity` holds every row's slack at IPOPT's
last barrier parameter, and where a set sample 1e-3 below its bound must become active its
steps are cut to a small fraction by the fraction to the boundary (docs/limits.md). Here the
rows are split instead: a **working set** of rows and variable bounds held as equalities
(from the old solution: those within :data:`ACTIVE_TOL` of their bounds), the others
dropped. Each step solves the equality-constrained QP of the linearisation (the Lagrangian's
Hessian at the old point, the rows' Jacobian at the current one) with the banded KKT of
:class:`~tocontrol_ros.core.direct.sensitivity.BandedKKT`; its working set is corrected as a
**primal-dual active-set** method does (Hintermueller, Ito and Kunisch 2002): a dropped row
that the linearised step would violate is added at the bound it crosses, a held row whose
multiplier has the wrong sign is dropped, and the QP is solved again at the same point; a
step whose working set stands is taken whole. That is the path-following predictor-corrector
of Jaeschke, Yang and Biegler ("Fast economic MPC based on NLP sensitivities", 2014) and
Kungurtsev and Diehl's SQP path following in one loop: the first accepted step is the
tangent predictor with its QP's active set, the next ones correctors on the new set
(Newton with the Hessian kept, re-evaluated at most :data:`REFRESHES` times where a step
does not contract the residual).

Converged: stationarity :data:`STAT_TOL` (units of ``T``, s), rows :data:`PRIMAL_TOL`,
held rows' multipliers of the right sign within :data:`SIGN_TOL`, the others zero: a KKT
point of the NLP with strict complementarity (no barrier), so ``T`` is the converged
optimum of the same NLP. At most :data:`MAX_SOLVES` factorisations; a working set met twice
is a cycle and stops the loop: work decides, never the clock, and a loop that has not
converged is a failure with its reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.sensitivity import BandedKKT, banded_kkt

__all__ = ["ACTIVE_TOL", "MAX_SOLVES", "ActiveSetOutcome", "active_set_solve"]

#: A row or variable this close to its bound at the old solution starts in the working set
#: (IPOPT's solution at its barrier 1e-9 keeps active rows about ``1e-9 / multiplier``
#: inside their bounds).
ACTIVE_TOL = 1e-6
#: ... or whose multiplier is at least this (IPOPT's inactive rows keep about
#: ``1e-9 / room``).
ACTIVE_LAM = 1e-6
#: KKT factorisations at most (each QP of the loop, the working set's corrections
#: included). With 16, as many as the barrier step's budget, it converged on 0 of the 20
#: moves without the proximal term below; 40 is what the bench runs.
MAX_SOLVES = 40
#: Hessian re-evaluations at most (where an accepted step does not cut the residual by
#: :data:`CONTRACTION`).
REFRESHES, CONTRACTION = 2, 0.1
#: Convergence: stationarity (s), rows (their units), multipliers' wrong sign tolerated.
STAT_TOL, PRIMAL_TOL, SIGN_TOL = 1e-6, 1e-9, 1e-9
#: Regularisation of the Hessian block (a proximal term: without the barrier's terms of
#: the dropped rows nothing holds the redundant arm's free directions, and with ``1e-10``
#: or ``1e-6`` the first QP's step left the rows by up to 1e2 and the working set thrashed
#: on every move, the unmoved problem included; ``1e-4`` to ``1e-2`` solved the unmoved one
#: in 2-3 steps) and of the held rows' block; a fixed variable's penalty (its bound held by
#: ``BIG (w_i - bound)`` in the same banded matrix).
PRIMAL_REG, DUAL_REG, BIG = 1e-3, 1e-12, 1e8
#: Bounds of magnitude at least this are absent (IPOPT's ``nlp_lower_bound_inf``).
INF = 1e19


@dataclass(frozen=True)
class ActiveSetOutcome:
    """What the active-set route did, beside its :class:`FlatResult`.

    Attributes
    ----------
    solves : int
        KKT factorisations (QPs solved, working-set corrections included).
    steps : int
        Steps taken (the predictor and the correctors).
    hessians : int
        Evaluations of the Lagrangian's Hessian.
    changed : int
        Rows and variable bounds whose membership of the working set changed.
    reason : str
        "converged", or why it stopped.
    """

    solves: int
    steps: int
    hessians: int
    changed: int
    reason: str


def _sym_product(banded: BandedKKT, hv: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``H x`` for the Hessian ``H`` given by its upper triangle's nonzeros ``hv``."""
    hr, hc = banded.hr, banded.hc
    out = np.bincount(hr, weights=hv * x[hc], minlength=len(x))
    off = hr != hc
    return out + np.bincount(hc[off], weights=hv[off] * x[hr[off]], minlength=len(x))


def _side(value: np.ndarray, lam: np.ndarray, lo: np.ndarray, hi: np.ndarray,
          has_lo: np.ndarray, has_hi: np.ndarray) -> np.ndarray:
    """+1 held at the upper bound, -1 at the lower one, 0 not held.

    Held: a multiplier above :data:`ACTIVE_LAM` (its sign tells the bound), or a value
    within :data:`ACTIVE_TOL` of a bound. A warm state is often the solution slowed down a
    little (``limited._stretched``: up to 3e-4 of ``T``), which moves its active set rows
    up to about 1e-4 inside their bounds; its multipliers are the unstretched solution's.
    """
    lam = np.asarray(lam, dtype=float)
    up = has_hi & ((lam > ACTIVE_LAM) | (hi - value < ACTIVE_TOL))
    down = has_lo & ((lam < -ACTIVE_LAM) | (value - lo < ACTIVE_TOL)) & ~up
    return up.astype(np.int8) - down.astype(np.int8)


def active_set_solve(flat: FlatTranscription, w0: np.ndarray, lam_g0: np.ndarray,
                     lam_x0: np.ndarray, start_value: np.ndarray, target_value: np.ndarray,
                     k: float, lower: np.ndarray, upper: np.ndarray, set_pad: float,
                     should_stop=None) -> tuple[FlatResult, ActiveSetOutcome]:
    """The new problem's solution from a converged one on the same mesh (see the module).

    Parameters
    ----------
    flat : FlatTranscription
        The NLP on the old solution's mesh.
    w0 : ndarray, shape (K n + 1,)
        The old solution: control points (row by row), then ``T`` (s).
    lam_g0, lam_x0 : ndarray, shapes (rows,), (K n + 1,)
        Its multipliers (IPOPT's convention: positive at an upper bound).
    start_value, target_value : ndarray
        The new problem's start (joint state (2n,) or point) and target (point (m,) or
        joint state).
    k : float
    lower, upper : ndarray, shape (2n,)
        State bounds, as for :meth:`FlatTranscription.solve`.
    set_pad : float
    should_stop : callable, optional
        Polled every solve; True stops (a failure, "cancelled").

    Returns
    -------
    FlatResult
        ``success`` only at a KKT point within the tolerances; ``iterations``: KKT solves;
        ``message``: the route and the reason.
    ActiveSetOutcome
    """
    t0 = time.perf_counter()
    jac_fun, hess_fun = flat.kkt_functions
    par = flat.parameters(start_value, target_value, k)
    lbg, ubg, lbx, ubx = flat.bounds(lower, upper, set_pad)
    w = np.array(w0, dtype=float)
    nw, ng = len(w), len(lbg)
    eq = lbg == ubg
    has_lg, has_ug = (lbg > -INF) & ~eq, (ubg < INF) & ~eq
    has_lx, has_ux = lbx > -INF, ubx < INF
    grad_f = np.zeros(nw)
    grad_f[-1] = 1.0
    g, jac = jac_fun(w, par)
    g = np.array(g).ravel()
    hess = hess_fun(w, par, 1.0, np.asarray(lam_g0, dtype=float))
    banded = banded_kkt(flat, jac, hess)
    jr, jc = banded.jr, banded.jc
    hv = np.array(hess.nonzeros())
    jv = np.array(jac.nonzeros())
    row_side = _side(g, lam_g0, lbg, ubg, has_lg, has_ug)
    var_side = _side(w, lam_x0, lbx, ubx, has_lx, has_ux)
    side0 = (row_side.copy(), var_side.copy())
    y = np.where(eq, np.asarray(lam_g0, dtype=float), 0.0)
    v = np.zeros(nw)
    seen: set[bytes] = set()
    solves = steps = 0
    hessians, last, reason = 1, np.inf, f"not converged in {MAX_SOLVES} KKT solves"
    while True:
        if solves >= MAX_SOLVES:
            break
        if should_stop is not None and should_stop():
            reason = "cancelled"
            break
        held = eq | (row_side != 0)
        fixed = var_side != 0
        key = held.tobytes() + row_side.tobytes() + var_side.tobytes() + w.tobytes()
        if key in seen:
            reason = "the working set cycles"
            break
        seen.add(key)
        b = np.where(row_side > 0, ubg, lbg)
        bx = np.where(var_side > 0, ubx, lbx)
        diag = np.concatenate([PRIMAL_REG + np.where(fixed, BIG, 0.0),
                               np.where(held, -DUAL_REG, -1.0)])
        fact = banded.factor(hv, diag, np.where(held[jr], jv, 0.0))
        solves += 1
        if fact is None:
            reason = "KKT matrix singular"
            break
        rhs = np.concatenate([-grad_f + np.where(fixed, BIG * (bx - w), 0.0),
                              np.where(held, b - g, 0.0)])
        sol = banded.solve(fact, rhs)
        if not np.all(np.isfinite(sol)):
            reason = "KKT step not finite"
            break
        dw, y_new = sol[:nw], np.where(held, sol[nw:], 0.0)
        jty = np.bincount(jc, weights=jv * y_new[jr], minlength=nw)
        v_new = np.where(fixed, -(grad_f + _sym_product(banded, hv, dw) + jty), 0.0)
        # The working set's corrections from the linearised step.
        lin = g + np.bincount(jr, weights=jv * dw[jc], minlength=ng)
        w1 = w + dw
        add_u = (row_side == 0) & has_ug & (lin > ubg + PRIMAL_TOL)
        add_l = (row_side == 0) & has_lg & (lin < lbg - PRIMAL_TOL)
        drop = ((row_side > 0) & (y_new < -SIGN_TOL)) | ((row_side < 0) & (y_new > SIGN_TOL))
        fix_u = (var_side == 0) & has_ux & (w1 > ubx + PRIMAL_TOL)
        fix_l = (var_side == 0) & has_lx & (w1 < lbx - PRIMAL_TOL)
        free = ((var_side > 0) & (v_new < -SIGN_TOL)) | ((var_side < 0) & (v_new > SIGN_TOL))
        if np.any(add_u | add_l | drop) or np.any(fix_u | fix_l | free):
            row_side = np.where(add_u, 1, np.where(add_l, -1, np.where(drop, 0, row_side)))
            var_side = np.where(fix_u, 1, np.where(fix_l, -1, np.where(free, 0, var_side)))
            row_side, var_side = row_side.astype(np.int8), var_side.astype(np.int8)
            continue
        # The working set stands: the whole step.
        w, y, v = w1, y_new, v_new
        steps += 1
        g, jac = jac_fun(w, par)
        g = np.array(g).ravel()
        jv = np.array(jac.nonzeros())
        stat = grad_f + np.bincount(jc, weights=jv * y[jr], minlength=nw) + v
        primal = max(float(np.max(np.abs(np.where(held, g - np.where(row_side > 0, ubg, lbg),
                                                   0.0)))),
                     float(np.max(np.maximum(g - ubg, 0.0))),
                     float(np.max(np.maximum(lbg - g, 0.0))),
                     float(np.max(np.abs(np.where(fixed, w - bx, 0.0)))),
                     float(np.max(np.maximum(w - ubx, 0.0))),
                     float(np.max(np.maximum(lbx - w, 0.0))))
        err = max(float(np.max(np.abs(stat))) / STAT_TOL, primal / PRIMAL_TOL)
        if err <= 1.0:
            reason = "converged"
            break
        if err > CONTRACTION * last and hessians <= REFRESHES:
            hv = np.array(hess_fun(w, par, 1.0, y).nonzeros())
            hessians += 1
        last = err
    changed = int(np.sum(side0[0] != row_side) + np.sum(side0[1] != var_side))
    outcome = ActiveSetOutcome(solves, steps, hessians, changed, reason)
    ok = reason == "converged"
    residual = float(max(np.max(np.maximum(lbg - g, 0.0)), np.max(np.maximum(g - ubg, 0.0)),
                         np.max(np.maximum(lbx - w, 0.0)), np.max(np.maximum(w - ubx, 0.0))))
    message = (f"active-set step: {reason} after {solves} KKT solves, {steps} steps "
               f"({hessians} Hessians, {changed} rows or bounds changed activity)")
    return FlatResult(
        success=ok, message=message if ok else f"{message}: failed", T=float(w[-1]),
        P=w[:-1].reshape(flat.K, flat.model.n), residual=residual if ok else np.inf,
        iterations=solves, solve_time=time.perf_counter() - t0, lam_g=y, lam_x=v), outcome
