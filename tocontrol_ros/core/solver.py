"""Time-optimal planning: guess, continuation, multistart, warm start, verification.

:func:`plan` is the one-shot entry point. For one start it

1. solves a coarse direct transcription (k = 1) from a pair of inverse-kinematics seeds; its
   multipliers are the initial costates (:mod:`tocontrol_ros.core.direct.collocation`);
2. solves the boundary-value problem (16), (21) by multiple shooting and Newton at k = 1
   (:mod:`tocontrol_ros.core.indirect.shooting`);
3. continues in ``k`` (doubling up to the requested value, bisecting a step that fails),
   with the control law smoothed by ``delta`` at intermediate values;
4. at the requested ``k`` (> 1), moves to a mesh with a node at every sign change of a
   switching function ``S_i`` (switch nodes: the node's time is an unknown with
   ``S_i = 0`` there, and the RK4 steps next to it are graded towards it, see
   :class:`~tocontrol_ros.core.indirect.shooting.ShootingGrid`), drives ``delta`` down until
   ``T`` no longer changes, refines the mesh until every interval's RK4 error estimate is
   below tolerance, and confirms on the refined mesh that the next smaller ``delta`` leaves ``T``
   unchanged;
5. certifies the result (:mod:`~tocontrol_ros.core.certificate`: residual, ``H``, the
   torques inside the set, re-integration of the nominal torques and of the canonical system).

Newton keeps its LU factors while they work (chord steps with Broyden's rank-one updates,
also across the solves of one mesh and into a warm start). Because the switch nodes move
with the switches, a warm start after a small move usually keeps the previous mesh: a few
Newton iterations and one error estimate.

Multistart runs step 1 from several seed pairs spread over the self-motion manifolds (then
from more that cross the ends of the best direct solutions), groups the direct solutions by
basin and continues the most promising ones; the best is returned and the others listed.
A promising candidate whose shooting fails in steps 2-3 is solved by the direct method at
the requested ``k`` and shot from there, without continuation in ``k``. A warm start skips
the guess and continues from a previous solution (e.g. after the target moved).

This module is the orchestration; the pieces live next to it:

- :mod:`~tocontrol_ros.core.options` (:class:`SolverOptions`), :mod:`~tocontrol_ros.core.result`
  (:class:`Status`, :class:`StartRecord`, :class:`PlanResult`, :class:`WarmState`);
- :mod:`~tocontrol_ros.core.context`: the solve's context (deadline, cancel flag, options),
  the iterate of one start and its Newton solve;
- :mod:`~tocontrol_ros.core.seeding`: seed pairs of the multistart (step 1);
- :mod:`~tocontrol_ros.core.indirect.mesh`: error estimates, refinement and the switch mesh
  (step 4);
- :mod:`~tocontrol_ros.core.certificate`, :mod:`~tocontrol_ros.core.verification`: the
  checks of step 5 and the status they give.

``from tocontrol_ros.core.solver import plan, SolverOptions, PlanResult, Status, verify,
Planner`` keeps working.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from tocontrol_ros.core.certificate import certify
from tocontrol_ros.core.context import Run, SolveContext, StopError, trajectory
from tocontrol_ros.core.direct.first_motion import first_motion
from tocontrol_ros.core.direct.limited import (
    finer_guess,
    plan_limited,
    plan_limited_warm,
    touches,
)
from tocontrol_ros.core.direct.tuning import FINE_GUESS_INTERVALS
from tocontrol_ros.core.guesses import recombined_guesses, solve_guesses
from tocontrol_ros.core.indirect.continuation import (
    final_smoothing,
    finish_warm,
    solve_at_k,
    solve_from_guess,
    warm_run,
)
from tocontrol_ros.core.options import SolverOptions
from tocontrol_ros.core.prepared import PreparedModel
from tocontrol_ros.core.problem import Problem
from tocontrol_ros.core.result import PathWarmState, PlanResult, StartRecord, Status, WarmState
from tocontrol_ros.core.seeding import (
    distinct_basins,
    gravity_free,
    revolute_joints,
    seed_pairs,
    time_ratio_bound,
)
from tocontrol_ros.core.tuning import (
    AT_K_MARGIN,
    CANDIDATE_MARGIN,
    EXHAUSTIVE_CANDIDATES,
    INCUMBENT_TRIES,
    SAME_K1,
    WARM_GAIN,
)
from tocontrol_ros.core.verification import fine_sample, limit_warnings, verdict, verify

__all__ = ["Status", "SolverOptions", "StartRecord", "PlanResult", "WarmState", "Planner",
           "plan", "verify"]


#: StartRecord.status of a distinct direct solution left out by the rule of
#: :data:`~tocontrol_ros.core.tuning.CANDIDATE_MARGIN`.
SKIPPED = "not continued: its direct T cannot beat the best"


class Planner(PreparedModel):
    """Holds the compiled functions of one model, reused across many solves; plans.

    Parameters
    ----------
    model : RobotModel
    """

    def plan(self, problem: Problem, options: SolverOptions | None = None,
             warm_start: PlanResult | None = None,
             should_stop: Callable[[], bool] | None = None) -> PlanResult:
        """See :func:`plan`."""
        return _plan(self, problem, options or SolverOptions(), warm_start, should_stop)

    def first(self, problem: Problem, options: SolverOptions | None = None) -> PlanResult:
        """A certified motion inside every limit at once, slower than the optimum.

        A seed configurations' joint path timed by TOPP-RA (``method="first"``,
        :func:`~tocontrol_ros.core.direct.first_motion.first_motion`): tens of milliseconds
        where :meth:`plan` takes up to seconds.
        """
        return first_motion(problem, options or SolverOptions())


_PLANNERS: dict[int, Planner] = {}


def plan(problem: Problem, options: SolverOptions | None = None,
         warm_start: PlanResult | None = None,
         should_stop: Callable[[], bool] | None = None) -> PlanResult:
    """Solve a time-optimal problem.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions, optional
    warm_start : PlanResult, optional
        A previous successful result of the same model, start kind and target kind: its
        solution is continued to this problem (no guess, no continuation in ``k`` when the
        exponents match). Falls back to a cold solve when it does not converge.
    should_stop : callable, optional
        Polled between Newton iterations; returning True cancels the solve.

    Returns
    -------
    PlanResult
        Never raises for numerical failure: see ``success``, ``status`` and ``message``.
    """
    planner = _PLANNERS.get(id(problem.model))
    if planner is None or planner.model is not problem.model or planner.stale():
        planner = Planner(problem.model)
        _PLANNERS[id(problem.model)] = planner
        if not problem.is_trivial():  # the first use of a model: on every core
            planner.prepare(problem, options, shooting=False)
    return planner.plan(problem, options, warm_start, should_stop)


# ------------------------------------------------------------------------ driver
def _plan(planner: Planner, problem: Problem, options: SolverOptions,
          warm_start: PlanResult | None, should_stop) -> PlanResult:
    """The multistart, and a near previous solution as one more candidate.

    The cold multistart always runs as asked; a warm start (only when
    :meth:`PlanResult.can_warm_start` allows it: same kinds and reserve, ends near the
    previous ones) is solved too, and returned only when its ``T`` is lower by more than
    :data:`WARM_GAIN` (relative). So the cold answer, which does not depend on what was
    solved before, is returned unless a near previous solution leads to a better basin.
    With ``options.warm_only`` a warm start that succeeds is returned alone (the
    multistart runs only when it fails).
    """
    t_start = time.perf_counter()
    if problem.model is not planner.model:
        raise ValueError("`problem.model` is not the planner's model")
    deadline = t_start + options.time_limit
    warm = None
    if warm_start is not None and \
            warm_start.can_warm_start(problem, options.warm_joint_radius) \
            and not problem.is_trivial():
        warm = _plan_from(planner, problem, options, warm_start, should_stop, deadline)
    if warm is not None:
        n = problem.model.n
        ends = warm.trajectory.state([0.0, warm.T])[:, :n] if warm.success \
            else np.full((2, n), np.nan)
        record = StartRecord(-1, ends[0], ends[1], np.nan, warm.T, "warm start" if
                             warm.success else f"warm start failed: {warm.message}")
        if warm.success and options.warm_only:
            best = replace(warm, starts=(replace(record, status="returned"),))
            best.timings["total"] = time.perf_counter() - t_start
            return best
    cold = _plan_from(planner, problem, options, None, should_stop, deadline)
    best = cold
    if warm is not None:
        better = warm.success and (not cold.success or warm.T < cold.T * (1 - WARM_GAIN))
        best = warm if better else cold
        starts = tuple(replace(r, status="continued") if better and r.status == "returned"
                       else r for r in cold.starts)
        record = replace(record, status="returned") if better else record
        timings = {key: cold.timings.get(key, 0.0) + warm.timings.get(key, 0.0)
                   for key in cold.timings}
        best = replace(best, starts=(record,) + starts, timings=timings)
    best.timings["total"] = time.perf_counter() - t_start
    return best


def _plan_from(planner: Planner, problem: Problem, options: SolverOptions,
               warm_start: PlanResult | None, should_stop, deadline: float) -> PlanResult:
    """One solve: warm from ``warm_start`` only (a failure is reported), else cold."""
    t_start = time.perf_counter()
    ctx = SolveContext(planner.system, problem, options, deadline, should_stop)
    timings = {"guess": 0.0, "shooting": 0.0, "refine": 0.0, "verify": 0.0}
    if problem.is_trivial():
        timings["total"] = time.perf_counter() - t_start
        return PlanResult.trivial(problem, timings)
    notes: list[str] = []
    run = None
    records: list[StartRecord] = []
    try:
        finished = False
        if warm_start is not None and isinstance(warm_start.warm_state, PathWarmState):
            return plan_limited_warm(planner, ctx, warm_start.warm_state, timings, t_start,
                                     warm_start.trajectory)
        if warm_start is not None:
            # A planner made since (optimised libraries landed) loads the shooting's first.
            ctx.extend(planner.prepare_shooting(problem, options))
            run, finished = warm_run(ctx, warm_start)
            timings["shooting"] += time.perf_counter() - t_start
            if run is None:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, Status.NEWTON_FAILED,
                                "the warm start did not converge", timings)
        else:
            run, records, status, message = _cold(planner, ctx, timings)
            notes += ctx.memo.get("notes", [])
            if status is _LIMITS_BIND:
                return plan_limited(planner, ctx, timings, t_start, notes)
            if status in _SHOOTING_FAILURES and options.direct_fallback:
                return _fallback(planner, ctx, timings, t_start, status, message, records,
                                 run)
            if status is not Status.SUCCESS:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, status, message, timings, records, run)
            faster = _faster_failures(records, run.t_final)
            if faster and options.direct_fallback:
                direct, note = _faster_direct(planner, ctx, timings, t_start, faster, run,
                                              records)
                if direct is not None:
                    return direct
                notes.append(note)
        # The next basins of the multistart, best T first, in case the best one's
        # certificate fails (a motion that cannot be certified is never returned when a
        # certified one was found).
        queue = [(run, None)] + ctx.memo.get("others", [])
        why = ""
        while queue:
            run, idx = queue.pop(0)
            t0 = time.perf_counter()
            tried = list(notes)
            finish = finish_warm if finished else final_smoothing
            tried += finish(ctx, run, _offer)
            timings["refine"] += time.perf_counter() - t0
            traj = trajectory(ctx, run)
            sample = fine_sample(traj)
            if _leaves_limits(problem, sample):
                if warm_start is not None:
                    timings["total"] = time.perf_counter() - t_start
                    return _failure(problem, Status.LIMITS_INFEASIBLE, "the warm solution "
                                    "leaves the joint limits", timings, run=run)
                notes.append("the solution of the maximum principle leaves the joint limits")
                return plan_limited(planner, ctx, timings, t_start, notes)
            if idx is not None:
                records = [replace(r, status="returned") if r.index == idx else
                           replace(r, status=why) if r.status == "returned" else r
                           for r in records]
            result = _result(ctx, run, records, tried, timings, t_start, traj, sample)
            if result.status is not Status.VERIFICATION_FAILED or not queue:
                return result
            why = result.message
            notes.append(f"the basin with T = {result.T:.6f} s failed its certificate "
                         f"({result.message}); the next best one was tried")
    except StopError as stop:
        best = None
        if stop.status is Status.TIME_LIMIT:
            best = ctx.incumbent(INCUMBENT_TRIES, timings, t_start)
        timings["total"] = time.perf_counter() - t_start
        if best is not None:
            return _time_limited(best)
        return _failure(problem, stop.status, "solve interrupted", timings, records, run)


def _time_limited(best: PlanResult) -> PlanResult:
    """``best``, a checked motion found before the deadline, as a ``TIME_LIMIT`` result.

    Not a success (the solve did not finish: the motion is not shown to be the least ``T``
    of its basin), but it carries the motion and its certificate.
    """
    checked = "certified" if best.certificate is not None else "converged (not certified)"
    note = (f"the time limit ran out: this is the best {checked} motion found before it "
            f"(T = {best.T:.6f} s), not shown to be the optimum")
    return replace(best, success=False, status=Status.TIME_LIMIT,
                   message=f"{Status.TIME_LIMIT.value}: {note}",
                   warnings=(note,) + best.warnings)


def _leaves_limits(problem: Problem, sample) -> bool:
    """Whether a fine sample of a solution leaves the problem's joint limits."""
    return problem.limits.active and max(problem.limits.violations(sample.q, sample.qd)) > 0


def _offer(ctx: SolveContext, snap: tuple) -> None:
    """Offer a run's :meth:`~Run.snapshot` (:meth:`SolveContext.offer`) when it can pass.

    Only at the requested ``k`` and within ``options.tol``: a looser one cannot pass its
    certificate. A snapshot, because later stages move the run.
    """
    grid, w, k, delta, residual = snap
    problem = ctx.problem
    if k != problem.k or not residual <= ctx.options.tol:
        return
    frozen = Run(grid=grid, w=w, k=k, delta=delta, residual=residual)

    def build(timings: dict, t_start: float) -> PlanResult:
        traj = trajectory(ctx, frozen)
        sample = fine_sample(traj)
        if _leaves_limits(problem, sample):
            return _failure(problem, Status.LIMITS_INFEASIBLE, "leaves the joint limits",
                            timings)
        return _result(ctx, frozen, [], [], timings, t_start, traj, sample)

    ctx.offer(frozen.t_final, build)


#: Failures of the shooting after which ``options.direct_fallback`` solves directly.
_SHOOTING_FAILURES = (Status.NEWTON_FAILED, Status.CONTINUATION_FAILED)


def _fallback(planner: Planner, ctx: SolveContext, timings: dict, t_start: float,
              status: Status, message: str, records: list[StartRecord], run) -> PlanResult:
    """The problem solved as a B-spline path after the shooting failed on every candidate.

    The bounded direct solve of :func:`~tocontrol_ros.core.direct.limited.plan_limited` (with the
    limits, if any, as bounds) from the multistart's guesses; when it fails too, the
    shooting's failure is reported, with both messages.
    """
    why = f"the maximum principle's shooting failed ({status.value}: {message})"
    res = plan_limited(planner, ctx, timings, t_start, [], reason=(
        f"{why}: solved as a B-spline path instead (docs/limits.md)"))
    if res.success:
        return res
    timings["total"] = time.perf_counter() - t_start
    # Its own words (its status, LIMITS_INFEASIBLE, speaks of limits the problem may not have).
    why_direct = next((r.status for r in res.starts if r.status.startswith("bounded solve")),
                      res.message)
    return _failure(ctx.problem, status, f"{message}; the direct B-spline method did not "
                    f"succeed either ({why_direct})", timings, records, run)


def _faster_failures(records: list[StartRecord], T: float) -> frozenset[int]:
    """Seed pairs whose shooting failed though their guess's ``T`` (s) is below ``T`` (s).

    The guess solves ``k = 1``, whose control set (the unit ball) lies inside every other
    one: a basin whose ``k = 1`` motion is faster than the one found very likely holds a
    faster motion at ``k`` as well.
    """
    failed = tuple(s.value for s in _SHOOTING_FAILURES)
    return frozenset(r.index for r in records
                     if r.status.startswith(failed) and r.guess_T < T)


def _faster_direct(planner: Planner, ctx: SolveContext, timings: dict, t_start: float,
                   faster: frozenset[int], run: Run, records: list[StartRecord]
                   ) -> tuple[PlanResult | None, str]:
    """The B-spline solve of the candidates :func:`_faster_failures` names.

    Returns its result when it succeeds and is faster than ``run`` (its records merged
    with the multistart's), else None and a note saying why. Found by the planner node's CI
    run (one start per goal): from a moving state the best guess (k = 1, T 0.466 s) stalled
    in the continuation, and the default multistart returned another basin's T = 0.916 s
    where this basin's B-spline path has 0.406 s. Its work is bounded by the candidates it
    solves (IPOPT's iteration limits); the caller's deadline applies as everywhere.
    """
    best_guess = min(r.guess_T for r in records if r.index in faster)
    why = (f"the shooting failed from {len(faster)} candidate(s) whose guess (T = "
           f"{best_guess:.6f} s at k = 1) is faster than the solution found "
           f"(T = {run.t_final:.6f} s)")
    res = plan_limited(planner, ctx, timings, t_start, [], only=faster, reason=(
        f"{why}: solved from them as a B-spline path (docs/limits.md)"))
    if not res.success:
        return None, f"{why}; their B-spline solve failed ({res.message})"
    if res.T >= run.t_final:
        return None, (f"{why}; their B-spline path is not faster (T = {res.T:.6f} s)")
    direct = {r.index: r for r in res.starts if r.index in faster}
    merged = []
    for r in records:
        if r.index in direct:  # the multistart's guess_T (k = 1), the direct outcome
            r = replace(r, T=direct[r.index].T, status=direct[r.index].status)
        elif r.status == "returned":
            r = replace(r, status="slower than the B-spline path")
        merged.append(r)
    return replace(res, starts=tuple(merged)), ""


def _result(ctx: SolveContext, run: Run, records: list[StartRecord], notes: list[str],
            timings: dict, t_start: float, traj, sample) -> PlanResult:
    """The checked result of a converged run (its trajectory and fine sampling)."""
    problem, options = ctx.problem, ctx.options
    t0 = time.perf_counter()
    cert = certify(problem, traj, options.certificate_options(run.grid.steps), sample=sample,
                   solver_residual=run.residual) if options.verify else None
    timings["verify"] = time.perf_counter() - t0
    status, message = verdict(options, cert, run.residual)
    timings["total"] = time.perf_counter() - t_start
    t_final = run.t_final
    records = [replace(r, T=t_final) if r.status == "returned" else r for r in records]
    grid = run.grid
    return PlanResult(
        success=status is Status.SUCCESS, status=status, message=message, T=t_final,
        k=run.k, trajectory=traj, residual=run.residual, iterations=run.iterations,
        timings=timings, continuation=tuple(run.log), max_abs_u=float(np.max(np.abs(sample.u))),
        delta=run.delta, intervals=grid.N,
        verification=dict(cert.figures) if cert else {}, certificate=cert,
        warnings=tuple(notes) + limit_warnings(problem, sample), starts=tuple(records),
        problem=problem,
        warm_state=WarmState(lengths=grid.lengths_of(run.w).copy(), w=run.w.copy(),
                             steps=grid.steps, kinds=grid.kinds.copy(), breaks=grid.breaks,
                             factors=run.lu()))


def _failure(problem: Problem, status: Status, message: str, timings: dict, starts=(),
             run: Run | None = None) -> PlanResult:
    if run is None:
        return PlanResult.failure(problem, status, message, timings, k=float("nan"),
                                  starts=tuple(starts))
    return PlanResult.failure(problem, status, message, timings, k=run.k,
                              residual=run.residual, iterations=run.iterations,
                              continuation=tuple(run.log), delta=run.delta,
                              intervals=run.grid.N, starts=tuple(starts))


# -------------------------------------------------------------------- cold start
#: Internal status of :func:`_cold`: the best guess reaches the joint limits.
_LIMITS_BIND = object()


def _cold(planner: Planner, ctx: SolveContext, timings: dict):
    """Multistart: direct guesses from seed pairs, the best distinct ones continued.

    Ranked seeds, then recombined ones (:func:`~.guesses.recombined_guesses`); a candidate
    whose shooting fails is solved at k directly (:func:`_direct_at_k`) by the rule of
    :data:`AT_K_MARGIN`.

    Returns
    -------
    (run, records, status, message)
        The best run (the first failure's when none succeeded, None without a guess) and
        one :class:`StartRecord` per seed pair.
    """
    problem, options = ctx.problem, ctx.options
    t0 = time.perf_counter()
    pairs = seed_pairs(problem, options, options.exhaustive)
    ctx.memo["pairs"] = pairs
    if not pairs:
        return None, [], Status.NO_GUESS, "no inverse-kinematics seed"
    guesses, x_bounds = solve_guesses(planner, ctx, pairs)
    if x_bounds is None and not options.exhaustive:  # within limits: the bounded solve's
        guesses, pairs = recombined_guesses(planner, ctx, guesses, pairs)
        ctx.memo["pairs"] = pairs
    if x_bounds is not None or not problem.limits.active:
        # Guesses a bounded solve can start from (no bounds: every one).
        ctx.memo["guesses"] = [(g[0], g[3]) for g in guesses]
    timings["guess"] += time.perf_counter() - t0
    ok = [g for g in guesses if g[3].success]
    records = {g[0]: StartRecord(g[0], g[1], g[2], g[3].T if g[3].success else np.nan,
                                 np.nan, "guess only" if g[3].success else
                                 f"direct method failed: {g[3].message}") for g in guesses}
    if not ok:
        return None, list(records.values()), Status.NO_GUESS, guesses[0][3].message
    # Distinct basins: direct solutions whose end configurations differ.
    ok.sort(key=lambda g: g[3].T)
    if touches(problem, ok[0][3].x):
        return None, list(records.values()), _LIMITS_BIND, ""
    # The first solve of a model that gets here compiles the shooting's functions (plan()
    # leaves them out): the time limit is for solving.
    ctx.extend(planner.prepare_shooting(problem, options))
    distinct = distinct_basins(ok, lambda g: g[3], problem.model.n,
                               revolute_joints(problem.model))
    best = None
    failures, succeeded = [], []
    t0 = time.perf_counter()
    count = EXHAUSTIVE_CANDIDATES if options.exhaustive else options.candidates
    # The bound needs an arm on which gravity does no work (with gravity the larger torque
    # set also frees more torque for acceleration): checked along the candidates' guesses.
    ratio = time_ratio_bound(problem.model.n, problem.k) if gravity_free(
        problem.model, np.vstack([g[3].x[:, :problem.model.n] for g in distinct[:count]])) \
        else 0.0
    first_direct = np.inf  # the least direct T (k = 1) among the candidates that succeeded
    for g in distinct[:count]:
        if best is not None and not options.exhaustive and \
                g[3].T * ratio > best[0].t_final * (1 + CANDIDATE_MARGIN):
            # Sorted by direct T, so no later candidate can beat the best either.
            records[g[0]] = replace(records[g[0]], status=SKIPPED)
            continue
        run, status, message = solve_from_guess(ctx, g[3])
        done = "continued"
        if status in _SHOOTING_FAILURES and problem.k > 1 and \
                g[3].T <= first_direct * (1 + AT_K_MARGIN):
            # The continuation in k is one path to the basin at k, a direct solve at k
            # another: taken while no candidate succeeded, or when this one's k = 1 T is
            # within AT_K_MARGIN of the first that did (they come by that T). A slower
            # failure is left to the rule of _faster_failures.
            at_k = _direct_at_k(planner, ctx, g[3])
            if at_k is not None:
                done = (f"continued from a direct solve at k = {problem.k:g} (from k = 1: "
                        f"{status.value}: {message})")
                run, status, message = at_k, Status.SUCCESS, ""
        if status is Status.SUCCESS:
            records[g[0]] = replace(records[g[0]], T=run.t_final, status=done)
            first_direct = min(first_direct, g[3].T)
            succeeded.append((run, g[0]))
            if best is None or run.t_final < best[0].t_final:
                best = (run, g[0])
        else:
            records[g[0]] = replace(records[g[0]], status=f"{status.value}: {message}")
            failures.append((run, status, message))
    if best is None and distinct:
        # Every candidate failed from its coarse guess: the first again from its guess
        # solved on a finer mesh and to a tight tolerance (on redundant arms Newton at
        # k = 1 and the continuation fail from the coarse one more often: the planar 5R
        # and 7R of bench/scaling.py, one start).
        best = _from_finer_guess(planner, ctx, distinct[0], failures, records, succeeded)
    timings["shooting"] += time.perf_counter() - t0
    if best is None:
        run, status, message = failures[0]
        return run, list(records.values()), status, message
    records[best[1]] = replace(records[best[1]], status="returned")
    ctx.memo["others"] = sorted(((r, i) for r, i in succeeded if i != best[1]),
                                key=lambda ri: ri[0].t_final)
    return best[0], sorted(records.values(), key=lambda r: r.index), Status.SUCCESS, ""


def _direct_at_k(planner: Planner, ctx: SolveContext, guess) -> Run | None:
    """A candidate whose shooting failed from its guess, solved at the requested k directly.

    The direct method at ``problem.k`` from the guess (finer, :func:`finer_guess`), then
    the shooting at that k from it (:func:`solve_at_k`), no continuation in k: the basin a
    stalled guess proposes can still hold the best motion. None when either fails.
    """
    problem = ctx.problem
    direct = finer_guess(planner, problem, guess, problem.k)
    if not direct.success:
        return None
    run, status, _ = solve_at_k(ctx, direct)
    return run if status is Status.SUCCESS else None


def _from_finer_guess(planner: Planner, ctx: SolveContext, g: tuple, failures: list,
                      records: dict, succeeded: list):
    """After every candidate failed: the first again from its guess solved on a finer mesh.

    Updates ``records``, ``failures``, ``succeeded`` and ``ctx.memo`` (the finer guess for
    the fallback); returns ``(run, index)`` when the shooting succeeded from it, else None.
    """
    problem, options = ctx.problem, ctx.options
    best = None
    fine = finer_guess(planner, problem, g[3])
    stalled_from = _k1_time(failures[0][0]) \
        if failures[0][1] is Status.CONTINUATION_FAILED else None
    if fine.success and stalled_from is not None and \
            abs(fine.T - stalled_from) <= SAME_K1 * stalled_from:
        # It leads to the k = 1 solution the continuation stalled from: the same
        # stall again (the Panda without limits: 2.3 s), so only the fallback uses it.
        ctx.memo["finer"] = {g[0]: fine}
    elif fine.success:
        run, status, message = solve_from_guess(ctx, fine)
        if status is Status.SUCCESS:
            records[g[0]] = replace(records[g[0]], T=run.t_final, status="continued")
            ctx.memo.setdefault("notes", []).append(
                f"the shooting failed from every guess on {options.guess_intervals} "
                f"intervals ({failures[0][2]}); solved from the first one solved again "
                f"on {FINE_GUESS_INTERVALS}")
            best = (run, g[0])
            succeeded.append(best)
        else:
            failures.insert(0, (run, status, message))
            # The fallback's B-spline solve starts from the finer guess too (the
            # planar 8R's coarse one was 23 % faster than the k = 1 optimum).
            ctx.memo["finer"] = {g[0]: fine}
    return best


def _k1_time(run) -> float | None:
    """``T`` (s) of a run's converged solve at ``k = 1`` without smoothing, or None."""
    if run is None:
        return None
    return next((T for k, delta, T, *_ in run.log if k == 1.0 and delta == 0.0), None)


