"""The first motion: a certified motion inside every limit, at once (issue 32).

The planner's optimum takes from a fraction of a second (the paper's arm) to seconds (an arm
whose joint limits bind). A motion that is slower but already executable is available far
sooner: a joint path between seed configurations of the planner
(:func:`~tocontrol_ros.core.seeding.seed_pairs`), timed optimally along that path by TOPP-RA
(``toppra``: reachability analysis, one small linear program per gridpoint, a convex
problem), then certified like every other plan. :func:`first_motion`:

1. chooses the end configurations ``(q_a, q_b)``: among the planner's seed pairs (the
   multistart's own, best-ranked first) and the target's configuration followed from the
   start along the straight task-space line (:func:`_followed`), the :data:`CANDIDATES`
   with the least velocity-limited bang-bang estimate are timed at rest along their
   straight joint line, and the fastest is kept (the first seed pair alone is ranked
   without the velocity limits, which bind on real arms, and its end is anywhere on the
   self-motion manifold: its line was up to 4 times slower). From rest, the path is that
   straight line
   (inside the position limits when both ends are: the box of the limits is convex); from a
   moving start state ``(q_0, qd_0)`` a straight line cannot take a velocity off its
   direction, so the path is the parabola ``q_0 + v s + (q_b - q_0 - v) s^2`` whose tangent
   ``v = qd_0 tau`` makes ``qd(0) = qd_0`` at the path speed ``sd(0) = 1 / tau``, for the
   first time scale ``tau`` (:data:`TIME_SCALES` of the rest-to-rest time) whose parabola
   stays inside the position limits and can be timed;
2. times the path by TOPP-RA on :data:`GRIDPOINTS` segments (interpolation discretisation:
   each segment's constant path acceleration meets the constraints at both its ends) under
   the joint velocity limits (``problem.limits.plan_velocity``) and the torques inside the
   convexified set ``sum_i u_i^(2k) <= 1``, ``u = tau / (tau_max torque_scale)``, which is
   not a box: TOPP-RA takes linear constraints, so each gridpoint gets a box inside the set
   (see :func:`_boxes`), first the inscribed cube ``|u_i| <= n^(-1/(2k))`` (its corners are
   on the set's boundary), then, for :data:`ADAPT_PASSES` passes, the box whose corner lies
   on the boundary in the direction of the last pass's torques at that gridpoint (a box
   inside the set wherever it is put; the one along the torques the path needs lets the
   loaded joints go nearer their limits). Viscous friction ``D qd = D q'(s) sd`` is linear in
   ``sd``, which TOPP-RA's form ``a sdd + b sd^2 + c`` cannot hold: it is bounded, on each
   side, by a line in ``sd^2`` (a tangent of the concave ``sqrt`` above it, a chord below
   it, :func:`_friction_lines`), so that the constraints stay inside the true ones;
3. checks the torques between the gridpoints (:data:`CHECK_POINTS` per segment, both sides
   of each acceleration jump) and, where they leave the set, times the path again with the
   boxes shrunk (at most :data:`MARGIN_ROUNDS` times);
4. certifies the motion open loop (:func:`~tocontrol_ros.core.certificate.certify_open_loop`,
   as the bounded direct solve does): its nominal torques re-integrated from its start must
   reach the target at rest, inside the set and within the joint limits.

The result is a :class:`~tocontrol_ros.core.result.PlanResult` with ``method="first"``: a
success only when certified; any failure says which step failed and why.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import casadi as ca
import numpy as np

from tocontrol_ros.core.certificate import certify_open_loop
from tocontrol_ros.core.direct.scaled_path import PolynomialPath, ScaledPath, mapped
from tocontrol_ros.core.options import SolverOptions
from tocontrol_ros.core.problem import Problem
from tocontrol_ros.core.result import PlanResult, Status
from tocontrol_ros.core.robot.ik import IK_TOL
from tocontrol_ros.core.seeding import seed_pairs
from tocontrol_ros.core.verification import fine_sample, limit_warnings, verdict

__all__ = ["first_motion", "GRIDPOINTS"]

#: Candidate end configurations timed at rest before one is chosen (the planner's seed pairs
#: and the target followed from the start, ranked by :func:`_estimates`). On 40 cases drawn
#: as bench/limits.py's (Panda, UR5, xArm7, limited 3R; 10 each, from rest) the chosen line
#: was the fastest of all 17 candidates in 38 and within 6 % in the others; the first seed
#: pair's alone was up to 4 times slower, and the followed target was the fastest in 30.
CANDIDATES = 3
#: Points of the straight task-space line along which the target's configuration is
#: followed from the start (:func:`_followed`), and Newton steps at each.
FOLLOW_STEPS, FOLLOW_ITERATIONS = 20, 3
#: TOPP-RA segments along the path. On the Panda and the limited 3R (bench/limits.py cases)
#: T fell by 1-3 % from 50 to 100 segments and by 0.1-1.2 % from 100 to 200; each pass, and
#: the certificate's open loop, costs in proportion.
GRIDPOINTS = 100
#: Passes that adapt each gridpoint's box to the torques of the pass before (a second one
#: gained under 0.1 % of T on the Panda and the limited 3R of bench/limits.py).
ADAPT_PASSES = 1
#: Share of the corner direction given to every joint when a box is adapted, so that a
#: joint the last pass hardly loaded keeps some room.
ADAPT_FLOOR = 0.1
#: The boxes are shrunk by this fraction at first: the torques between the gridpoints,
#: which TOPP-RA does not see, stay inside the set.
SET_MARGIN = 1e-3
#: Times the path is timed again with wider margins when the torques between the
#: gridpoints still leave the set.
MARGIN_ROUNDS = 3
#: Times per segment (both ends included) at which the torques are checked.
CHECK_POINTS = 5
#: The velocity limits are kept by this fraction (the open-loop re-integration of the
#: certificate, a different integrator, must stay within them).
VELOCITY_PAD = 1e-4
#: Friction's tangent lines are taken at no less than this fraction of the largest squared
#: path speed of the pass before (a tangent near zero would pin the path speed there).
TANGENT_FLOOR = 1e-2
#: The friction chords hold up to this multiple of the last pass's largest squared path
#: speed, which bounds the path speed there.
SPEED_CAP = 4.0
#: A moving start's parabola is tried with these multiples of the straight path's
#: rest-to-rest time as ``tau``, in turn, until one can be timed. A longer ``tau`` starts
#: more slowly along the path (``qdd(0) = 2 (q_b - q_0 - v) / tau^2``, less force needed at
#: the start); on the moving cases of bench/limits.py (Panda, limited 3R) the first was
#: always the fastest, by 5-25 %.
TIME_SCALES = (1.0, 2.0, 4.0)
#: Stands for "no bound" on a squared path speed (1/s^2): TOPP-RA's solvers take numbers.
X_HUGE = 1e8
#: The certificate re-integrates the nominal torques open loop at these tolerances, tighter
#: than the optimum's (1e-10): a first motion is slower, and an arm that is unstable open
#: loop amplifies the integration error with time (a 1.8 s Panda motion: about e^(15 t),
#: 3 mm at the target from 1e-10, 0.03 mm from 1e-12, at the same cost).
OPEN_LOOP_RTOL, OPEN_LOOP_ATOL = 1e-12, 1e-13


def first_motion(problem: Problem, options: SolverOptions | None = None,
                 pairs: list | None = None) -> PlanResult:
    """A certified motion inside every limit: a seed path, timed optimally along it.

    See the module. Fast (nothing iterative: a few TOPP-RA passes, each a small linear
    program per gridpoint, and the certificate), not the optimum: its ``T`` is the best
    timing of one fixed path, never below the (global) optimum's.

    Parameters
    ----------
    problem : Problem
        Any start (point, or joint state at rest or moving) and target.
    options : SolverOptions, optional
        The seed pairs' options (``ik_count``), the certificate's tolerances and ``verify``.
    pairs : list of (ndarray, ndarray), optional
        The planner's seed pairs when already known (default:
        ``seed_pairs(problem, options)``), best-ranked first; the candidates' ends.

    Returns
    -------
    PlanResult
        ``method="first"``; ``iterations`` is the number of TOPP-RA passes, ``intervals``
        the segments, ``residual`` 0 (nothing is solved iteratively: the certificate checks
        the ends). Timings: ``guess`` (the seed pairs and the choice of the path),
        ``scaling`` (TOPP-RA), ``verify`` (the certificate), ``total`` (s). Never raises for
        a numerical failure.
    """
    options = options or SolverOptions()
    t_start = time.perf_counter()
    timings = {"guess": 0.0, "scaling": 0.0, "verify": 0.0}
    if problem.is_trivial():
        timings["total"] = time.perf_counter() - t_start
        return PlanResult(success=True, status=Status.TRIVIAL, message=Status.TRIVIAL.value,
                          T=0.0, k=problem.k, trajectory=None, residual=0.0, iterations=0,
                          timings=timings, continuation=(), max_abs_u=0.0, delta=0.0,
                          intervals=0, problem=problem, method="first")
    if pairs is None:
        pairs = seed_pairs(problem, options)
    timings["guess"] = time.perf_counter() - t_start
    if not pairs:
        return _failure(problem, Status.NO_GUESS, "no inverse-kinematics seed", timings,
                        t_start)
    t0 = time.perf_counter()
    found = _chosen(problem, pairs)
    timings["guess"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    if not isinstance(found[0], Status):
        found = _timed(problem, *found)
    timings["scaling"] = time.perf_counter() - t0
    if isinstance(found[0], Status):
        return _failure(problem, *found, timings, t_start)
    traj, passes, note = found
    sample = fine_sample(traj)
    t0 = time.perf_counter()
    cert_options = replace(options.certificate_options(1), rtol=OPEN_LOOP_RTOL,
                           atol=OPEN_LOOP_ATOL)
    cert = certify_open_loop(problem, traj, cert_options,
                             sample=sample) if options.verify else None
    timings["verify"] = time.perf_counter() - t0
    status, message = verdict(options, cert, 0.0)
    timings["total"] = time.perf_counter() - t_start
    return PlanResult(
        success=status is Status.SUCCESS, status=status, message=f"{message} ({note})", T=traj.T,
        k=problem.k, trajectory=traj, residual=0.0, iterations=passes, timings=timings,
        continuation=(), max_abs_u=float(np.max(np.abs(sample.u))), delta=0.0,
        intervals=len(traj.h), verification=dict(cert.figures) if cert else {},
        certificate=cert, warnings=limit_warnings(problem, sample),
        problem=problem, method="first")


def _failure(problem: Problem, status: Status, why: str, timings: dict,
             t_start: float) -> PlanResult:
    timings["total"] = time.perf_counter() - t_start
    return PlanResult(success=False, status=status, message=f"{status.value}: the first "
                      f"motion: {why}", T=float("nan"), k=problem.k, trajectory=None,
                      residual=float("nan"), iterations=0, timings=timings, continuation=(),
                      max_abs_u=float("nan"), delta=float("nan"), intervals=0,
                      problem=problem, method="first")


# ---------------------------------------------------------------------- the path
def _chosen(problem: Problem, pairs: list):
    """The end configurations whose straight path is fastest at rest, and its time.

    Candidates: the planner's seed pairs and, for a point target, the target followed from
    the first pair's start (:func:`_followed`). The :data:`CANDIDATES` with the least
    velocity-limited bang-bang estimate (:func:`_estimates`) are timed at rest by one
    TOPP-RA pass each.

    Returns
    -------
    (qa, qb, T, label) or (Status, why)
        ``T`` (s): the rest-to-rest time of the straight path in the cube (friction left
        out: it ranks, and sets a moving start's time scale).
    """
    n = problem.model.n
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    cands = [(f"seed pair {i}", qa, qb) for i, (qa, qb) in enumerate(pairs)]
    if problem.target.kind == "point":
        near = _followed(problem, pairs[0][0])
        if near is not None:
            cands.append(("the target followed from the start", pairs[0][0], near))
    cands = [c for c in cands if _inside(PolynomialPath.straight(c[1], c[2]), lo, hi)]
    if not cands:
        return Status.LIMITS_INFEASIBLE, "no seed pair is inside the position limits"
    s = np.linspace(0.0, 1.0, GRIDPOINTS + 1)
    cube = np.full((len(s), n), n ** (-1.0 / (2.0 * problem.k)))
    best, why = None, ""
    for i in np.argsort(_estimates(problem, cands), kind="stable")[:CANDIDATES]:
        label, qa, qb = cands[i]
        coef = _Coefficients(problem, PolynomialPath.straight(qa, qb), s)
        x, why = _toppra(coef, s, 0.0, cube, None)
        if x is not None and (best is None or _duration(x, s) < best[2]):
            best = (qa, qb, _duration(x, s), label)
    if best is None:
        return Status.SCALING_FAILED, f"no straight path between seed configurations could " \
            f"be timed at rest ({why})"
    return best


def _followed(problem: Problem, qa: np.ndarray) -> np.ndarray | None:
    """The target's configuration reached from ``qa`` along the straight task-space line.

    :data:`FOLLOW_STEPS` points of the line from ``P(qa)`` to the target, each with
    :data:`FOLLOW_ITERATIONS` Newton steps of least norm weighted by the velocity limits
    (``dq = W J^T (J W J^T)^-1 r``, ``W = diag(v^2)``: the least ``sum (dq_i / v_i)^2``), a
    joint that would leave its position limits held where it is; then as many more at the
    target. None unless it ends within ``IK_TOL`` of the target. Inverse kinematics from
    random seeds, or the planner's self-motion families, end anywhere on the self-motion
    manifold; this one ends near the start, where a short joint path is.
    """
    model, lim = problem.model, problem.limits
    fk, jac = model.function("P"), model.function("J")
    w = np.where(np.isfinite(lim.plan_velocity), lim.plan_velocity, 1.0)
    target = problem.target.value
    x0 = np.array(fk(qa)).ravel()
    q = np.array(qa, dtype=float)
    goals = [x0 + (target - x0) * (i / FOLLOW_STEPS) for i in range(1, FOLLOW_STEPS + 1)]
    for goal in goals + [target]:
        for _ in range(FOLLOW_ITERATIONS):
            q = _limited_step(q, goal - np.array(fk(q)).ravel(), np.array(jac(q)), w,
                              lim.plan_lower, lim.plan_upper)
            if q is None:  # singular, or the free joints cannot move the tip there
                return None
    if not np.linalg.norm(np.array(fk(q)).ravel() - target) <= IK_TOL:
        return None
    return q


def _limited_step(q, r, jac, w, lo, hi) -> np.ndarray | None:
    """``q`` moved by the weighted least-norm step towards the task error ``r`` (m,).

    Joints the step would take out of ``[lo, hi]`` are held and the step is taken again
    with the others (an active set, at most n rounds); None when the rest cannot take it.
    """
    free = np.ones(len(q), dtype=bool)
    for _ in range(len(q)):
        wf = np.where(free, w, 0.0)
        jw = jac * wf
        try:
            moved = q + wf * (jw.T @ np.linalg.solve(jw @ jw.T, r))
        except np.linalg.LinAlgError:
            return None
        out = free & ((moved < lo) | (moved > hi))
        if not out.any():
            return moved
        free &= ~out
    return None


def _estimates(problem: Problem, cands: list) -> np.ndarray:
    """Rest-to-rest time estimates (s) of the candidates' straight paths.

    Per joint, bang-bang with the diagonal inertia at the start (as the seed ranking) capped
    at the velocity limit (a trapezoid when the move is long enough to reach it); the
    slowest joint's.
    """
    model = problem.model
    qa = np.array([c[1] for c in cands])
    d = np.abs(np.array([c[2] for c in cands]) - qa)
    mass = np.array(mapped(model, "M", len(qa))(qa.T))
    inertia = np.array([np.diag(mass[:, i * model.n:(i + 1) * model.n])
                        for i in range(len(qa))])
    acc = model.tau_max * problem.torque_scale / inertia
    v = problem.limits.plan_velocity
    with np.errstate(invalid="ignore"):
        t = np.where(d * acc >= v ** 2, d / v + v / acc, 2.0 * np.sqrt(d / acc))
    return np.max(t, axis=1)


def _timed(problem: Problem, qa: np.ndarray, qb: np.ndarray, rest_T: float, label: str):
    """The timed path between ``qa`` and ``qb``: ``(ScaledPath, passes, note)``.

    Or ``(status, why)`` when there is none. ``rest_T`` (s) sets a moving start's time scale.
    """
    n = problem.model.n
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    qd0 = problem.start.value[n:] if problem.start.kind == "state" else np.zeros(n)
    if not np.any(qd0):
        out = _scaled(problem, PolynomialPath.straight(qa, qb), 0.0)
        if isinstance(out[0], Status):
            return out
        return (*out, f"first motion: the straight joint path to {label}, timed by TOPP-RA")
    why = []
    for factor in TIME_SCALES:
        tau = factor * rest_T
        path = PolynomialPath.parabola(qa, qb, qd0 * tau)
        if not _inside(path, lo, hi):
            why.append(f"tau = {tau:.3g} s: leaves the position limits")
            continue
        out = _scaled(problem, path, 1.0 / tau)
        if not isinstance(out[0], Status):
            return (*out, f"first motion: a parabola from the moving start along its "
                    f"velocity to {label} (tau = {tau:.3g} s), timed by TOPP-RA")
        why.append(f"tau = {tau:.3g} s: {out[1]}")
    return Status.SCALING_FAILED, "no parabola from the moving start along its velocity " \
        "could be timed: " + "; ".join(why)


def _inside(path: PolynomialPath, lo: np.ndarray, hi: np.ndarray) -> bool:
    low, high = path.position_range()
    return bool(np.all(low >= lo - 1e-12) and np.all(high <= hi + 1e-12))


# ------------------------------------------------------------------ the scaling
class _Coefficients:
    """The torques along a path at the gridpoints: ``u = a sdd + b sd^2 + c + f sd``.

    All in normalised torque (``tau / (tau_max torque_scale)``), shapes (N + 1, n); ``xv``
    (N + 1,) bounds ``sd^2`` by the velocity limits.
    """

    def __init__(self, problem: Problem, path: PolynomialPath, s: np.ndarray) -> None:
        model = problem.model
        fn = mapped(model, "rigid_body", len(s), lambda: _rigid_body(model))
        q, d1, d2 = path(s), path(s, 1), path(s, 2)
        zero = np.zeros_like(q)
        scale = model.tau_max * problem.torque_scale
        c = np.array(fn(q.T, zero.T, zero.T)).T
        self.a = (np.array(fn(q.T, zero.T, d1.T)).T - c) / scale
        self.b = (np.array(fn(q.T, d1.T, d2.T)).T - c) / scale
        self.c = c / scale
        self.f = model.damping * d1 / scale
        # |q'(s)| is linear on a segment and sd^2 too (sdd is constant there): bounding
        # sd^2 at a gridpoint by the larger |q'| of its two segments keeps the speeds
        # between the gridpoints within the limits as well.
        speed = np.abs(d1)
        seg = np.maximum(speed[:-1], speed[1:])
        speed = np.maximum(np.vstack([seg, seg[-1:]]), np.vstack([seg[:1], seg]))
        v = problem.limits.plan_velocity * (1.0 - VELOCITY_PAD)
        with np.errstate(divide="ignore"):
            self.xv = np.min((v / speed) ** 2, axis=1)

    def torques(self, x: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``|u|`` at every gridpoint, the larger of both sides' (N + 1, n), for ``x``."""
        sdd = (x[1:] - x[:-1]) / (2.0 * np.diff(s))
        base = self.b * x[:, None] + self.c + self.f * np.sqrt(x)[:, None]
        after = np.abs(base[:-1] + self.a[:-1] * sdd[:, None])
        before = np.abs(base[1:] + self.a[1:] * sdd[:, None])
        return np.maximum(np.vstack([after, before[-1:]]), np.vstack([after[:1], before]))


def _rigid_body(model) -> ca.Function:
    """``(q, qd, qdd) -> tau`` without viscous friction (which enters linearly in sd)."""
    q, qd, qdd = (ca.SX.sym(name, model.n) for name in ("q", "qd", "qdd"))
    return ca.Function("rigid_body", [q, qd, qdd], [model.rnea_sym(q, qd, qdd, friction=False)])


def _scaled(problem: Problem, path: PolynomialPath, sd0: float):
    """``(ScaledPath, passes)`` of ``path`` from path speed ``sd0``, or ``(status, why)``."""
    s = np.linspace(0.0, 1.0, GRIDPOINTS + 1)
    coef = _Coefficients(problem, path, s)
    margin, passes = SET_MARGIN, 0
    for _ in range(MARGIN_ROUNDS + 1):
        x, count = _best_scaling(problem, coef, s, sd0, margin)
        passes += count
        if isinstance(x, str):
            return Status.SCALING_FAILED, x
        traj = ScaledPath(problem.model, path, s, x, problem.k, problem.torque_scale)
        _, u, _ = traj.segment_samples(CHECK_POINTS)
        excess = float(np.max(np.sum(np.abs(u) ** (2 * problem.k), axis=1))) - 1.0
        if excess <= 0.0:
            return traj, passes
        margin += 2.0 * excess
    return Status.SCALING_FAILED, f"the torques between the gridpoints leave the set by " \
        f"{excess:.2g} after {MARGIN_ROUNDS} wider margins"


def _best_scaling(problem: Problem, coef: _Coefficients, s: np.ndarray, sd0: float,
                  margin: float):
    """The fastest of the passes (squared path speeds (N + 1,)) and their count.

    Or a message when the first pass fails.
    """
    n = problem.model.n
    friction = bool(np.any(coef.f))
    cube = np.full((len(s), n), n ** (-1.0 / (2.0 * problem.k)))
    # Without friction the first pass is exact; with it, its speeds only place the lines.
    x, why = _toppra(coef, s, sd0, cube * (1.0 - margin), None)
    passes = 1
    if x is None:
        return f"TOPP-RA found no timing inside the cube |u_i| <= n^(-1/(2k)) ({why})", passes
    if friction:
        x, why = _toppra(coef, s, sd0, cube * (1.0 - margin), x)
        passes += 1
        if x is None:
            return f"TOPP-RA found no timing with friction bounded ({why})", passes
    best = x
    for _ in range(ADAPT_PASSES):
        boxes = _boxes(coef.torques(best, s), problem.k) * (1.0 - margin)
        x, _ = _toppra(coef, s, sd0, boxes, best if friction else None)
        passes += 1
        if x is None or _duration(x, s) >= _duration(best, s):
            break
        best = x
    return best, passes


def _duration(x: np.ndarray, s: np.ndarray) -> float:
    sd = np.sqrt(np.maximum(x, 0.0))
    return float(np.sum(2.0 * np.diff(s) / (sd[:-1] + sd[1:])))


def _boxes(demand: np.ndarray, k: float) -> np.ndarray:
    """Boxes (N + 1, n) with their corner on the set's boundary along ``demand`` (N + 1, n).

    ``demand + ADAPT_FLOOR max(demand)`` per gridpoint, scaled so that its ``2k``-norm is
    1: then every ``u`` with ``|u_i| <= box_i`` has ``sum u_i^(2k) <= sum box_i^(2k) = 1``.
    """
    w = demand + ADAPT_FLOOR * np.max(demand, axis=1, keepdims=True) + 1e-12
    return w / np.sum(w ** (2.0 * k), axis=1, keepdims=True) ** (1.0 / (2.0 * k))


def _friction_lines(coef: _Coefficients, x_prev: np.ndarray | None):
    """Lines in ``x = sd^2`` around ``f sqrt(x)``: ``(U0, U1, L0, L1, x_cap)``.

    ``L0 + L1 x <= f sqrt(x) <= U0 + U1 x`` for ``0 <= x <= x_cap``: a tangent of the
    concave ``sqrt`` at the last pass's ``x`` (floored) bounds it above, the chord from 0 to
    ``x_cap`` below (for ``f < 0`` the two swap). Without ``x_prev``: no friction, no cap.
    """
    zero = np.zeros_like(coef.f)
    if x_prev is None:
        return zero, zero, zero, zero, np.full(len(coef.f), np.inf)
    x_top = float(np.max(x_prev))
    x0 = np.maximum(x_prev, TANGENT_FLOOR * x_top)[:, None]
    cap = np.full(len(x_prev), SPEED_CAP * x_top)
    tangent0, tangent1 = 0.5 * np.sqrt(x0), 0.5 / np.sqrt(x0)
    chord1 = 1.0 / np.sqrt(cap)[:, None]
    pos = coef.f >= 0.0
    f = coef.f
    upper0 = np.where(pos, f * tangent0, 0.0)
    upper1 = np.where(pos, f * tangent1, f * chord1)
    lower0 = np.where(pos, 0.0, f * tangent0)
    lower1 = np.where(pos, f * chord1, f * tangent1)
    return upper0, upper1, lower0, lower1, cap


def _toppra(coef: _Coefficients, s: np.ndarray, sd0: float, boxes: np.ndarray,
            x_prev: np.ndarray | None):
    """One TOPP-RA pass: squared path speeds (N + 1,) to rest at ``s = 1``, or (None, why).

    The torque rows ``-box_i <= u_i <= box_i`` (friction by :func:`_friction_lines`),
    divided by the box so that TOPP-RA's ``F v <= g`` is the same at every gridpoint.
    """
    import toppra.algorithm

    u0, u1, l0, l1, cap = _friction_lines(coef, x_prev)
    rows_a = np.hstack([coef.a / boxes, -coef.a / boxes])
    rows_b = np.hstack([(coef.b + u1) / boxes, -(coef.b + l1) / boxes])
    rows_c = np.hstack([(coef.c + u0) / boxes, -(coef.c + l0) / boxes])
    x_max = np.minimum(np.minimum(coef.xv, cap), X_HUGE)
    x_max[0] = max(x_max[0], sd0 ** 2)  # the start's own speed (inside its velocity limits)
    constraint = _constraint_class()(rows_a, rows_b, rows_c, x_max)
    algo = toppra.algorithm.TOPPRA([constraint], _path_class()(coef.a.shape[1]), gridpoints=s,
                                   solver_wrapper="seidel")
    _, sd, _ = algo.compute_parameterization(sd0, 0.0)
    if sd is None or not np.all(np.isfinite(sd)):
        return None, algo.problem_data.return_code.value
    return np.asarray(sd, dtype=float) ** 2, ""


_CLASSES: dict = {}


def _constraint_class():
    """A TOPP-RA linear constraint with given rows.

    A class made on first use: toppra (and the matplotlib it imports) is loaded only when a
    first motion is asked for.
    """
    if "constraint" not in _CLASSES:
        from toppra.constraint import DiscretizationType, LinearConstraint
        from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate

        # Its failures are this module's results; its log lines would only repeat them.
        logging.getLogger("toppra").setLevel(logging.ERROR)

        class RowsConstraint(LinearConstraint):
            """``a u + b x + c <= 1`` row by row, ``0 <= x <= x_max``, per gridpoint."""

            def __init__(self, a, b, c, x_max):
                super().__init__()
                self.set_discretization_type(DiscretizationType.Interpolation)
                self.identical = True
                self.rows, self.x_max = (a, b, c), x_max

            def compute_constraint_params(self, path, gridpoints):
                a, b, c = self.rows
                m = a.shape[1]
                out = canlinear_colloc_to_interpolate(a, b, c, np.eye(m), np.ones(m), None,
                                                      None, gridpoints, identical=True)
                xbound = np.column_stack([np.zeros(len(gridpoints)), self.x_max])
                return (*out[:5], None, xbound)

        _CLASSES["constraint"] = RowsConstraint
    return _CLASSES["constraint"]


def _path_class():
    """A stand-in geometric path for TOPP-RA (the rows carry the path already)."""
    if "path" not in _CLASSES:
        from toppra.interpolator import AbstractGeometricPath

        class Unit(AbstractGeometricPath):
            def __init__(self, dof: int) -> None:
                self._dof = dof

            @property
            def dof(self) -> int:
                return self._dof

            @property
            def path_interval(self) -> np.ndarray:
                return np.array([0.0, 1.0])

        _CLASSES["path"] = Unit
    return _CLASSES["path"]
