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

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory
from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL, SET_MARGIN
from tocontrol_ros.core.methods.context import EarlyMotion
from tocontrol_ros.core.types.result import PlanResult

__all__ = ["iterate_watch"]

#: ``hold(res, traj)``: the path slowed down into the set between the samples, or None.
Hold = Callable[[FlatResult, FlatTrajectory], "tuple[FlatResult, FlatTrajectory] | None"]
#: ``certify(res, traj, note)``: the checked result of a path (its certificate).
Certify = Callable[[FlatResult, FlatTrajectory, str], PlanResult]


def iterate_watch(early: EarlyMotion | None, flat: FlatTranscription, values: tuple,
                  bounds: tuple, pad: float | np.ndarray, hold: Hold, certify: Certify,
                  what: str) -> Callable[[int, np.ndarray], bool] | None:
    """The watcher of one IPOPT solve that offers its certified iterates to ``early``.

    Parameters
    ----------
    early : EarlyMotion or None
        The receiver (None: no watcher, None returned).
    flat : FlatTranscription
        The transcription being solved.
    values : tuple
        ``(start value, target value, k)`` of the solve.
    bounds : tuple
        ``(lower, upper)`` state bounds, shape (2n,) each.
    pad : float or ndarray, shape (S,)
        The set's pad of the solve (its rows' bounds).
    hold : callable
        ``hold(res, traj)``: the path slowed down into the set between the samples, or
        None (the bounded solve's own rule).
    certify : callable
        ``certify(res, traj, note)``: the path's checked result (the bounded solve's own
        certificate and verdict), ``note`` among its warnings.
    what : str
        What the solve is, for the note (e.g. "a warm re-solve on 64 spans").

    Returns
    -------
    callable or None
        ``watch(iteration, w, g) -> False`` for :meth:`FlatTranscription.solve` (it never
        stops the solve).
    """
    if early is None:
        return None
    n, K, k = flat.model.n, flat.K, values[2]
    lbg, ubg, lbx, ubx = flat.bounds(*bounds, pad, (values[0], values[1]))

    def watch(iteration: int, w: np.ndarray, g: np.ndarray) -> bool:
        if early.done or iteration == 0 or iteration % early.every:
            return False
        t0 = time.perf_counter()
        P, T = w[:-1].reshape(K, n), float(w[-1])
        # The NLP's residual (as FlatTranscription.residual) from the rows IPOPT evaluated.
        residual = float(max(np.max(np.maximum(lbg - g, 0.0)), np.max(np.maximum(g - ubg, 0.0)),
                             np.max(np.maximum(lbx - w, 0.0)), np.max(np.maximum(w - ubx, 0.0))))
        seen = {"iteration": iteration, "T": T, "residual": residual, "inside": None,
                "certified": None, "at": t0}
        if residual <= RESIDUAL_TOL or early.full:
            try:
                _check(early, seen, flat, iteration, T, P, residual, k, hold, certify, what)
            except Exception as exc:  # noqa: BLE001  (inside IPOPT's callback: never abort it)
                early.done = True  # the same exception on any load: no more checks
                seen["error"] = f"{type(exc).__name__}: {exc}"
        seen["seconds"] = time.perf_counter() - t0
        early.seen.append(seen)
        return False

    return watch


def _check(early: EarlyMotion, seen: dict, flat: FlatTranscription, iteration: int, T: float,
           P: np.ndarray, residual: float, k: float, hold: Hold, certify: Certify,
           what: str) -> None:
    """One iterate held inside the set and certified; offered to ``early`` if it passes."""
    res = FlatResult(success=True, message=f"IPOPT's iterate {iteration}", T=T, P=P,
                     residual=residual, iterations=iteration, solve_time=0.0)
    traj = FlatTrajectory(flat, res, k)
    held = (res, traj) if float(np.max(traj.set_values())) <= 1.0 - SET_MARGIN \
        else hold(res, traj)
    seen["inside"] = held is not None
    if held is None:
        return
    result = certify(*held, f"IPOPT's iterate {iteration} of {what}, before it converged: "
                     "certified, not the optimum (a first motion)")
    seen["certified"] = bool(result.success)
    seen["published_T"] = float(result.T)
    if result.success:
        early.done = bool(early.offer(result))
