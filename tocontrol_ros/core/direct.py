"""Direct transcription of the time-optimal problem (Hermite-Simpson collocation + IPOPT).

Two uses: the initial guess of the shooting solver (a coarse mesh), whose constraint
multipliers give the costates, and an independent reference (a fine mesh) to check ``T``.

Sign convention of the costates: IPOPT's Lagrangian is ``T + lambda^T c(w)`` with the
collocation defect ``c_j = x_{j+1} - x_j - h/6 (f_j + 4 f_m + f_{j+1})``. Its stationarity
in ``x`` is a discretisation of ``psid = -(df/dx)^T psi`` with ``psi = +lambda``, in ``u``
it says that ``u`` maximises ``psi^T B u`` on the control set, and in ``T`` it says that the
mean of ``psi^T f`` is 1, i.e. ``H = -1 + psi^T f = 0``: so ``lambda_j`` approximates the
paper's ``psi`` (9) on interval ``j`` with no sign flip and no scaling (the defects carry the
units of ``x``). Node values are averages of the neighbouring intervals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .model import RobotModel

__all__ = ["DirectResult", "DirectCollocation", "initial_path"]


@dataclass(frozen=True)
class DirectResult:
    """Outcome of a direct solve.

    Attributes
    ----------
    success : bool
    message : str
        IPOPT's return status.
    T : float
        Final time (s).
    t : ndarray, shape (N + 1,)
        Mesh times (s).
    x : ndarray, shape (N + 1, 2n)
        States at the mesh points.
    u : ndarray, shape (N + 1, n)
        Normalised controls at the mesh points.
    psi : ndarray, shape (N + 1, 2n)
        Costate estimates from the defect multipliers.
    iterations : int
    solve_time : float
        Wall time of the IPOPT call (s).
    """

    success: bool
    message: str
    T: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    psi: np.ndarray
    iterations: int
    solve_time: float


def initial_path(model: RobotModel, q0: np.ndarray, qT: np.ndarray, intervals: int,
                 torque_scale: float = 1.0) -> tuple[float, np.ndarray, np.ndarray]:
    """A rest-to-rest smoothstep path from ``q0`` to ``qT`` and a time estimate.

    Returns
    -------
    T : float
        Time estimate (s): the slowest joint's bang-bang time with its diagonal inertia.
    x : ndarray, shape (intervals + 1, 2n)
    u : ndarray, shape (intervals + 1, n)
        Normalised torques of the path by inverse dynamics, clipped to the unit box.
    """
    dq = qT - q0
    inertia = np.diag(model.mass_matrix(q0))
    acc = model.tau_max * torque_scale / inertia
    t_final = max(1.5 * float(np.max(2 * np.sqrt(np.abs(dq) / acc))), 1e-2)
    tau = np.linspace(0, 1, intervals + 1)
    s = 3 * tau**2 - 2 * tau**3
    ds = (6 * tau - 6 * tau**2) / t_final
    dds = (6 - 12 * tau) / t_final**2
    q = q0 + np.outer(s, dq)
    qd = np.outer(ds, dq)
    qdd = np.outer(dds, dq)
    u = np.array([model.inverse_dynamics(q[i], qd[i], qdd[i]) for i in range(intervals + 1)])
    u = np.clip(u / (model.tau_max * torque_scale), -0.9, 0.9)
    return t_final, np.hstack([q, qd]), u


class DirectCollocation:
    """Hermite-Simpson transcription, built once per mesh and reused for many solves.

    Parameters
    ----------
    model : RobotModel
    intervals : int
        Number of mesh intervals ``N``.
    start_kind, target_kind : {"point", "state"}
    box : bool
        Use the original box ``|u_i| <= 1`` instead of ``sum u_i^(2k) <= 1``.
    torque_scale : float
        ``1 - reserve``.
    tol : float
        IPOPT tolerance.
    max_iter : int
        IPOPT iteration limit.
    """

    def __init__(self, model: RobotModel, intervals: int, start_kind: str = "point",
                 target_kind: str = "point", box: bool = False, torque_scale: float = 1.0,
                 tol: float = 1e-8, max_iter: int = 500) -> None:
        self.model = model
        self.N = intervals
        self.start_kind = start_kind
        self.target_kind = target_kind
        self.box = box
        n, m = model.n, model.m
        N = intervals
        x_sym = ca.SX.sym("x", 2 * n)
        u_sym = ca.SX.sym("u", n)
        scale = ca.DM(model.tau_max * torque_scale)
        qdd = model.forward_dynamics_sym(x_sym[:n], x_sym[n:], scale * u_sym)
        f = ca.Function("f", [x_sym, u_sym], [ca.vertcat(x_sym[n:], qdd)])
        fk = ca.Function("P", [x_sym[:n]], [model.point_sym(x_sym[:n])])

        X = ca.SX.sym("X", 2 * n, N + 1)
        U = ca.SX.sym("U", n, N + 1)
        UM = ca.SX.sym("UM", n, N)
        T = ca.SX.sym("T")
        ns = m if start_kind == "point" else 2 * n
        nt = m if target_kind == "point" else 2 * n
        par = ca.SX.sym("p", ns + nt + 1)
        k = par[-1]
        h = T / N
        F = f.map(N + 1)(X, U)
        XM = 0.5 * (X[:, :-1] + X[:, 1:]) + h / 8 * (F[:, :-1] - F[:, 1:])
        FM = f.map(N)(XM, UM)
        defects = X[:, 1:] - X[:, :-1] - h / 6 * (F[:, :-1] + 4 * FM + F[:, 1:])
        g = [ca.vec(defects)]
        lbg = [np.zeros(2 * n * N)]
        ubg = [np.zeros(2 * n * N)]
        if not box:
            allu = ca.horzcat(U, UM)
            g.append(ca.sum1(allu ** (2 * k)).T - 1)
            lbg.append(-np.inf * np.ones(2 * N + 1))
            ubg.append(np.zeros(2 * N + 1))
        for kind, col, offset, size in ((start_kind, 0, 0, ns), (target_kind, N, ns, nt)):
            xc = X[:, col]
            target = par[offset:offset + size]
            if kind == "point":
                g += [fk(xc[:n]) - target, xc[n:]]
                lbg.append(np.zeros(m + n))
                ubg.append(np.zeros(m + n))
            else:
                g.append(xc - target)
                lbg.append(np.zeros(2 * n))
                ubg.append(np.zeros(2 * n))
        w = ca.vertcat(ca.vec(X), ca.vec(U), ca.vec(UM), T)
        self._nx = 2 * n * (N + 1)
        self._nu = n * (N + 1)
        self._num = n * N
        nlp = {"x": w, "f": T, "g": ca.vertcat(*g), "p": par}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                "ipopt.tol": tol, "ipopt.max_iter": max_iter,
                "ipopt.acceptable_tol": tol, "ipopt.mu_strategy": "adaptive", "calc_lam_p": False}
        self.solver = ca.nlpsol("direct", "ipopt", nlp, opts)
        self.lbg = np.concatenate(lbg)
        self.ubg = np.concatenate(ubg)
        big = 1e20
        # Joint position limits are checked on the result, not enforced (as in the shooting
        # solver, where the maximum principle has no state constraints): no state bounds.
        lbx_x = -big * np.ones(2 * n * (N + 1))
        ubx_x = big * np.ones(2 * n * (N + 1))
        ulim = 1.0 if box else 1.0 + 1e-9
        self.lbx = np.concatenate([lbx_x, -ulim * np.ones(self._nu + self._num), [1e-3]])
        self.ubx = np.concatenate([ubx_x, ulim * np.ones(self._nu + self._num), [big]])

    def solve(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
              t_guess: float, x_guess: np.ndarray, u_guess: np.ndarray) -> DirectResult:
        """Solve from a guess.

        Parameters
        ----------
        start_value, target_value : ndarray
            Point (m,) or joint state (2n,), as the kinds given at construction.
        k : float
            Exponent of the control set (ignored for the box).
        t_guess : float
            Final time guess (s).
        x_guess : ndarray, shape (N + 1, 2n)
        u_guess : ndarray, shape (N + 1, n)

        Returns
        -------
        DirectResult
        """
        n, N = self.model.n, self.N
        um_guess = 0.5 * (u_guess[:-1] + u_guess[1:])
        w0 = np.concatenate([x_guess.ravel(), u_guess.ravel(), um_guess.ravel(), [t_guess]])
        par = np.concatenate([start_value, target_value, [k]])
        t0 = time.perf_counter()
        sol = self.solver(x0=w0, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg,
                          ubg=self.ubg)
        elapsed = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.array(sol["x"]).ravel()
        lam = np.array(sol["lam_g"]).ravel()
        x = w[:self._nx].reshape(N + 1, 2 * n)
        u = w[self._nx:self._nx + self._nu].reshape(N + 1, n)
        t_final = float(w[-1])
        lam_def = lam[:2 * n * N].reshape(N, 2 * n)
        psi = np.empty((N + 1, 2 * n))
        psi[1:-1] = 0.5 * (lam_def[:-1] + lam_def[1:])
        psi[0] = 1.5 * lam_def[0] - 0.5 * lam_def[1] if N > 1 else lam_def[0]
        psi[-1] = 1.5 * lam_def[-1] - 0.5 * lam_def[-2] if N > 1 else lam_def[-1]
        return DirectResult(
            success=bool(stats["success"]), message=str(stats["return_status"]),
            T=t_final, t=np.linspace(0, t_final, N + 1), x=x, u=u, psi=psi,
            iterations=int(stats.get("iter_count", -1)), solve_time=elapsed)
