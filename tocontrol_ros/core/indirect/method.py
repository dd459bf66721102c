"""The paper's maximum principle as a method of the contract: multistart, shooting, certificate.

:class:`MaximumPrinciple` (``SolverOptions.method`` ``"indirect"``, and ``"auto"``) solves
a problem cold in the steps of :mod:`tocontrol_ros.core.planning.solver`'s overview: direct
guesses at k = 1 from seed pairs (:func:`~tocontrol_ros.core.direct.guesses.solve_guesses`),
the most promising distinct ones shot and continued in ``k``
(:mod:`~tocontrol_ros.core.indirect.continuation`), the best one refined and certified
(:func:`~tocontrol_ros.core.indirect.certificate.certify`); the next basins are tried when
the best one's certificate fails. Where the joint limits bind (the best guess touches them,
or the solution leaves them) or the shooting fails on every candidate, it hands the problem
to the bounded B-spline solve (:class:`~tocontrol_ros.core.direct.method.BoundedPath`). A
warm start continues a previous maximum-principle solution
(:func:`~tocontrol_ros.core.indirect.continuation.warm_run`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from tocontrol_ros.core.checks.verification import fine_sample, limit_warnings, verdict
from tocontrol_ros.core.direct.guesses import recombined_guesses, solve_guesses
from tocontrol_ros.core.direct.limited import finer_guess, plan_limited, touches
from tocontrol_ros.core.direct.tuning import FINE_GUESS_INTERVALS
from tocontrol_ros.core.indirect.certificate import certify
from tocontrol_ros.core.indirect.continuation import (
    final_smoothing,
    finish_warm,
    solve_at_k,
    solve_from_guess,
    warm_run,
)
from tocontrol_ros.core.indirect.run import Run, trajectory
from tocontrol_ros.core.indirect.tuning import AT_K_MARGIN, SAME_K1
from tocontrol_ros.core.indirect.warm import WarmState
from tocontrol_ros.core.methods.context import SolveContext, StopError
from tocontrol_ros.core.methods.contract import Compiled, Method, register
from tocontrol_ros.core.methods.seeding import (
    distinct_basins,
    gravity_free,
    revolute_joints,
    seed_pairs,
    time_ratio_bound,
)
from tocontrol_ros.core.methods.tuning import CANDIDATE_MARGIN, EXHAUSTIVE_CANDIDATES
from tocontrol_ros.core.types.certificate import Certificate, CertificateOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, StartRecord, Status
from tocontrol_ros.core.types.trajectory import Motion

__all__ = ["MaximumPrinciple", "SKIPPED"]

#: StartRecord.status of a distinct direct solution left out by the rule of
#: :data:`~tocontrol_ros.core.methods.tuning.CANDIDATE_MARGIN`.
SKIPPED = "not continued: its direct T cannot beat the best"


class MaximumPrinciple(Method):
    """The paper's method (see the module docstring); ``PlanResult.method`` ``"indirect"``."""

    name = "indirect"

    def owns(self, warm_state: object) -> bool:
        """A previous maximum-principle solution's shooting mesh and unknowns."""
        return isinstance(warm_state, WarmState)

    def certify(self, problem: Problem, motion: Motion,
                options: CertificateOptions) -> Certificate:
        """The canonical system and the nominal torques re-integrated (:func:`certify`)."""
        return certify(problem, motion, options)

    def solve(self, compiled: Compiled, ctx: SolveContext, timings: dict,
              t_start: float) -> PlanResult:
        """The multistart, then the best basin refined and certified (the next on failure)."""
        problem, options = ctx.problem, ctx.options
        run, records = None, []
        if problem.collision is not None:  # clearance is a constraint of the bounded solve
            return plan_limited(compiled, ctx, timings, t_start, [], reason=(
                "a collision model is given: solved as a B-spline path with hard bounds "
                "(docs/collision.md)"))
        try:
            run, records, status, message = _cold(compiled, ctx, timings)
            notes = list(ctx.memo.get("notes", []))
            if status is _LIMITS_BIND:
                return plan_limited(compiled, ctx, timings, t_start, notes)
            if status in _SHOOTING_FAILURES and options.direct_fallback:
                return _fallback(compiled, ctx, timings, t_start, status, message, records,
                                 run)
            if status is not Status.SUCCESS:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, status, message, timings, records, run)
            faster = _faster_failures(records, run.t_final)
            if faster and options.direct_fallback:
                direct, note = _faster_direct(compiled, ctx, timings, t_start, faster, run,
                                              records)
                if direct is not None:
                    return direct
                notes.append(note)
            return _finish(compiled, ctx, run, records, notes, timings, t_start, warm=False)
        except StopError as stop:
            stop.partial = _failure_fields(records, run)
            raise

    def warm_start(self, compiled: Compiled, ctx: SolveContext, previous: PlanResult,
                   timings: dict, t_start: float) -> PlanResult:
        """The previous solution continued to this problem (a failure is reported)."""
        problem, run = ctx.problem, None
        try:
            # A planner made since (optimised libraries landed) loads the shooting's first.
            ctx.extend(compiled.prepare_shooting(problem, ctx.options))
            run, finished = warm_run(ctx, previous)
            timings["shooting"] += time.perf_counter() - t_start
            if run is None:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, Status.NEWTON_FAILED,
                                "the warm start did not converge", timings)
            return _finish(compiled, ctx, run, [], [], timings, t_start, warm=True,
                           finished=finished)
        except StopError as stop:
            stop.partial = _failure_fields([], run)
            raise


def _finish(compiled: Compiled, ctx: SolveContext, run: Run, records: list[StartRecord],
            notes: list[str], timings: dict, t_start: float, warm: bool,
            finished: bool = False) -> PlanResult:
    """The best run refined, checked and certified; the next basins when its certificate fails.

    The next basins of the multistart, best T first, in case the best one's certificate
    fails (a motion that cannot be certified is never returned when a certified one was
    found). A cold solution that leaves the joint limits goes to the bounded solve; a warm
    one fails (the caller then solves cold).
    """
    problem = ctx.problem
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
            if warm:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, Status.LIMITS_INFEASIBLE, "the warm solution "
                                "leaves the joint limits", timings, run=run)
            notes.append("the solution of the maximum principle leaves the joint limits")
            return plan_limited(compiled, ctx, timings, t_start, notes)
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
    raise AssertionError("unreachable: the queue holds the best run")


def _failure_fields(records: list[StartRecord], run: Run | None) -> dict:
    """``PlanResult.failure``'s fields of an interrupted solve: its records and its run."""
    fields = {"starts": tuple(records)}
    if run is not None:
        fields.update(k=run.k, residual=run.residual, iterations=run.iterations,
                      continuation=tuple(run.log), delta=run.delta, intervals=run.grid.N)
    return fields


def _leaves_limits(problem: Problem, sample) -> bool:
    """Whether a fine sample of a solution leaves the problem's joint limits."""
    return problem.limits.active and (
        max(problem.limits.violations(sample.q, sample.qd)) > 0
        or problem.limits.acceleration_violation(sample.qdd) > 0)


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


def _fallback(planner: Compiled, ctx: SolveContext, timings: dict, t_start: float,
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


def _faster_direct(planner: Compiled, ctx: SolveContext, timings: dict, t_start: float,
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
    """A failed result with the records and the run it had (:func:`_failure_fields`)."""
    return PlanResult.failure(problem, status, message, timings,
                              **{"k": float("nan"), **_failure_fields(starts, run)})


# -------------------------------------------------------------------- cold start
#: Internal status of :func:`_cold`: the best guess reaches the joint limits.
_LIMITS_BIND = object()


def _cold(planner: Compiled, ctx: SolveContext, timings: dict):
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


def _direct_at_k(planner: Compiled, ctx: SolveContext, guess) -> Run | None:
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


def _from_finer_guess(planner: Compiled, ctx: SolveContext, g: tuple, failures: list,
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


register(MaximumPrinciple())
