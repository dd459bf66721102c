"""A warm re-solve's motions before it converges: IPOPT's iterates checked as they come.

IPOPT's iterates of a bounded solve keep the variables' bounds (the control points inside
the joints' position limits, ``T`` positive: an interior-point method); its rows (the set at
the samples, the velocity rows, the boundary rows) hold once the NLP's residual is small.
An iterate whose residual is within :data:`~.tuning.RESIDUAL_TOL`, whose torques between
the samples stay inside the set (slowed down just enough where they do not, as a converged
solve's), and which passes the certificate is a motion as safe to run as the optimum, only
slower. :func:`iterate_watch` makes the watcher that
:meth:`~.flat.FlatTranscription.solve` calls at each iteration: it checks every
``early.every``-th iterate (a count, never the clock) and offers the certified ones to
:class:`~tocontrol_ros.core.methods.context.EarlyMotion` (a memory hit's first motion,
published while IPOPT goes on to the optimum). It only reads the iterate: the solve and its
answer are the same to the bit with or without it (``test/memory/test_early.py``); an
exception in the checks (or in ``offer``) ends the checks, recorded in ``early.seen``, and
never IPOPT's solve.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from tocontrol_ros.core.direct.checked import checked_iterate
from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription, violation
from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL
from tocontrol_ros.core.methods.context import EarlyMotion, SolveContext

__all__ = ["iterate_watch"]


def iterate_watch(ctx: SolveContext, flat: FlatTranscription, values: tuple, bounds: tuple,
                  pad: float | np.ndarray, timings: dict, t_start: float,
                  what: str) -> Callable[[int, np.ndarray], bool] | None:
    """The watcher of one IPOPT solve that offers its certified iterates to ``ctx.early``.

    Parameters
    ----------
    ctx : SolveContext
        The solve's context; its ``early`` is the receiver (None: no watcher, None
        returned).
    flat : FlatTranscription
        The transcription being solved.
    values : tuple
        ``(start value, target value, k)`` of the solve.
    bounds : tuple
        ``(lower, upper)`` state bounds, shape (2n,) each.
    pad : float or ndarray, shape (S,)
        The set's pad of the solve (its rows' bounds).
    timings : dict
        The plan's timings so far (copied into each checked iterate's result).
    t_start : float
        ``time.perf_counter()`` at the plan's start.
    what : str
        What the solve is, for the note (e.g. "a warm re-solve on 64 spans").

    Returns
    -------
    callable or None
        ``watch(iteration, w, g) -> False`` for :meth:`FlatTranscription.solve` (it never
        stops the solve).
    """
    early = ctx.early
    if early is None:
        return None
    n, K = flat.model.n, flat.K
    lbg, ubg, lbx, ubx = flat.bounds(*bounds, pad, (values[0], values[1]))

    def watch(iteration: int, w: np.ndarray, g: np.ndarray) -> bool:
        if early.done or iteration == 0 or iteration % early.every:
            return False
        t0 = time.perf_counter()
        P, T = w[:-1].reshape(K, n), float(w[-1])
        # The NLP's residual (as FlatTranscription.residual) from the rows IPOPT evaluated.
        residual = violation(w, g, lbg, ubg, lbx, ubx)
        seen = {"iteration": iteration, "T": T, "residual": residual, "inside": None,
                "certified": None, "at": t0}
        if T > early.max_T:
            seen["slow"] = True  # not worth its checks: not offered
        elif residual <= RESIDUAL_TOL or early.full:
            try:
                _check(ctx, seen, flat, iteration, T, P, residual, values, bounds,
                       dict(timings), t_start, what)
            except Exception as exc:  # noqa: BLE001  (inside IPOPT's callback: never abort it)
                early.done = True  # the same exception on any load: no more checks
                seen["error"] = f"{type(exc).__name__}: {exc}"
        seen["seconds"] = time.perf_counter() - t0
        early.seen.append(seen)
        return False

    return watch


def _check(ctx: SolveContext, seen: dict, flat: FlatTranscription, iteration: int, T: float,
           P: np.ndarray, residual: float, values: tuple, bounds: tuple, timings: dict,
           t_start: float, what: str) -> None:
    """One iterate held inside the set and certified; offered to ``ctx.early`` if it passes."""
    res = FlatResult(success=True, message=f"IPOPT's iterate {iteration}", T=T, P=P,
                     residual=residual, iterations=iteration, solve_time=0.0)
    held, result = checked_iterate(
        ctx, flat, res, values, bounds, f"IPOPT's iterate {iteration} of {what}, before it "
        "converged: certified, not the optimum (a first motion)", timings, t_start)
    seen["inside"] = held
    if result is None:
        return
    early: EarlyMotion = ctx.early
    seen["certified"] = bool(result.success)
    seen["published_T"] = float(result.T)
    early.give(result, seen)  # not when slowed down into the set beyond the bound
