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
5. certifies the result (:mod:`~tocontrol_ros.core.checks.certificate`: residual, ``H``, the
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

This module is the orchestration: it sees the methods only through the contract
(:mod:`~tocontrol_ros.core.methods.contract`), picks one by ``SolverOptions.method``
(``"auto"``: the maximum principle, :mod:`tocontrol_ros.core.indirect.method`, which hands
problems whose joint limits bind to the bounded solve, :mod:`tocontrol_ros.core.direct.method`),
runs a near previous solution as one more candidate, and answers at the caller's deadline
with the best motion found so far. The steps above live in the methods' folders:

- :mod:`~tocontrol_ros.core.methods.seeding`: seed pairs of the multistart (step 1), and
  :mod:`~tocontrol_ros.core.direct.guesses`, their direct solves;
- :mod:`~tocontrol_ros.core.indirect.continuation` and :mod:`~tocontrol_ros.core.indirect.mesh`
  (steps 2-4); :mod:`~tocontrol_ros.core.indirect.certificate` (step 5);
- :mod:`~tocontrol_ros.core.types`: the problem, options, result.
"""

from __future__ import annotations

import functools
import os
import threading
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

# The package's methods register themselves with the contract on import.
import tocontrol_ros.core.direct.method  # noqa: F401
import tocontrol_ros.core.indirect.method  # noqa: F401
from tocontrol_ros.core.checks.verification import verify
from tocontrol_ros.core.direct.clearance import SELF_ROW_BAND
from tocontrol_ros.core.direct.first_motion import first_motion, quick_motion
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.geometry.scene import Scene
from tocontrol_ros.core.methods.context import EarlyMotion, SolveContext, StopError
from tocontrol_ros.core.methods.contract import method_named, method_owning
from tocontrol_ros.core.planning.prepared import PreparedModel
from tocontrol_ros.core.planning.tuning import INCUMBENT_TRIES, WARM_GAIN
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, StartRecord, Status

__all__ = ["Status", "SolverOptions", "StartRecord", "PlanResult", "Planner", "plan", "solve_once",
           "solve_in", "verify"]


#: Test hook (issue 53): ``TOCONTROL_SLOW_SOLVER=f`` (f > 1) makes each solve of this module
#: (``Planner.plan``, ``first``, ``quick``, :func:`solve_once`) take about ``f`` times as long:
#: the solve, then a sleep of ``f - 1`` times its duration. A solve called inside another
#: (``Planner.plan`` runs :func:`solve_once`) is not slowed again: ``f`` times, not ``f``
#: squared. The results are unchanged (no decision reads it); the test suite must pass with
#: a solver that slow. Read at import.
SLOW_SOLVER = float(os.environ.get("TOCONTROL_SLOW_SOLVER", "") or 1.0)
#: The real clock, bound at import: a test that replaces ``time.perf_counter`` with a clock
#: that jumps (test_determinism) must not make the hook sleep for minutes.
_REAL_CLOCK = time.perf_counter
_SLEEP = time.sleep
#: How deep the calling thread is in slowed solves (only the outermost one sleeps).
_SLOWED_DEPTH = threading.local()


def _slowed(fn):
    """``fn`` slowed by :data:`SLOW_SOLVER` (itself when it is 1 or less)."""
    if not SLOW_SOLVER > 1.0:
        return fn

    @functools.wraps(fn)
    def slowed(*args, **kwargs):
        depth = getattr(_SLOWED_DEPTH, "depth", 0)
        _SLOWED_DEPTH.depth = depth + 1
        t0 = _REAL_CLOCK()
        try:
            out = fn(*args, **kwargs)
        finally:
            _SLOWED_DEPTH.depth = depth
        if depth == 0:
            _SLEEP((SLOW_SOLVER - 1.0) * (_REAL_CLOCK() - t0))
        return out
    return slowed


class Planner(PreparedModel):
    """Holds the compiled functions of one model, reused across many solves; plans.

    Parameters
    ----------
    model : RobotModel
    """

    @_slowed
    def plan(self, problem: Problem, options: SolverOptions | None = None,
             warm_start: PlanResult | None = None,
             should_stop: Callable[[], bool] | None = None,
             on_first: Callable[[PlanResult], None] | None = None) -> PlanResult:
        """See :func:`plan`."""
        return _plan(self, problem, options or SolverOptions(), warm_start, should_stop,
                     on_first)

    @_slowed
    def quick(self, problem: Problem, q_near: np.ndarray,
              options: SolverOptions | None = None) -> PlanResult:
        """A replan's quick motion: the target's configuration near ``q_near`` (rad, (n,)).

        :func:`~tocontrol_ros.core.direct.first_motion.quick_motion`: the path from the
        start state timed by TOPP-RA and certified, in milliseconds.
        """
        return quick_motion(problem, q_near, None, options or SolverOptions())

    @_slowed
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
         should_stop: Callable[[], bool] | None = None,
         on_first: Callable[[PlanResult], None] | None = None) -> PlanResult:
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
    on_first : callable, optional
        Called at once, on the solving thread, with a certified motion found before the
        answer: a warm re-solve's first certified iterate (of the parametric step, its
        warnings saying ``(route: first iterate)``, or of IPOPT; at most one per plan,
        through :class:`~tocontrol_ros.core.methods.context.EarlyMotion`). The answer (the
        optimum) is returned as without it, the same to the bit.

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
    return planner.plan(problem, options, warm_start, should_stop, on_first)


# ------------------------------------------------------------------------ driver
def _first_only(on_first: Callable[[PlanResult], None] | None) -> EarlyMotion | None:
    """``plan``'s ``on_first`` as the solve's receiver of early motions: the first one only."""
    if on_first is None:
        return None

    def offer(result: PlanResult) -> bool:
        on_first(result)
        return True  # one first motion a plan

    return EarlyMotion(offer)


def _plan(planner: Planner, problem: Problem, options: SolverOptions,
          warm_start: PlanResult | None, should_stop, on_first=None) -> PlanResult:
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
        warm = solve_once(planner, problem, options, warm_start, should_stop, deadline,
                          _first_only(on_first))
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
    cold = _with_self_rows(planner, problem, options, should_stop, deadline)
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


#: At most this many re-solves with more self pairs as rows (:func:`_with_self_rows`).
SELF_ROW_ROUNDS = 2
#: At most this many of them, where the warm re-solve fails, run the multistart again with
#: the pairs as rows from its first solve (case 16 table of bench/collision.py: warm from
#: the refused motion 150 iterations twice; cold with its two pairs as rows, certified).
SELF_ROW_COLD = 1


def _with_self_rows(planner: Planner, problem: Problem, options: SolverOptions,
                    should_stop, deadline: float) -> PlanResult:
    """The cold solve; with a collision model, again with self rows while the certificate asks.

    The arm's own pairs are rows of the bounded solve only for
    ``problem.collision.row_pairs``. A bounded-solve motion refused by its certificate whose
    self pairs come within :data:`~tocontrol_ros.core.direct.clearance.SELF_ROW_BAND` of the
    margin (Coal's exact distances at 401 times) is solved again with those pairs as rows
    as well, warm from the refused motion (its mesh and path; where that fails, from
    IPOPT's default start on them: ``PathWarmState.rows_added``), at most
    :data:`SELF_ROW_ROUNDS` times; where that fails too, the multistart is run again with
    the pairs as rows from its first solve (at most :data:`SELF_ROW_COLD` times in a plan);
    a round that adds no pair, or whose solves fail, stops.
    The result carries the caller's problem; its message names the pairs added, and a
    failed round keeps the refused result (its status and message, and why the round
    failed).
    """
    out = solve_once(planner, problem, options, None, should_stop, deadline)
    col, added, note = problem.collision, [], ""
    cold, colds = SELF_ROW_COLD, []
    for _ in range(SELF_ROW_ROUNDS):
        traj = out.trajectory
        if col is None or out.status is not Status.VERIFICATION_FAILED or \
                not isinstance(traj, FlatTrajectory) or not col.self_pairs:
            break
        q = traj.evaluate(np.linspace(0.0, out.T, 401)).q
        near = replace(col, scene=Scene()).clearance(q).pair_distances  # self pairs only
        new = [p for p in col.self_pairs if p not in col.row_pairs and p in near
               and float(np.min(near[p])) < col.margin + SELF_ROW_BAND]
        if not new:
            break
        col = col.with_row_pairs(new)
        added += new
        warm = replace(out, warm_state=PathWarmState(np.array(traj.breaks),
                                                     np.array(traj.result.P), traj.T,
                                                     None, None, rows_added=True))
        again = solve_once(planner, replace(problem, collision=col), options, warm,
                           should_stop, deadline)
        if again.status not in (Status.SUCCESS, Status.VERIFICATION_FAILED) and cold:
            cold -= 1  # the multistart again, the pairs rows from its first solve
            failed = again.message
            again = solve_once(planner, replace(problem, collision=col), options, None,
                               should_stop, deadline)
            if again.status in (Status.SUCCESS, Status.VERIFICATION_FAILED):
                colds.append(f"warm from the refused motion: {failed}; solved cold with "
                             f"them as rows")
            else:
                again = replace(again, message=f"{failed}; cold: {again.message}")
        if again.status in (Status.SUCCESS, Status.VERIFICATION_FAILED):
            out = again
        else:
            note = f"; with them as rows, warm from it: {again.message}"
            break
    if not added:
        return out
    note = f"self pairs made rows after a refused motion: " \
        f"{['/'.join(p) for p in added]}{''.join(f' ({c})' for c in colds)}{note}"
    return replace(out, problem=problem if out.problem is not None else None,
                   message=f"{out.message} ({note})", warnings=out.warnings + (note,))


@_slowed
def solve_once(planner: Planner, problem: Problem, options: SolverOptions,
               warm_start: PlanResult | None, should_stop, deadline: float,
               early: EarlyMotion | None = None) -> PlanResult:
    """One solve by one method: warm from ``warm_start`` only, else cold.

    The method is the contract's (:mod:`~tocontrol_ros.core.methods.contract`): a warm start
    goes to the method that owns its warm state (a failure is reported), a cold solve to the
    one ``options.method`` names. At the deadline, the best motion offered so far that passes
    its checks is returned with ``TIME_LIMIT``; a cancelled or timed-out solve without one
    reports what the method had (``StopError.partial``). ``early``: where a method that can
    offers its certified iterates before it converges
    (:class:`~tocontrol_ros.core.methods.context.EarlyMotion`; the bounded solve's warm
    re-solve does); the result is the same with or without it.
    """
    t_start = time.perf_counter()
    ctx = SolveContext(planner.system, problem, options, deadline, should_stop, early=early)
    return solve_in(planner, ctx, warm_start, t_start)


@_slowed
def solve_in(compiled: PreparedModel, ctx: SolveContext, warm_start: PlanResult | None,
             t_start: float | None = None) -> PlanResult:
    """:func:`solve_once` in a given context: ``ctx.problem`` by ``compiled``'s functions.

    A piece of :meth:`PreparedModel.map` may call it in a worker process with the context it
    was given (``compiled`` is then the worker's own prepared model, whose system the
    solve uses). ``t_start``: ``time.perf_counter()`` at the call (now by default).
    """
    t_start = time.perf_counter() if t_start is None else t_start
    problem, options = ctx.problem, ctx.options
    if ctx.system is None:
        ctx = replace(ctx, system=compiled.system)
    timings = {"guess": 0.0, "shooting": 0.0, "refine": 0.0, "verify": 0.0}
    if problem.is_trivial():
        timings["total"] = time.perf_counter() - t_start
        return PlanResult.trivial(problem, timings)
    method = method_named(options.method)
    try:
        if warm_start is not None:
            owner = method_owning(warm_start.warm_state)
            if owner is None:
                timings["total"] = time.perf_counter() - t_start
                return PlanResult.failure(
                    problem, Status.NEWTON_FAILED, "no method continues the warm start's "
                    f"state ({type(warm_start.warm_state).__name__})", timings,
                    k=float("nan"))
            return owner.warm_start(compiled, ctx, warm_start, timings, t_start)
        ctx.extend(method.prepare(compiled, problem, options))
        return method.solve(compiled, ctx, timings, t_start)
    except StopError as stop:
        best = None
        if stop.status is Status.TIME_LIMIT:
            best = ctx.incumbent(INCUMBENT_TRIES, timings, t_start)
        timings["total"] = time.perf_counter() - t_start
        if best is not None:
            return _time_limited(best)
        fields = {"k": float("nan"), **(stop.partial or {})}
        return PlanResult.failure(problem, stop.status, "solve interrupted", timings,
                                  **fields)


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
