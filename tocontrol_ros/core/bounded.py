"""Time-optimal motions whose joint limits bind: direct multiple shooting with hard bounds.

Where the position or velocity limits bind, the maximum principle needs state-constrained
arcs (see ``docs/limits.md`` for why the barrier route was set aside), so the solver solves
the same problem (minimum ``T``, ``sum_i u_i^(2k) <= 1``, the same boundary conditions)
by a direct method with the limits as hard bounds:

- the controls are piecewise linear in time between ``N + 1`` mesh points, each inside the
  control set, so that every control along the motion is (a convex combination of points
  of a convex set);
- each of the ``N`` intervals is integrated by ``M`` RK4 steps under that control; the
  states at the mesh points and after every RK4 step are bounded by the joint limits;
- the trajectory is that integration: :class:`ShootingTrajectory` evaluates it at any time
  with the same RK4 steps, so the published torques produce the published states.

IPOPT solves the NLP with CasADi's exact derivatives, compiled to C once per model and mesh;
the guess is the Hermite-Simpson transcription with the bounds
(:mod:`tocontrol_ros.core.direct`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .compiled import c_name, compile_functions
from .model import RobotModel
from .pmp import LawParams
from .trajectory import TrajectorySample, sample_times

__all__ = ["BoundedResult", "BoundedShooting", "ShootingTrajectory"]


@dataclass(frozen=True)
class BoundedResult:
    """Outcome of :meth:`BoundedShooting.solve`.

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
        Normalised controls at the mesh points (linear in between).
    residual : float
        Max-norm of the constraint violation (continuity, control set, boundary, bounds).
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
    residual: float
    iterations: int
    solve_time: float


def _interval_function(model: RobotModel, steps: int, torque_scale: float) -> ca.Function:
    """``(x0, ua, ub, h, s) -> (x(s h), states after each RK4 step)`` of one interval.

    The control is ``ua + sigma (ub - ua)`` at ``sigma`` = elapsed / ``h``; ``steps`` RK4 steps
    cover ``[0, s h]`` (``s = 1``: the whole interval).
    """
    n = model.n
    x = ca.SX.sym("x", 2 * n)
    u = ca.SX.sym("u", n)
    f = ca.Function("f", [x, u], [model.state_derivative_sym(x, torque_scale * u)])
    x0 = ca.SX.sym("x0", 2 * n)
    ua, ub = ca.SX.sym("ua", n), ca.SX.sym("ub", n)
    h, s = ca.SX.sym("h"), ca.SX.sym("s")
    dt = s * h / steps
    xs, after = x0, []
    for i in range(steps):
        s0, s1 = s * i / steps, s * (i + 1) / steps
        u0, um, u1 = (ua + sig * (ub - ua) for sig in (s0, 0.5 * (s0 + s1), s1))
        k1 = f(xs, u0)
        k2 = f(xs + 0.5 * dt * k1, um)
        k3 = f(xs + 0.5 * dt * k2, um)
        k4 = f(xs + dt * k3, u1)
        xs = xs + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        after.append(xs)
    return ca.Function("bounded_interval", [x0, ua, ub, h, s], [xs, ca.horzcat(*after)],
                       ["x0", "ua", "ub", "h", "s"], ["x1", "steps"])


#: Joints up to which the NLP gets exact Hessians (see :class:`BoundedShooting`).
EXACT_HESSIAN_JOINTS = 4


class _Interrupt(ca.Callback):
    """IPOPT's iteration callback: stops the solve at a deadline or when asked to."""

    def __init__(self, nx: int, ng: int, npar: int) -> None:
        ca.Callback.__init__(self)
        self._sizes = (nx, 1, ng, nx, ng, npar)
        self.deadline, self.should_stop = np.inf, None
        self.construct("bounded_interrupt", {})

    def arm(self, deadline: float, should_stop) -> None:
        self.deadline, self.should_stop = deadline, should_stop

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._sizes[i], 1)

    def eval(self, arg):
        stop = time.perf_counter() > self.deadline or (
            self.should_stop is not None and self.should_stop())
        return [1 if stop else 0]


class BoundedShooting:
    """The bounded NLP of one model, mesh and boundary kinds, built once, solved many times.

    Parameters
    ----------
    model : RobotModel
    intervals : int
        Mesh intervals ``N`` (uniform in time).
    steps : int
        RK4 steps per interval ``M``.
    start_kind, target_kind : {"point", "state"}
    torque_scale : float
        ``1 - reserve``.
    tol : float
        IPOPT tolerance.
    """

    def __init__(self, model: RobotModel, intervals: int, steps: int, start_kind: str,
                 target_kind: str, torque_scale: float = 1.0, tol: float = 1e-8) -> None:
        n, N = model.n, intervals
        self.model, self.N, self.steps = model, N, steps
        self.start_kind, self.target_kind = start_kind, target_kind
        self.torque_scale = torque_scale
        self.interval = _interval_function(model, steps, torque_scale)
        sizes = [model.m if kind == "point" else 2 * n for kind in (start_kind, target_kind)]
        par = ca.MX.sym("p", sizes[0] + sizes[1] + 1)
        k = par[-1]
        X = ca.MX.sym("X", 2 * n, N + 1)
        U = ca.MX.sym("U", n, N + 1)
        T = ca.MX.sym("T")
        x1, inner = self.interval.map(N)(X[:, :-1], U[:, :-1], U[:, 1:],
                                         ca.repmat(T / N, 1, N), ca.DM.ones(1, N))
        q = ca.MX.sym("q", n)
        point = ca.Function("P", [q], [model.point_sym(q)])
        g = [ca.vec(X[:, 1:] - x1), ca.sum1(U ** (2 * k)).T]
        offset = 0
        for kind, col, size in ((start_kind, 0, sizes[0]), (target_kind, N, sizes[1])):
            value = par[offset:offset + size]
            offset += size
            g += [point(X[:n, col]) - value, X[n:, col]] if kind == "point" else \
                [X[:, col] - value]
        inner_states = inner[:, [i for i in range(inner.shape[1]) if (i + 1) % steps]] \
            if steps > 1 else ca.MX.zeros(2 * n, 0)
        g.append(ca.vec(inner_states))
        self._n_inner = inner_states.shape[1]
        w = ca.vertcat(ca.vec(X), ca.vec(U), T)
        self._nx, self._nu = 2 * n * (N + 1), n * (N + 1)
        self._ng_eq = 2 * n * N
        self._n_set = N + 1
        self._ng_bc = sum(m + n if kind == "point" else 2 * n
                          for kind, m in ((start_kind, model.m), (target_kind, model.m)))
        g = ca.vertcat(*g)
        self._interrupt = _Interrupt(w.shape[0], g.shape[0], par.shape[0])
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", g.shape[0])
        grad = ca.DM.zeros(w.shape[0])  # dense: IPOPT's interface copies it as a dense vector
        grad[-1] = 1.0
        # The NLP's derivatives as functions of their own, compiled to C once per model and
        # mesh (cached on disk like the shooting solver's); without a compiler they run in
        # CasADi's virtual machine.
        # Exact Hessians up to EXACT_HESSIAN_JOINTS joints; beyond, the Hessian of one
        # interval has millions of operations (7 joints, 4 RK4 steps: 5.4 million) and
        # IPOPT's limited-memory quasi-Newton approximation takes its place.
        self.exact_hessian = n <= EXACT_HESSIAN_JOINTS
        funs = [ca.Function("bounded_g", [w, par], [g]),
                ca.Function("bounded_grad_f", [w, par], [T, grad]),
                ca.Function("bounded_jac_g", [w, par], [g, ca.jacobian(g, w)])]
        if self.exact_hessian:
            funs.append(ca.Function("bounded_hess_l", [w, par, lam_f, lam_g],
                                    [ca.triu(ca.hessian(ca.dot(lam_g, g), w)[0])]))
        funs, self.compile_status = compile_functions(
            f"bounded_{c_name(model.name)}_{n}x{N}x{steps}_{start_kind}_{target_kind}", funs)
        nlp = {"x": w, "f": T, "g": funs[0](w, par), "p": par}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                "ipopt.tol": tol, "ipopt.acceptable_tol": tol,
                "ipopt.max_iter": 500 if self.exact_hessian else 3000,
                "ipopt.mu_strategy": "adaptive", "calc_lam_p": False,
                "grad_f": funs[1], "jac_g": funs[2],
                "no_nlp_grad": True, "calc_lam_x": False,
                "iteration_callback": self._interrupt}
        if self.exact_hessian:
            opts["hess_lag"] = funs[3]
        else:
            opts["ipopt.hessian_approximation"] = "limited-memory"
        self.solver = ca.nlpsol("bounded", "ipopt", nlp, opts)

    def solve(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
              bounds: tuple[np.ndarray, np.ndarray], t_guess: float, x_guess: np.ndarray,
              u_guess: np.ndarray, max_time: float = 1e6, should_stop=None
              ) -> BoundedResult:
        """Solve from a guess on this mesh.

        Parameters
        ----------
        start_value, target_value : ndarray
            Point (m,) or joint state (2n,), as the kinds given at construction.
        k : float
            Exponent of the control set.
        bounds : (ndarray, ndarray), each shape (2n,)
            Lower and upper bounds of ``(q, qd)`` (rad, m, rad/s, m/s; infinite for none),
            at the mesh points and after every RK4 step.
        t_guess : float
            Final time guess (s).
        x_guess : ndarray, shape (N + 1, 2n)
        u_guess : ndarray, shape (N + 1, n)
        max_time : float
            Wall-time budget of the IPOPT call (s); it stops at the next iteration after.
        should_stop : callable, optional
            Polled at every IPOPT iteration; True stops the solve ("User_Requested_Stop").

        Returns
        -------
        BoundedResult
        """
        n, N = self.model.n, self.N
        big = 1e20
        lo = np.maximum(bounds[0], -big)
        hi = np.minimum(bounds[1], big)
        lbx = np.concatenate([np.tile(lo, N + 1), -np.ones(self._nu), [1e-3]])
        ubx = np.concatenate([np.tile(hi, N + 1), np.ones(self._nu), [big]])
        zeros_bc = np.zeros(self._ng_bc)
        lbg = np.concatenate([np.zeros(self._ng_eq), np.full(self._n_set, -big), zeros_bc,
                              np.tile(lo, self._n_inner)])
        ubg = np.concatenate([np.zeros(self._ng_eq), np.ones(self._n_set), zeros_bc,
                              np.tile(hi, self._n_inner)])
        x0 = np.clip(np.asarray(x_guess, dtype=float), lo, hi)
        w0 = np.concatenate([x0.ravel(), np.clip(u_guess, -0.99, 0.99).ravel(), [t_guess]])
        par = np.concatenate([start_value, target_value, [k]])
        t0 = time.perf_counter()
        self._interrupt.arm(t0 + max_time, should_stop)
        try:
            sol = self.solver(x0=w0, p=par, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        finally:
            self._interrupt.arm(np.inf, None)
        elapsed = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.array(sol["x"]).ravel()
        g = np.array(sol["g"]).ravel()
        residual = float(np.max(np.abs(g - np.clip(g, lbg, ubg)), initial=0.0))
        x = w[:self._nx].reshape(N + 1, 2 * n)
        u = w[self._nx:self._nx + self._nu].reshape(N + 1, n)
        # IPOPT meets the control set to its tolerance; the published torques meet it to
        # rounding (a radial scaling of at most that tolerance).
        norm = np.sum(np.abs(u) ** (2 * k), axis=1, keepdims=True) ** (1 / (2 * k))
        u = u / np.maximum(norm, 1.0)
        t_final = float(w[-1])
        return BoundedResult(
            success=bool(stats["success"]), message=str(stats["return_status"]), T=t_final,
            t=np.linspace(0.0, t_final, N + 1), x=x, u=u, residual=residual,
            iterations=int(stats.get("iter_count", -1)), solve_time=elapsed)


class ShootingTrajectory:
    """The motion of a :class:`BoundedResult`: its controls and their RK4 integration.

    Same interface as :class:`~tocontrol_ros.core.trajectory.Trajectory`. The state at
    ``t`` is integrated from the mesh point before it with the NLP's own RK4 steps (exact
    at the mesh points); controls are linear between the mesh points; accelerations are
    the model's forward dynamics. There are no costates: ``psi``, ``S`` and ``H`` are NaN.

    Parameters
    ----------
    transcription : BoundedShooting
    result : BoundedResult
    k : float
    """

    def __init__(self, transcription: BoundedShooting, result: BoundedResult,
                 k: float) -> None:
        model = transcription.model
        self.n = model.n
        self.T = result.T
        self.t_grid = result.t
        self.joint_names = model.joint_names
        self.law = LawParams(k, 0.0, transcription.torque_scale)
        self.par = self.law.array()
        self._x, self._u = result.x, result.u
        self._interval = transcription.interval
        self._steps = transcription.steps
        self._f = model.function("f")
        self._tau_scale = model.tau_max * transcription.torque_scale
        self.z_grid = np.hstack([result.x, np.full_like(result.x, np.nan)])

    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.T / (len(self.t_grid) - 1)
        j = np.clip(np.floor(t / h).astype(int), 0, len(self.t_grid) - 2)
        return j, np.clip((t - self.t_grid[j]) / h, 0.0, 1.0)

    def _controls(self, t: np.ndarray) -> np.ndarray:
        j, s = self._locate(t)
        return self._u[j] + s[:, None] * (self._u[j + 1] - self._u[j])

    def state(self, t) -> np.ndarray:
        """``(x, psi)`` at times ``t``, shape (K, 4n); ``psi`` is NaN (no costates)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        j, s = self._locate(t)
        h = self.T / (len(self.t_grid) - 1)
        fn = self._interval.map(len(t))
        x = np.array(fn(self._x[j].T, self._u[j].T, self._u[j + 1].T,
                        np.full((1, len(t)), h), s[None, :])[0]).T
        return np.hstack([x, np.full_like(x, np.nan)])

    def evaluate(self, t) -> TrajectorySample:
        """All quantities at times ``t`` (s), scalar or shape (K,)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        n = self.n
        x = self.state(t)[:, :2 * n]
        u = self._controls(t)
        xd = np.array(self._f(x.T, (u * self.par[2]).T)).T
        nan = np.full((len(t), n), np.nan)
        return TrajectorySample(t=t, q=x[:, :n], qd=x[:, n:], qdd=xd[:, n:], u=u,
                                tau=u * self._tau_scale, psi=np.hstack([nan, nan]), S=nan,
                                H=np.full(len(t), np.nan))

    def sample(self, dt: float) -> TrajectorySample:
        """Samples every ``dt`` seconds from 0, always including ``T``."""
        return self.evaluate(sample_times(self.T, dt))

    def control(self, t: float) -> np.ndarray:
        """Normalised control at one time, shape (n,)."""
        return self._controls(np.atleast_1d(float(t)))[0]

    def control_at(self, t: np.ndarray) -> np.ndarray:
        """Normalised controls at times ``t`` (K,), shape (K, n)."""
        return self._controls(np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0,
                                      self.T))

    def step_error(self) -> float:
        """Largest RK4 error of an interval's end state: its steps against twice as many.

        Max-norm over the intervals and the state components (rad, m, rad/s, m/s), the
        Richardson estimate ``16/15 |x_M - x_2M|``.
        """
        N = len(self.t_grid) - 1
        h = self.T / N
        ones = np.ones((1, N))
        u_mid = 0.5 * (self._u[:-1] + self._u[1:])
        step = self._interval.map(N)
        mid = step(self._x[:-1].T, self._u[:-1].T, u_mid.T, 0.5 * h * ones, ones)[0]
        end = np.array(step(mid, u_mid.T, self._u[1:].T, 0.5 * h * ones, ones)[0]).T
        return float(np.max(np.abs(end - self._x[1:])) * 16 / 15)

    def overshoot(self, lower: np.ndarray, upper: np.ndarray, points: int = 4) -> float:
        """Largest excess of the state over bounds (2n,) at ``points`` times per RK4 step."""
        N = len(self.t_grid) - 1
        count = N * self._steps * points
        t = (np.arange(count) + 0.5) * self.T / count
        x = self.state(t)[:, :2 * self.n]
        return float(np.max(np.maximum(x - upper, lower - x)))
