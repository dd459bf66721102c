"""Plans whose joint limits bind: detection, and the bounded direct solve.

:func:`~tocontrol_ros.core.solver.plan` solves the maximum principle first; when its best
direct guess comes within :data:`TOUCH` of a joint limit (:func:`touches`), or its solution
leaves the limits, :func:`plan_limited` solves the problem again with the limits as hard
bounds:

1. every seed pair gets a coarse Hermite-Simpson solve at the requested ``k`` with the
   bounds at its mesh points, from the initial path timed within the velocity limits;
2. the best ``options.candidates`` distinct ones are solved by the bounded multiple
   shooting (:mod:`~tocontrol_ros.core.bounded`), its mesh doubled (at most
   :data:`REFINEMENTS` times) while its RK4 error estimate is above ``integration_tol`` or
   its motion leaves the limits between RK4 steps;
3. the least ``T`` is verified (re-integration, limits included) and returned with
   ``method="direct"``.

See ``docs/limits.md`` for the formulation and why the maximum principle does not carry the
limits itself.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .bounded import BoundedResult, ShootingTrajectory
from .certificate import certify_open_loop
from .context import SolveContext
from .direct import DirectResult, initial_path
from .problem import Problem
from .result import PlanResult, StartRecord, Status
from .seeding import distinct_basins, seed_pairs
from .verification import fine_sample, limit_warnings, verdict

if TYPE_CHECKING:
    from .solver import Planner

__all__ = ["MESH", "PAD", "REFINEMENTS", "TOUCH", "plan_limited", "state_bounds", "touches"]

#: A direct guess within this fraction of a position range (or of a velocity limit) of the
#: planning limits is taken to touch them.
TOUCH = 0.02

#: Intervals and RK4 steps per interval of the bounded multiple shooting, up to 4 joints
#: and beyond (where one RK4 step per interval keeps the generated derivative code to a size
#: that compiles in minutes).
MESH = {"small": (48, 4), "large": (96, 1)}

#: The bounded solve keeps inside the planning limits by this fraction of each range (of
#: each velocity limit): it bounds the states after each RK4 step, and the motion between
#: them and its re-integration by another integrator differ by the discretisation error.
PAD = 3e-4

#: The mesh is doubled at most this many times.
REFINEMENTS = 2

#: Tolerance on the bounded NLP's constraint violation (its residual).
RESIDUAL_TOL = 1e-6


def touches(problem: Problem, x: np.ndarray) -> bool:
    """Whether states ``x`` (K, 2n) come within :data:`TOUCH` of the planning limits."""
    lim = problem.limits
    if not lim.active:
        return False
    n = problem.model.n
    lo, hi, v = lim.plan_lower, lim.plan_upper, lim.plan_velocity
    width = hi - lo
    q, qd = x[:, :n], x[:, n:2 * n]
    with np.errstate(invalid="ignore"):
        near_q = np.isfinite(width) & ((q - lo < TOUCH * width) | (hi - q < TOUCH * width))
        near_v = np.isfinite(v) & (np.abs(qd) > (1 - TOUCH) * v)
    return bool(np.any(near_q) or np.any(near_v))


def state_bounds(problem: Problem, pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (2n,) of the state: the planning limits shrunk by ``pad`` of each range.

    Widened where needed to hold a start or target joint state.
    """
    lim = problem.limits
    n = problem.model.n
    lo, hi, v = lim.plan_lower, lim.plan_upper, lim.plan_velocity
    width = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    lower = np.concatenate([lo + pad * width, -(1 - pad) * v])
    upper = np.concatenate([hi - pad * width, (1 - pad) * v])
    if problem.start.kind == "state":
        x0 = problem.start.value
        lower, upper = np.minimum(lower, x0), np.maximum(upper, x0)
    if problem.target.kind == "state":
        xt = problem.target.value[:n]
        lower[:n], upper[:n] = np.minimum(lower[:n], xt), np.maximum(upper[:n], xt)
    return lower, upper


def plan_limited(planner: Planner, ctx: SolveContext, timings: dict, t_start: float,
                 notes: list[str]) -> PlanResult:
    """Solve ``ctx.problem`` with its joint limits as hard bounds (see the module)."""
    problem, options = ctx.problem, ctx.options
    t0 = time.perf_counter()
    notes = list(notes) + ["joint limits bind: solved by direct multiple shooting with hard "
                           "bounds (docs/limits.md)"]
    bounds = state_bounds(problem, PAD)
    coarse = planner.direct(problem, options.guess_intervals)
    values = (problem.start.value, problem.target.value, problem.k)
    records, solved = [], []
    for idx, (qa, qb) in enumerate(seed_pairs(problem, options)):
        ctx.check()
        guess = initial_path(problem.model, qa, qb, options.guess_intervals,
                             problem.torque_scale, problem.limits.plan_velocity)
        res = coarse.solve(*values, *guess, x_bounds=bounds)
        records.append(StartRecord(idx, qa, qb, res.T if res.success else np.nan, np.nan,
                                   "guess only" if res.success else
                                   f"direct method failed: {res.message}"))
        if res.success:
            solved.append((idx, res))
    timings["guess"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    best = None
    for idx, res in distinct_basins(solved, lambda g: g[1],
                                    problem.model.n)[:options.candidates]:
        out, fine = _refined(planner, ctx, bounds, res)
        records[idx] = replace(records[idx], T=out.T if out.success else np.nan,
                               status="continued" if out.success else
                               f"bounded solve failed: {out.message}")
        if out.success and (best is None or out.T < best[1].T):
            best = (idx, out, fine)
    timings["shooting"] += time.perf_counter() - t0
    if best is None:
        timings["total"] = time.perf_counter() - t_start
        why = records[0].status if records else "no inverse-kinematics seed"
        return PlanResult(
            success=False, status=Status.LIMITS_INFEASIBLE,
            message=f"{Status.LIMITS_INFEASIBLE.value}: {why}", T=float("nan"), k=problem.k,
            trajectory=None, residual=float("nan"), iterations=0, timings=timings,
            continuation=(), max_abs_u=float("nan"), delta=float("nan"), intervals=0,
            warnings=tuple(notes), starts=tuple(records), problem=problem, method="direct")
    idx, res, fine = best
    records[idx] = replace(records[idx], status="returned")
    traj = ShootingTrajectory(fine, res, problem.k)
    sample = fine_sample(traj)
    t0 = time.perf_counter()
    cert_options = replace(options.certificate_options(fine.steps),
                           residual_tol=RESIDUAL_TOL)
    cert = certify_open_loop(problem, traj, cert_options, sample=sample,
                             solver_residual=res.residual) if options.verify else None
    timings["verify"] = time.perf_counter() - t0
    status, message = verdict(options, cert, res.residual, RESIDUAL_TOL)
    timings["total"] = time.perf_counter() - t_start
    return PlanResult(
        success=status is Status.SUCCESS, status=status, message=message, T=res.T,
        k=problem.k, trajectory=traj, residual=res.residual, iterations=res.iterations,
        timings=timings, continuation=(), max_abs_u=float(np.max(np.abs(sample.u))),
        delta=0.0, intervals=fine.N, verification=dict(cert.figures) if cert else {},
        certificate=cert,
        warnings=tuple(notes) + limit_warnings(problem, sample), starts=tuple(records),
        problem=problem, method="direct")


def _refined(planner: Planner, ctx: SolveContext, bounds, guess: DirectResult):
    """The bounded multiple shooting from a guess, on finer meshes until it is accurate.

    Returns the last result and the transcription that made it.
    """
    problem = ctx.problem
    values = (problem.start.value, problem.target.value, problem.k)
    inside = state_bounds(problem, 0.5 * PAD)
    source = _interpolate
    for level in range(REFINEMENTS + 1):
        fine = planner.bounded(problem, level)
        out = fine.solve(*values, bounds, *source(guess, fine.N),
                         max_time=ctx.deadline - time.perf_counter(),
                         should_stop=ctx.should_stop)
        ctx.check()
        if not out.success:
            return out, fine
        traj = ShootingTrajectory(fine, out, problem.k)
        if traj.step_error() <= ctx.options.integration_tol and traj.overshoot(*inside) <= 0:
            return out, fine
        guess, source = traj, _resample
    return out, fine


def _interpolate(res: DirectResult | BoundedResult, intervals: int
                 ) -> tuple[float, np.ndarray, np.ndarray]:
    """A direct solution on ``intervals`` uniform intervals: (T, x (N+1, 2n), u (N+1, n))."""
    tau_old = res.t / res.T
    tau = np.linspace(0.0, 1.0, intervals + 1)
    x = np.stack([np.interp(tau, tau_old, col) for col in res.x.T], axis=1)
    u = np.stack([np.interp(tau, tau_old, col) for col in res.u.T], axis=1)
    return res.T, x, u


def _resample(traj: ShootingTrajectory, intervals: int
              ) -> tuple[float, np.ndarray, np.ndarray]:
    """A bounded solution on ``intervals`` uniform intervals: (T, x, u)."""
    t = np.linspace(0.0, traj.T, intervals + 1)
    return traj.T, traj.state(t)[:, :2 * traj.n], traj.control_at(t)
