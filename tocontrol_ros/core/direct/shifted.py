"""A memory hit's first motion at once: the stored motion moved onto the request's ends.

A memory's hit re-solves a stored optimum 2-8 cm from the request (IPOPT, a median 40-100
iterations on the Panda's cell: about a second through the node, docs/memory.md); its first
certified IPOPT iterate came a median 200 ms after the request. But the stored motion is
already nearly the answer: the same basin, the same path up to a few centimetres. Moved
onto the request's ends and run a little slower, it is a motion to publish at once:

1. the ends: a joint-state end is the request's; a point end is reached by Newton steps
   from the stored motion's end configuration (:func:`~.first_motion.configuration_near`:
   weighted least norm, the position limits held), so the end configuration stays in the
   stored motion's basin;
2. the control points moved two ways: by a smooth blend, ``P_j + (1 - w_j) (q_a - P_0) +
   w_j (q_b - P_last)``, where ``w_j`` rises (:func:`blend_weights`: a quintic smoothstep
   of the control points' Greville abscissae) from 0 on the first three control points to
   1 on the last three, so the path's position, velocity and acceleration at each end are
   the stored motion's, moved (a motion from rest ends at rest); and by the joints' speed
   to spare (:func:`slack_moved`: the Panda's time-optimal motions run at the velocity
   limits between their ends, where the smooth blend adds its largest speed); the inner
   control points held inside the position bounds (a stored optimum often rides one);
3. each moved path timed on the stored breakpoints and on breakpoints stretched span by
   span (:func:`span_stretched`: each span slower where its speeds or torques exceed the
   limits, faster where they have room), at the least multiple of its time whose NLP rows
   hold (the set at the samples with the solve's pads, the velocity and position rows, the
   ends: :meth:`~.flat.FlatTranscription.residual` within :data:`~.tuning.RESIDUAL_TOL`),
   among :data:`SHIFT_FACTORS`, then :data:`SHIFT_BISECTIONS` halvings towards the one
   below it (decided by work, never the clock); the fastest of the four is kept;
4. the motion checked as an IPOPT iterate is (:func:`~.checked.checked_iterate`: the
   torques between the samples held inside the set, slowed down where needed, and the
   certificate, re-integrated open loop).

:func:`first_from_warm` makes it for a warm state on its own mesh (the bounded method's
:meth:`~tocontrol_ros.core.methods.contract.Method.first_from`): the memory's ``recall``
hands it to its ``first`` receiver (the planner's ``publish: first_then_optimum``) before
any re-solve starts, and the re-solves then go on without checking IPOPT's iterates (side
by side where there are workers). Where it fails (an end not reached near the stored one,
no factor that holds, the certificate), the nearest re-solve offers its first certified
IPOPT iterate as before. The re-solves, and so the answer, are the same either way.
"""

from __future__ import annotations

import time

import numpy as np

from tocontrol_ros.core.direct.bspline import knots
from tocontrol_ros.core.direct.checked import checked_iterate
from tocontrol_ros.core.direct.first_motion import configuration_near
from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory
from tocontrol_ros.core.direct.limited import state_bounds
from tocontrol_ros.core.direct.set_pads import warm_row_pads
from tocontrol_ros.core.direct.tuning import PAD, RESIDUAL_TOL
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.types.result import PlanResult

__all__ = ["SHIFT_FACTORS", "SHIFT_BISECTIONS", "SHIFTED_FIRST", "blend_weights",
           "slack_moved", "shifted_motion", "first_from_warm"]

#: Multiples of the stored ``T`` tried for the moved path, least first (the least that
#: holds the NLP's rows is kept, then refined by :data:`SHIFT_BISECTIONS` halvings).
SHIFT_FACTORS = (0.9, 0.95, 0.98, 1.0, 1.01, 1.02, 1.03, 1.05, 1.08, 1.12, 1.2, 1.35, 1.5,
                 2.0)
#: Halvings of the interval between the least factor that holds and the one below it.
SHIFT_BISECTIONS = 5
#: Control points at each end moved with that end alone (position, velocity and
#: acceleration at the ends kept).
END_POINTS = 3
#: Offer the moved motion first (False: a hit's first motion is IPOPT's first certified
#: iterate, as before session 40; bench/memory_shifted.py measures one against the other).
SHIFTED_FIRST = True
#: Rounds of :func:`span_stretched` (each measures the path on the previous breakpoints).
STRETCH_ROUNDS = 6
#: Times per span at which :func:`span_stretched` measures speeds and torques.
STRETCH_POINTS = 8
#: Least and greatest stretch of a span in one round.
STRETCH_RANGE = (0.7, 2.0)
#: Derivative control points over which the speed to spare is averaged (a Hann window).
SPARE_WINDOW = 9


def blend_weights(flat: FlatTranscription) -> np.ndarray:
    """The weights ``w`` (K,) of the target's move on each control point.

    0 on the first :data:`END_POINTS`, 1 on the last ones, a quintic smoothstep of the
    control points' Greville abscissae (the mean of their ``degree`` inner knots) between.
    """
    d, K = flat.degree, flat.K
    t = knots(np.asarray(flat.breaks, dtype=float), d)
    greville = np.array([t[j + 1:j + d + 1].mean() for j in range(K)])
    lo, hi = greville[END_POINTS - 1], greville[K - END_POINTS]
    x = np.clip((greville - lo) / (hi - lo), 0.0, 1.0) if hi > lo else \
        (np.arange(K) >= K - END_POINTS).astype(float)
    return x ** 3 * (10.0 - 15.0 * x + 6.0 * x ** 2)


def slack_moved(flat: FlatTranscription, P: np.ndarray, T: float, qa: np.ndarray,
                qb: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """The control points (K, n) moved onto ``qa``, ``qb`` where the joints have speed to spare.

    The path's derivative is a B-spline whose control points ``Q_j = d (P_(j+1) - P_j) /
    (t_(j+d+1) - t_(j+1))`` bound it (the convex hull property). Each joint's extra move
    ``D = (qb - qa) - (P_last - P_0)`` is added to its ``Q_j`` in proportion to the speed it
    has to spare there in the move's direction (``speed T - sign(D) Q_j``, at least 0), none
    on the first and last two (the ends' velocity and acceleration kept); a joint without
    a finite speed limit, or with no speed to spare, takes :func:`blend_weights`' share.
    The time-optimal motions of an arm whose velocity limits bind run at those limits
    between their ends, where the smooth blend adds its largest speed.

    Parameters
    ----------
    flat : FlatTranscription
    P : ndarray, shape (K, n)
        The stored control points (rad, m).
    T : float
        The stored motion's time (s).
    qa, qb : ndarray, shape (n,)
        The request's end configurations.
    speed : ndarray, shape (n,)
        The joints' velocity limits (rad/s, m/s; inf: none).
    """
    d, K = flat.degree, flat.K
    t = knots(np.asarray(flat.breaks, dtype=float), d)
    gap = (t[d + 1:d + K] - t[1:K]) / d  # (K - 1,): P_(j+1) - P_j = Q_j gap_j
    Q = np.diff(P, axis=0) / gap[:, None]
    D = (qb - qa) - (P[-1] - P[0])
    inner = np.zeros(K - 1)
    inner[2:K - 3] = 1.0
    spare = np.where(np.isfinite(speed), speed * T, 0.0)[None, :] - np.sign(D)[None, :] * Q
    spare = np.clip(spare, 0.0, None) * inner[:, None]
    kernel = np.hanning(SPARE_WINDOW + 2)[1:-1]  # shares without jumps: bounded accelerations
    spare = np.apply_along_axis(lambda c: np.convolve(c, kernel, mode="same"), 0, spare)
    spare *= inner[:, None]
    mass = spare.T @ gap  # (n,)
    w = blend_weights(flat)
    smooth = np.diff(w) / gap  # the smooth blend's share, sum(smooth * gap) = 1
    own = (mass > 0.0) & np.isfinite(speed)  # joints that take shares of their own
    share = np.where(own[None, :], spare / np.where(own, mass, 1.0)[None, :],
                     smooth[:, None])
    moved = np.empty_like(P)
    moved[0] = qa
    moved[1:] = qa + np.cumsum((Q + D[None, :] * share) * gap[:, None], axis=0)
    moved[-END_POINTS:] = P[-END_POINTS:] + (qb - P[-1])  # the same, without the sums' round-off
    return moved


def span_stretched(flat: FlatTranscription, P: np.ndarray, T: float, k: float,
                   speed: np.ndarray, rounds: int = STRETCH_ROUNDS
                   ) -> tuple[np.ndarray, float]:
    """Breakpoints (L + 1,) and ``T`` (s) that run each span of a path as fast as it allows.

    A span's duration is scaled by how far its speeds exceed the velocity limits (speeds
    scale as 1 / the stretch) and its torques the set (inertial torques scale as 1 / the
    stretch squared: the square root of the set's norm ``(sum u_i^(2k))^(1 / 2k)``), the
    larger of the two over its :data:`STRETCH_POINTS` times and its neighbours' (a B-spline's
    point reaches over several spans), between :data:`STRETCH_RANGE`: spans with room to
    spare run faster. Each of ``rounds`` rounds measures the path on the breakpoints the
    previous one made. The control points stay: only the time each span takes changes.
    """
    breaks = np.asarray(flat.breaks, dtype=float)
    finite = np.isfinite(speed)
    for _ in range(rounds):
        on = flat.on(breaks)
        traj = FlatTrajectory(on, FlatResult(success=True, message="moved", T=T, P=P,
                                             residual=0.0, iterations=0, solve_time=0.0), k)
        got = traj.evaluate(traj.set_fractions(STRETCH_POINTS) * T)
        L = len(breaks) - 1
        fast = np.max(np.abs(got.qd[:, finite]) / speed[finite], axis=1, initial=0.0)
        norm = np.sum(np.abs(got.u) ** (2 * k), axis=1) ** (1.0 / (2 * k))
        need = np.maximum(fast, np.sqrt(norm)).reshape(L, STRETCH_POINTS).max(axis=1)
        need = np.maximum.reduce([need, np.r_[need[1:], need[-1]], np.r_[need[0], need[:-1]]])
        h = np.diff(breaks) * np.clip(need, *STRETCH_RANGE)
        T = T * float(np.sum(h))
        breaks = np.r_[0.0, np.cumsum(h) / np.sum(h)]
        breaks[-1] = 1.0
    return breaks, T


def _end(ctx: SolveContext, end, q_stored: np.ndarray) -> np.ndarray | None:
    """The configuration of one of the request's ends near the stored one, or None."""
    n = ctx.problem.model.n
    if end.kind == "state":
        return np.asarray(end.value[:n], dtype=float)
    return configuration_near(ctx.problem, end.value, q_stored)


def shifted_motion(ctx: SolveContext, flat: FlatTranscription, warm: PathWarmState,
                   bounds: tuple, values: tuple, pad: float | np.ndarray, timings: dict,
                   t_start: float) -> tuple[PlanResult | None, str]:
    """The stored motion ``warm`` moved onto ``ctx.problem``'s ends and timed (the module).

    Parameters
    ----------
    ctx : SolveContext
        The warm re-solve's (its problem, options for the certificate).
    flat : FlatTranscription
        The NLP on ``warm``'s mesh (``warm.breaks``).
    warm : PathWarmState
        The stored motion: control points (K, n) on ``flat``'s mesh, ``T`` (s).
    bounds : tuple of ndarray
        The state bounds (lower, upper), shape (2n,) each, as for the solve.
    values : tuple
        The request's start value, target value and ``k``.
    pad : float or ndarray, shape (S,)
        The set's pad of the solve's rows.
    timings : dict
        The plan's timings so far (copied into the result).
    t_start : float
        ``time.perf_counter()`` at the plan's start.

    Returns
    -------
    result : PlanResult or None
        The moved motion checked and certified (``success`` says whether it passed); None
        where it could not be made.
    why : str
        What was done, or why there is none.
    """
    problem = ctx.problem
    P = np.asarray(warm.P, dtype=float)
    if P.shape != (flat.K, problem.model.n) or len(warm.breaks) != len(flat.breaks):
        return None, "the stored motion is not on the re-solve's mesh"
    qa, qb = _end(ctx, problem.start, P[0]), _end(ctx, problem.target, P[-1])
    if qa is None or qb is None:
        return None, "the request's end configuration was not reached near the stored one"
    w = blend_weights(flat)[:, None]
    speed = problem.limits.plan_velocity
    paths = {"smooth": P + (1.0 - w) * (qa - P[0]) + w * (qb - P[-1]),
             "speed": slack_moved(flat, P, warm.T, qa, qb, speed)}
    # A stored optimum often rides a position bound for a while: the move would push its
    # inner control points past it. Held at the bound (the spline inside the control
    # points' hull); the ends' points keep the ends.
    n, inner = problem.model.n, slice(END_POINTS, -END_POINTS)
    for moved in paths.values():
        moved[inner] = np.clip(moved[inner], bounds[0][:n], bounds[1][:n])
    # Each path on the stored mesh, and on breakpoints stretched span by span.
    tries = []
    for name, moved in paths.items():
        tries.append((name, flat, moved, warm.T))
        breaks, T_spans = span_stretched(flat, moved, warm.T, problem.k, speed)
        tries.append((f"{name}, spans stretched", flat.on(breaks), moved, T_spans))
    timed = []
    for name, on, moved, T0 in tries:
        least = _least_factor(on, values, T0, moved, bounds, pad)
        if least is not None:
            timed.append((T0 * least[0], least[1], name, on, moved))
    if not timed:
        return None, (f"the moved path holds the NLP's rows at none of {SHIFT_FACTORS[0]:g}-"
                      f"{SHIFT_FACTORS[-1]:g} times the stored T")
    T, residual, name, on, moved = min(timed, key=lambda x: x[0])
    it = FlatResult(success=True, message="the stored motion moved", T=T, P=moved,
                    residual=residual, iterations=0, solve_time=0.0)
    _, result = checked_iterate(
        ctx, on, it, values, bounds, "the nearest stored motion moved onto the request's "
        f"ends and timed ({name}; {100.0 * (T / warm.T - 1.0):+.1f} % of its time): "
        "certified, not the optimum (a first motion; route: shifted)", dict(timings), t_start)
    if result is None:
        return None, "the moved path's torques leave the set between the samples"
    return result, f"moved ({name}) and timed at {T / warm.T:.4g} times the stored T"


def _least_factor(flat: FlatTranscription, values: tuple, T: float, moved: np.ndarray,
                  bounds: tuple, pad) -> tuple[float, float] | None:
    """``(factor, residual)``: the least multiple of ``T`` whose NLP rows hold, or None.

    ``residual``: the NLP's residual there. The least of :data:`SHIFT_FACTORS` that holds,
    then :data:`SHIFT_BISECTIONS` halvings towards the one below it.
    """
    def residual(factor: float) -> float:
        return flat.residual(values[0], values[1], values[2], T * factor, moved, *bounds,
                             set_pad=pad)

    best = None
    for factor in SHIFT_FACTORS:
        r = residual(factor)
        if r <= RESIDUAL_TOL:
            best = (factor, r)
            break
    if best is None:
        return None
    below = [f for f in SHIFT_FACTORS if f < best[0]]
    if below:
        lo = below[-1]
        for _ in range(SHIFT_BISECTIONS):
            mid = 0.5 * (lo + best[0])
            r = residual(mid)
            if r <= RESIDUAL_TOL:
                best = (mid, r)
            else:
                lo = mid
    return best


def first_from_warm(compiled, ctx: SolveContext, warm: PathWarmState
                    ) -> tuple[PlanResult | None, str]:
    """:func:`shifted_motion` of a warm state on its own mesh: a hit's first motion.

    The NLP is the one the warm re-solve solves (``compiled.flat(problem, warm.breaks,
    warm="dual_far")``: built once, the re-solve's), the state bounds and the set's pads
    per sample those of the re-solve (:func:`~.set_pads.warm_row_pads`).

    Parameters
    ----------
    compiled : Compiled
        The planner's compiled functions (``flat``).
    ctx : SolveContext
        Its problem (the request) and options (the certificate's).
    warm : PathWarmState
        The stored motion (its serving state).

    Returns
    -------
    result : PlanResult or None
        The moved motion, certified or not (``success``); None where none was made.
    why : str
        What was done, or why there is none.
    """
    if not SHIFTED_FIRST:
        return None, "switched off (shifted.SHIFTED_FIRST)"
    t_start = time.perf_counter()
    problem = ctx.problem
    flat = compiled.flat(problem, warm.breaks, warm="dual_far")
    bounds = state_bounds(problem, PAD)
    values = (problem.start.value, problem.target.value, problem.k)
    pad = warm_row_pads(flat, warm, problem.k)
    timings = {"guess": time.perf_counter() - t_start, "shooting": 0.0, "refine": 0.0,
               "verify": 0.0}
    return shifted_motion(ctx, flat, warm, bounds, values, pad, timings, t_start)
