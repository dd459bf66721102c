"""A converged bounded solve carried to a farther problem in sub-moves: path following.

The parametric step (:func:`~tocontrol_ros.core.direct.sensitivity.sensitivity_solve`)
carries a converged primal-dual solution to a problem a replan away (2 cm); a memory's hit
is 2-8 cm from its stored neighbour, where one step's linearisation carries tens of rows
across their bounds and the steps do not converge (on the benchmark's Panda cell: "not
converged in 16 KKT solves", 83 rows held). :func:`follow` walks the parameters (start,
target, ``k``) from the solved problem's to the new one's along the straight line, in
sub-moves of at most :data:`POINT_STEP` of a point end and :data:`JOINT_STEP` of a joint
state end, each by the parametric step from the previous sub-move's answer (its first
Newton step is the tangent predictor, the rest correctors; rows held as there): the
homotopy (continuation) method of parametric programming (Allgower and Georg, ch. 1;
Jaeschke, Yang and Biegler 2014 for NLP path following). A sub-move that fails is halved,
at most :data:`HALVINGS` times in a row; at most :data:`MAX_MOVES` sub-moves are tried in
all. Decided by work (sub-moves, halvings, the parametric step's own steps), never by the
clock; a walk that does not reach the new problem is a failure with its reason (the caller
then re-solves with IPOPT).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.sensitivity import sensitivity_solve

__all__ = ["FollowOutcome", "follow", "move_size", "sub_moves", "POINT_STEP", "JOINT_STEP",
           "HALVINGS", "MAX_MOVES"]

#: Largest move of a point end per sub-move (m): the replans' 2 cm, where the parametric
#: step converged on 12 of 20 Panda moves (docs/limits.md).
POINT_STEP = 0.02
#: Largest move of a joint state end per sub-move (rad, rad/s; max-norm).
JOINT_STEP = 0.05
#: A failed sub-move is halved at most this many times in a row.
HALVINGS = 3
#: Sub-moves tried at most (those that failed included).
MAX_MOVES = 16


@dataclass(frozen=True)
class FollowOutcome:
    """What :func:`follow` did.

    Attributes
    ----------
    moves : int
        Sub-moves tried (each one parametric solve), the failed ones included.
    planned : int
        Sub-moves of the plan before any halving (:func:`sub_moves`).
    halvings : int
        Sub-moves halved after a failure.
    steps : int
        Newton steps of every sub-move together (predictors and correctors).
    solves : int
        KKT factorisations of every sub-move together.
    reached : float
        How far along the line the accepted sub-moves reached (1: the new problem).
    reason : str
        "converged", or why the walk stopped.
    """

    moves: int
    planned: int
    halvings: int
    steps: int
    solves: int
    reached: float
    reason: str


def move_size(old: tuple, new: tuple) -> float:
    """The move from ``old`` to ``new`` parameters, ``(start, target, k)`` each, in sub-moves.

    A point end (shape (m,), m <= 3) in units of :data:`POINT_STEP` (Euclidean), a joint
    state end (2n,) in units of :data:`JOINT_STEP` (max-norm); the larger of the two ends.
    """
    size = 0.0
    for a, b in zip(old[:2], new[:2], strict=True):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        size = max(size, float(np.linalg.norm(b - a)) / POINT_STEP if a.size <= 3
                   else float(np.max(np.abs(b - a))) / JOINT_STEP)
    return size


def sub_moves(old: tuple, new: tuple) -> int:
    """Sub-moves from ``old`` to ``new`` parameters, ``(start, target, k)`` each.

    A point end (shape (m,), m <= 3) moves at most :data:`POINT_STEP` (Euclidean) per
    sub-move, a joint state end (2n,) at most :data:`JOINT_STEP` (max-norm); ``k`` in as
    many as the ends need. At least 1.
    """
    return max(1, math.ceil(move_size(old, new) - 1e-9))


def _along(old: tuple, new: tuple, s: float) -> tuple:
    """The parameters a fraction ``s`` of the way from ``old`` to ``new``."""
    if s >= 1.0:
        return new
    return tuple(np.asarray(a, dtype=float) + s * (np.asarray(b, dtype=float)
                                                   - np.asarray(a, dtype=float))
                 for a, b in zip(old[:2], new[:2], strict=True)) \
        + (float(old[2]) + s * (float(new[2]) - float(old[2])),)


def follow(flat: FlatTranscription, w0: np.ndarray, lam_g0: np.ndarray, lam_x0: np.ndarray,
           old_values: tuple, new_values: tuple, lower: np.ndarray, upper: np.ndarray,
           set_pad: float | np.ndarray, should_stop=None
           ) -> tuple[FlatResult, FollowOutcome]:
    """The new problem's solution from a converged one of ``old_values`` (see the module).

    Parameters
    ----------
    flat : FlatTranscription
        The NLP on the old solution's mesh (its kinds of start and target are both
        problems').
    w0 : ndarray, shape (K n + 1,)
        The old solution: control points (row by row), then ``T`` (s).
    lam_g0, lam_x0 : ndarray, shapes (rows,), (K n + 1,)
        Its multipliers (IPOPT's convention).
    old_values, new_values : tuple
        ``(start_value, target_value, k)`` of the solved problem and of the new one.
    lower, upper : ndarray, shape (2n,)
        State bounds, as for :meth:`FlatTranscription.solve`.
    set_pad : float or ndarray, shape (S,)
        The set's pad, one for all samples or one per sample.
    should_stop : callable, optional
        Polled by every parametric step; True stops (a failure, "cancelled").

    Returns
    -------
    FlatResult
        The last sub-move's answer (``success`` only when it is the new problem's);
        ``iterations``: Newton steps of every sub-move; ``message``: the walk and the last
        sub-move's outcome.
    FollowOutcome
    """
    t0 = time.perf_counter()
    planned = sub_moves(old_values, new_values)
    h0 = 1.0 / planned
    s, h = 0.0, h0
    w = np.asarray(w0, dtype=float)
    lam_g, lam_x = np.asarray(lam_g0, dtype=float), np.asarray(lam_x0, dtype=float)
    moves = halvings = steps = solves = cut = 0
    last, reason = None, f"not reached in {MAX_MOVES} sub-moves"
    while s < 1.0:
        if moves >= MAX_MOVES:
            break
        to = 1.0 if s + h >= 1.0 - 1e-12 else s + h
        res, out = sensitivity_solve(flat, w, lam_g, lam_x, *_along(old_values, new_values, to),
                                     lower, upper, set_pad, should_stop=should_stop)
        moves += 1
        steps += out.steps
        solves += out.solves
        last = res
        if out.reason == "cancelled":
            reason = "cancelled"
            break
        if res.success:
            s, cut = to, 0
            w = np.concatenate([res.P.ravel(), [res.T]])
            lam_g, lam_x = res.lam_g, res.lam_x
            h = min(h0, 2.0 * h)  # after a halving, back up towards the plan's length
            continue
        if cut >= HALVINGS:
            reason = (f"a sub-move failed {cut + 1} times in a row at {s:.3g} of the way "
                      f"(last: {out.reason})")
            break
        cut += 1
        halvings += 1
        h *= 0.5
    done = s >= 1.0
    if done:
        reason = "converged"
    outcome = FollowOutcome(moves, planned, halvings, steps, solves, s, reason)
    message = (f"parametric path following: {reason} after {moves} sub-moves ({planned} "
               f"planned, {halvings} halved), {steps} Newton steps, {solves} KKT solves")
    if last is not None:
        message += f"; last sub-move: {last.message}"
    if not done or last is None:
        return FlatResult(success=False, message=f"{message}: failed", T=float(w[-1]),
                          P=w[:-1].reshape(flat.K, flat.model.n), residual=np.inf,
                          iterations=steps, solve_time=time.perf_counter() - t0,
                          lam_g=lam_g, lam_x=lam_x), outcome
    return FlatResult(success=True, message=message, T=last.T, P=last.P,
                      residual=last.residual, iterations=steps,
                      solve_time=time.perf_counter() - t0, lam_g=last.lam_g,
                      lam_x=last.lam_x), outcome
