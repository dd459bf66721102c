"""A bounded solution made a checked plan; and a warm re-solve's first motion before its optimum.

:func:`stretched` slows a path down just enough to hold its torques inside the control set
between the samples; :func:`verified` certifies it (re-integration, limits) into a
:class:`~tocontrol_ros.core.types.result.PlanResult`. Both serve every bounded solve
(:mod:`~tocontrol_ros.core.direct.limited`).

:class:`FirstIterate` is the real-time iteration of issue 47 on the warm re-solve by the
parametric step (:mod:`~tocontrol_ros.core.direct.sensitivity`): watching its Newton
iterates (``on_step``), the first one that is already a motion to publish (the NLP's rows
and bounds held to :data:`~.tuning.RESIDUAL_TOL`, the torques inside the set between the
samples, slowed down by :func:`stretched` where needed, certified as every plan) is offered
to the solve's ``ctx.early`` at once (:class:`~tocontrol_ros.core.methods.context.EarlyMotion`,
the receiver IPOPT's iterates go to as well: :mod:`~.early`), while the steps go on to the
optimum, which is the plan's answer as before (the steps are the same with or without the
watch). Decided by work: an iterate is checked only when its violation is within the
tolerance, at most :data:`FIRST_TRIES` of them per solve; an iterate that fails its checks is
never given (docs/limits.md, "Answering at the first feasible iterate").
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.checks.verification import fine_sample, limit_warnings, verdict
from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory
from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL, SET_MARGIN, STRETCHES
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.methods.context import EarlyMotion, SolveContext
from tocontrol_ros.core.types.result import PlanResult, Status

__all__ = ["FIRST_STRETCH", "FIRST_TRIES", "FirstIterate", "checked_iterate", "stretched",
           "verified"]

#: Iterates of one warm re-solve checked at most as a first motion (each a trajectory, the
#: set's check between the samples, a time stretch where that fails, and a certificate
#: where it holds: 6-10 ms at a load of 2, 5-60 ms at 9-10). Only iterates whose violation
#: of the NLP's rows is within the tolerance are checked. On bench/warm_resolve.py's 20
#: moves (bench/warm_first_iterate.py) a first motion came on 11 with 1 or 2 tries, 12 with
#: 3 (case 7: its first two feasible iterates leave the set between the samples), 13 with
#: every iterate checked (case 6, in its pad round); a failed check costs what a passed one
#: does, and the moves whose first feasible iterate fails its checks (6, 7, 16, 20) mostly
#: fail the next ones too: one.
FIRST_TRIES = 1
#: An iterate whose torques leave the set between the samples is slowed down by the time
#: stretch (:func:`stretched`) to be a first motion (cases 13 and 19 of those 20 moves,
#: 3-4 Newton steps before their answers); False: not a first motion (9 first motions; a
#: failed check then costs no stretch). Paired at a load of 9 the two did not differ
#: beyond the noise (docs/limits.md).
FIRST_STRETCH = True


def verified(ctx: SolveContext, res: FlatResult, traj: FlatTrajectory, records: list,
             notes: list[str], timings: dict, t_start: float) -> PlanResult:
    """The verified result of a bounded solve (its warm state: the mesh and path).

    Parameters
    ----------
    ctx : SolveContext
    res : FlatResult
        The solve's answer (control points, ``T`` in s, its residual and multipliers).
    traj : FlatTrajectory
        Its trajectory (held inside the set between the samples).
    records : list of StartRecord
    notes : list of str
        The result's warnings, first.
    timings : dict
        The plan's timings (s); ``verify`` and ``total`` are set here.
    t_start : float
        ``time.perf_counter()`` at the plan's start.

    Returns
    -------
    PlanResult
        ``success`` when the certificate passes and the residual is within
        :data:`~.tuning.RESIDUAL_TOL`.
    """
    problem, options = ctx.problem, ctx.options
    sample = fine_sample(traj)
    t0 = time.perf_counter()
    cert_options = replace(options.certificate_options(1), residual_tol=RESIDUAL_TOL)
    cert = certify_open_loop(problem, traj, cert_options, sample=sample,
                             solver_residual=res.residual) if options.verify else None
    timings["verify"] = time.perf_counter() - t0
    status, message = verdict(options, cert, res.residual, RESIDUAL_TOL)
    timings["total"] = time.perf_counter() - t_start
    success = status is Status.SUCCESS
    return PlanResult(
        success=success, status=status, message=message, T=res.T,
        k=problem.k, trajectory=traj, residual=res.residual, iterations=res.iterations,
        timings=timings, continuation=(), max_abs_u=float(np.max(np.abs(sample.u))),
        delta=0.0, intervals=len(traj.breaks) - 1, verification=dict(cert.figures) if cert else {},
        certificate=cert,
        warnings=tuple(notes) + limit_warnings(problem, sample), starts=tuple(records),
        problem=problem, method="direct",
        warm_state=PathWarmState(np.array(traj.breaks), np.array(res.P), res.T,
                                 res.lam_g, res.lam_x, set_values=traj.known_set_values(),
                                 k=problem.k, torque_scale=problem.torque_scale)
        if success else None)


def stretched(flat: FlatTranscription, out: FlatResult, traj: FlatTrajectory, values,
              bounds) -> tuple[FlatResult, FlatTrajectory] | None:
    """The same path run slower, its torques inside the set between the samples, or None.

    ``T (1 + e)`` for the first ``e`` of :data:`~.tuning.STRETCHES` that suffices.

    Slowing a path down scales its inertial torques by ``1 / (1 + e)^2`` and its friction
    by ``1 / (1 + e)``; the gravity torques stay, so the set's value need not fall, and each
    ``e`` is checked: the torques at 32 times per span, and the NLP's residual (its velocity
    rows only loosen; a start or target joint state with a velocity is no longer met: no
    stretch). ``T`` grows by ``e``, in place of one to three IPOPT solves from the default
    start: on two of eight Panda problems (one start, its limits) the pad re-solves took 17
    and 19 s (1-16 s each, IPOPT crawling at 118 spans); the stretches were 1e-4 and 1e-6,
    in 61 and 15 ms. The stretches that meet the residual are checked against the set in
    one call (:meth:`FlatTrajectory.slower_set_values`: the same numbers as one by one, the
    same choice; issue 47).
    """
    stretches = []
    for e in STRETCHES:
        T = out.T * (1.0 + e)
        resid = flat.residual(*values, T, out.P, *bounds)
        if resid <= RESIDUAL_TOL:
            stretches.append((T, resid))
    if not stretches:
        return None
    values = traj.slower_set_values([T for T, _ in stretches])
    for (T, resid), row in zip(stretches, values, strict=True):
        if float(np.max(row)) <= 1.0 - SET_MARGIN:
            res = replace(out, T=T, residual=resid)
            return res, traj.with_result(res, set_values=row)
    return None


def checked_iterate(ctx: SolveContext, flat: FlatTranscription, it: FlatResult, values,
                    bounds, note: str, timings: dict, t_start: float, stretch: bool = True
                    ) -> tuple[bool, PlanResult | None]:
    """A solve's iterate as a motion: held inside the set between the samples, certified.

    The check of a first motion before the optimum, the same for the parametric steps'
    iterates (:class:`FirstIterate`) and IPOPT's (:mod:`~.early`).

    Parameters
    ----------
    ctx : SolveContext
    flat : FlatTranscription
        The NLP the iterate belongs to.
    it : FlatResult
        The iterate (its rows already within :data:`~.tuning.RESIDUAL_TOL`).
    values : tuple
        The problem's start value, target value and ``k``.
    bounds : tuple of ndarray
        The state bounds (lower, upper), as for :meth:`FlatTranscription.solve`.
    note : str
        The result's warning saying what it is.
    timings : dict
        The result's timings (s).
    t_start : float
        ``time.perf_counter()`` at the plan's start.
    stretch : bool
        Slow the path down (:func:`stretched`) where its torques leave the set between the
        samples; False: such an iterate is not held.

    Returns
    -------
    held : bool
        Whether the torques stay inside the set between the samples (slowed down if needed).
    result : PlanResult or None
        Its verified result (``success`` says whether it passed), None where not held.
    """
    traj = FlatTrajectory(flat, it, values[2])
    if float(np.max(traj.set_values())) > 1.0 - SET_MARGIN:
        slower = stretched(flat, it, traj, values, bounds) if stretch else None
        if slower is None:
            return False, None
        it, traj = slower
    return True, verified(ctx, it, traj, [], [note], timings, t_start)


class FirstIterate:
    """The parametric steps' ``on_step``: the first iterate that is a motion to publish.

    Parameters
    ----------
    ctx : SolveContext
        Its ``early`` (:class:`~tocontrol_ros.core.methods.context.EarlyMotion`) is offered
        the certified first motion (a :class:`~tocontrol_ros.core.types.result.PlanResult`,
        ``success``, its warnings saying ``(route: first iterate)``).
    flat : FlatTranscription
        The NLP the steps solve.
    bounds : tuple of ndarray
        The state bounds (lower, upper), as for :meth:`FlatTranscription.solve`.
    values : tuple
        The problem's start value, target value and ``k``.
    note : str
        The first motion's first warning (how it was solved).
    timings : dict
        The plan's timings so far (copied: the first motion's own).
    t_start, t0 : float
        ``time.perf_counter()`` at the plan's start and at the warm solve's start.

    Attributes
    ----------
    result : PlanResult or None
        The first motion offered to ``ctx.early``, once found.
    tries : int
        Iterates checked (at most :data:`FIRST_TRIES`).
    """

    def __init__(self, ctx: SolveContext, flat: FlatTranscription, bounds, values,
                 note: str, timings: dict, t_start: float, t0: float) -> None:
        self.ctx, self.flat, self.bounds, self.values = ctx, flat, bounds, values
        self.note, self.timings, self.t_start, self.t0 = note, timings, t_start, t0
        self.result: PlanResult | None = None
        self.tries = 0

    @property
    def watching(self) -> bool:
        """Whether an iterate may still be given (a caller wants one; none given yet)."""
        early = self.ctx.early
        return early is not None and not early.done and self.result is None \
            and self.tries < FIRST_TRIES

    def __call__(self, it: FlatResult) -> None:
        """Check the iterate ``it`` (``on_step``); offer it to ``ctx.early`` if it passes."""
        if not self.watching or not np.isfinite(it.residual) or it.residual > RESIDUAL_TOL:
            return
        self.tries += 1
        timings = dict(self.timings)
        timings["shooting"] = timings.get("shooting", 0.0) + time.perf_counter() - self.t0
        note = (f"{self.note} (route: first iterate): the parametric step's iterate after "
                f"{it.iterations} Newton steps, feasible and certified but not converged; "
                f"the optimum follows")
        _, first = checked_iterate(self.ctx, self.flat, it, self.values, self.bounds, note,
                                   timings, self.t_start, FIRST_STRETCH)
        if first is not None and first.success:
            self.result = first
            early: EarlyMotion = self.ctx.early
            early.give(first)
