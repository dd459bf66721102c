"""The solution of the boundary-value problem as an object evaluated at any time.

The solver's discrete solution is the RK4 grid of the canonical state ``z = (x, psi)``. The
trajectory evaluates ``z(t)`` by one RK4 step of length ``t - t_j`` from the grid point
``t_j <= t`` before it, which is exact at the grid points and has the solver's accuracy in
between; everything else (controls, torques, accelerations, switching functions,
Hamiltonian) is a function of ``z(t)``.
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.indirect.pmp import CanonicalSystem
from tocontrol_ros.core.types.law import LawParams
from tocontrol_ros.core.types.trajectory import TrajectorySample, sample_times

__all__ = ["Trajectory"]


class Trajectory:
    """A time-optimal trajectory: evaluate it at any time, or sample it.

    Parameters
    ----------
    system : CanonicalSystem
    t_grid : ndarray, shape (K,)
        Increasing times of the RK4 grid (s), from 0 to ``T``.
    z_grid : ndarray, shape (K, 4n)
        Canonical state at the grid times.
    law : LawParams
        The control law's parameters of the solution.

    Attributes
    ----------
    law : LawParams
    par : ndarray, shape (3,)
        ``law.array()``, as the compiled functions take it.
    """

    def __init__(self, system: CanonicalSystem, t_grid: np.ndarray, z_grid: np.ndarray,
                 law: LawParams) -> None:
        self.system = system
        self.n = system.n
        self.t_grid = np.asarray(t_grid, dtype=float)
        self.z_grid = np.asarray(z_grid, dtype=float)
        self.law = law
        self.par = law.array()
        self.T = float(self.t_grid[-1])
        self.joint_names = system.model.joint_names
        self._tau_scale = system.model.tau_max * law.torque_scale
        # The solver's own compiled RK4 step (no Jacobians): exact at the grid points.
        self._rk4 = system.step_function(sensitivities=False)
        self._point = system.pointwise()

    def state(self, t) -> np.ndarray:
        """Canonical state ``z(t)``, shape (K, 4n) for K times (clipped to [0, T])."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        idx = np.clip(np.searchsorted(self.t_grid, t, side="right") - 1, 0,
                      len(self.t_grid) - 1)
        h = t - self.t_grid[idx]
        out = self.z_grid[idx]  # exact at the grid points; one RK4 step elsewhere
        move = np.flatnonzero(h != 0)
        if len(move) == 1:  # the integrator's hot path: skip building a mapped function
            out[move[0]] = np.array(self._rk4(out[move[0]], h[move[0]], self.par)).ravel()
        elif len(move):
            out[move] = self.system.step_rows(out[move], h[move], self.par)
        return out

    def evaluate(self, t) -> TrajectorySample:
        """All quantities at times ``t`` (s), scalar or shape (K,).

        Returns
        -------
        TrajectorySample
        """
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        z = self.state(t)
        n = self.n
        if len(t) == 1:
            f, u, s, ham = [np.array(v).T for v in self._point(z[0], self.par)]
        else:
            f, u, s, ham = self.system.pointwise_batch(z, self.par)
        return TrajectorySample(
            t=t, q=z[:, :n], qd=z[:, n:2 * n], qdd=f[:, n:2 * n], u=u,
            tau=u * self._tau_scale, psi=z[:, 2 * n:], S=s, H=np.array(ham).ravel())

    def sample(self, dt: float) -> TrajectorySample:
        """Samples every ``dt`` seconds from 0, always including ``T``.

        Parameters
        ----------
        dt : float
            Sample period (s), positive.
        """
        return self.evaluate(sample_times(self.T, dt))

    def control(self, t: float) -> np.ndarray:
        """Normalised control at one time, shape (n,)."""
        z = self.state(t)[0]
        return np.array(self._point(z, self.par)[1]).ravel()
