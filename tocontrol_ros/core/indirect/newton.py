"""The damped Newton method that solves the shooting equations, with chord steps.

:func:`newton_solve` solves ``G(w) = 0`` for the equations of a
:class:`~tocontrol_ros.core.indirect.shooting.ShootingGrid`: damped Newton steps with a
backtracking line search, and between them chord steps on the kept LU factors with
Broyden's rank-one updates (:class:`_Broyden`). The pieces of one iteration: the end tests
(:func:`_stopped`), a chord step (:func:`_chord_step`), a Newton step on a fresh Jacobian
(:func:`_newton_step`), its line search (:func:`_line_search`) and the stall test
(:func:`_stall`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import SuperLU, splu

from tocontrol_ros.core.indirect.shooting import ShootingGrid
from tocontrol_ros.core.indirect.tuning import (
    CHORD_CONTRACTION,
    CHORD_MAX,
    STALL_COUNT,
    STALL_STEP,
)

__all__ = ["NewtonReport", "newton_solve"]


@dataclass(frozen=True)
class NewtonReport:
    """Outcome of one Newton solve.

    Attributes
    ----------
    converged : bool
    w : ndarray
        Final unknowns.
    residual : float
        Max-norm of the equations at ``w``.
    iterations : int
    message : str
    factors : scipy.sparse.linalg.SuperLU or None
        LU factors of the last Jacobian evaluated (not necessarily at ``w``): a later solve
        on the same grid (the next ``delta``, a warm start) can begin with chord steps.
    """

    converged: bool
    w: np.ndarray
    residual: float
    iterations: int
    message: str
    factors: object = None


class _Broyden:
    """Chord steps with Broyden's ("good") rank-one updates of the kept LU factors.

    Along full steps ``s_0, s_1, ...`` from the factorised Jacobian ``B_0``, the update
    ``B_(j+1) = B_j + G_(j+1) s_j^T / |s_j|^2`` gives the next step in product form, with one
    solve with the factors and a few dot products (Kelley, *Iterative Methods for Linear and
    Nonlinear Equations*, SIAM 1995, Alg. 7.3.1 ``brsol``): ``z = -B_0^-1 G``, then
    ``z += s_(j+1) (s_j . z) / |s_j|^2`` for ``j < n``, and ``s_(n+1) = z / (1 - s_n . z /
    |s_n|^2)``. Near a root the steps converge superlinearly, plain chord steps linearly.
    """

    def __init__(self, lu) -> None:
        self.lu = lu
        self.steps: list[np.ndarray] = []
        self.norms2: list[float] = []

    def step(self, g: np.ndarray) -> np.ndarray:
        """The next step at the residual ``g`` (the previous steps all taken in full)."""
        z = -self.lu.solve(g)
        if not self.steps:  # the plain chord step
            return z
        for j in range(len(self.steps) - 1):
            z += self.steps[j + 1] * ((self.steps[j] @ z) / self.norms2[j])
        denom = 1.0 - (self.steps[-1] @ z) / self.norms2[-1]
        return z / denom if abs(denom) > 1e-8 else z

    def taken(self, step: np.ndarray) -> None:
        """Record a step taken in full from the point of the last :meth:`step`."""
        nrm2 = float(step @ step)
        if nrm2 > 0:
            self.steps.append(step)
            self.norms2.append(nrm2)


def newton_solve(grid: ShootingGrid, w0: np.ndarray, values: np.ndarray, par: np.ndarray,
                 tol: float = 1e-10, max_iter: int = 40, deadline: float | None = None,
                 should_stop=None, contraction: float = CHORD_CONTRACTION,
                 factors=None) -> NewtonReport:
    """Damped Newton on ``G(w) = 0`` with a backtracking line search on ``|G|^2 / 2``.

    The factorised Jacobian is kept while it works (chord steps): after a full step that
    shrank ``max |G|`` by at least ``contraction``, the next step reuses the old LU factors
    with Broyden's rank-one updates along the steps taken (:class:`_Broyden`), and is
    accepted only if it shrinks ``max |G|`` as much again, at most :data:`CHORD_MAX` times;
    otherwise the Jacobian is evaluated anew at the current point and a damped Newton step
    taken. The Jacobian (the RK4 sensitivities) costs about six residuals and its
    factorisation two more, so near a solution (mesh refinement, warm starts, small
    continuation steps) this saves most of the work; convergence is always judged on ``G``
    itself.

    Parameters
    ----------
    grid : ShootingGrid
    w0 : ndarray, shape (grid.size,)
    values : ndarray
        Boundary values (start then target).
    par : ndarray, shape (3,)
        ``(k, delta, torque_scale)``.
    tol : float
        Convergence when ``max |G| <= tol``.
    max_iter : int
        Iterations, chord steps included.
    deadline : float, optional
        ``time.perf_counter()`` value after which to give up.
    should_stop : callable, optional
        Returns True to cancel (checked every iteration).
    contraction : float
        Required reduction factor of ``max |G|`` to keep (and to accept) chord steps; 0
        gives plain Newton.
    factors : scipy.sparse.linalg.SuperLU, optional
        LU factors of a Jacobian of this grid near ``w0`` (e.g. the previous solve's
        :attr:`NewtonReport.factors`): the first step is a chord step on them.

    Returns
    -------
    NewtonReport
    """
    w = np.array(w0, dtype=float)
    g, jac, lu, inverse = _start(grid, w, values, par, contraction, factors)
    small = 0  # consecutive damped Newton steps shorter than STALL_STEP
    chords = 0  # chord steps since the last Jacobian
    for it in range(1, max_iter + 1):
        res, report = _stopped(w, g, it - 1, tol, should_stop, deadline, lu)
        if report is not None:
            return report
        if jac is None and chords < CHORD_MAX:  # chord step with the kept factors
            taken = _chord_step(grid, inverse, w, g, res, contraction, values, par)
            if taken is not None:
                w, g = taken
                chords += 1
                continue
        chords = 0
        newton = _newton_step(grid, w, g, jac, values, par)
        if newton is None:
            return NewtonReport(False, w, res, it - 1, "singular Newton matrix")
        g, lu, inverse, step = newton
        lam, w_new, g_new, merit_new = _line_search(grid, w, g, step, values, par)
        if not np.isfinite(merit_new):
            return NewtonReport(False, w, res, it, "non-finite residual along the step")
        small, report = _stall(small, lam, w_new, g_new, it, lu)
        if report is not None:
            return report
        w = w_new
        if lam == 1.0 and float(np.max(np.abs(g_new))) <= contraction * res:
            inverse.taken(step)
            g, jac = g_new, None  # try the same factors next
        else:
            g, jac = grid.residual(w, values, par)
    res = float(np.max(np.abs(g)))
    return NewtonReport(res <= tol, w, res, max_iter,
                        "converged" if res <= tol else "iteration limit reached", lu)


def _start(grid: ShootingGrid, w: np.ndarray, values: np.ndarray, par: np.ndarray,
           contraction: float, factors: SuperLU | None
           ) -> tuple[np.ndarray, sp.csc_matrix | None, SuperLU | None, _Broyden | None]:
    """The residual at the first point, with its Jacobian or with the factors given.

    Parameters
    ----------
    grid : ShootingGrid
    w : ndarray, shape (grid.size,)
        The first point.
    values, par : ndarray
        As for :func:`newton_solve`.
    contraction : float
        As for :func:`newton_solve`; 0 leaves ``factors`` unused.
    factors : scipy.sparse.linalg.SuperLU or None
        As for :func:`newton_solve`; used when their shape fits the grid.

    Returns
    -------
    g : ndarray, shape (grid.size,)
        ``G(w)``.
    jac : scipy.sparse.csc_matrix, shape (grid.size, grid.size), or None
        ``dG/dw`` at ``w``; None when the first step is a chord step on ``factors``.
    lu : scipy.sparse.linalg.SuperLU or None
        ``factors`` when they are used.
    inverse : _Broyden or None
        The factors with Broyden updates along the chord steps (None without factors).
    """
    if contraction > 0 and factors is not None and factors.shape == (grid.size, grid.size):
        lu = factors  # LU factors of a Jacobian; `jac` is None when they are not at `w`
        g, jac = grid.residual(w, values, par, jacobian=False)
    else:
        g, jac = grid.residual(w, values, par)
        lu = None
    return g, jac, lu, _Broyden(lu) if lu is not None else None


def _stopped(w: np.ndarray, g: np.ndarray, done: int, tol: float,
             should_stop: Callable[[], bool] | None, deadline: float | None,
             lu: SuperLU | None) -> tuple[float, NewtonReport | None]:
    """The tests before each iteration: a non-finite ``G``, convergence, cancel, deadline.

    Parameters
    ----------
    w : ndarray, shape (grid.size,)
        The current point.
    g : ndarray, shape (grid.size,)
        ``G(w)``.
    done : int
        Iterations done so far.
    tol, should_stop, deadline
        As for :func:`newton_solve` (``deadline`` a ``time.perf_counter()`` value, s).
    lu : scipy.sparse.linalg.SuperLU or None
        The current factors, kept in the report of a converged solve.

    Returns
    -------
    res : float
        ``max |G|`` (nan when ``G`` is not finite).
    report : NewtonReport or None
        The outcome when the solve ends here, else None.
    """
    if not np.all(np.isfinite(g)):
        return float("nan"), NewtonReport(False, w, float("nan"), done, "non-finite residual")
    res = float(np.max(np.abs(g)))
    if res <= tol:
        return res, NewtonReport(True, w, res, done, "converged", lu)
    if should_stop is not None and should_stop():
        return res, NewtonReport(False, w, res, done, "cancelled")
    if deadline is not None and time.perf_counter() > deadline:
        return res, NewtonReport(False, w, res, done, "time limit reached")
    return res, None


def _chord_step(grid: ShootingGrid, inverse: _Broyden, w: np.ndarray, g: np.ndarray,
                res: float, contraction: float, values: np.ndarray, par: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """A full chord step on the kept factors, taken if it shrinks ``max |G|`` enough.

    The step (:meth:`_Broyden.step`) is tried only when it keeps ``T`` and the intervals
    positive in full, and taken (and recorded for the next Broyden update) only when
    ``max |G|`` at its end is at most ``contraction * res``.

    Parameters
    ----------
    grid : ShootingGrid
    inverse : _Broyden
        The kept factors with the updates along the chord steps taken since.
    w : ndarray, shape (grid.size,)
        The current point.
    g : ndarray, shape (grid.size,)
        ``G(w)``.
    res : float
        ``max |G(w)|``.
    contraction : float
        As for :func:`newton_solve`.
    values, par : ndarray
        As for :func:`newton_solve`.

    Returns
    -------
    tuple of ndarray or None
        The new point and ``G`` there (shape (grid.size,) each); None when the step is not
        taken (the factors have gone stale).
    """
    step = inverse.step(g)
    lam = grid.admissible_step(w, step)
    if lam == 1.0 and np.all(np.isfinite(step)):
        g_new, _ = grid.residual(w + step, values, par, jacobian=False)
        res_new = float(np.max(np.abs(g_new)))
        if np.isfinite(res_new) and res_new <= contraction * res:
            inverse.taken(step)
            return w + step, g_new
    return None


def _newton_step(grid: ShootingGrid, w: np.ndarray, g: np.ndarray,
                 jac: sp.csc_matrix | None, values: np.ndarray, par: np.ndarray
                 ) -> tuple[np.ndarray, SuperLU, _Broyden, np.ndarray] | None:
    """The full Newton step on the Jacobian at ``w``, and that Jacobian's new LU factors.

    Parameters
    ----------
    grid : ShootingGrid
    w : ndarray, shape (grid.size,)
        The current point.
    g : ndarray, shape (grid.size,)
        ``G(w)``.
    jac : scipy.sparse.csc_matrix, shape (grid.size, grid.size), or None
        ``dG/dw`` at ``w``; None when only factors were kept (then evaluated here, with
        ``G``).
    values, par : ndarray
        As for :func:`newton_solve`.

    Returns
    -------
    tuple or None
        ``(g, lu, inverse, step)``: ``G(w)``, the LU factors of ``dG/dw``, a new
        :class:`_Broyden` on them and the step (shape (grid.size,)); None when the matrix is
        singular (the factorisation fails or the step is not finite).
    """
    if jac is None:  # the factors went stale or served long enough: a Newton step
        g, jac = grid.residual(w, values, par)
    try:
        lu = splu(jac)
        inverse = _Broyden(lu)
        step = inverse.step(g)
    except RuntimeError:
        return None
    if not np.all(np.isfinite(step)):
        return None
    return g, lu, inverse, step


def _line_search(grid: ShootingGrid, w: np.ndarray, g: np.ndarray, step: np.ndarray,
                 values: np.ndarray, par: np.ndarray
                 ) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Backtracking along a Newton step on the merit ``|G|^2 / 2``.

    From the largest fraction of the step that keeps ``T`` and the intervals positive
    (:meth:`ShootingGrid.admissible_step`), halved until the merit falls to ``1 - 1e-4 lam``
    of its value at ``w`` (Armijo) or the fraction below 1e-4.

    Parameters
    ----------
    grid, w, g
        As for :func:`_newton_step`.
    step : ndarray, shape (grid.size,)
        The full Newton step.
    values, par : ndarray
        As for :func:`newton_solve`.

    Returns
    -------
    lam : float
        Fraction of the step taken.
    w_new : ndarray, shape (grid.size,)
        ``w + lam step``.
    g_new : ndarray, shape (grid.size,)
        ``G(w_new)``.
    merit_new : float
        ``|G(w_new)|^2 / 2``; inf when ``G(w_new)`` is not finite or the merit overflows.
    """
    merit = 0.5 * float(g @ g)
    lam = grid.admissible_step(w, step)  # keeps T and the intervals positive
    while True:
        w_new = w + lam * step
        g_new, _ = grid.residual(w_new, values, par, jacobian=False)
        with np.errstate(over="ignore"):  # a huge residual: merit inf, step rejected
            merit_new = 0.5 * float(g_new @ g_new) if np.all(np.isfinite(g_new)) \
                else np.inf
        if merit_new <= (1 - 1e-4 * lam) * merit or lam < 1e-4:
            break
        lam *= 0.5
    return lam, w_new, g_new, merit_new


def _stall(small: int, lam: float, w_new: np.ndarray, g_new: np.ndarray, it: int,
           lu: SuperLU) -> tuple[int, NewtonReport | None]:
    """The stall test: :data:`STALL_COUNT` damped steps in a row below :data:`STALL_STEP`.

    Parameters
    ----------
    small : int
        Damped steps shorter than :data:`STALL_STEP` in a row before this one.
    lam : float
        Fraction of the Newton step this one took.
    w_new : ndarray, shape (grid.size,)
        The point it reached.
    g_new : ndarray, shape (grid.size,)
        ``G(w_new)``.
    it : int
        Iterations done, this one included.
    lu : scipy.sparse.linalg.SuperLU
        The factors of the step's Jacobian, kept in the report.

    Returns
    -------
    small : int
        The count with this step.
    report : NewtonReport or None
        The outcome when Newton has stalled, else None.
    """
    # Damped steps that barely reduce the residual: Newton is stuck (a continuation
    # step too long, a bad guess); say so now instead of using up max_iter.
    small = small + 1 if lam < STALL_STEP else 0
    if small >= STALL_COUNT:
        return small, NewtonReport(False, w_new, float(np.max(np.abs(g_new))), it,
                                   f"stalled ({STALL_COUNT} damped steps below "
                                   f"{STALL_STEP:g} in a row)", lu)
    return small, None
