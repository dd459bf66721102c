"""Bounded minimum-time motions as a stage-wise optimal-control NLP (issue 47's prototype).

The same problem as :mod:`~tocontrol_ros.core.direct.flat` (minimise ``T`` with the torque set
``sum_i (tau_i / (tau_max_i scale))^(2k) <= 1 - pad``, joint position and velocity limits on the
whole motion, a start state or point, a target point reached at rest with the end
configuration free), written in the form that structure-exploiting solvers (Fatrop, an SQP
with HPIPM's Riccati QP) take: ``N`` uniform intervals of length ``h = T / N``, variables in
stage order ``x_0, u_0, x_1, u_1, ..., x_N`` and constraints per stage, dynamics (``x_k+1 -
F(x_k, u_k) = 0``) then path rows.

``order = 1`` (piecewise-constant accelerations): ``x = (q, qd, T)`` (2n + 1,), ``u = qdd``
(n,); ``order = 2`` (piecewise-linear accelerations, C2 paths like the B-spline's):
``x = (q, qd, qdd, T)`` (3n + 1,), ``u`` = jerk (n,). The double (triple) integrator is
integrated exactly on each interval, so ``F`` is polynomial in ``(x, u)``; the final time ``T``
is a state with ``T_k+1 = T_k`` (Fatrop's free final time; ``h = T / N``), the objective
``T_0``. (``h`` as the state instead: the SQP's proximal margin then held ``T`` back, 2 % of
its 4 % move in the first iteration on a Panda case.) Per interval the path rows are

- the torque set at :data:`SAMPLES` fractions of the interval, the torques being the
  inverse dynamics of the interval's polynomial (recursive Newton-Euler of the model, with
  its viscous friction): the published torques produce the published states exactly;
- the position limits on the whole interval by the convex hull of its Bernstein
  coefficients (the inner ones are rows, the nodes are bounds on the variables), the same
  for the velocity (order 2; order 1's velocity is linear: the node bounds suffice).

Stage 0 adds the start point's rows (a point start), stage ``N`` the target point's
``P(q_N) = p_T`` (and, order 2, the torque set at the end); ``qd_N = 0`` and a start state are
bounds. Start, target, ``k`` and the torque scale are parameters: one NLP per
``(model, N, start_kind, order)``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["SAMPLES", "StagewiseTranscription", "inverse_dynamics"]

#: Fractions of each interval at which the torque set is sampled, per order. Order 1's
#: accelerations jump at the nodes, so both ends of every interval are sampled; order 2's
#: torques are continuous, the end of an interval is the start of the next.
SAMPLES = {1: (0.0, 0.5, 1.0), 2: (0.0, 1.0 / 3.0, 2.0 / 3.0)}
#: Bounds of the final time T (s).
T_RANGE = (1e-3, 100.0)
#: Bounds of an interval's length on a free mesh (s).
H_RANGE = (1e-3, 1.0)


def _poly(order: int, x, u, s):
    """Position, velocity and acceleration at time ``s`` (s) into an interval (SX)."""
    n = u.numel()
    q, v = x[:n], x[n:2 * n]
    if order == 1:
        a = u
        return q + s * v + s ** 2 / 2 * a, v + s * a, a
    a = x[2 * n:3 * n]
    return (q + s * v + s ** 2 / 2 * a + s ** 3 / 6 * u, v + s * a + s ** 2 / 2 * u,
            a + s * u)


class StagewiseTranscription:
    """The stage-wise NLP on ``N`` uniform intervals, built once, solved many times.

    Parameters
    ----------
    model : RobotModel
    N : int
        Intervals.
    start_kind : {"state", "point"}
        A start joint state (fixed by bounds) or a start point at rest (free configuration).
    order : {1, 2}
        Piecewise-constant (1) or piecewise-linear (2) joint accelerations.
    free_mesh : bool
        Each interval's length ``h_k`` a control (in ``H_RANGE``), the state's last entry
        the elapsed time, the objective its final value: the nodes can move to where the
        motion switches.

    Attributes
    ----------
    nx, nu : list of int, length N + 1
        States and controls per stage (``nu[N] = 0``).
    ng : list of int, length N + 1
        Path rows per stage (the dynamics rows apart).
    nlp : dict
        ``x``, ``p``, ``f``, ``g`` (SX): the NLP as ``nlpsol`` takes it.
    """

    def __init__(self, model, N: int, start_kind: str = "state", order: int = 1,
                 free_mesh: bool = False) -> None:
        if order not in SAMPLES or start_kind not in ("state", "point"):
            raise ValueError(f"order {order!r} or start kind {start_kind!r} not supported")
        self.model, self.N, self.start_kind, self.order = model, N, start_kind, order
        self.free_mesh = free_mesh
        n, m = model.n, model.m
        nxs = order * n + n + 1
        self._nx, self._nu = nxs, n + (1 if free_mesh else 0)
        x = ca.SX.sym("x", nxs)
        uu = ca.SX.sym("u", self._nu)
        u = uu[:n]
        k = ca.SX.sym("k")
        scale = ca.SX.sym("scale", n)
        # Uniform: x[-1] = T, h = T / N. Free mesh: x[-1] = the elapsed time, h = u[n].
        h = uu[n] if free_mesh else x[-1] / N
        last = x[-1] + h if free_mesh else x[-1]
        q1, v1, a1 = _poly(order, x, u, h)
        xn = ca.vertcat(q1, v1, last) if order == 1 else ca.vertcat(q1, v1, a1, last)
        rows = [self._set(*_poly(order, x, u, s * h), k, scale) for s in SAMPLES[order]]
        q, v = x[:n], x[n:2 * n]
        if order == 1:
            rows += [q + h * v / 2]
        else:
            a = x[2 * n:3 * n]
            rows += [q + h * v / 3, q + 2 * h * v / 3 + h ** 2 * a / 6, v + h * a / 2]
        path = ca.vertcat(*rows)
        self._stage = ca.Function("stage", [x, uu, k, scale], [xn, path])
        self._path_rows = path.numel()
        qs = ca.SX.sym("q", n)
        self._fk = ca.Function("fk", [qs], [model.point_sym(qs)])
        self._build(n, m, k, scale)

    def stage_derivatives(self) -> ca.Function:
        """One stage's rows, their Jacobian and the Hessian of their weighted sum (SX).

        ``(x, u, k, scale, lam) -> (rows, jac, hess)`` in ``z = (x, u)``: what every
        solver evaluates per stage and iteration (to time it compiled, or to assemble the
        NLP's derivatives from compiled stages).
        """
        x = ca.SX.sym("x", self._nx)
        u = ca.SX.sym("u", self._nu)
        k, scale = ca.SX.sym("k"), ca.SX.sym("scale", self.model.n)
        xn, path = self._stage(x, u, k, scale)
        rows = ca.vertcat(xn, path)
        lam = ca.SX.sym("lam", rows.numel())
        z = ca.vertcat(x, u)
        return ca.Function(f"stage_deriv_{self.model.n}_{self.order}", [x, u, k, scale, lam],
                           [rows, ca.jacobian(rows, z), ca.hessian(ca.dot(lam, rows), z)[0]])

    def _set(self, q, v, a, k, scale):
        u = self.model.rnea_sym(q, v, a) / scale
        return ca.sum1(ca.fabs(u) ** (2 * k))

    def _build(self, n: int, m: int, k, scale) -> None:
        N, nxs, order = self.N, self._nx, self.order
        point = self.start_kind == "point"
        p_start = ca.SX.sym("p_start", m if point else 0)
        p_target = ca.SX.sym("p_target", m)
        par = ca.vertcat(p_start, p_target, k, scale)
        xs = [ca.SX.sym(f"x{i}", nxs) for i in range(N + 1)]
        us = [ca.SX.sym(f"u{i}", self._nu) for i in range(N)]
        w, g = [], []
        self.ng = []
        for i in range(N):
            w += [xs[i], us[i]]
            xn, path = self._stage(xs[i], us[i], k, scale)
            g.append(xs[i + 1] - xn)
            head = [self._fk(xs[i][:n]) - p_start] if (point and i == 0) else []
            g += head + [path]
            self.ng.append(path.numel() + (m if head else 0))
        w.append(xs[N])
        final = [self._fk(xs[N][:n]) - p_target]
        if order == 2:
            final.append(self._set(xs[N][:n], xs[N][n:2 * n], xs[N][2 * n:3 * n], k, scale))
        g += final
        self.ng.append(sum(e.numel() for e in final))
        self.nx = [nxs] * (N + 1)
        self.nu = [self._nu] * N + [0]
        f = xs[N][-1] if self.free_mesh else xs[0][-1]
        self.nlp = {"x": ca.vertcat(*w), "p": par, "f": f, "g": ca.vertcat(*g)}
        self.n_w, self.n_g = self.nlp["x"].numel(), self.nlp["g"].numel()
        self._g_fun = ca.Function("g", [self.nlp["x"], par], [self.nlp["g"]])

    # ------------------------------------------------------------------ layout
    def _x_index(self, i: int) -> int:
        """Offset of ``x_i`` in ``w``."""
        return i * (self._nx + self._nu)

    def unpack(self, w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """``T`` (s), node states ``X`` (N + 1, nx) and controls ``U`` (N, n) of ``w``."""
        w = np.asarray(w, dtype=float).ravel()
        nu, nxs, N = self._nu, self._nx, self.N
        body = w[:N * (nxs + nu)].reshape(N, nxs + nu)
        X = np.vstack([body[:, :nxs], w[N * (nxs + nu):][None, :]])
        U = body[:, nxs:]
        return float(X[N if self.free_mesh else 0, -1]), X, U

    def node_times(self, w: np.ndarray) -> np.ndarray:
        """Node times (N + 1,) (s) of ``w``."""
        T, X, _ = self.unpack(w)
        return X[:, -1].copy() if self.free_mesh else np.linspace(0.0, T, self.N + 1)

    def pack(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``w`` from node states (N + 1, nx) and controls (N, n)."""
        return np.concatenate([np.hstack([X[:-1], U]).ravel(), X[-1]])

    def parameters(self, start_value, target_value, k: float, scale: np.ndarray) -> np.ndarray:
        """The NLP's parameter vector (start point or nothing, target point, k, scale)."""
        start = np.asarray(start_value, dtype=float) if self.start_kind == "point" else []
        return np.concatenate([start, np.asarray(target_value, dtype=float), [k],
                               np.asarray(scale, dtype=float)])

    def bounds(self, start_value, lower: np.ndarray, upper: np.ndarray, set_pad: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``lbx, ubx, lbg, ubg`` for state bounds ``lower, upper`` (2n,) (velocity symmetric).

        A start joint state (2n,) is fixed by bounds on ``x_0``; the end is at rest.
        """
        n, N, nxs, order = self.model.n, self.N, self._nx, self.order
        big = 1e20
        lo_q, hi_q = np.asarray(lower[:n], float), np.asarray(upper[:n], float)
        vmax = np.asarray(upper[n:], float)
        xl = np.concatenate([lo_q, -vmax] + ([np.full(n, -big)] if order == 2 else [])
                            + [[0.0 if self.free_mesh else T_RANGE[0]]])
        xu = np.concatenate([hi_q, vmax] + ([np.full(n, big)] if order == 2 else [])
                            + [[T_RANGE[1]]])
        lbx, ubx = [], []
        for i in range(N + 1):
            a, b = xl.copy(), xu.copy()
            if i == 0 and self.free_mesh:
                a[-1] = b[-1] = 0.0
            if i == 0 and self.start_kind == "state":
                a[:2 * n] = b[:2 * n] = np.asarray(start_value, dtype=float)[:2 * n]
            if i == 0 and self.start_kind == "point":
                a[n:2 * n] = b[n:2 * n] = 0.0
            if i == N:
                a[n:2 * n] = b[n:2 * n] = 0.0
            lbx.append(a)
            ubx.append(b)
            if i < N:
                lbx.append(np.full(n, -big) if not self.free_mesh else
                           np.concatenate([np.full(n, -big), [H_RANGE[0]]]))
                ubx.append(np.full(n, big) if not self.free_mesh else
                           np.concatenate([np.full(n, big), [H_RANGE[1]]]))
        ns = len(SAMPLES[order])
        pl = np.concatenate([np.full(ns, -big)] + [lo_q] * order
                            + ([-vmax] if order == 2 else []))
        pu = np.concatenate([np.full(ns, 1.0 - set_pad)] + [hi_q] * order
                            + ([vmax] if order == 2 else []))
        lbg, ubg = [], []
        m = self.model.m
        for i in range(N):
            lbg.append(np.zeros(nxs))
            ubg.append(np.zeros(nxs))
            if i == 0 and self.start_kind == "point":
                lbg.append(np.zeros(m))
                ubg.append(np.zeros(m))
            lbg.append(pl)
            ubg.append(pu)
        lbg.append(np.zeros(m))
        ubg.append(np.zeros(m))
        if order == 2:
            lbg.append([-big])
            ubg.append([1.0 - set_pad])
        return (np.concatenate(lbx), np.concatenate(ubx), np.concatenate(lbg),
                np.concatenate(ubg))

    def residual(self, w, par, lbx, ubx, lbg, ubg) -> float:
        """Largest violation of the NLP's rows and bounds at ``w``."""
        g = np.array(self._g_fun(w, par)).ravel()
        return float(max(np.max(np.maximum(lbg - g, 0)), np.max(np.maximum(g - ubg, 0)),
                         np.max(np.maximum(lbx - w, 0)), np.max(np.maximum(w - ubx, 0))))

    # ------------------------------------------------------------- the motion
    def guess(self, T: float, q_of_t, qd_of_t, qdd_of_t=None) -> np.ndarray:
        """``w`` from a path given as functions of time (s) -> (len(t), n) arrays.

        Node positions and velocities from the path; controls consistent with the node
        velocities (order 1: ``(qd_k+1 - qd_k) / h``; order 2: the differences of the
        node accelerations, ``qdd_of_t`` or differences of ``qd``).
        """
        N = self.N
        t = np.linspace(0.0, T, N + 1)
        h = T / N
        q, qd = np.asarray(q_of_t(t)), np.asarray(qd_of_t(t))
        tcol = (t if self.free_mesh else np.full(N + 1, T))[:, None]
        hcol = [np.full((N, 1), h)] if self.free_mesh else []
        if self.order == 1:
            return self.pack(np.hstack([q, qd, tcol]),
                             np.hstack([np.diff(qd, axis=0) / h] + hcol))
        qdd = np.asarray(qdd_of_t(t)) if qdd_of_t is not None else np.gradient(qd, t, axis=0)
        return self.pack(np.hstack([q, qd, qdd, tcol]),
                         np.hstack([np.diff(qdd, axis=0) / h] + hcol))

    def evaluate(self, w: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """``q, qd, qdd`` (len(t), n) of the solution ``w`` at times ``t`` (s) in [0, T].

        At a node the next interval's acceleration is taken (order 1's jumps).
        """
        T, X, U = self.unpack(w)
        n, N = self.model.n, self.N
        nodes = self.node_times(w)
        t = np.clip(np.asarray(t, dtype=float), 0.0, T)
        i = np.clip(np.searchsorted(nodes, t, side="right") - 1, 0, N - 1)
        s = (t - nodes[i])[:, None]
        q0, v0 = X[i, :n], X[i, n:2 * n]
        U = U[:, :n]
        if self.order == 1:
            a = U[i]
            return q0 + s * v0 + s ** 2 / 2 * a, v0 + s * a, a
        a0, j = X[i, 2 * n:3 * n], U[i]
        return (q0 + s * v0 + s ** 2 / 2 * a0 + s ** 3 / 6 * j,
                v0 + s * a0 + s ** 2 / 2 * j, a0 + s * j)

    def state_at(self, w: np.ndarray, t: float) -> np.ndarray:
        """The motion's joint state (2n,) at time ``t`` (s): a replan's start."""
        q, qd, _ = self.evaluate(w, np.array([t]))
        return np.concatenate([q[0], qd[0]])

    def shifted(self, w: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """A replan's start and guess from the running motion ``w``.

        Returns the motion's state at ``dt`` (s), shape (2n,), and the rest of the motion,
        ``T - dt`` long, resampled on this mesh (a ``w``).
        """
        T = self.unpack(w)[0]

        def part(j):
            return lambda t: self.evaluate(w, dt + np.asarray(t))[j]

        return self.state_at(w, dt), self.guess(T - dt, part(0), part(1), part(2))

    def set_values(self, w: np.ndarray, k: float, scale: np.ndarray, per_interval: int = 32
                   ) -> np.ndarray:
        """``sum_i |tau_i / scale_i|^(2k)`` on a fine sampling (both sides of every node)."""
        nodes = self.node_times(w)
        frac = np.linspace(0.0, 1.0 - 1e-9, per_interval + 1)
        t = (nodes[:-1, None] + frac[None, :] * np.diff(nodes)[:, None]).ravel()
        q, qd, qdd = self.evaluate(w, t)
        tau = inverse_dynamics(self.model, q, qd, qdd)
        return np.sum(np.abs(tau / scale) ** (2 * k), axis=1)


def inverse_dynamics(model, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """The model's inverse dynamics at many points: torques (K, n) (N m) of (K, n) inputs."""
    fn = model.function("id").map(len(q))
    return np.array(fn(np.asarray(q).T, np.asarray(qd).T, np.asarray(qdd).T)).T
