"""Multiple shooting with exact sensitivities and a damped Newton method.

Unknowns ``w = (z_0, ..., z_N, T, nu_0, nu_T)``: the canonical state ``z = (x, psi)`` at the
``N + 1`` nodes of a uniform grid in normalised time, the final time, and the multipliers of
the transversality conditions. Equations: continuity ``z_{j+1} - Phi_j(z_j, T) = 0`` (each
interval integrated with a fixed number of RK4 steps, its Jacobians by CasADi's forward
mode) and the boundary and transversality conditions (21) in multiplier form:

- start point ``p0``: ``P(q(0)) = p0``, ``qd(0) = 0``, ``psi_q(0) = J(q(0))^T nu_0``;
- start joint state ``(q0, qd0)``: ``x(0) = (q0, qd0)``;
- target point, target joint state: likewise at ``T``;
- ``H(T) = 0``.

``psi_q = J^T nu`` says that ``psi_q`` is orthogonal to the tangent space ``null(J)`` of the
self-motion manifold, which is the paper's (18)-(20) without choosing ``m`` independent
columns, so it holds for any ``n >= m`` wherever ``J`` has full rank (for ``n = m`` it is
void, as it should be). The system is square: ``4n(N+1) + 1 + 2m`` unknowns and equations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from .pmp import CanonicalSystem

__all__ = ["ShootingGrid", "NewtonReport", "newton_solve", "integrate"]


def integrate(system: CanonicalSystem, starts: np.ndarray, lengths: np.ndarray, steps: int,
              t_final: float, par: np.ndarray, sensitivities: bool = True):
    """Integrate ``dz/dtau = T F(z)`` over intervals, each with ``steps`` RK4 steps.

    Parameters
    ----------
    system : CanonicalSystem
    starts : ndarray, shape (N, 4n)
        State at the start of each interval.
    lengths : ndarray, shape (N,)
        Interval lengths in normalised time.
    steps : int
    t_final : float
        ``T`` (s).
    par : ndarray, shape (3,)
        ``(k, delta, torque_scale)``.
    sensitivities : bool

    Returns
    -------
    z1 : ndarray, shape (N, 4n)
        End states.
    a : ndarray, shape (N, 4n, 4n)
        ``dz1/dz0`` per interval (None without sensitivities).
    b : ndarray, shape (N, 4n)
        ``dz1/dT`` per interval (None without sensitivities).
    """
    dtau = np.asarray(lengths, dtype=float) / steps
    h = (t_final * dtau)[None, :]
    z = np.ascontiguousarray(starts.T)
    a_tot = b_tot = None
    with np.errstate(over="ignore", invalid="ignore"):  # non-finite results are checked
        for i in range(steps):
            z, a_s, b_s = system.step_batch(z, h, par, sensitivities)
            if not sensitivities:
                continue
            db = b_s * dtau[:, None]  # dz1/dT = dz1/dh * dh/dT
            if i == 0:
                a_tot, b_tot = a_s, db
            else:
                a_tot = a_s @ a_tot
                b_tot = np.einsum("nij,nj->ni", a_s, b_tot) + db
    return z.T, a_tot, b_tot


@dataclass(frozen=True)
class NewtonReport:
    """Outcome of one Newton solve.

    Attributes
    ----------
    converged : bool
    w : ndarray
        Final unknowns.
    residual : float
        Max-norm of the equations at ``w``.
    iterations : int
    message : str
    """

    converged: bool
    w: np.ndarray
    residual: float
    iterations: int
    message: str


class ShootingGrid:
    """Compiled equations of one problem structure on one grid.

    Parameters
    ----------
    system : CanonicalSystem
    lengths : ndarray, shape (N,)
        Lengths of the shooting intervals in normalised time (sum 1).
    steps : int
        RK4 steps per interval.
    start_kind, target_kind : {"point", "state"}
    """

    def __init__(self, system: CanonicalSystem, lengths: np.ndarray, steps: int,
                 start_kind: str, target_kind: str) -> None:
        self.system = system
        self.lengths = np.asarray(lengths, dtype=float)
        self.N = len(self.lengths)
        self.steps = steps
        self.start_kind = start_kind
        self.target_kind = target_kind
        model = system.model
        n, m = model.n, model.m
        self.n, self.m = n, m
        self.nz = 4 * n
        self.n_nu0 = m if start_kind == "point" else 0
        self.n_nuT = m if target_kind == "point" else 0
        self.size = self.nz * (self.N + 1) + 1 + self.n_nu0 + self.n_nuT
        self.tau = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.bc = self._boundary_function()
        self._pattern()

    def flow(self, nodes: np.ndarray, t_final: float, par: np.ndarray, sensitivities=True):
        """Integrate every interval from its start node (see :func:`integrate`)."""
        return integrate(self.system, nodes[:-1], self.lengths, self.steps, t_final, par,
                         sensitivities)

    # ------------------------------------------------------------ boundary
    def _boundary_function(self) -> ca.Function:
        key = ("bc", self.start_kind, self.target_kind)
        cache = self.system._cache
        if key in cache:
            return cache[key]
        model, n, m = self.system.model, self.n, self.m
        z0 = ca.SX.sym("z0", self.nz)
        zT = ca.SX.sym("zT", self.nz)
        nu0 = ca.SX.sym("nu0", self.n_nu0)
        nuT = ca.SX.sym("nuT", self.n_nuT)
        ns = m if self.start_kind == "point" else 2 * n
        nt = m if self.target_kind == "point" else 2 * n
        values = ca.SX.sym("values", ns + nt)
        res = []
        for kind, z, nu, val in ((self.start_kind, z0, nu0, values[:ns]),
                                 (self.target_kind, zT, nuT, values[ns:])):
            q = z[:n]
            if kind == "point":
                jac = ca.jacobian(model.point_sym(q), q)
                res += [model.point_sym(q) - val, z[n:2 * n],
                        z[2 * n:3 * n] - ca.mtimes(jac.T, nu)]
            else:
                res.append(z[:2 * n] - val)
        ham = ca.Function("H", [self.system.z, self.system.par], [self.system.ham])
        res.append(ham(zT, self.system.par))
        r = ca.vertcat(*res)
        args = [z0, zT, nu0, nuT]
        fun = ca.Function("bc", [z0, zT, nu0, nuT, values, self.system.par],
                          [r] + [ca.jacobian(r, a) for a in args])
        cache[key] = fun
        return fun

    # ------------------------------------------------------- sparse pattern
    def _pattern(self) -> None:
        """Row/column indices of the Jacobian's non-zeros, in the order values are filled."""
        nz, N = self.nz, self.N
        rows, cols = [], []
        it = np.arange(nz)
        rr, cc = np.meshgrid(it, it, indexing="ij")
        col_T = nz * (N + 1)
        for j in range(N):
            r0 = j * nz
            rows.append((r0 + rr).ravel())   # -A_j at block column j
            cols.append((j * nz + cc).ravel())
            rows.append(r0 + it)             # +I at block column j + 1
            cols.append((j + 1) * nz + it)
            rows.append(r0 + it)             # -b_j at column T
            cols.append(np.full(nz, col_T))
        self._n_cont = len(np.concatenate(rows)) if rows else 0
        nbc = nz + 1 + self.n_nu0 + self.n_nuT
        r_bc = nz * N + np.arange(nbc)
        blocks = [np.arange(nz), N * nz + np.arange(nz),
                  col_T + 1 + np.arange(self.n_nu0),
                  col_T + 1 + self.n_nu0 + np.arange(self.n_nuT)]
        for b in blocks:
            rr2, cc2 = np.meshgrid(r_bc, b, indexing="ij")
            rows.append(rr2.ravel())
            cols.append(cc2.ravel())
        self._rows = np.concatenate(rows)
        self._cols = np.concatenate(cols)
        self._eye = np.ones(nz)

    # ------------------------------------------------------------ pack/unpack
    def unpack(self, w: np.ndarray):
        """Split unknowns into nodes (N + 1, 4n), T, nu0 (m or 0), nuT (m or 0)."""
        nz, N = self.nz, self.N
        nodes = w[:nz * (N + 1)].reshape(N + 1, nz)
        t_final = w[nz * (N + 1)]
        nu0 = w[nz * (N + 1) + 1: nz * (N + 1) + 1 + self.n_nu0]
        nuT = w[nz * (N + 1) + 1 + self.n_nu0:]
        return nodes, float(t_final), nu0, nuT

    def pack(self, nodes: np.ndarray, t_final: float, nu0=None, nuT=None) -> np.ndarray:
        """Inverse of :meth:`unpack` (missing multipliers start at 0)."""
        nu0 = np.zeros(self.n_nu0) if nu0 is None else np.asarray(nu0, dtype=float)
        nuT = np.zeros(self.n_nuT) if nuT is None else np.asarray(nuT, dtype=float)
        return np.concatenate([np.asarray(nodes, dtype=float).ravel(), [t_final], nu0, nuT])

    # ------------------------------------------------------------ equations
    def residual(self, w: np.ndarray, values: np.ndarray, par: np.ndarray,
                 jacobian: bool = True):
        """Equations ``G(w)`` (size,) and, optionally, their sparse Jacobian (CSC)."""
        nodes, t_final, nu0, nuT = self.unpack(w)
        z1, a, b = self.flow(nodes, t_final, par, sensitivities=jacobian)
        cont = (nodes[1:] - z1).ravel()
        bc_out = self.bc(nodes[0], nodes[-1], nu0, nuT, values, par)
        g = np.concatenate([cont, np.array(bc_out[0]).ravel()])
        if not jacobian:
            return g, None
        vals = []
        for j in range(self.N):
            vals += [-a[j].ravel(), self._eye, -b[j]]
        for blk in bc_out[1:]:
            vals.append(np.array(blk).ravel())
        data = np.concatenate(vals)
        jac = sp.csc_matrix((data, (self._rows, self._cols)), shape=(self.size, self.size))
        return g, jac


def newton_solve(grid: ShootingGrid, w0: np.ndarray, values: np.ndarray, par: np.ndarray,
                 tol: float = 1e-10, max_iter: int = 40, deadline: float | None = None,
                 should_stop=None) -> NewtonReport:
    """Damped Newton on ``G(w) = 0`` with a backtracking line search on ``|G|^2 / 2``.

    Parameters
    ----------
    grid : ShootingGrid
    w0 : ndarray, shape (grid.size,)
    values : ndarray
        Boundary values (start then target).
    par : ndarray, shape (3,)
        ``(k, delta, torque_scale)``.
    tol : float
        Convergence when ``max |G| <= tol``.
    max_iter : int
    deadline : float, optional
        ``time.perf_counter()`` value after which to give up.
    should_stop : callable, optional
        Returns True to cancel (checked every iteration).

    Returns
    -------
    NewtonReport
    """
    w = np.array(w0, dtype=float)
    col_T = grid.nz * (grid.N + 1)
    g, jac = grid.residual(w, values, par)
    merit = 0.5 * float(g @ g)
    for it in range(1, max_iter + 1):
        if not np.all(np.isfinite(g)):
            return NewtonReport(False, w, float("nan"), it - 1, "non-finite residual")
        res = float(np.max(np.abs(g)))
        if res <= tol:
            return NewtonReport(True, w, res, it - 1, "converged")
        if should_stop is not None and should_stop():
            return NewtonReport(False, w, res, it - 1, "cancelled")
        if deadline is not None and time.perf_counter() > deadline:
            return NewtonReport(False, w, res, it - 1, "time limit reached")
        try:
            step = -splu(jac).solve(g)
        except RuntimeError:
            return NewtonReport(False, w, res, it - 1, "singular Newton matrix")
        if not np.all(np.isfinite(step)):
            return NewtonReport(False, w, res, it - 1, "singular Newton matrix")
        lam = 1.0
        if step[col_T] < 0 and w[col_T] + step[col_T] <= 0.2 * w[col_T]:
            lam = 0.8 * w[col_T] / -step[col_T]  # keep T positive
        while True:
            w_new = w + lam * step
            g_new, _ = grid.residual(w_new, values, par, jacobian=False)
            merit_new = 0.5 * float(g_new @ g_new) if np.all(np.isfinite(g_new)) else np.inf
            if merit_new <= (1 - 1e-4 * lam) * merit or lam < 1e-4:
                break
            lam *= 0.5
        if not np.isfinite(merit_new):
            return NewtonReport(False, w, res, it, "non-finite residual along the step")
        w = w_new
        g, jac = grid.residual(w, values, par)
        merit = 0.5 * float(g @ g)
    res = float(np.max(np.abs(g)))
    return NewtonReport(res <= tol, w, res, max_iter,
                        "converged" if res <= tol else "iteration limit reached")
