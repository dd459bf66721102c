"""Legendre-Gauss-Radau collocation (degree 3) of the time-optimal problem, CasADi + IPOPT.

The peer a user would write with CasADi instead of our solver, on the same model functions
(``model.forward_dynamics_sym``, ``model.point_sym``), the same control set (the convexified
``sum_i u_i^(2k) <= 1`` or the box ``|u_i| <= 1``), free final time ``T`` (the objective),
and the same boundary conditions: ``P(q(0)) = p_s``, ``qd(0) = 0``, ``P(q(T)) = p_f``,
``qd(T) = 0`` with the configurations free. Per mesh interval the state is the polynomial
through the interval's start and its three Radau points (the last one is the interval's
end); the controls live at the Radau points; the control set holds at each of them.
"""

from dataclasses import dataclass

import casadi as ca
import numpy as np

DEGREE = 3


@dataclass(frozen=True)
class RadauResult:
    success: bool
    message: str
    T: float
    iterations: int


def _coefficients(degree):
    """Radau points ``tau`` (with 0 first) and derivative matrix ``C[j, r] = l_j'(tau_r)``."""
    tau = np.append(0.0, ca.collocation_points(degree, "radau"))
    C = np.zeros((degree + 1, degree + 1))
    for j in range(degree + 1):
        coeff = np.poly1d([1.0])
        for r in range(degree + 1):
            if r != j:
                coeff *= np.poly1d([1.0, -tau[r]]) / (tau[j] - tau[r])
        deriv = np.polyder(coeff)
        for r in range(degree + 1):
            C[j, r] = deriv(tau[r])
    return tau, C


class RadauCollocation:
    """Radau IIA collocation over ``N`` equal intervals, built once and solved many times.

    Parameters
    ----------
    model : RobotModel
    intervals : int
    box : bool
        The box ``|u_i| <= 1`` instead of ``sum u_i^(2k) <= 1``.
    tol : float
        IPOPT tolerance (as the project's ``DirectCollocation``: 1e-8).
    """

    def __init__(self, model, intervals, box=False, tol=1e-8, max_iter=500):
        self.model = model
        self.N = N = intervals
        self.box = box
        n, m, d = model.n, model.m, DEGREE
        self.tau, C = _coefficients(d)
        xs = ca.SX.sym("x", 2 * n)
        us = ca.SX.sym("u", n)
        qdd = model.forward_dynamics_sym(xs[:n], xs[n:], ca.DM(model.tau_max) * us)
        f = ca.Function("f", [xs, us], [ca.vertcat(xs[n:], qdd)]).map(N)
        fk = ca.Function("P", [xs[:n]], [model.point_sym(xs[:n])])

        X = ca.SX.sym("X", 2 * n, N + 1)            # interval ends
        XI = [ca.SX.sym(f"XI{r}", 2 * n, N) for r in range(1, d)]  # interior Radau points
        U = [ca.SX.sym(f"U{r}", n, N) for r in range(1, d + 1)]    # controls, Radau points
        T = ca.SX.sym("T")
        par = ca.SX.sym("p", 2 * m + 1)
        k = par[-1]
        h = T / N
        P = [X[:, :-1]] + XI + [X[:, 1:]]
        g, lbg, ubg = [], [], []
        for r in range(1, d + 1):
            slope = sum(C[j, r] * P[j] for j in range(d + 1))
            g.append(ca.vec(slope - h * f(P[r], U[r - 1])))
            lbg.append(np.zeros(2 * n * N))
            ubg.append(np.zeros(2 * n * N))
        if not box:
            for Ur in U:
                g.append(ca.sum1(Ur ** (2 * k)).T - 1)
                lbg.append(-np.inf * np.ones(N))
                ubg.append(np.zeros(N))
        for col, offset in ((0, 0), (N, m)):
            xc = X[:, col]
            g += [fk(xc[:n]) - par[offset:offset + m], xc[n:]]
            lbg.append(np.zeros(m + n))
            ubg.append(np.zeros(m + n))
        w = ca.vertcat(ca.vec(X), *[ca.vec(x) for x in XI], *[ca.vec(u) for u in U], T)
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                "ipopt.tol": tol, "ipopt.acceptable_tol": tol, "ipopt.max_iter": max_iter,
                "ipopt.mu_strategy": "adaptive", "calc_lam_p": False}
        self.solver = ca.nlpsol("radau", "ipopt", {"x": w, "f": T, "g": ca.vertcat(*g),
                                                   "p": par}, opts)
        self.lbg = np.concatenate(lbg)
        self.ubg = np.concatenate(ubg)
        nx = 2 * n * (N + 1) + 2 * n * N * (d - 1)
        nu = n * N * d
        ulim = 1.0 if box else 1.0 + 1e-9
        big = 1e20
        self.lbx = np.concatenate([-big * np.ones(nx), -ulim * np.ones(nu), [1e-3]])
        self.ubx = np.concatenate([big * np.ones(nx), ulim * np.ones(nu), [big]])

    def times(self):
        """Normalised times of the ends (N + 1,) and of each Radau point r = 1..d, (d, N)."""
        ends = np.linspace(0.0, 1.0, self.N + 1)
        pts = np.array([(np.arange(self.N) + self.tau[r]) / self.N
                        for r in range(1, DEGREE + 1)])
        return ends, pts

    def guess(self, state, control, T):
        """Initial point from callables of normalised time ``s`` in [0, 1].

        ``state(s)`` -> (len(s), 2n), ``control(s)`` -> (len(s), n).
        """
        ends, pts = self.times()
        parts = [state(ends).ravel()]
        parts += [state(pts[r - 1]).ravel() for r in range(1, DEGREE)]
        parts += [control(pts[r - 1]).ravel() for r in range(1, DEGREE + 1)]
        return np.concatenate(parts + [[T]])

    def solve(self, start_point, target_point, k, w0):
        par = np.concatenate([start_point, target_point, [k]])
        sol = self.solver(x0=w0, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg,
                          ubg=self.ubg)
        stats = self.solver.stats()
        return RadauResult(success=bool(stats["success"]), message=str(stats["return_status"]),
                           T=float(np.array(sol["x"]).ravel()[-1]),
                           iterations=int(stats.get("iter_count", -1)))


def interpolator(t_nodes, values):
    """Linear interpolation in normalised time of node values (K, p) given at ``t_nodes``."""
    s_nodes = np.asarray(t_nodes) / t_nodes[-1]

    def at(s):
        s = np.atleast_1d(s)
        return np.stack([np.interp(s, s_nodes, values[:, i]) for i in range(values.shape[1])],
                        axis=1)
    return at
