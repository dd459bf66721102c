"""What every stage of one solve shares: its context, and the iterate of one start.

:class:`SolveContext` carries the problem, the options, the deadline and the cancel flag;
:class:`Run` is the mutable iterate of one start, and :func:`newton` the solve that moves it.

The stages (:mod:`~tocontrol_ros.core.solver`, :mod:`~tocontrol_ros.core.indirect.mesh`) take a
:class:`SolveContext` and a :class:`Run`; a cancelled or timed-out solve unwinds them all by
:class:`StopError`, which :func:`~tocontrol_ros.core.solver.plan` turns into a result.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from tocontrol_ros.core.indirect.newton import NewtonReport, newton_solve
from tocontrol_ros.core.indirect.pmp import CanonicalSystem, LawParams
from tocontrol_ros.core.indirect.shooting import ShootingGrid
from tocontrol_ros.core.options import SolverOptions
from tocontrol_ros.core.problem import Problem
from tocontrol_ros.core.result import PlanResult, Status
from tocontrol_ros.core.trajectory import Trajectory

__all__ = ["SolveContext", "Run", "StopError", "newton", "trajectory"]


class StopError(Exception):
    """Internal: the deadline passed or the caller cancelled."""

    def __init__(self, status: Status) -> None:
        super().__init__(status.value)
        self.status = status

    def __reduce__(self):
        return (StopError, (self.status,))  # from a worker process (core/pool.py)


@dataclass(frozen=True)
class SolveContext:
    """One call of :func:`~tocontrol_ros.core.solver.plan`: what every stage reads.

    Attributes
    ----------
    system : CanonicalSystem
        The compiled canonical system of the problem's model.
    problem : Problem
    options : SolverOptions
    deadline : float
        ``time.perf_counter()`` value at which the solve stops with ``TIME_LIMIT``.
    should_stop : callable or None
        Polled between Newton iterations; returning True cancels the solve.
    memo : dict
        Values computed once per solve: ``"pairs"``, the multistart's seed pairs (inverse
        kinematics costs), reused by the bounded solve where the joint limits bind;
        ``"incumbents"``, the motions found so far (:meth:`offer`).
    """

    system: CanonicalSystem
    problem: Problem
    options: SolverOptions
    deadline: float
    should_stop: Callable[[], bool] | None = None
    memo: dict = field(default_factory=dict)

    def portable(self) -> SolveContext:
        """A copy for another process (:mod:`~tocontrol_ros.core.pool`).

        Without the compiled system (a worker has its own), the cancel callback (the pool
        passes an event instead, :meth:`attached`) and the memo (incumbents stay here).
        """
        return replace(self, system=None, should_stop=None, memo={})

    def attached(self, should_stop: Callable[[], bool] | None) -> SolveContext:
        """A copy with ``should_stop`` as its cancel callback."""
        return replace(self, should_stop=should_stop)

    def extend(self, seconds: float) -> None:
        """Move the deadline ``seconds`` later (time spent compiling, not solving)."""
        if seconds > 0.0:
            object.__setattr__(self, "deadline", self.deadline + seconds)

    def law(self, k: float, delta: float) -> LawParams:
        """The control law's parameters at ``k`` and ``delta`` for this problem."""
        return LawParams(k, delta, self.problem.torque_scale)

    def offer(self, T: float, build: Callable[[dict, float], PlanResult]) -> None:
        """Keep a motion found so far: its ``T`` (s) and how to build its checked result.

        ``build(timings, t_start)`` returns the result (its timings and start time as
        :func:`~tocontrol_ros.core.solver.plan` reports them).
        At the caller's deadline :func:`~tocontrol_ros.core.solver.plan` returns the best
        one that passes its checks (:meth:`incumbent`), with the ``TIME_LIMIT`` status.
        ``build`` must not depend on state that later stages change (take a snapshot).
        """
        if np.isfinite(T):
            self.memo.setdefault("incumbents", []).append((float(T), build))

    def incumbent(self, tries: int, timings: dict, t_start: float) -> PlanResult | None:
        """The least-``T`` motion offered whose result passes its checks, or None.

        At most ``tries`` results are built (each one a certificate), least ``T`` first.
        """
        offered = sorted(self.memo.get("incumbents", ()), key=lambda entry: entry[0])
        for _, build in offered[:tries]:
            result = build(timings, t_start)
            if result.status is Status.SUCCESS:
                return result
        return None

    def check(self) -> None:
        """Raise :class:`StopError` when the caller cancelled or the deadline passed."""
        if self.should_stop is not None and self.should_stop():
            raise StopError(Status.CANCELLED)
        if time.perf_counter() > self.deadline:
            raise StopError(Status.TIME_LIMIT)


@dataclass
class Run:
    """Mutable state of one start while it is being solved."""

    grid: ShootingGrid
    w: np.ndarray
    k: float
    delta: float
    iterations: int = 0
    log: list = field(default_factory=list)
    residual: float = np.inf
    factors: tuple | None = None  # (grid, LU factors of a Jacobian on that grid)

    @property
    def t_final(self) -> float:
        """The current ``T`` (s)."""
        return self.grid.unpack(self.w)[1]

    def lu(self):
        """The kept LU factors if they belong to the current grid, else None."""
        return self.factors[1] if self.factors and self.factors[0] is self.grid else None

    def snapshot(self) -> tuple:
        """What :meth:`restore` needs to go back to the current solution."""
        return (self.grid, self.w.copy(), self.k, self.delta, self.residual)

    def restore(self, snap: tuple) -> None:
        """Go back to a :meth:`snapshot` (the log and the iteration count stay)."""
        self.grid, w, self.k, self.delta, self.residual = snap
        self.w = w.copy()


def newton(ctx: SolveContext, run: Run, k: float, delta: float,
           tol: float | None = None) -> NewtonReport:
    """Solve the BVP at ``(k, delta)`` on the run's grid from its unknowns.

    On convergence the run moves to the solution and logs it; otherwise it stays. ``tol``
    replaces ``ctx.options.tol`` for a solve that only starts the next one.

    Raises
    ------
    StopError
        When the caller cancelled or the deadline passed.
    """
    options = ctx.options
    rep = newton_solve(run.grid, run.w, ctx.problem.boundary_values, ctx.law(k, delta).array(),
                       tol=options.tol if tol is None else tol,
                       max_iter=options.max_newton, deadline=ctx.deadline,
                       should_stop=ctx.should_stop, factors=run.lu())
    run.iterations += rep.iterations
    if rep.factors is not None:
        run.factors = (run.grid, rep.factors)
    if rep.message == "cancelled":
        raise StopError(Status.CANCELLED)
    if rep.message == "time limit reached":
        raise StopError(Status.TIME_LIMIT)
    if rep.converged:
        run.w, run.k, run.delta, run.residual = rep.w, k, delta, rep.residual
        run.log.append((k, delta, run.t_final, rep.iterations, rep.residual))
    return rep


def _dense(system: CanonicalSystem, run: Run, par: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """The solution at every RK4 step point: times (K,) in s and states (K, 4n)."""
    grid = run.grid
    nodes, t_final, _, _ = grid.unpack(run.w)
    lengths = grid.lengths_of(run.w)
    if system.stagewise:
        z = nodes[:-1].T.copy()
        cols = []
        for i in range(grid.steps):
            h = (t_final * lengths * grid.fractions[:, i])[None, :]
            z = system.step_batch(z, h, par, sensitivities=False)[0]
            cols.append(z.T)
        after = np.stack(cols, axis=1)  # (N, steps, nz): the state after each step
    else:
        after = system.interval_batch(nodes[:-1], t_final * lengths[:, None] * grid.fractions,
                                      None, par, sensitivities=False, dense=True)[0]
    stacked = np.concatenate([nodes[:-1, None], after], axis=1)  # (N, steps + 1, nz)
    z_grid = np.concatenate([stacked[:, :-1].reshape(-1, grid.nz), nodes[-1:]])
    offsets = np.concatenate([np.zeros((grid.N, 1)), np.cumsum(grid.fractions, axis=1)[:, :-1]],
                             axis=1)
    tau = grid.tau_of(run.w)
    t_grid = np.concatenate([((tau[:-1, None] + lengths[:, None] * offsets) * t_final).ravel(),
                             [t_final]])
    return t_grid, z_grid


def trajectory(ctx: SolveContext, run: Run) -> Trajectory:
    """The run's current solution as a :class:`Trajectory` (evaluated at any time)."""
    law = ctx.law(run.k, run.delta)
    t_grid, z_grid = _dense(ctx.system, run, law.array())
    return Trajectory(ctx.system, t_grid, z_grid, law)
