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

from tocontrol_ros.core.direct.collocation_nlp import Layout, compiled_functions, nlp_functions
from tocontrol_ros.core.direct.ipopt import IpoptOutcome, ipopt_options
from tocontrol_ros.core.direct.tuning import GUESS_LOAD
from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["DirectResult", "DirectCollocation", "compile_direct", "initial_path", "initial_paths"]


@dataclass(frozen=True, kw_only=True)
class DirectResult(IpoptOutcome):
    """Outcome of a direct solve: the fields of :class:`~.ipopt.IpoptOutcome`, then these.

    Attributes
    ----------
    t : ndarray, shape (N + 1,)
        Mesh times (s).
    x : ndarray, shape (N + 1, 2n)
        States at the mesh points.
    u : ndarray, shape (N + 1, n)
        Normalised controls at the mesh points.
    psi : ndarray, shape (N + 1, 2n)
        Costate estimates from the defect multipliers.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    psi: np.ndarray


def initial_path(model: RobotModel, q0: np.ndarray, qT: np.ndarray, intervals: int,
                 torque_scale: float = 1.0, velocity: np.ndarray | None = None
                 ) -> tuple[float, np.ndarray, np.ndarray]:
    """A rest-to-rest smoothstep path from ``q0`` to ``qT``, timed to fit the control set.

    The first time is the slowest joint's bang-bang time with its diagonal inertia, times
    1.5; then, twice, the time is scaled by ``sqrt(peak / GUESS_LOAD)`` (by at most a factor
    4 either way), ``peak`` being the largest ``|u|`` (Euclidean) of the path's normalised
    torques: exact when the largest is inertial (at the path's ends, at rest, without
    gravity), approximate otherwise. The guess then starts inside the k = 1 control set,
    which saves IPOPT iterations and makes one-start solves succeed more often.

    With ``velocity`` (n,) (rad/s, m/s), the time is at least what keeps the path's peak
    speed (``1.5 |dq| / T``) at ``GUESS_LOAD`` of each joint's velocity limit.

    Returns
    -------
    T : float
        Time of the path (s).
    x : ndarray, shape (intervals + 1, 2n)
    u : ndarray, shape (intervals + 1, n)
        Normalised torques of the path by inverse dynamics, clipped to [-0.9, 0.9].
    """
    t_final, x, u = initial_paths(model, np.atleast_2d(q0), np.atleast_2d(qT), intervals,
                                  torque_scale, velocity)
    return float(t_final[0]), x[0], u[0]


def initial_paths(model: RobotModel, q0: np.ndarray, qT: np.ndarray, intervals: int,
                  torque_scale: float = 1.0, velocity: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`initial_path` for ``S`` seed pairs at once (the same values, seed by seed).

    One call of the diagonal of the model's mass matrix and three of its inverse dynamics for
    all the seeds (CasADi maps them over the columns), instead of four per seed.

    Parameters
    ----------
    model : RobotModel
    q0, qT : ndarray, shape (S, n)
        Start and end configurations of the paths (rad, m).
    intervals : int
    torque_scale : float
    velocity : ndarray, shape (n,), optional
        Velocity limits (rad/s, m/s).

    Returns
    -------
    T : ndarray, shape (S,)
        Times of the paths (s).
    x : ndarray, shape (S, intervals + 1, 2n)
    u : ndarray, shape (S, intervals + 1, n)
    """
    q0 = np.asarray(q0, dtype=float)
    dq = np.asarray(qT, dtype=float) - q0                        # (S, n)
    count, n = dq.shape
    inertia = model.diagonal_inertia(q0)                         # (S, n)
    acc = model.tau_max * torque_scale / inertia
    t_final = np.maximum(1.5 * np.max(2 * np.sqrt(np.abs(dq) / acc), axis=1), 1e-2)
    t_vel = np.zeros(count) if velocity is None else \
        np.max(1.5 * np.abs(dq) / (GUESS_LOAD * velocity), axis=1)
    t_final = np.maximum(t_final, t_vel)
    tau = np.linspace(0, 1, intervals + 1)
    q = q0[:, None, :] + (3 * tau**2 - 2 * tau**3)[None, :, None] * dq[:, None, :]
    # A seed whose peak is not a positive number keeps its time (and so its torques).
    active = np.ones(count, dtype=bool)
    for rescale in (True, True, False):
        qd = ((6 * tau - 6 * tau**2)[None, :] / t_final[:, None])[:, :, None] * dq[:, None, :]
        qdd = ((6 - 12 * tau)[None, :] / t_final[:, None] ** 2)[:, :, None] * dq[:, None, :]
        cols = count * (intervals + 1)
        u = np.array(model.function("id")(q.reshape(cols, n).T, qd.reshape(cols, n).T,
                                          qdd.reshape(cols, n).T)).T
        u = u.reshape(count, intervals + 1, n) / (model.tau_max * torque_scale)
        if not rescale:
            break
        peak = np.max(np.linalg.norm(u, axis=2), axis=1)
        with np.errstate(invalid="ignore"):
            active &= np.isfinite(peak) & (peak > 0)
        factor = np.clip(np.sqrt(np.where(active, peak, GUESS_LOAD) / GUESS_LOAD), 0.25, 4.0)
        t_final = np.where(active, np.maximum(np.maximum(t_final * factor, 1e-2), t_vel),
                           t_final)
    return t_final, np.concatenate([q, qd], axis=2), np.clip(u, -0.9, 0.9)


def compile_direct(model: RobotModel, intervals: int, start_kind: str = "point",
                   target_kind: str = "point", box: bool = False) -> str:
    """Compile what a :class:`DirectCollocation` of these arguments needs, without making one.

    Inside :func:`~tocontrol_ros.core.robot.compiled.parallel_builds` this only starts the builds
    (a :class:`DirectCollocation` made after the block loads them). Returns how the
    functions run (as ``compile_status``).
    """
    lay = Layout(model.n, model.m, intervals, start_kind, target_kind, box)
    _, how_point, _, how_asm = compiled_functions(model, lay)
    return how_point if how_point == how_asm else f"dynamics {how_point}, assembly {how_asm}"


class DirectCollocation:
    """Hermite-Simpson transcription, built once per mesh and reused for many solves.

    The NLP is the plain one (variables ``X, U, UM, T``; defects, control set and boundary
    conditions as constraints; the same IPOPT options), but its derivatives are assembled
    from per-point pieces instead of being differentiated by CasADi as one expression: the
    dynamics' Jacobian at the nodes and midpoints
    (:func:`~.collocation_nlp._point_functions`), one weighted Hessian of the dynamics per
    point, its weight being the adjoint of that point's acceleration, and per interval the
    chain rule through the midpoint (:func:`~.collocation_nlp._interval_functions`),
    gathered into the sparse Jacobian and Hessian
    (:func:`~.collocation_nlp._assembly_functions`). The values agree with automatic
    differentiation of the
    whole expression to rounding (``test/core/test_direct.py``), at a fraction of the work
    (the whole expression's Hessian: 154 thousand operations for the paper's arm at 12
    intervals, 6.9 million for the 7-joint Panda). The per-point and per-interval functions
    are compiled to C once per model, the gathering once per mesh (cached on disk,
    :func:`~tocontrol_ros.core.robot.compiled.compile_functions`); without a C compiler the same
    graph runs in CasADi's virtual machine.

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
    tol, max_iter : float, int
        IPOPT's tolerance and iteration limit (:func:`~.ipopt.ipopt_options`).

    Attributes
    ----------
    compile_status : str
        How the NLP's functions run: ``"cached"``, ``"compiled"`` or ``"virtual machine
        (reason)"``.
    """

    def __init__(self, model: RobotModel, intervals: int, start_kind: str = "point",
                 target_kind: str = "point", box: bool = False, torque_scale: float = 1.0,
                 tol: float = 1e-8, max_iter: int = 500) -> None:
        self.model = model
        self.N = intervals
        self.start_kind = start_kind
        self.target_kind = target_kind
        self.box = box
        n, N = model.n, intervals
        lay = Layout(model.n, model.m, intervals, start_kind, target_kind, box)
        point, how_point, asm, how_asm = compiled_functions(model, lay)
        self.compile_status = how_point if how_point == how_asm else \
            f"dynamics {how_point}, assembly {how_asm}"
        funs = nlp_functions(lay, point, asm, model.tau_max * torque_scale)
        w = ca.MX.sym("w", lay.nw)
        par = ca.MX.sym("p", lay.npar)
        nlp = {"x": w, "f": w[lay.iT], "g": funs["g"](w, par), "p": par}
        opts = ipopt_options(tol, max_iter, funs["grad_f"], funs["jac_g"], funs["hess_l"])
        # No iterative refinement unless a solve needs it, and no residual check of each
        # solve of the step's linear system: less time for the same iterations and T
        # (IPOPT's own overhead, not MUMPS, dominates at this size).
        opts.update({"ipopt.min_refinement_steps": 0, "ipopt.fast_step_computation": "yes"})
        self.solver = ca.nlpsol("direct", "ipopt", nlp, opts)
        self._nx = lay.nx
        self._nu = lay.nu
        self._num = lay.num
        self.lbg = lay.lbg
        self.ubg = lay.ubg
        big = 1e20
        # No state bounds by default: `solve` takes the joint limits where they bind.
        lbx_x = -big * np.ones(2 * n * (N + 1))
        ubx_x = big * np.ones(2 * n * (N + 1))
        ulim = 1.0 if box else 1.0 + 1e-9
        self.lbx = np.concatenate([lbx_x, -ulim * np.ones(self._nu + self._num), [1e-3]])
        self.ubx = np.concatenate([ubx_x, ulim * np.ones(self._nu + self._num), [big]])

    def solve(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
              t_guess: float, x_guess: np.ndarray, u_guess: np.ndarray,
              x_bounds: tuple[np.ndarray, np.ndarray] | None = None) -> DirectResult:
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
        x_bounds : (ndarray, ndarray), each shape (2n,), optional
            Lower and upper bounds of the state ``(q, qd)`` at every mesh point (hard
            bounds; infinite entries for none). Default: none.

        Returns
        -------
        DirectResult
        """
        n, N = self.model.n, self.N
        um_guess = 0.5 * (u_guess[:-1] + u_guess[1:])
        w0 = np.concatenate([x_guess.ravel(), u_guess.ravel(), um_guess.ravel(), [t_guess]])
        par = np.concatenate([start_value, target_value, [k]])
        t0 = time.perf_counter()
        lbx, ubx = self.lbx, self.ubx
        if x_bounds is not None:
            big = 1e20
            lbx, ubx = lbx.copy(), ubx.copy()
            lbx[:self._nx] = np.tile(np.maximum(x_bounds[0], -big), N + 1)
            ubx[:self._nx] = np.tile(np.minimum(x_bounds[1], big), N + 1)
            w0[:self._nx] = np.clip(w0[:self._nx], lbx[:self._nx], ubx[:self._nx])
        sol = self.solver(x0=w0, p=par, lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.ubg)
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
