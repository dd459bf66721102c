"""A converged bounded solve carried to a nearby problem: a parametric primal-dual step.

At the primal-dual solution ``(w*, lam*)`` of the bounded B-spline NLP
(:class:`~tocontrol_ros.core.direct.flat.FlatTranscription`) for parameters ``p0`` (start,
target, ``k``), the solution of a nearby problem ``p1`` (a moved target) is, under strict
complementarity and second-order sufficiency, ``w(p1) = w* + dw + O(|p1 - p0|^2)`` with
``dw`` from one solve with the KKT matrix at ``(w*, lam*)`` (Fiacco; Bonnans and Shapiro,
ch. 5). Here the KKT system is IPOPT's own primal-dual barrier system at a fixed barrier
parameter :data:`MU` (as sIPOPT, Pirnay, Lopez-Negrete and Biegler 2012, and the advanced-
step controller of Zavala and Biegler 2009 do): every row keeps a slack and bound
multipliers, so no active set has to be guessed from the interior-point solution, and the
matrix's sparsity never changes. The first Newton step from the old solution on the new
parameters is the tangent predictor; the correctors are further Newton steps, the
Lagrangian's Hessian kept from the first (chord steps: the rows, their Jacobian and the
barrier terms evaluated again each step; the Hessian re-evaluated, at most
:data:`REFRESHES` times, after a step cut by the boundary or one that did not cut the
residual by :data:`CONTRACTION`), each cut by the fraction-to-the-boundary rule, so slacks
and multipliers stay positive and every inequality holds strictly (the whole move's dual
step is taken in full instead, the multipliers that it takes below the barrier's reach
reset onto it: :data:`DUAL_RESET`). Where the move changes
the active set the slacks and multipliers of those rows must change places: the barrier
alone then cut its steps to 1e-4-1e-2 of their length and did not converge within the
budget (docs/limits.md, "Warm re-solves by the parametric step"). So a step cut below
:data:`HOLD_BELOW` of its length is solved again with the rows that block it first held at
their bounds as equalities (their slack gone, their multiplier free), the primal active-set
method's move inside the barrier step; a held row whose multiplier turns to the wrong sign
once the step is nearly converged goes back to the barrier (:data:`RELEASE_ROOM` inside
its bound). The answer is then a KKT point with those rows exactly at their bounds and the
others' complementarity at ``MU``. A step still blocked after :data:`HOLD_ROUNDS` such
re-solves stops the solve (the rows to hold keep growing: such solves did not converge).
At most :data:`MAX_STEPS` steps and :data:`MAX_SOLVES` factorisations: the solver decides
by work, never by the clock; a solve that has not converged then is a failure with its
reason. The caller
(:func:`~tocontrol_ros.core.direct.limited.plan_limited_warm`) then follows the move in
:data:`PATH_SUBMOVES` sub-moves (``submoves``: a Newton homotopy that takes off a share of
the old point's KKT residual on the new parameters at a time, each sub-move's first step
the tangent predictor to the next point of the path, the next ones its correctors; its own
budget), and re-solves with IPOPT where that fails too.

A Newton step on a guessed active set (strongly active rows as equalities, the others
checked after) failed on the planner's solutions: many rows are weakly active, and dropping
their small multipliers left the stationarity residual at 0.24 (docs/limits.md).

The KKT matrix ``[[H + S_x, J^T], [J, -D]]`` is ordered along the path (each control
point's variables, then the rows that touch it), which makes it banded (a band of about
``10 n`` on each side) bordered by ``T``'s row and column: factorised by LAPACK's banded
LU with partial pivoting (``dgbtrf``), ``T`` by a Schur complement: about 1 ms at 24 spans
on the Panda.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.linalg import lapack

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription, violation
from tocontrol_ros.core.direct.kkt_step import kkt_derivatives

__all__ = ["DUAL_RESET", "FAR_SIDE_LEAST_ROOM", "HOLD_ROUNDS", "MAX_STEPS", "MU", "PATH_SOLVES",
           "PATH_STEPS", "PATH_SUBMOVES", "PATH_SUB_BUDGET", "BandedKKT", "SensitivityOutcome",
           "banded_kkt", "iterate", "sensitivity_solve"]

#: The barrier parameter the steps hold: IPOPT's last one at its tolerance 1e-8, where the
#: warm point sits (larger ones took more steps). Measured on the Panda's 24 spans, ``T``
#: converged equals IPOPT's converged re-solve of the same NLP to about 1e-8 (relative).
MU = 1e-9
#: Newton steps at most (the predictor included).
MAX_STEPS = 12
#: Hessian re-evaluations at most, when a step cuts the residual by less than this factor.
REFRESHES, CONTRACTION = 4, 0.1
#: Steps cut below this fraction by the boundary this many times in a row: the active set
#: is changing and the steps would not converge within the budget (measured: they never
#: did); stopped there, so that the fallback starts sooner.
BLOCKED_FRACTION, BLOCKED_STEPS = 0.1, 3
#: Fraction-to-the-boundary factor (IPOPT's ``tau_min``).
TAU = 0.99
#: Convergence: stationarity (units of the objective ``T``, s), primal rows (their units)
#: and complementarity within this factor of ``MU``.
STAT_TOL, PRIMAL_TOL, COMPL_FACTOR = 1e-6, 1e-9, 10.0
#: Regularisation of the Hessian block (the redundant arm's self-motion where nothing
#: holds it) and of the equality rows' block; the residuals are judged unregularised.
PRIMAL_REG, DUAL_REG = 1e-10, 1e-12
#: Bounds of magnitude at least this are absent (IPOPT's ``nlp_lower_bound_inf``).
INF = 1e19
#: A step cut below :data:`HOLD_BELOW` of its length by the bounds: the rows that the
#: whole step would carry across their bounds within :data:`HOLD_SPREAD` times that cut
#: (the ones that block first) are held at their bounds and the step solved again
#: (docs/limits.md; on the 20 moves of bench/warm_resolve.py a spread of 2 converged on
#: 13, 1.2 on 11, 5 on 10, 10 on 8: then rows that only the linearisation carries across
#: are held too).
HOLD_BELOW, HOLD_SPREAD = 0.5, 2.0
#: KKT factorisations at most (the steps and the re-solves after rows are held).
MAX_SOLVES = 16
#: Re-solves after holding rows within one step at most: one more and the step's rows to
#: hold keep growing (the linearisation carries ever more rows across: on the 20 moves of
#: bench/warm_resolve.py the steps that converged held rows at most 3 times within a step,
#: those that failed up to 12 times, or cycled releasing and holding one row); the solve
#: stops there, a failure, so that what follows starts sooner (docs/limits.md).
HOLD_ROUNDS = 4
#: A held row's multiplier of the wrong sign by more than this, once the residual is below
#: ``RELEASE_ERR`` (in units of the tolerances) after a whole step, releases it to the
#: barrier, ``RELEASE_ROOM`` inside its bound.
SIGN_TOL, RELEASE_ERR, RELEASE_ROOM = 1e-9, 1e6, 1e-4
#: A sub-move of the path-following (``submoves`` > 1) is done when its residual is within
#: this many times the tolerances.
SUB_TOL = 1e3
#: Where the whole move's steps do not converge, the move is followed in this many
#: sub-moves within these budgets (Newton steps, KKT factorisations: in all, and within
#: each sub-move). Measured in process on the 20 moves of bench/warm_resolve.py
#: (docs/limits.md): of the 7 moves whose whole-move steps failed, 2 sub-moves converged
#: on 3 (17-21 steps, 37-45 ms; each sub-move within 12 steps and 20 factorisations), 3
#: sub-moves on 1, 4 on 3 (27-38 steps), 8 on 3 (32-44 steps); each sub-move needs
#: Hessians of its own (with the whole move's 5, 2 sub-moves converged on one). The moves
#: that failed in 2 sub-moves never ended the first: the budget of a sub-move stops them
#: after 14 steps or 24 factorisations instead of the whole budget.
PATH_SUBMOVES, PATH_STEPS, PATH_SOLVES = 2, 28, 48
PATH_SUB_BUDGET = (14, 24)
#: The barrier's start pushes a value with two bounds into each by that bound's own least
#: room (:func:`_barrier_start`); False: the upper side by its room to the old value, which
#: put a value on its lower bound back onto it (the route before; bench/warm_resolve.py's
#: *before* column).
FAR_SIDE_LEAST_ROOM = True
#: The whole move's steps (``submoves`` 1) take the full dual step, then put every bound
#: multiplier whose product with its slack fell below ``MU / KAPPA`` (or turned negative)
#: back on the barrier's own value ``MU / slack``, instead of cutting the dual step by the
#: fraction to the boundary: the rows that leave the active set cut that step to 1e-2 and
#: less in the first steps (IPOPT's ``kappa_sigma`` safeguard resets multipliers so, after
#: its cut step). Measured on bench/warm_resolve.py's 20 moves with the pads per sample
#: (bench/warm_pad_rows.py): one parametric solve on 11 (10 without), 1-2 Newton steps
#: fewer on 4 of them; at one pad for all it lost 2 moves to IPOPT and in the sub-moves it
#: lost both of theirs (docs/limits.md, "Pads per sample"). False: the route before.
DUAL_RESET, KAPPA = True, 1e10


@dataclass(frozen=True)
class SensitivityOutcome:
    """What the parametric step did, beside its :class:`FlatResult`.

    Attributes
    ----------
    steps : int
        Newton steps taken (the predictor and the correctors).
    hessians : int
        Evaluations of the Lagrangian's Hessian (each followed by a factorisation; every
        step factorises the matrix with its new barrier terms).
    changed : int
        Rows whose activity changed (slack below ``1e-6`` or held at the start and not at
        the end, or the other way).
    holds, released : int
        Rows held at their bounds because they blocked a step, and held rows released to
        the barrier again (their multiplier of the wrong sign).
    solves : int
        KKT factorisations (the steps and the re-solves after rows were held).
    reason : str
        "converged", or why it stopped.
    """

    steps: int
    hessians: int
    changed: int
    reason: str
    holds: int = 0
    released: int = 0
    solves: int = 0


class BandedKKT:
    """The KKT matrix's ordering along the path, its band, built once per sparsity.

    ``[[H + diag_w, J^T], [J, diag_g]]`` for the Lagrangian's Hessian ``H`` (upper triangle
    as CasADi gives it) and the rows' Jacobian ``J``, both by their nonzeros; ordered along
    the path (each control point's variables, then the rows that touch it), banded,
    bordered by ``T`` (the last variable). Also used by the active-set route
    (:mod:`~tocontrol_ros.core.direct.active_set`).
    """

    def __init__(self, jac_rc: tuple, hess_rc: tuple, nw: int, ng: int, n: int) -> None:
        jr, jc = jac_rc
        hr, hc = hess_rc
        self.jr, self.jc, self.hr, self.hc = jr, jc, hr, hc
        iT, N = nw - 1, nw + ng
        # Each unknown's place along the path: a control point's index, a row's the mean of
        # its control points'; T (the last variable) is the border.
        key_w = np.arange(nw, dtype=float) // n
        path = jc != iT
        tot, cnt = np.zeros(ng), np.zeros(ng)
        np.add.at(tot, jr[path], key_w[jc[path]])
        np.add.at(cnt, jr[path], 1.0)
        key_g = np.where(cnt > 0, tot / np.maximum(cnt, 1.0), 0.0)
        core = np.concatenate([np.arange(iT), nw + np.arange(ng)])
        keys = np.concatenate([key_w[:iT], key_g + 0.5])  # a row after its variables
        order = core[np.argsort(keys, kind="stable")]
        pos = np.full(N, -1)
        pos[order] = np.arange(len(order))
        self.pos, self.iT, self.nw, self.ng, self.M = pos, iT, nw, ng, len(order)
        # The core's unknowns (all but T) and their places in the band, for the solves.
        self.core_at = np.flatnonzero(pos >= 0)
        self.core_pos = pos[self.core_at]
        # The matrix's entries: H (upper triangle, mirrored), the diagonal, J and J^T.
        off = hr != hc
        rows = np.concatenate([hr, hc[off], np.arange(N), nw + jr, jc])
        cols = np.concatenate([hc, hr[off], np.arange(N), jc, nw + jr])
        self.parts = (len(hr), int(off.sum()), N, len(jr))
        self.off = off
        pr, pc = pos[rows], pos[cols]
        inner = (pr >= 0) & (pc >= 0)
        self.kl = int(np.max(pr[inner] - pc[inner]))
        self.ku = int(np.max(pc[inner] - pr[inner]))
        rows_ab = 2 * self.kl + self.ku + 1
        self.shape_ab = (rows_ab, self.M)
        self.inner = inner
        # Each entry's place in LAPACK's band storage, column-major (Fortran order, as
        # dgbtrf takes it: assembled there, no copy; the same sums as row-major's).
        self.lin = (self.kl + self.ku + pr[inner] - pc[inner]) + pc[inner] * rows_ab
        # The border: T's column (rows of the core) and T's diagonal entry.
        col_T = (cols == iT) & (pr >= 0)
        self.col_T, self.col_T_at = col_T, pr[col_T]
        self.diag_T = (rows == iT) & (cols == iT)

    def factor(self, hess: np.ndarray, diag: np.ndarray, jac: np.ndarray):
        """LU of the core band and the border's Schur complement; None if singular."""
        data = np.concatenate([hess, hess[self.off], diag, jac, jac])
        ab = np.bincount(self.lin, weights=data[self.inner],
                         minlength=self.shape_ab[0] * self.M).reshape(self.shape_ab, order="F")
        b = np.bincount(self.col_T_at, weights=data[self.col_T], minlength=self.M)
        d = float(np.sum(data[self.diag_T]))
        lub, piv, info = lapack.dgbtrf(ab, self.kl, self.ku, overwrite_ab=True)
        if info != 0:
            return None
        u, info = lapack.dgbtrs(lub, self.kl, self.ku, b, piv)
        schur = d - float(b @ u)
        if info != 0 or not np.isfinite(schur) or schur == 0.0:
            return None
        return lub, piv, b, u, schur

    def solve(self, fact, rhs: np.ndarray) -> np.ndarray:
        """The solution (N,) of the factorised system for ``rhs`` (N,), original order."""
        lub, piv, b, u, schur = fact
        r1 = np.empty(self.M)
        r1[self.core_pos] = rhs[self.core_at]
        v, _ = lapack.dgbtrs(lub, self.kl, self.ku, r1, piv, overwrite_b=True)
        xT = (rhs[self.iT] - float(b @ v)) / schur
        x1 = v - u * xT
        out = np.empty_like(rhs)
        out[self.core_at] = x1[self.core_pos]
        out[self.iT] = xT
        return out


def banded_kkt(flat: FlatTranscription, jac, hess) -> BandedKKT:
    """The :class:`BandedKKT` of ``flat``'s NLP, built at its first use and kept.

    Parameters
    ----------
    flat : FlatTranscription
    jac, hess : casadi.DM or casadi.Sparsity
        The rows' Jacobian and the Lagrangian's Hessian as ``flat.kkt_functions`` return
        them, or their sparsities (only the sparsity is read).
    """
    nw, ng = hess.size1(), jac.size1()
    key = ("kkt", nw, ng)
    banded = flat.kkt_cache.get(key)
    if banded is None:
        banded = BandedKKT(_triplets(jac), _triplets(hess), nw, ng, flat.model.n)
        flat.kkt_cache[key] = banded
    return banded


def _triplets(fn_out) -> tuple[np.ndarray, np.ndarray]:
    sp = fn_out if isinstance(fn_out, ca.Sparsity) else fn_out.sparsity()
    r, c = sp.get_triplet()
    return np.asarray(r, dtype=int), np.asarray(c, dtype=int)


def _least_room(lam: np.ndarray) -> np.ndarray:
    """The least slack a bound with multiplier ``lam`` starts with (their product ``MU``)."""
    return MU / np.maximum(lam, np.sqrt(MU))


def _split(lam: np.ndarray, room: np.ndarray, has: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """A bound's multiplier and slack from IPOPT's, their product at least :data:`MU`."""
    room = np.maximum(room, _least_room(lam))
    lam = np.maximum(lam, MU / room)
    return np.where(has, lam, 0.0), np.where(has, room, 1.0)


def _barrier_start(value: np.ndarray, lower: np.ndarray, upper: np.ndarray, lam: np.ndarray,
                   has_l: np.ndarray, has_u: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The barrier's start from IPOPT's point: slacks (or variables) and bound multipliers.

    Parameters
    ----------
    value : ndarray, shape (m,)
        The rows' values (or the variables) at IPOPT's point.
    lower, upper : ndarray, shape (m,)
        Their bounds.
    lam : ndarray, shape (m,)
        IPOPT's multipliers (positive at an upper bound, negative at a lower one).
    has_l, has_u : ndarray of bool, shape (m,)
        Which bounds the barrier holds.

    Returns
    -------
    value : ndarray, shape (m,)
        Inside each bound by at least its least room (:func:`_least_room`, the product with
        its multiplier :data:`MU`): IPOPT returns points on its relaxed bounds.
    z_l, z_u : ndarray, shape (m,)
        The lower and upper bounds' multipliers (0 where absent).

    A two-sided bound's far side pushes the value in by its own least room only
    (:data:`FAR_SIDE_LEAST_ROOM`); pushed in by its room to the old value, as before, a
    value on its lower bound was pulled back onto it: a zero slack, and the first KKT step
    not finite (a velocity row held at its lower bound by the steps, carried to a wider pad:
    bench/warm_resolve.py's case 20).
    """
    z_l, room_l = _split(np.maximum(-lam, 0.0), value - lower, has_l)
    z_u, room_u = _split(np.maximum(lam, 0.0), upper - value, has_u)
    value = np.where(has_l, np.maximum(value, lower + room_l), value)
    far = _least_room(np.maximum(lam, 0.0)) if FAR_SIDE_LEAST_ROOM else room_u
    return np.where(has_u, np.minimum(value, upper - far), value), z_l, z_u


def iterate(flat: FlatTranscription, w: np.ndarray, g: np.ndarray, bounds: tuple,
            steps: int, solve_time: float, lam_g: np.ndarray, lam_x: np.ndarray
            ) -> FlatResult:
    """A Newton iterate as a (not converged) :class:`FlatResult`.

    Parameters
    ----------
    flat : FlatTranscription
    w : ndarray, shape (K n + 1,)
        The iterate: control points (row by row), then ``T`` (s).
    g : ndarray, shape (rows,)
        The NLP's rows at ``w``.
    bounds : tuple of ndarray
        ``(lbg, ubg, lbx, ubx)``, the NLP's bounds (its pads).
    steps : int
        Newton steps taken.
    solve_time : float
        The solve's time so far (s).
    lam_g, lam_x : ndarray, shapes (rows,), (K n + 1,)
        The iterate's multipliers (IPOPT's convention).

    Returns
    -------
    FlatResult
        ``success`` False, ``residual`` the largest violation of the bounds at ``w``.
    """
    return FlatResult(
        success=False, message=f"parametric step: iterate after {steps} Newton steps",
        T=float(w[-1]), P=w[:-1].reshape(flat.K, flat.model.n),
        residual=violation(w, g, *bounds), iterations=steps,
        solve_time=solve_time, lam_g=np.array(lam_g), lam_x=np.array(lam_x))


def _boundary_step(dx, room) -> float:
    """Largest ``a`` in (0, 1] with ``room + a dx >= (1 - TAU) room`` where ``dx < 0``."""
    neg = dx < 0.0
    if not np.any(neg):
        return 1.0
    return float(min(1.0, np.min(-TAU * room[neg] / dx[neg])))


def sensitivity_solve(flat: FlatTranscription, w0: np.ndarray, lam_g0: np.ndarray,
                      lam_x0: np.ndarray, start_value: np.ndarray, target_value: np.ndarray,
                      k: float, lower: np.ndarray, upper: np.ndarray,
                      set_pad: float | np.ndarray,
                      should_stop=None, hold: bool = True, submoves: int = 1,
                      max_steps: int | None = None, max_solves: int | None = None,
                      sub_budget: tuple[int, int] | None = None,
                      on_step: Callable[[FlatResult], None] | None = None
                      ) -> tuple[FlatResult, SensitivityOutcome]:
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
    set_pad : float or ndarray, shape (S,)
        The set's pad, one for all samples or one per sample (:mod:`~.set_pads`).
    should_stop : callable, optional
        Polled every step; True stops (a failure, "cancelled").
    hold : bool
        Hold the rows that block a step at their bounds (:data:`HOLD_BELOW`); False: the
        barrier alone (the route before; bench/warm_resolve.py's comparison).
    submoves : int
        The move in this many equal sub-moves (path-following, :data:`PATH_SUBMOVES`; 1:
        the whole move at once, the steps as before to the bit). Each sub-move has its own
        :data:`REFRESHES` Hessian re-evaluations.
    max_steps, max_solves : int, optional
        The work budget: Newton steps and KKT factorisations at most (default
        :data:`MAX_STEPS`, :data:`MAX_SOLVES`).
    sub_budget : tuple of int, optional
        Newton steps and factorisations at most within each sub-move (default: only the
        totals): a sub-move that has not ended within them stops the solve.
    on_step : callable, optional
        Called with each Newton step's iterate that is not the converged answer (after
        the step, before the next; the last one of a solve that stops unconverged too) as
        a :class:`FlatResult` (:func:`iterate`: ``success`` False, ``residual`` its largest
        violation of the NLP's rows and bounds, ``iterations`` the steps so far); it only
        reads (the steps are the same with or without it). The warm re-solve's first
        motion (:class:`~.checked.FirstIterate`) checks there whether an iterate is
        already a motion to publish.

    Returns
    -------
    FlatResult
        ``success`` only when the barrier KKT conditions hold to the tolerances;
        ``iterations``: Newton steps; ``message``: the route and the reason.
    SensitivityOutcome
    """
    t0 = time.perf_counter()
    max_steps = MAX_STEPS if max_steps is None else max_steps
    max_solves = MAX_SOLVES if max_solves is None else max_solves
    der = kkt_derivatives(flat)
    par = flat.parameters(start_value, target_value, k)
    lbg, ubg, lbx, ubx = flat.bounds(lower, upper, set_pad, (start_value, target_value))
    nw, ng = len(w0), len(lbg)
    w = np.array(w0, dtype=float)
    reset = DUAL_RESET and submoves == 1
    eq = lbg == ubg
    has_lg, has_ug = (lbg > -INF) & ~eq, (ubg < INF) & ~eq
    has_lx, has_ux = lbx > -INF, ubx < INF
    grad_f = np.zeros(nw)
    grad_f[-1] = 1.0
    g, jv = der.rows(w, par)
    hv = der.hessian(w, par, np.asarray(lam_g0, dtype=float))
    banded = banded_kkt(flat, der.jac_sparsity, der.hess_sparsity)
    # The barrier's variables from IPOPT's point: the bounds' multipliers split by sign,
    # slacks (the rows' values) inside their bounds with a product of at least MU (IPOPT
    # returns points on its relaxed bounds: a slack of 1e-14 would make the multiplier
    # MU / 1e-14 and break stationarity).
    lam_g0 = np.asarray(lam_g0, dtype=float)
    lam_x0 = np.asarray(lam_x0, dtype=float)
    s, zl, zu = _barrier_start(g, lbg, ubg, lam_g0, has_lg, has_ug)
    w, vl, vu = _barrier_start(w, lbx, ubx, lam_x0, has_lx, has_ux)
    y = np.where(eq, lam_g0, zu - zl)
    s = np.where(eq, lbg, s)
    # The four kinds of bounds side by side: the rows' lower and upper bounds, then the
    # variables' (slices lo_g, up_g, lo_x, up_x of the multipliers z, the rooms and the
    # masks), so that a step's complementarity, barrier terms, fraction to the boundary
    # and updates are one NumPy operation each instead of four: the same elementwise
    # arithmetic as one array per kind, to the bit (issue 47).
    lo_g, up_g = slice(0, ng), slice(ng, 2 * ng)
    lo_x, up_x = slice(2 * ng, 2 * ng + nw), slice(2 * ng + nw, 2 * (ng + nw))
    z = np.concatenate([zl, zu, vl, vu])
    room = np.where(np.concatenate([has_lg, has_ug, has_lx, has_ux]),
                    np.concatenate([s - lbg, ubg - s, w - lbx, ubx - w]), 1.0)
    g, jv = der.rows(w, par)
    active0 = (np.minimum(room[lo_g], room[up_g]) < 1e-6)
    # The move in sub-moves (a Newton homotopy, the path-following in the parameter):
    # sub-move j of m solves the KKT conditions less (1 - j / m) of their residual at the
    # old point on the new parameters (j = 0: the old point, solved; j = m: the new
    # problem). Each sub-move's first step is the tangent predictor to the next point of
    # the path, the following ones its correctors; it is done when its residual is within
    # SUB_TOL times the tolerances (the held rows carried on), the last one converged.
    r_w0 = grad_f + np.bincount(banded.jc, weights=jv * y[banded.jr], minlength=nw) \
        + z[up_x] - z[lo_x]
    # The rows' residual: s is lbg on the equality rows and the bound on the held rows
    # (their steps are zero), so g - s is g - lbg, g - bound and g - s as before.
    r_y0 = g - s
    sub, fresh, sub_from = 1, 1, (0, 0)
    hessians, steps, last, reason = 1, 0, np.inf, f"not converged in {max_steps} steps"
    full, blocked, solves, retry, holds, released = False, 0, 0, False, 0, 0
    rounds = 0  # re-solves after holding rows within this step
    seen = 0  # the last step whose iterate went to on_step
    # Rows held at a bound (+1 upper, -1 lower; 0: the barrier's slack): a row that blocks
    # a step, held there as an equality while its multiplier has the right sign.
    side = np.zeros(ng, dtype=np.int8)
    stale = True  # the masks below follow side (made again when a row is held or released)
    # A zero room or a step that is not finite ends as a failure ("KKT step not finite").
    with np.errstate(divide="ignore", invalid="ignore"):
        while True:
            if stale:
                held = side != 0
                any_held = bool(np.any(held))
                heq = eq | held
                hlg, hug, hin = has_lg & ~held, has_ug & ~held, ~heq
                b_held = np.where(side > 0, ubg, lbg)
                has = np.concatenate([hlg, hug, has_lx, has_ux])
                stale = False
            r_w = grad_f + np.bincount(banded.jc, weights=jv * y[banded.jr], minlength=nw) \
                + z[up_x] - z[lo_x]
            r_s = np.where(hin, -y - z[lo_g] + z[up_g], 0.0)
            r_y = g - s
            if sub < submoves:  # the homotopy's share of the old point's residual
                r_w = r_w - (1.0 - sub / submoves) * r_w0
                r_y = r_y - (1.0 - sub / submoves) * r_y0
            r_z = np.where(has, z * room - MU, 0.0)
            wrong = (side > 0) & (y < -SIGN_TOL) | (side < 0) & (y > SIGN_TOL) \
                if any_held else None
            any_wrong = wrong is not None and bool(np.any(wrong))
            err = max(float(np.max(np.abs(r_w))) / STAT_TOL,
                      float(np.max(np.abs(r_s))) / STAT_TOL,
                      float(np.max(np.abs(r_y))) / PRIMAL_TOL,
                      float(np.max(np.abs(r_z))) / (COMPL_FACTOR * MU))
            if on_step is not None and seen < steps and (err > 1.0 or any_wrong):
                # A new iterate that is not the answer (the answer is the caller's).
                seen = steps
                on_step(iterate(flat, w, g, (lbg, ubg, lbx, ubx), steps,
                                time.perf_counter() - t0,
                                np.where(heq, y, z[up_g] - z[lo_g]), z[up_x] - z[lo_x]))
            if sub < submoves and err <= SUB_TOL:
                sub += 1
                blocked, full, last, fresh, sub_from = 0, False, np.inf, 0, (steps, solves)
                continue
            if err <= 1.0 and not any_wrong:
                reason = "converged"
                break
            if steps >= max_steps:
                break
            if solves >= max_solves:
                reason = f"not converged in {max_solves} KKT solves"
                break
            if sub_budget is not None and (steps - sub_from[0] >= sub_budget[0]
                                           or solves - sub_from[1] >= sub_budget[1]):
                reason = (f"sub-move {sub} not done within its budget ({sub_budget[0]} "
                          f"steps, {sub_budget[1]} KKT solves)")
                break
            if blocked >= BLOCKED_STEPS:
                reason = (f"{blocked} steps in a row cut below {BLOCKED_FRACTION:g} of their "
                          f"length by the bounds (the active set changes)")
                break
            if should_stop is not None and should_stop():
                reason = "cancelled"
                break
            if any_wrong and full and err <= RELEASE_ERR:
                # A held row whose multiplier has turned: back to the barrier, a little inside.
                s = np.where(wrong, b_held - side * RELEASE_ROOM, s)
                z = z.copy()
                z[up_g] = np.where(wrong & (side > 0), MU / RELEASE_ROOM, z[up_g])
                z[lo_g] = np.where(wrong & (side < 0), MU / RELEASE_ROOM, z[lo_g])
                side = np.where(wrong, 0, side).astype(np.int8)
                room = room.copy()
                room[lo_g] = np.where(has_lg & (side == 0), s - lbg, 1.0)
                room[up_g] = np.where(has_ug & (side == 0), ubg - s, 1.0)
                released += int(np.sum(wrong))
                stale = True
                continue
            if not retry and steps > 0 and (not full or err > CONTRACTION * last) \
                    and fresh <= REFRESHES:
                hv = der.hessian(w, par, y)
                hessians += 1
                fresh += 1
            last = err
            sig = np.where(has, z / room, 0.0)
            sig_x, sig_s = sig[lo_x] + sig[up_x], sig[lo_g] + sig[up_g]
            d_row = np.where(heq, DUAL_REG, 1.0 / np.where(hin, sig_s, 1.0))
            diag = np.concatenate([sig_x + PRIMAL_REG, -d_row])
            r_q = np.where(has, r_z / room, 0.0)
            rt_s = r_s + r_q[lo_g] - r_q[up_g]
            rhs_w = -r_w - r_q[lo_x] + r_q[up_x]
            rhs_y = np.where(heq, -r_y, -r_y - rt_s * d_row)
            fact = banded.factor(hv, diag, jv)
            solves += 1
            if fact is None:
                reason = "KKT matrix singular"
                break
            sol = banded.solve(fact, np.concatenate([rhs_w, rhs_y]))
            if not np.all(np.isfinite(sol)):
                reason = "KKT step not finite"
                break
            dw, dy = sol[:nw], sol[nw:]
            ds = np.where(hin, (dy - rt_s) * d_row, 0.0)
            # Each bound's direction: an upper bound's room shrinks as the value grows
            # (-r - z (-d) is -r + z d to the bit).
            dir_ = np.concatenate([ds, -ds, dw, -dw])
            dz = np.where(has, (-r_z - z * dir_) / room, 0.0)
            # The four kinds of bounds in one pass (the same minimum as four).
            a_p = _boundary_step(np.where(has, dir_, 0.0), room)
            retry = False
            if hold and a_p < HOLD_BELOW:
                # Rows the whole step would carry across their bounds: held there, the step
                # solved again (the same Hessian).
                reach = HOLD_SPREAD * a_p
                room_lg, room_ug = room[lo_g], room[up_g]
                cross_u = hug & (ds > room_ug) & (room_ug <= reach * ds)
                cross_l = hlg & (ds < -room_lg) & (room_lg <= -reach * ds)
                if np.any(cross_u | cross_l):
                    if rounds >= HOLD_ROUNDS:
                        reason = (f"a step still blocked after {rounds} re-solves with rows "
                                  f"held (the rows that block it keep growing)")
                        break
                    rounds += 1
                    side = np.where(cross_u, 1, np.where(cross_l, -1, side)).astype(np.int8)
                    held = side != 0
                    s = np.where(cross_u, ubg, np.where(cross_l, lbg, s))
                    z = z.copy()
                    z[lo_g], z[up_g] = np.where(held, 0.0, z[lo_g]), np.where(held, 0.0, z[up_g])
                    room = room.copy()
                    room[lo_g] = np.where(has_lg & ~held, s - lbg, 1.0)
                    room[up_g] = np.where(has_ug & ~held, ubg - s, 1.0)
                    holds += int(np.sum(cross_u | cross_l))
                    retry = True
                    stale = True
                    continue
            # The dual step's fraction to the boundary (the whole move's reset takes it in
            # full: not computed there).
            a_d = 1.0 if reset else _boundary_step(dz, z + ~has)
            full = a_p == 1.0
            blocked = blocked + 1 if a_p < BLOCKED_FRACTION else 0
            rounds = 0
            w = w + a_p * dw
            s = s + a_p * ds
            y = y + a_p * dy
            z = z + a_d * dz
            room = np.where(has, np.concatenate([s - lbg, ubg - s, w - lbx, ubx - w]), 1.0)
            if reset:
                z = np.where(has & (z * room < MU / KAPPA), MU / room, z)
            steps += 1
            g, jv = der.rows(w, par)
    active1 = (np.minimum(room[lo_g], room[up_g]) < 1e-6) | (side != 0)
    outcome = SensitivityOutcome(steps, hessians, int(np.sum(active0 != active1)), reason,
                                 holds, released, solves)
    lam_g = np.where(eq | (side != 0), y, z[up_g] - z[lo_g])
    lam_x = z[up_x] - z[lo_x]
    residual = violation(w, g, lbg, ubg, lbx, ubx)
    ok = reason == "converged"
    moves = f" in {submoves} sub-moves" if submoves > 1 else ""
    message = (f"parametric step{moves}: {reason} after {steps} Newton steps "
               f"({solves} KKT solves, {hessians} Hessians, {outcome.changed} rows changed "
               f"activity, {holds} held at their bounds, {released} released)")
    return FlatResult(
        success=ok, message=message if ok else f"{message}: failed", T=float(w[-1]),
        P=w[:-1].reshape(flat.K, flat.model.n), residual=residual if ok else np.inf,
        iterations=steps, solve_time=time.perf_counter() - t0, lam_g=lam_g,
        lam_x=lam_x), outcome
