"""The first motion: a certified motion inside every limit, at once (issue 32).

The planner's optimum takes from a fraction of a second (the paper's arm) to seconds (an arm
whose joint limits bind). A motion that is slower but already executable is available far
sooner: a joint path between seed configurations of the planner
(:func:`~tocontrol_ros.core.methods.seeding.seed_pairs`),
timed optimally along that path by TOPP-RA
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
2. times the path by TOPP-RA under the velocity limits and, at every gridpoint, a box
   inside the convexified torque set ``sum_i u_i^(2k) <= 1`` (which is not a box: TOPP-RA
   takes linear constraints), viscous friction bounded by lines in ``sd^2``
   (:mod:`~tocontrol_ros.core.direct.time_scaling`);
3. checks the torques between the gridpoints, and times the path again with smaller boxes
   where they leave the set (the same module);
4. certifies the motion open loop
   (:func:`~tocontrol_ros.core.checks.certificate.certify_open_loop`, as the bounded direct
   solve does): its nominal torques re-integrated from its start must reach the target at
   rest, inside the set and within the joint limits.

The result is a :class:`~tocontrol_ros.core.types.result.PlanResult` with ``method="first"``: a
success only when certified; any failure says which step failed and why.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.checks.verification import fine_sample, limit_warnings, verdict
from tocontrol_ros.core.direct.scaled_path import PolynomialPath
from tocontrol_ros.core.direct.time_scaling import (
    DEFAULT_ENGINE,
    cube_time,
    first_pass,
    first_passes,
    rest_time,
    time_scaling,
)
from tocontrol_ros.core.direct.tuning import (
    CANDIDATES,
    FOLLOW_ITERATIONS,
    FOLLOW_STEPS,
    GRIDPOINTS,
    OPEN_LOOP_ATOL,
    OPEN_LOOP_RTOL,
    QUICK_GRIDPOINTS,
    QUICK_IK_ITERATIONS,
    QUICK_SPEED_SLACK,
    QUICK_TIME_SCALES,
    TIME_SCALES,
)
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.methods.seeding import seed_pairs
from tocontrol_ros.core.robot.ik import IK_TOL
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, Status

__all__ = ["configuration_near", "first_motion", "quick_motion"]


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
        return PlanResult.trivial(problem, timings, method="first")
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
    return _certified(problem, options, found, timings, t_start)


def quick_motion(problem: Problem, q_near: np.ndarray, time_scale: float | None = None,
                 options: SolverOptions | None = None,
                 gridpoints: int = QUICK_GRIDPOINTS, engine: str = DEFAULT_ENGINE) -> PlanResult:
    """A first motion whose end is known to be near ``q_near``: a replan's, in milliseconds.

    A replan of a running motion to a target near its own needs no search for the end
    configuration: the target's configuration is found by Newton steps from ``q_near``
    (the running motion's end; weighted least norm, the position limits held, as
    :func:`_followed` does at each of its points), and the path from the start to it is
    timed as :func:`first_motion` times its chosen path (a straight joint line from rest,
    a parabola along a moving start's velocity, its time scale the one of least ``T`` among
    :data:`QUICK_TIME_SCALES` multiples, each joint's speed capped at the larger of its start
    speed and its peak on the straight path's rest-to-rest timing), on ``gridpoints``
    TOPP-RA segments, then certified open loop. No end configurations are ranked: a pass
    for the rest-to-rest timing, one per time scale ranked, the full timing of the chosen
    one, and the certificate.

    Parameters
    ----------
    problem : Problem
        A joint-state start (at rest or moving) and a point or joint-state target.
    q_near : ndarray, shape (n,)
        A configuration near the target's (rad): where the Newton steps start.
    time_scale : float, optional
        A moving start's time scale (s): the parabola's ``tau`` is tried at
        :data:`QUICK_TIME_SCALES` multiples of it. Default: the straight path's rest-to-rest
        time (the planner's replans use the default: the running motion's time left made
        the motions of a stream grow).
    options : SolverOptions, optional
        The certificate's tolerances and ``verify``.
    gridpoints : int
        TOPP-RA's segments along the path (:data:`QUICK_GRIDPOINTS`).
    engine : str
        TOPP-RA's driver (:data:`~tocontrol_ros.core.direct.time_scaling.ENGINES`; the
        benchmark compares them).

    Returns
    -------
    PlanResult
        As :func:`first_motion`'s (``method="first"``); a failure says which step failed.
        Never raises for a numerical failure.
    """
    options = options or SolverOptions()
    t_start = time.perf_counter()
    timings = {"guess": 0.0, "scaling": 0.0, "verify": 0.0}
    if problem.start.kind != "state":
        raise ProblemError("quick_motion needs a joint-state start")
    if problem.is_trivial():
        timings["total"] = time.perf_counter() - t_start
        return PlanResult.trivial(problem, timings, method="first")
    n = problem.model.n
    q0 = np.asarray(problem.start.value[:n], dtype=float)
    if problem.target.kind == "point":
        qb = _newton_near(problem, np.asarray(q_near, dtype=float))
        if qb is None:
            qb = _followed(problem, np.asarray(q_near, dtype=float))
    else:
        qb = np.asarray(problem.target.value[:n], dtype=float)
    timings["guess"] = time.perf_counter() - t_start
    if qb is None:
        return _failure(problem, Status.NO_GUESS, "the target's configuration was not found "
                        "near the given one", timings, t_start)
    t0 = time.perf_counter()
    label = "the target near the running motion's end"
    qd0 = np.asarray(problem.start.value[n:], dtype=float)
    if not np.any(qd0):
        found = _timed(problem, q0, qb, 0.0, label, gridpoints, engine=engine)
    else:
        # The straight path's rest-to-rest timing sets the parabola's time scale and caps
        # the joint speeds at the larger of the start's and its peaks: timed optimally along
        # a path that first runs on along the start's velocity, the arm would speed up
        # there, and along a stream of replans each started faster than the last (the
        # paper's arm on a 0.15 m circle, goals 1.9 cm and 0.1 s apart: from 0.7 to 4.8
        # rad/s, T from 0.5 to 2.3 s).
        rest_T, why, peak = rest_time(problem, PolynomialPath.straight(q0, qb), gridpoints,
                                      peaks=True, engine=engine)
        if rest_T is None:
            return _failure(problem, Status.SCALING_FAILED, f"the straight path could not be "
                            f"timed at rest ({why})", timings, t_start)
        cap = np.maximum(np.abs(qd0), peak) * (1.0 + QUICK_SPEED_SLACK)
        cap = np.maximum(cap, QUICK_SPEED_SLACK * np.max(cap))  # joints at rest may move
        scale = time_scale if time_scale is not None and np.isfinite(time_scale) and \
            time_scale > 0.0 else rest_T
        found = _timed(problem, q0, qb, float(scale), label, gridpoints, QUICK_TIME_SCALES,
                       fastest=True, speed_cap=cap, engine=engine)
    timings["scaling"] = time.perf_counter() - t0
    if isinstance(found[0], Status):
        return _failure(problem, *found, timings, t_start)
    return _certified(problem, options, found, timings, t_start)


def _certified(problem: Problem, options: SolverOptions, found: tuple, timings: dict,
               t_start: float) -> PlanResult:
    """The timed path ``found`` = ``(ScaledPath, passes, note)`` certified, as a result."""
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
    return PlanResult.failure(problem, status, f"the first motion: {why}", timings,
                              method="first")


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
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    cands = [(f"seed pair {i}", qa, qb) for i, (qa, qb) in enumerate(pairs)]
    if problem.target.kind == "point":
        near = _followed(problem, pairs[0][0])
        if near is not None:
            cands.append(("the target followed from the start", pairs[0][0], near))
    cands = [c for c in cands if _inside(PolynomialPath.straight(c[1], c[2]), lo, hi)]
    if not cands:
        return Status.LIMITS_INFEASIBLE, "no seed pair is inside the position limits"
    best, why = None, ""
    for i in np.argsort(_estimates(problem, cands), kind="stable")[:CANDIDATES]:
        label, qa, qb = cands[i]
        T, why = rest_time(problem, PolynomialPath.straight(qa, qb))
        if T is not None and (best is None or T < best[2]):
            best = (qa, qb, T, label)
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
    fk = problem.model.function("P")
    target = problem.target.value
    x0 = np.array(fk(qa)).ravel()
    q = np.array(qa, dtype=float)
    goals = [x0 + (target - x0) * (i / FOLLOW_STEPS) for i in range(1, FOLLOW_STEPS + 1)]
    for goal in goals + [target]:
        q = _newton(problem, q, goal, FOLLOW_ITERATIONS, early=False)
        if q is None:  # singular, or the free joints cannot move the tip there
            return None
    if not np.linalg.norm(np.array(fk(q)).ravel() - target) <= IK_TOL:
        return None
    return q


def _newton_near(problem: Problem, q: np.ndarray) -> np.ndarray | None:
    """The target's configuration by Newton steps from ``q`` (near it), or None.

    :func:`configuration_near` of the target point (the caller then follows the task-space
    line, :func:`_followed`).
    """
    return configuration_near(problem, problem.target.value, q)


def configuration_near(problem: Problem, goal: np.ndarray, q: np.ndarray
                       ) -> np.ndarray | None:
    """A configuration reaching the task point ``goal`` found from ``q`` near it, or None.

    At most :data:`QUICK_IK_ITERATIONS` weighted least-norm steps straight at ``goal`` (least
    ``sum (dq_i / v_i)^2``, ``v`` the velocity limits; the position limits of ``problem``
    held); None unless within ``IK_TOL`` of it.

    Parameters
    ----------
    problem : Problem
        Its model and planning limits.
    goal : ndarray, shape (m,)
        Task point (m).
    q : ndarray, shape (n,)
        Where the steps start (rad, m).

    Returns
    -------
    ndarray, shape (n,) or None
    """
    lim, goal = problem.limits, np.asarray(goal, dtype=float)
    q = np.clip(np.array(q, dtype=float), lim.plan_lower, lim.plan_upper)
    q = _newton(problem, q, goal, QUICK_IK_ITERATIONS, early=True)
    return q if q is not None and np.linalg.norm(
        goal - problem.model.point_and_jacobian(q)[0]) <= IK_TOL else None


def _newton(problem: Problem, q: np.ndarray, goal: np.ndarray, iterations: int,
            early: bool) -> np.ndarray | None:
    """``iterations`` weighted least-norm steps from ``q`` at the task point ``goal`` (m).

    The steps of :func:`_followed` (at each point of its line) and :func:`_newton_near`:
    least ``sum (dq_i / v_i)^2`` (``v`` the velocity limits), the position limits held
    (:func:`_limited_step`). ``early``: stop once within ``IK_TOL``. None when a step
    cannot be taken (singular, or the free joints cannot move the tip there).
    """
    model, lim = problem.model, problem.limits
    w = np.where(np.isfinite(lim.plan_velocity), lim.plan_velocity, 1.0)
    for _ in range(iterations):
        p, jac = model.point_and_jacobian(q)  # P and J as model.point/jacobian, one call
        r = goal - p
        if early and np.linalg.norm(r) <= IK_TOL:
            return q
        q = _limited_step(q, r, jac, w, lim.plan_lower, lim.plan_upper)
        if q is None:
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
    inertia = model.diagonal_inertia(qa)
    acc = model.tau_max * problem.torque_scale / inertia
    v = problem.limits.plan_velocity
    with np.errstate(invalid="ignore"):
        t = np.where(d * acc >= v ** 2, d / v + v / acc, 2.0 * np.sqrt(d / acc))
    return np.max(t, axis=1)


def _timed(problem: Problem, qa: np.ndarray, qb: np.ndarray, rest_T: float, label: str,
           gridpoints: int = GRIDPOINTS, scales: tuple = TIME_SCALES, fastest: bool = False,
           speed_cap: np.ndarray | None = None, engine: str = DEFAULT_ENGINE):
    """The timed path between ``qa`` and ``qb``: ``(ScaledPath, passes, note)``.

    Or ``(status, why)`` when there is none. ``rest_T`` (s) sets a moving start's time scale;
    its parabola is the first of ``scales`` that can be timed, or with ``fastest`` the one
    of least ``T`` among them. ``speed_cap``, ``engine``: :func:`time_scaling`'s.
    """
    n = problem.model.n
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    qd0 = problem.start.value[n:] if problem.start.kind == "state" else np.zeros(n)
    if not np.any(qd0):
        out = time_scaling(problem, PolynomialPath.straight(qa, qb), 0.0, gridpoints,
                           speed_cap, engine)
        if isinstance(out[0], Status):
            return out
        return (*out, f"first motion: the straight joint path to {label}, timed by TOPP-RA")
    why, timed, passes = [], {}, 0

    ranked: dict = {}  # scale index -> (its path, its first pass), with fastest

    def attempt(i: int):
        """The path of scale ``scales[i]`` timed, or None (why noted); memoised."""
        nonlocal passes
        if i not in timed:
            tau = scales[i] * rest_T
            path, first = ranked.get(i, (PolynomialPath.parabola(qa, qb, qd0 * tau), None))
            timed[i] = None
            if first is None and not _inside(path, lo, hi):  # a ranked one is inside
                why.append(f"tau = {tau:.3g} s: leaves the position limits")
            else:
                out = time_scaling(problem, path, 1.0 / tau, gridpoints, speed_cap, engine,
                                   first)
                if isinstance(out[0], Status):
                    why.append(f"tau = {tau:.3g} s: {out[1]}")
                else:
                    passes += out[1]
                    timed[i] = (out[0], tau)
        return timed[i]

    if not fastest:
        best = next((r for r in map(attempt, range(len(scales))) if r is not None), None)
    else:
        # The least T: each scale's parabola ranked by one TOPP-RA pass in the cube, from
        # the middle scale down while it falls, else up while it falls (unimodal in the
        # scale on the cases measured); then timed in full in that order until one can be.
        # That pass is time_scaling's first (first_pass: the cube shrunk by its margin),
        # handed on, not done again; with the compiled sweeps every scale's is made ahead in
        # one go (_ranked) and the search reads them, with "seidel" pass by pass (with
        # "toppra", the implementation before issue 47: cube_time, the full cube, pass by
        # pass, and time_scaling starts over).
        estimate: dict = {}
        together = engine == DEFAULT_ENGINE  # the compiled sweeps: one call for all scales
        if together:  # every scale's first pass in one go, read by the search
            estimate, made = _ranked(problem, qa, qb, qd0, rest_T, scales, gridpoints,
                                     speed_cap, engine, ranked)

        searched: dict = {}  # the scales the search read, in its order: its choices

        def rank(i: int) -> float:
            if i not in estimate:  # the other engines: pass by pass, as the search asks
                tau = scales[i] * rest_T
                path = PolynomialPath.parabola(qa, qb, qd0 * tau)
                if not _inside(path, lo, hi):
                    estimate[i] = np.inf
                elif engine == "toppra":
                    estimate[i] = cube_time(problem, path, 1.0 / tau, gridpoints, speed_cap,
                                            engine)
                else:
                    ranked[i] = (path, first_pass(problem, path, 1.0 / tau, gridpoints,
                                                  speed_cap, engine))
                    estimate[i] = ranked[i][1].T
            searched.setdefault(i, estimate[i])
            return estimate[i]

        mid = len(scales) // 2
        if np.isfinite(rank(mid)):
            for step in (-1, 1):
                i = mid + step
                while 0 <= i < len(scales) and rank(i) < rank(i - step):
                    i += step
                if i != mid + step:
                    break
        else:
            for i in range(len(scales)):
                rank(i)
        passes += made if together else len(searched)
        best = None
        for i in sorted(searched, key=searched.get):
            best = attempt(i)
            if best is not None:
                break
    if best is not None:
        return (best[0], max(passes, 1), f"first motion: a parabola from the moving start "
                f"along its velocity to {label} (tau = {best[1]:.3g} s), timed by TOPP-RA")
    return Status.SCALING_FAILED, "no parabola from the moving start along its velocity " \
        "could be timed: " + "; ".join(why)


def _ranked(problem: Problem, qa: np.ndarray, qb: np.ndarray, qd0: np.ndarray,
            rest_T: float, scales: tuple, gridpoints: int, speed_cap: np.ndarray | None,
            engine: str, ranked: dict) -> tuple[dict, int]:
    """Every time scale's parabola ranked by its first pass, all in one go.

    The parabolas inside the position limits get :func:`first_passes` (one call of each
    step for all of them: the passes :func:`_timed`'s search would make one by one, the
    same numbers), kept in ``ranked`` (index -> (path, its pass)); the others ``inf``.
    Returns ``({index: T (s)}, the passes made)``.
    """
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    taus = [scale * rest_T for scale in scales]
    paths = [PolynomialPath.parabola(qa, qb, qd0 * tau) for tau in taus]
    low, high = PolynomialPath.position_ranges(paths)
    inside = np.flatnonzero(np.all(low >= lo - 1e-12, axis=1)
                            & np.all(high <= hi + 1e-12, axis=1))
    firsts = first_passes(problem, [paths[i] for i in inside],
                          [1.0 / taus[i] for i in inside], gridpoints, speed_cap, engine)
    estimate = dict.fromkeys(range(len(scales)), np.inf)
    for i, first in zip(inside, firsts, strict=True):
        ranked[int(i)] = (paths[i], first)
        estimate[int(i)] = first.T
    return estimate, len(firsts)


def _inside(path: PolynomialPath, lo: np.ndarray, hi: np.ndarray) -> bool:
    low, high = path.position_range()
    return bool(np.all(low >= lo - 1e-12) and np.all(high <= hi + 1e-12))
