"""The maximum principle's iterate of one start, and the Newton solve that moves it.

The stages of the indirect method (:mod:`.continuation`, :mod:`.mesh`, and the
orchestration's candidates) take a :class:`~tocontrol_ros.core.methods.context.SolveContext`
and a :class:`Run`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tocontrol_ros.core.indirect.newton import NewtonReport, newton_solve
from tocontrol_ros.core.indirect.pmp import CanonicalSystem
from tocontrol_ros.core.indirect.shooting import ShootingGrid
from tocontrol_ros.core.indirect.trajectory import Trajectory
from tocontrol_ros.core.methods.context import SolveContext, StopError
from tocontrol_ros.core.types.result import Status

__all__ = ["Run", "newton", "trajectory"]


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
