"""Solvers of the stage-wise NLP (:mod:`~tocontrol_ros.core.direct.stagewise`), one interface.

``"ipopt"`` (interior point, MUMPS: the reference), ``"fatrop"`` (a structured interior
point, Riccati recursion over the stages) and ``"sqp"`` (CasADi's ``sqpmethod`` with HPIPM,
a Riccati interior-point QP, as its QP solver; the Lagrangian's Hessian convexified). All
three are in the pinned CasADi wheel and solve the same NLP from the same start; a warm
start passes the previous solution's primal point and multipliers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from tocontrol_ros.core.direct.stagewise import StagewiseTranscription, inverse_dynamics
from tocontrol_ros.core.direct.stagewise_sqp import StageSqp
from tocontrol_ros.core.direct.tuning import PAD_ROUNDS, SET_MARGIN, SET_PAD, WARM_MU

__all__ = ["SOLVERS", "StageResult", "StageWarm", "StagewiseSolver"]

SOLVERS = ("ipopt", "fatrop", "sqp")
#: The SQP has converged when T changes by less than this (relative) in an iteration that
#: ends with a residual below ``tol`` (see :meth:`StageSqp.solve`).
SQP_T_TOL = 1e-9
#: Fatrop's first barrier parameter in a warm start.
FATROP_WARM_MU = 1e-5
#: Stats of CasADi's NLP functions: their wall times are the functions' evaluations, the
#: rest of a solve is the solver's own work.
_FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l", "nlp_grad",
              "nlp_jac_fg")


@dataclass(frozen=True)
class StageWarm:
    """What a warm re-solve starts from: the primal point and the multipliers.

    Attributes
    ----------
    w : ndarray, shape (n_w,)
    lam_g : ndarray, shape (n_g,)
    lam_x : ndarray, shape (n_w,)
    """

    w: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray


@dataclass(frozen=True)
class StageResult:
    """One solve of the stage-wise NLP.

    Attributes
    ----------
    success : bool
        The solver reported convergence and the residual is below ``1e-6``.
    status, message : str
        The solver's return status; ``message`` adds the residual.
    T : float
        Final time (s).
    t : ndarray, shape (N + 1,)
        Node times (s).
    q, qd : ndarray, shape (N + 1, n)
        Node positions (rad, m) and velocities.
    qdd : ndarray, shape (N + 1, n)
        Accelerations at the nodes (order 1: the interval's, the last repeated).
    tau : ndarray, shape (N + 1, n)
        Inverse-dynamics torques (N m) at the nodes with ``qdd``.
    iterations : int
    seconds : float
        Wall time of the solver call (s).
    eval_seconds : float
        Of which in CasADi's NLP functions (derivatives included).
    residual : float
        Largest violation of the NLP's rows and bounds.
    warm : StageWarm
    w : ndarray
        The solution vector (stage order).
    set_max : float
        Largest ``sum_i |u_i|^(2k)`` on 32 samples per interval (:meth:`StagewiseSolver.
        solve_within_set`; NaN when not checked).
    pad : float
        The set pad of the last solve.
    """

    success: bool
    status: str
    message: str
    T: float
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    iterations: int
    seconds: float
    eval_seconds: float
    residual: float
    warm: StageWarm = field(repr=False)
    w: np.ndarray = field(repr=False)
    set_max: float = float("nan")
    pad: float = SET_PAD


class StagewiseSolver:
    """A transcription with its solvers, created on first use and kept.

    Parameters
    ----------
    transcription : StagewiseTranscription
    tol : float
        Tolerance of every solver (IPOPT's ``tol``, Fatrop's ``tol``, the SQP's primal and
        dual tolerances).
    max_iter : int
    """

    def __init__(self, transcription: StagewiseTranscription, tol: float = 1e-8,
                 max_iter: int = 300) -> None:
        self.tr, self.tol, self.max_iter = transcription, tol, max_iter
        self._solvers: dict = {}
        self._sqp: StageSqp | None = None
        self.sqp_log: list[dict] = []

    def _options(self, solver: str, warm: bool, max_iter: int) -> dict:
        tr = self.tr
        common = {"print_time": False, "expand": True}
        if solver == "ipopt":
            opts = {**common, "ipopt.print_level": 0, "ipopt.sb": "yes",
                    "ipopt.tol": self.tol, "ipopt.acceptable_tol": self.tol,
                    "ipopt.max_iter": max_iter, "ipopt.linear_solver": "mumps"}
            if warm:
                opts.update({"ipopt.warm_start_init_point": "yes",
                             "ipopt.mu_strategy": "monotone", "ipopt.mu_init": WARM_MU})
            return opts
        if solver == "fatrop":
            fat = {"print_level": 0, "tol": self.tol, "max_iter": max_iter}
            if warm:
                # Fatrop 1.1.8 takes no initial multipliers: a primal start near its bounds.
                fat.update({"mu_init": FATROP_WARM_MU, "bound_push": 1e-6,
                            "bound_frac": 1e-6})
            return {**common, "structure_detection": "manual", "N": tr.N,
                    "nx": tr.nx, "nu": tr.nu, "ng": tr.ng, "fatrop": fat}
        raise ValueError(f"unknown solver {solver!r}; one of {SOLVERS}")

    def solver(self, solver: str, warm: bool = False, max_iter: int | None = None
               ) -> ca.Function:
        """The ``nlpsol`` of ``solver`` (built once per warm flag and iteration limit)."""
        max_iter = self.max_iter if max_iter is None else max_iter
        key = (solver, warm, max_iter)
        if key not in self._solvers:
            name = "sqpmethod" if solver == "sqp" else solver
            self._solvers[key] = ca.nlpsol(f"sw_{solver}", name, self.tr.nlp,
                                           self._options(solver, warm, max_iter))
        return self._solvers[key]

    def solve(self, start_value, target_value, k: float, scale: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, guess: np.ndarray,
              warm: StageWarm | None = None, solver: str = "ipopt",
              max_iter: int | None = None, set_pad: float = SET_PAD) -> StageResult:
        """Solve from ``guess`` (a ``w``, e.g. :meth:`StagewiseTranscription.guess`).

        Parameters
        ----------
        start_value : ndarray
            Start joint state (2n,) or point (m,), as the transcription's start kind.
        target_value : ndarray, shape (m,)
            Target point (m).
        k : float
            Convexification exponent.
        scale : ndarray, shape (n,)
            Torque limits times ``1 - reserve`` (N m).
        lower, upper : ndarray, shape (2n,)
            State bounds, padded (``limited.state_bounds``); velocities symmetric.
        guess : ndarray, shape (n_w,)
        warm : StageWarm, optional
            Multipliers (and the primal point, unless ``guess`` is given separately: the
            guess wins) of a previous solve: the solver's warm start.
        solver : {"ipopt", "fatrop", "sqp"}
        max_iter : int, optional
            Iteration limit (e.g. 1-3 real-time SQP iterations).
        set_pad : float
        """
        tr = self.tr
        par = tr.parameters(start_value, target_value, k, scale)
        lbx, ubx, lbg, ubg = tr.bounds(start_value, lower, upper, set_pad)
        x0 = np.clip(np.asarray(guess, dtype=float), lbx, ubx)
        if solver == "sqp":
            return self._sqp_solve(par, (lbx, ubx, lbg, ubg), x0, warm, max_iter)
        fn = self.solver(solver, warm is not None, max_iter)
        args = {"x0": x0, "p": par, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
        if warm is not None:
            args.update(lam_g0=warm.lam_g, lam_x0=warm.lam_x)
        t0 = time.perf_counter()
        sol = fn(**args)
        seconds = time.perf_counter() - t0
        try:
            stats = fn.stats()
        except RuntimeError as e:  # sqpmethod after a failed QP (CasADi 3.8.2): no status
            stats = {"success": False, "return_status": f"no status ({str(e)[-60:]})"}
        w = np.array(sol["x"]).ravel()
        residual = tr.residual(w, par, lbx, ubx, lbg, ubg)
        status = str(stats.get("return_status", ""))
        ok = bool(stats.get("success", False)) and residual < 1e-6
        evals = sum(float(stats.get(f"t_wall_{f}", 0.0)) for f in _FUNCTIONS)
        return self._result(w, sol["lam_g"], sol["lam_x"], ok, status, residual,
                            int(stats.get("iter_count", -1)), seconds, evals)

    def solve_within_set(self, start_value, target_value, k: float, scale: np.ndarray,
                         lower: np.ndarray, upper: np.ndarray, guess: np.ndarray,
                         rounds: int = PAD_ROUNDS, **kw) -> StageResult:
        """:meth:`solve`, then the torque set checked on the whole motion, the pad widened.

        The set is sampled at 3 times per interval in the NLP; between them the torques may
        leave it. As the B-spline solve does (``docs/limits.md``), the solution is checked on
        32 samples per interval and, while some exceed ``1 - SET_MARGIN``, solved again
        (warm, with IPOPT) with the pad widened by twice the excess, at most ``rounds``
        times. A result still outside the set is a failure.
        """
        pad = kw.pop("set_pad", SET_PAD)
        args = (start_value, target_value, k, scale, lower, upper)
        r = self.solve(*args, guess=guess, set_pad=pad, **kw)
        for i in range(rounds + 1):
            if not r.success:
                return r
            smax = float(np.max(self.tr.set_values(r.w, k, scale)))
            r = replace(r, set_max=smax, pad=pad)
            if smax <= 1.0 - SET_MARGIN:
                return r
            if i == rounds:
                break
            pad += 2.0 * (smax - (1.0 - SET_MARGIN))
            r = self.solve(*args, guess=r.w, warm=r.warm, set_pad=pad, solver="ipopt")
        return replace(r, success=False,
                       message=f"torque set {r.set_max:.6f} > 1 after {rounds} wider pads")

    def _sqp_solve(self, par, bounds, x0, warm, max_iter) -> StageResult:
        if self._sqp is None:
            self._sqp = StageSqp(self.tr)
        t0 = time.perf_counter()
        w, lam_g, lam_x, log = self._sqp.solve(
            x0, None if warm is None else warm.lam_g, par, *bounds,
            max_iter=self.max_iter if max_iter is None else max_iter,
            t_tol=SQP_T_TOL, residual_tol=self.tol)
        seconds = time.perf_counter() - t0
        last = log[-1]
        converged = last["qp_ok"] and last["dT"] < SQP_T_TOL and last["residual"] < self.tol
        status = "converged" if converged else (
            f"QP failed ({last['qp_status']})" if not last["qp_ok"] else "iteration limit")
        self.sqp_log = log
        return self._result(w, lam_g, lam_x, converged, status, last["residual"], len(log),
                            seconds, sum(f["eval_s"] for f in log))

    def _result(self, w, lam_g, lam_x, ok, status, residual, iterations, seconds, evals
                ) -> StageResult:
        tr = self.tr
        T, X, U = tr.unpack(w)
        n = tr.model.n
        t = tr.node_times(w)
        U = U[:, :n]
        qdd = np.vstack([U, U[-1:]]) if tr.order == 1 else X[:, 2 * n:3 * n]
        tau = inverse_dynamics(tr.model, X[:, :n], X[:, n:2 * n], qdd)
        return StageResult(
            success=bool(ok), status=status, message=f"{status}; residual {residual:.2e}",
            T=T, t=t, q=X[:, :n], qd=X[:, n:2 * n], qdd=qdd, tau=np.asarray(tau),
            iterations=iterations, seconds=seconds, eval_seconds=evals, residual=residual,
            warm=StageWarm(w, np.array(lam_g).ravel(), np.array(lam_x).ravel()), w=w)
