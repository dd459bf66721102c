"""Bounded minimum-time motions as B-spline joint paths with inverse-dynamics torques.

The transcription of the limit-bound problem (``docs/limits.md``). The joint path is a
clamped B-spline of degree ``p`` in normalised time ``s = t / T`` with ``L`` uniform spans and
``K = L + p`` control points ``P_j`` (n,):

    q(t) = sum_j N_j(s) P_j,   qd(t) = q'(s) / T,   qdd(t) = q''(s) / T^2,

and the torques are the inverse dynamics of that path, ``u(t) = ID(q, qd, qdd) / (tau_max
scale)``, at every time: the published torques produce the published states exactly (up to
the integrator that checks them), whatever the mesh. This matters for real arms: a light
wrist (12 N m on a few hundredths of kg m^2) turns a torque error of 1e-4 into a speed error
of a hundredth of a rad/s within a second, so a transcription whose torques are only
interpolated (Hermite-Simpson, or piecewise-linear controls between mesh points) drifts by
tenths of a metre when its torques are re-integrated.

The NLP, in ``w = (P, T)``: minimise ``T`` subject to

- the control set at ``S`` sample times (``per_span`` per span and ``s = 1``):
  ``sum_i u_i^(2k) <= 1 - SET_PAD``;
- the joint limits at every time, linear in ``w`` through the convex hull of the control
  points and of the derivative's: ``lower <= P_j <= upper`` (bounds on the variables) and
  ``-v <= p (P_j+1 - P_j) / ((t_j+p+1 - t_j+1) T) <= v`` (one two-sided row per difference
  and joint, see :meth:`FlatTranscription._velocity_rows`); with acceleration limits ``a``,
  the second derivative's control points too: ``-a <= c2_j (Q_j+1 - Q_j) / T^2 <= a`` with
  ``Q_j = c_j (P_j+1 - P_j)`` and ``c2_j = (p - 1) / (t_j+p+1 - t_j+2)``
  (:meth:`FlatTranscription._acceleration_rows`): ``|qdd| <= a`` at every time;
- the boundary conditions: ``P_0 = q_0`` and ``B1(0) P = T qd_0`` at a start joint state; a
  target point ``P(P_{K-1}) = p_T`` with ``P_{K-1} = P_{K-2}`` (at rest), or a target state;
- with a collision model only, the clearance rows at every sample
  (:mod:`~tocontrol_ros.core.direct.clearance`), after all the others.

Its derivatives are assembled from one compiled function per sample (the constraint, its
gradient and its weighted Hessian in the span's ``(p + 1) n`` control points and ``T``).
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy import sparse
from scipy.interpolate import CubicHermiteSpline
from scipy.sparse.linalg import spsolve

from tocontrol_ros.core.direct.bspline import basis, breakpoints, knots
from tocontrol_ros.core.direct.clearance import (
    END_ROOM,
    END_SPAN,
    ClearanceRows,
    compile_clearance,
)
from tocontrol_ros.core.direct.collocation_nlp import Scatter
from tocontrol_ros.core.direct.ipopt import IpoptOutcome, ipopt_options
from tocontrol_ros.core.direct.kkt_step import buffered_rows
from tocontrol_ros.core.direct.tuning import (
    FAR_MU,
    RESTART_MAX_PERTURBATION,
    RESUME_MU,
    SET_PAD,
    TIGHT_MU,
    WARM_MU,
    WARM_PUSH,
)
from tocontrol_ros.core.robot.compiled import compile_owned
from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["HESSIANS", "FlatResult", "FlatTranscription", "compile_flat", "violation"]


def violation(w: np.ndarray, g: np.ndarray, lbg: np.ndarray, ubg: np.ndarray,
              lbx: np.ndarray, ubx: np.ndarray) -> float:
    """The largest violation of an NLP's row and variable bounds.

    Parameters
    ----------
    w : ndarray, shape (nw,)
        The variables.
    g : ndarray, shape (ng,)
        The rows at ``w``.
    lbg, ubg : ndarray, shape (ng,)
        The rows' bounds.
    lbx, ubx : ndarray, shape (nw,)
        The variables' bounds.

    Returns
    -------
    float
        ``max(lbg - g, g - ubg, lbx - w, w - ubx, 0)`` over every entry.
    """
    return float(max(np.max(np.maximum(lbg - g, 0.0)), np.max(np.maximum(g - ubg, 0.0)),
                     np.max(np.maximum(lbx - w, 0.0)), np.max(np.maximum(w - ubx, 0.0))))


#: The Newton matrices the set's rows may give IPOPT (``FlatTranscription(hessian=...)``):
#: ``"exact"`` the Lagrangian's Hessian; ``"id_linear"`` without the inverse dynamics'
#: second derivatives (``Hess_y(w^T u)`` below); ``"ggn"`` the generalised Gauss-Newton
#: matrix ``Juz^T diag(mu d2c/du2) Juz`` alone (positive semi-definite: the set is convex
#: in ``u``). The rows, their Jacobian and so the KKT conditions are the same in all three.
HESSIANS = ("exact", "id_linear", "ggn")


def _sample_functions(model: RobotModel, degree: int, hessian: str = "exact"
                      ) -> list[ca.Function]:
    """Per-sample functions (SX): torques, the set's value, gradient and weighted Hessian.

    ``z = (vec P_loc, T)`` with ``P_loc`` (n, degree + 1) the span's control points. The
    Hessian is assembled through ``y = (q, qd, qdd)`` (3n,), the inverse dynamics' inputs:
    with ``u = ID(y) / scale``, ``w = mu dc/du`` and ``Ju = du/dy``,

        Hess_z(mu c) = Jy^T (Ju^T diag(mu d2c/du2) Ju + Hess_y(w^T u)) Jy
                       + sum_j (Ju^T w)_j Hess_z(y_j),

    ``Jy = dy/dz`` being bilinear in ``P`` and ``1/T``. The same matrix as differentiating
    ``c(z)`` twice, from a graph about half as long (the inverse dynamics is differentiated
    in its ``3n`` inputs, not in the ``(degree + 1) n + 1`` of ``z``): shorter to compile
    and to run. ``hessian`` (one of :data:`HESSIANS`) leaves out the middle term
    (``"id_linear"``) or the last two (``"ggn"``).
    """
    if hessian not in HESSIANS:
        raise ValueError(f"`hessian` must be one of {HESSIANS}, got {hessian!r}")
    n, d1 = model.n, degree + 1
    P = ca.SX.sym("P", n, d1)
    T = ca.SX.sym("T")
    b = ca.SX.sym("b", 3, d1)
    k = ca.SX.sym("k")
    mu = ca.SX.sym("mu")
    scale = ca.SX.sym("scale", n)
    z = ca.vertcat(ca.vec(P), T)
    y = ca.vertcat(ca.mtimes(P, b[0, :].T), ca.mtimes(P, b[1, :].T) / T,
                   ca.mtimes(P, b[2, :].T) / T ** 2)
    u = model.rnea_sym(y[:n], y[n:2 * n], y[2 * n:]) / scale
    # |u|^(2k): k need not be an integer (u^5 at k = 2.5 would leave negative torques
    # unbounded, and u^4.5 of a negative u is NaN).
    au = ca.fabs(u)
    c = ca.sum1(au ** (2 * k))
    # The inverse dynamics' derivatives in its own inputs, then evaluated at y(z).
    ys, vs, gs = ca.SX.sym("y", 3 * n), ca.SX.sym("v", n), ca.SX.sym("g", 3 * n)
    tau = model.rnea_sym(ys[:n], ys[n:2 * n], ys[2 * n:])
    jac_id = ca.Function("jac_id", [ys], [ca.jacobian(tau, ys)])
    hess_id = ca.Function("hess_id", [ys, vs], [ca.hessian(ca.dot(vs, tau), ys)[0]])
    jy = ca.jacobian(y, z)
    hess_y = ca.Function("hess_y", [z, b, gs], [ca.hessian(ca.dot(gs, y), z)[0]])
    ju = jac_id(y) / ca.repmat(scale, 1, 3 * n)
    w = mu * 2 * k * ca.sign(u) * au ** (2 * k - 1)
    juz = ca.mtimes(ju, jy)
    hess = ca.mtimes(juz.T, ca.mtimes(ca.diag(mu * 2 * k * (2 * k - 1) * au ** (2 * k - 2)),
                                      juz))
    if hessian == "exact":
        hess = hess + ca.mtimes(jy.T, ca.mtimes(hess_id(y, w / scale), jy))
    if hessian != "ggn":
        hess = hess + hess_y(z, b, ca.densify(ca.mtimes(ju.T, w)))
    dz = z.numel()
    upper = ca.vertcat(*[hess[r, col] for col in range(dz) for r in range(col + 1)])
    qs, qds, qdds = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd"))
    return [
        ca.Function("flat_set", [P, T, b, k, scale], [c]),
        ca.Function("flat_set_grad", [P, T, b, k, scale], [c, ca.densify(ca.gradient(c, z))]),
        ca.Function("flat_set_hess", [P, T, b, k, scale, mu], [ca.densify(ca.cse(upper))]),
        ca.Function("flat_id", [qs, qds, qdds, scale],
                    [model.rnea_sym(qs, qds, qdds) / scale])]


#: Geometries (the breakpoints' basis values) kept per transcription and its views.
GEOMETRIES = 16


def compile_flat(model: RobotModel, degree: int = 3, hessian: str = "exact"
                 ) -> tuple[list[ca.Function], str]:
    """The per-sample functions compiled, once per model, degree and Hessian kind.

    See ``compile_owned``; ``hessian`` one of :data:`HESSIANS` (another library for each
    but ``"exact"``). Inside :func:`~tocontrol_ros.core.robot.compiled.parallel_builds`
    this only starts the build.
    """
    if hessian == "exact":
        return compile_owned(model, ("flat", degree), f"flat{model.n}p{degree}",
                             lambda: _sample_functions(model, degree))
    return compile_owned(model, ("flat", degree, hessian), f"flat{model.n}p{degree}{hessian}",
                         lambda: _sample_functions(model, degree, hessian))


class _Interrupt(ca.Callback):
    """IPOPT's iteration callback: stops the solve at a deadline, when asked, or by work.

    The work limit (a number of iterations) can be tighter than the transcription's own.
    ``watch(iteration, x, g)``, when armed with one, sees each iterate's primal variables
    and its rows' values (copies, shapes (nx,) and (ng,): IPOPT's current iterate, which
    CasADi hands the callback) and may stop the solve by returning True; it must not change
    anything IPOPT reads, so the solve is the same to the bit with or without it.
    """

    def __init__(self, nx: int, ng: int, npar: int) -> None:
        ca.Callback.__init__(self)
        self._sizes = (nx, 1, ng, nx, ng, npar)
        self.arm(np.inf, None, None)
        self.construct("flat_interrupt", {})

    def arm(self, deadline: float, should_stop, max_iter: int | None, watch=None) -> None:
        self.deadline, self.should_stop, self.max_iter = deadline, should_stop, max_iter
        self.watch = watch
        self.calls, self.reason = 0, ""

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
        # IPOPT calls this once per iteration, the starting point (iteration 0) included.
        self.calls += 1
        if self.watch is not None and self.watch(self.calls - 1, np.array(arg[0]).ravel(),
                                                 np.array(arg[2]).ravel()):
            self.reason = "stopped by its watcher"
        elif self.max_iter is not None and self.calls > self.max_iter:
            self.reason = f"stopped after {self.max_iter} iterations (its work limit)"
        elif self.should_stop is not None and self.should_stop():
            self.reason = "cancelled"
        elif time.perf_counter() > self.deadline:  # the caller's deadline, nothing else
            self.reason = "time limit reached"
        return [1 if self.reason else 0]


@dataclass(frozen=True, kw_only=True)
class FlatResult(IpoptOutcome):
    """Outcome of a B-spline solve: the fields of :class:`~.ipopt.IpoptOutcome`, then these.

    Attributes
    ----------
    P : ndarray, shape (K, n)
        Control points (rad, m).
    residual : float
        Largest violation of the NLP's constraints (its bounds included).
    lam_g : ndarray or None
        IPOPT's multipliers of the NLP's rows (constraints) at the result, shape (rows,):
        what a warm re-solve on the same mesh starts from (``warm="dual"``).
    lam_x : ndarray or None
        Its multipliers of the variables' bounds, shape (K n + 1,).
    """

    P: np.ndarray
    residual: float
    lam_g: np.ndarray | None = field(default=None, repr=False)
    lam_x: np.ndarray | None = field(default=None, repr=False)


def _warm_options(warm: bool | str) -> dict:
    """IPOPT's options of a transcription's start mode (see :class:`FlatTranscription`)."""
    cap = {"ipopt.max_hessian_perturbation": RESTART_MAX_PERTURBATION}
    if warm == "dual":
        return {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": WARM_MU,
                "ipopt.warm_start_init_point": "yes"}
    if warm == "dual_tight":  # the multipliers' start pushed 1e-9 into its bounds, not 1e-3
        return {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": TIGHT_MU,
                "ipopt.warm_start_init_point": "yes", **{
                    f"ipopt.warm_start_{key}": TIGHT_MU for key in (
                        "bound_push", "bound_frac", "slack_bound_push", "slack_bound_frac",
                        "mult_bound_push")}}
    if warm == "dual_far":  # a stored neighbour centimetres away: the barrier from 1e-5
        return {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": FAR_MU,
                "ipopt.warm_start_init_point": "yes", **{
                    f"ipopt.warm_start_{key}": FAR_MU for key in (
                        "bound_push", "bound_frac", "slack_bound_push", "slack_bound_frac",
                        "mult_bound_push")}}
    if not warm or warm == "restart":  # IPOPT's default start
        return cap
    mu = RESUME_MU if warm == "resume" else WARM_MU
    return {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": mu,
            **(cap if warm == "resume" else {}), **{
                f"ipopt.{key}": WARM_PUSH for key in ("bound_push", "bound_frac",
                                                     "slack_bound_push", "slack_bound_frac")}}


class FlatTranscription:
    """The bounded problem on one B-spline mesh, built once and reused for many solves.

    Parameters
    ----------
    model : RobotModel
    spans : int
        Uniform spans ``L`` of the spline (``L + degree`` control points per joint).
    start_kind, target_kind : {"point", "state"}
    degree : int
        Spline degree (3: ``C2`` paths, continuous torques).
    per_span : int
        Sample times per span for the control set and the limits.
    torque_scale : float
        ``1 - reserve``.
    tol, max_iter : float, int
        IPOPT's tolerance and iteration limit (:func:`~.ipopt.ipopt_options`).
    warm : bool or "resume" or "dual" or "dual_far" or "restart"
        False: IPOPT's default start, its Hessian regularisation capped at
        :data:`RESTART_MAX_PERTURBATION` (the uniform mesh's first solves). True: every
        solve starts at a solution of a nearby problem (a refined mesh, solved from the
        coarser one's path): IPOPT then starts its barrier at :data:`WARM_MU` with
        a monotone decrease, and moves the start at most ``WARM_PUSH`` inside its bounds,
        instead of starting at ``mu = 0.1`` 1 % inside them, which first leaves the
        solution (see :data:`WARM_MU`). ``"resume"``: from a solution that tightened
        constraints make infeasible (a wider set pad): the same, the barrier from
        :data:`RESUME_MU`, its Hessian regularisation capped as ``"restart"``'s.
        ``"dual"``: from a solution of this mesh and its multipliers
        (``lam_g0``, ``lam_x0`` of :meth:`solve`: a warm re-solve for a moved target),
        IPOPT's warm start (``warm_start_init_point``), the barrier from :data:`WARM_MU`:
        on the Panda's warm re-solves (80 spans, target moved 2 cm along x, y, z) 35, 24
        and 18 IPOPT iterations instead of 53, 46 and 34 from the path alone (BENCHMARKS.md;
        29, 29 and 22 from the solution solved again alone, where the barrier from
        1e-9, 1e-8, 1e-6, 1e-5: 53-65, 36-51, 47-52, 77-128; IPOPT's adaptive barrier
        58-104; its warm-start pushes of 1e-6 or 1e-9 instead of 1e-3: within 3).
        ``"dual_far"``: as ``"dual"`` from a stored neighbour a few centimetres away (a
        memory's hit), the barrier from :data:`FAR_MU` and the warm start pushed that far
        inside its bounds (:data:`FAR_MU`'s measurements).
        ``"restart"``: as False (the last resort of a re-solve with a wider pad).
    clearance : ClearanceRows, optional
        The clearance rows (:func:`~tocontrol_ros.core.direct.clearance.clearance_rows`);
        default none: the NLP of a problem without a collision model is unchanged.
    acceleration : ndarray, shape (n,), optional
        Acceleration limits held at every time (rad/s^2; ``inf``: none), the planning
        limits (margin applied). None or all infinite: no acceleration rows (the NLP of a
        problem without them, unchanged).
    hessian : {"exact", "id_linear", "ggn"}
        The set rows' part of the Newton matrix IPOPT is given (:data:`HESSIANS`); the
        NLP and its first derivatives are the same whichever.
    clearance_samples : ndarray of int, optional
        The samples (indices into :attr:`samples`) that carry clearance rows; default all.
        Fewer: a smaller NLP whose solution holds the margin only there, for a solve whose
        caller checks the other samples' rows itself (the refinement's active set,
        ``limited._refine_item``); :meth:`full_lam_g` maps its multipliers to all rows.
    """

    def __init__(self, model: RobotModel, spans: int | np.ndarray, start_kind: str = "state",
                 target_kind: str = "point", degree: int = 3, per_span: int = 3,
                 torque_scale: float = 1.0, tol: float = 1e-8, max_iter: int = 300,
                 warm: bool | str = False, clearance: ClearanceRows | None = None,
                 acceleration: np.ndarray | None = None, hessian: str = "exact",
                 clearance_samples: np.ndarray | None = None) -> None:
        self.hessian = hessian
        self.clearance = clearance if clearance is not None and clearance.count else None
        self.breaks = breakpoints(spans)
        self.spans = len(self.breaks) - 1
        self.model, self.degree, self.per_span = model, degree, per_span
        self.start_kind, self.target_kind = start_kind, target_kind
        self.torque_scale = torque_scale
        self.warm, self.tol, self.max_iter = warm, tol, max_iter
        self.acceleration = None if acceleration is None or \
            not np.any(np.isfinite(acceleration)) else np.asarray(acceleration, dtype=float)
        n, m, L, p = model.n, model.m, self.spans, degree
        br = self.breaks
        K = L + p
        self.K = K
        funs, self.compile_status = compile_flat(model, degree, hessian)
        self._set, set_grad, set_hess, self._id = funs
        self.scale = model.tau_max * torque_scale
        S = L * per_span + 1
        # Sample r lies in span r // per_span (the last, s = 1, in the last span), whatever
        # the breakpoints.
        self._span = np.minimum(np.arange(S) // per_span, L - 1)
        self._geo = self._geometry(br)
        # Breakpoints (their bytes) -> their geometry, shared by the views (on): a replan
        # on the serving mesh asks for the same uniform breakpoints every time.
        self._geo_cache: dict = {br.tobytes(): self._geo}
        nw = K * n + 1
        iT = nw - 1
        d = (p + 1) * n + 1
        w = ca.MX.sym("w", nw)
        sizes = [m if kind == "point" else 2 * n for kind in (start_kind, target_kind)]
        par = ca.MX.sym("par", sum(sizes) + 1)
        # The mesh's geometry is a parameter too (see :meth:`on`): the samples' basis
        # values, the derivative's hull coefficients, the end velocities' basis.
        geo = ca.MX.sym("geo", len(self._geo))
        nb = 3 * (p + 1) * S
        bcat = ca.reshape(geo[:nb], 3, (p + 1) * S)  # each sample's (3, p + 1), side by side
        cvec = geo[nb:nb + K - 1]
        b_start_vel = geo[nb + K - 1:nb + K + p]
        # then the acceleration rows' (K - 2,) when held, then the clearance rows' per-sample
        # step weights and derivative coefficients ((p + 1) S,), if any
        b_end_vel = geo[nb + K + p:nb + K + 2 * p + 1]
        c2vec = geo[nb + K + 2 * p + 1:nb + K + 2 * p + 1 + K - 2] \
            if self.acceleration is not None else None
        Pm = ca.reshape(w[:K * n], n, K)
        T = w[iT]
        k = par[-1]
        sc = ca.DM(self.scale)
        # Each sample's local control points, side by side: (n, (p + 1) S).
        span = self._span
        cols = (span[:, None] + np.arange(p + 1)[None, :]).ravel()
        Ploc = Pm[:, cols.tolist()]
        zvars = (span[:, None] * n + np.arange(d - 1)[None, :])  # (S, d - 1) indices into w

        g_lin = self._velocity_rows(Pm, T, cvec)
        if self.acceleration is not None:  # the bounds tell the two kinds of rows apart
            g_lin = ca.vertcat(g_lin, self._acceleration_rows(Pm, T, cvec, c2vec))
        g_b = self._boundary_rows(Pm, T, par, sizes, b_start_vel, b_end_vel)
        g_set = ca.vec(self._set.map(S)(ca.reshape(Ploc, n, (p + 1) * S), T, bcat, k, sc))
        ng_set, ng_lin, ng_b = S, g_lin.numel(), g_b.numel()
        ng = ng_set + ng_lin + ng_b
        g = ca.vertcat(g_set, g_lin, g_b)
        self._rows = (ng_set, ng_lin, ng_b)
        local = (ca.reshape(Ploc, n, (p + 1) * S), T, bcat, k, sc)
        g_eval, jac = self._constraint_jacobian(set_grad, local, zvars, w, g_lin, g_b)
        self._ng_clear = 0
        self.clearance_samples = np.arange(S) if clearance_samples is None \
            else np.unique(np.asarray(clearance_samples, dtype=int))
        if self.clearance is not None:
            keep = self.clearance_samples  # each kept sample's (p + 1) columns
            kc = (keep[:, None] * (p + 1) + np.arange(p + 1)[None, :]).ravel().tolist()
            clear_local = (Ploc[:, kc], T, bcat[0, kc], ca.reshape(
                geo[len(self._geo) - (p + 1) * S:], p + 1, S)[:, keep.tolist()])
            clear = self._clearance_rows(clear_local, zvars[keep], w)
            g, g_eval, jac = (ca.vertcat(g, clear[0]), ca.vertcat(g_eval, clear[1]),
                              ca.vertcat(jac, clear[2]))
            ng += self._ng_clear
        lam_g = ca.MX.sym("lam_g", ng)
        lam_f = ca.MX.sym("lam_f")
        hess = self._lagrangian_hessian(set_hess, local, zvars, w, g_lin, g_b, lam_g)
        if self.clearance is not None:
            hess = hess + self._clearance_hessian(clear_local, zvars[self.clearance_samples],
                                                  w, lam_g[ng - self._ng_clear:])
        self._nw, self._iT, self._ng = nw, iT, ng
        allp = ca.vertcat(par, geo)
        jac_fun = ca.Function("jac_g", [w, allp], [g_eval, jac], ["x", "p"], ["g", "jac"])
        hess_fun = ca.Function("hess_l", [w, allp, lam_f, lam_g], [hess],
                               ["x", "p", "lam_f", "lam_g"], ["hess"])
        # The same derivatives for the parametric step (sensitivity.py): rows with their
        # Jacobian, the Lagrangian's Hessian (upper triangle; the objective T is linear).
        self.kkt_functions = (jac_fun, hess_fun)
        self.kkt_cache: dict = {}  # the KKT matrix's ordering, shared by the views (on)
        opts = ipopt_options(
            tol, max_iter,
            ca.Function("grad_f", [w, allp], [T, ca.DM([0.0] * iT + [1.0])], ["x", "p"],
                        ["f", "grad"]),
            jac_fun, hess_fun)
        opts.update(_warm_options(warm))
        self._interrupt = _Interrupt(nw, ng, allp.numel())
        opts["iteration_callback"] = self._interrupt
        self.row_function = ca.Function("g", [w, allp], [g])  # the rows (w, p) -> g
        self.solver = ca.nlpsol("flat", "ipopt", {"x": w, "f": T, "g": g, "p": allp}, opts)

    def _velocity_rows(self, Pm: ca.MX, T: ca.MX, cvec: ca.MX) -> ca.MX:
        """The velocity rows, ``c_j (P_j+1 - P_j) / T`` per joint (n (K - 1),).

        The convex hull of the derivative's control points: bounded by ``-v`` and ``v`` (the
        limits are the rows' bounds, :meth:`bounds`), they hold the velocity limit at every
        time, not only at the samples (the control points' own hull is bounds on the
        variables: no rows). One two-sided row per difference and joint, in the velocity's
        units: written as the linear pair ``c_j (P_j+1 - P_j) -/+ v T <= / >= 0`` there were
        twice the rows, and the barrier of each pushed ``T`` up by about ``mu / T`` however
        far the row was from its limit (IPOPT's first iterations from a guess took ``T``
        from 0.33 to 0.69 s and back on a Panda case, 101 iterations). On the 34 uniform-mesh
        solves of six Panda plans' candidates: 1880 IPOPT iterations instead of 2566, 24 %
        less CPU time, the same ``T`` on 24, a faster basin on 8 and a slower one on 2.
        """
        n = self.model.n
        return ca.vertcat(*[cvec * (Pm[i, 1:] - Pm[i, :-1]).T / T for i in range(n)])

    def _acceleration_rows(self, Pm: ca.MX, T: ca.MX, cvec: ca.MX, c2vec: ca.MX) -> ca.MX:
        """The acceleration rows, ``c2_j (Q_j+1 - Q_j) / T^2`` per joint (n (K - 2),).

        ``Q_j = c_j (P_j+1 - P_j)`` are the control points of ``q'(s)``; these rows are the
        control points of ``q''(s)`` over ``T^2``, whose convex hull holds ``qdd(t)`` at
        every time: bounded by ``-a`` and ``a`` (:meth:`bounds`), the acceleration limit
        holds on the whole motion, not only at samples.
        """
        n = self.model.n
        rows = []
        for i in range(n):
            Q = cvec * (Pm[i, 1:] - Pm[i, :-1]).T
            rows.append(c2vec * (Q[1:] - Q[:-1]) / T ** 2)
        return ca.vertcat(*rows)

    def _clearance_rows(self, local: tuple, zvars: np.ndarray, w: ca.MX
                        ) -> tuple[ca.MX, ca.MX, ca.MX]:
        """The clearance rows (R per sample, sample by sample).

        As ``g``, as evaluated with their gradients, and their Jacobian (scattered into the
        span's variables and ``T``).
        """
        rows = self.clearance
        funs, _ = compile_clearance(self.model, rows, self.degree)
        self._clear_value, self._clear_hess = funs[0], funs[2]
        S, R = len(zvars), len(rows.groups())
        self._ng_clear = S * R
        values = ca.vec(funs[0].map(S)(*local))
        cs, grads = funs[1].map(S)(*local)
        scat = Scatter(S * R, w.numel())
        for r in range(S):
            scat.block(np.arange(r * R, (r + 1) * R), np.concatenate([zvars[r], [w.numel() - 1]]))
        return values, ca.vec(cs), scat.apply(ca.vec(grads))

    def clearance_allowance(self, start_value: np.ndarray, target_value: np.ndarray
                            ) -> np.ndarray:
        """How far below zero each clearance row may go (m), shape (S, groups).

        The rows ask the spheres for the margin, and the spheres stand up to their worst
        gap (1.5-3.8 cm on the Panda) outside the link's geometry: a start (or a joint
        state target) that the exact check accepts can have spheres closer than the
        margin, and its rows could not hold at the first sample whatever the motion. A
        row group whose spheres at an end are closer than ``margin +``
        :data:`~tocontrol_ros.core.direct.clearance.END_ROOM` is lowered by the shortfall
        at that end, and by less and less away from it: by the shortfall times
        ``1 - (s / END_SPAN)^2`` at a sample ``s`` (the target's: ``1 - s``), none from
        :data:`~tocontrol_ros.core.direct.clearance.END_SPAN` of the motion on (every
        other group keeps the full margin everywhere). The motion has to leave the end's
        neighbourhood to use no room mid-motion (before session 30 the room held on the
        whole motion, and a motion could come closer than the margin mid-motion where the
        certificate refused it). The certificate checks the exact clearance against the
        full margin (nothing closer is published).
        """
        n, d1 = self.model.n, self.degree + 1
        s = self.samples
        ends = [(np.asarray(start_value, dtype=float), s)]
        if self.target_kind != "point":
            ends.append((np.asarray(target_value, dtype=float), 1.0 - s))
        allow = np.zeros((len(s), len(self.clearance.groups())))
        for value, away in ends:
            if len(value) < n:
                continue
            q = np.tile(value[:n, None], (1, d1))
            b = np.zeros((1, d1))
            b[0, 0] = 1.0
            g = np.array(self._clear_value(q, 1.0, b, np.zeros(d1))).ravel()
            fade = np.clip(1.0 - (away / END_SPAN) ** 2, 0.0, 1.0)
            allow = np.maximum(allow, fade[:, None] * np.maximum(END_ROOM - g, 0.0)[None, :])
        return allow

    def _clearance_hessian(self, local: tuple, zvars: np.ndarray, w: ca.MX, lam: ca.MX
                           ) -> ca.MX:
        """The clearance rows' part of the Lagrangian's Hessian (upper triangle)."""
        S, R = len(zvars), len(self.clearance.groups())
        nw, iT = w.numel(), w.numel() - 1
        d = zvars.shape[1] + 1
        hs = self._clear_hess.map(S)(*local, ca.reshape(lam, R, S))
        sh = Scatter(nw, nw, triu=True)
        ur, uc = (np.array(v) for v in zip(*[(r, c) for c in range(d) for r in range(c + 1)],
                                           strict=True))
        for r in range(S):
            v = np.concatenate([zvars[r], [iT]])
            sh.add(v[ur], v[uc])
        return sh.apply(ca.vec(hs))

    def _boundary_rows(self, Pm: ca.MX, T: ca.MX, par: ca.MX, sizes: list[int],
                       b_start_vel: ca.MX, b_end_vel: ca.MX) -> ca.MX:
        """The start's and the target's rows: a point at rest, or a joint state."""
        n, K, p, model = self.model.n, self.K, self.degree, self.model
        sv, tv = par[:sizes[0]], par[sizes[0]:-1]
        q_sym = ca.SX.sym("q", n)
        fk = ca.Function("P", [q_sym], [model.point_sym(q_sym)])
        g_b = []
        for kind, value, pts, b_vel, q_end in (
                (self.start_kind, sv, Pm[:, :p + 1], b_start_vel, Pm[:, 0]),
                (self.target_kind, tv, Pm[:, K - p - 1:], b_end_vel, Pm[:, -1])):
            vel = ca.mtimes(pts, b_vel)  # q'(s) at the end: T qd
            if kind == "point":  # at rest, anywhere on the self-motion manifold
                g_b += [fk(q_end) - value, vel]
            else:
                g_b += [q_end - value[:n], vel - T * value[n:]]
        return ca.vertcat(*g_b)

    def _constraint_jacobian(self, set_grad: ca.Function, local: tuple, zvars: np.ndarray,
                             w: ca.MX, g_lin: ca.MX, g_b: ca.MX) -> tuple[ca.MX, ca.MX]:
        """The rows' values and Jacobian.

        The samples' gradients scattered, the velocity rows, the boundary rows. ``local``:
        the samples' local control points (n, (p + 1) S), ``T``, their basis values, ``k``
        and the torque scale; ``zvars`` (S, (p + 1) n): each sample's variables.
        """
        ng_set, ng_lin, ng_b = self._rows
        ng, nw, iT = ng_set + ng_lin + ng_b, w.numel(), w.numel() - 1
        cs, grads = set_grad.map(ng_set)(*local)
        scat = Scatter(ng, nw)
        for r in range(ng_set):
            scat.block(np.array([r]), np.concatenate([zvars[r], [iT]]))
        jac_set = scat.apply(ca.vec(grads))
        jac_lin = ca.jacobian(g_lin, w)
        jac_b = ca.jacobian(g_b, w)
        g_eval = ca.vertcat(ca.vec(cs), g_lin, g_b)  # the set's values come with its gradients
        jac = jac_set + ca.vertcat(ca.MX(ng_set, nw), jac_lin, ca.MX(ng_b, nw)) \
            + ca.vertcat(ca.MX(ng_set + ng_lin, nw), jac_b)
        return g_eval, jac

    def _lagrangian_hessian(self, set_hess: ca.Function, local: tuple, zvars: np.ndarray,
                            w: ca.MX, g_lin: ca.MX, g_b: ca.MX, lam_g: ca.MX) -> ca.MX:
        """The Lagrangian's Hessian (upper triangle).

        Each sample's block in its span's variables and ``T``, scattered, plus the velocity
        rows' (in the control points and ``T``) and the boundary rows'.
        """
        ng_set, ng_lin, _ = self._rows
        nw, iT = w.numel(), w.numel() - 1
        d = zvars.shape[1] + 1
        hs = set_hess.map(ng_set)(*local, lam_g[:ng_set].T)
        sh = Scatter(nw, nw, triu=True)
        ur, uc = (np.array(v) for v in zip(*[(r, c) for c in range(d) for r in range(c + 1)],
                                           strict=True))
        for r in range(ng_set):
            v = np.concatenate([zvars[r], [iT]])
            sh.add(v[ur], v[uc])
        hess = sh.apply(ca.vec(hs))
        hv = ca.triu(ca.hessian(ca.dot(lam_g[ng_set:ng_set + ng_lin], g_lin), w)[0])
        hb = ca.triu(ca.hessian(ca.dot(lam_g[ng_set + ng_lin:ng_set + ng_lin + g_b.numel()], g_b),
                                    w)[0])
        return hess + hv + hb

    @property
    def rows(self) -> int:
        """Rows of the NLP (its constraints; ``lam_g`` has as many)."""
        return self._ng

    def bounds(self, lower: np.ndarray, upper: np.ndarray,
               set_pad: float | np.ndarray = SET_PAD, ends: tuple | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``lbg``, ``ubg``, ``lbx``, ``ubx`` for state bounds (2n,) (infinite entries: none).

        The position bounds are bounds on the control points (variables, not rows); ``T``
        is at least 1 ms. ``set_pad``: the set's pad, one for every sample or one per
        sample (S,) (:func:`~tocontrol_ros.core.direct.set_pads.row_pads`). ``ends``:
        (start value, target value) of the solve, for the clearance rows' allowance
        (:meth:`clearance_allowance`); without it none.
        """
        n = self.model.n
        ng_set, ng_lin, ng_b = self._rows
        lbg = np.concatenate([np.full(ng_set, -np.inf), np.zeros(ng_lin), np.zeros(ng_b)])
        ubg = np.concatenate([1.0 - np.broadcast_to(np.asarray(set_pad, dtype=float), ng_set),
                              np.zeros(ng_lin), np.zeros(ng_b)])
        v = np.repeat(np.asarray(upper[n:], dtype=float), self.K - 1)  # rows joint by joint
        if self.acceleration is not None:
            v = np.concatenate([v, np.repeat(self.acceleration, self.K - 2)])
        lbg[ng_set:ng_set + ng_lin], ubg[ng_set:ng_set + ng_lin] = -v, v
        if self._ng_clear:  # clearance rows: >= 0, less the ends' allowance
            allow = np.zeros(self._ng_clear) if ends is None \
                else self.clearance_allowance(*ends)[self.clearance_samples].ravel()
            lbg = np.concatenate([lbg, -allow])
            ubg = np.concatenate([ubg, np.full(self._ng_clear, np.inf)])
        lbx = np.concatenate([np.tile(lower[:n], self.K), [1e-3]])
        ubx = np.concatenate([np.tile(upper[:n], self.K), [np.inf]])

        def big(v):
            return np.where(np.isfinite(v), v, np.copysign(1e20, v))
        return big(lbg), big(ubg), big(lbx), big(ubx)

    def fit(self, T: float, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Least-squares control points (K, n) of a path given at times ``t`` (s).

        The positions and velocities ``q``, ``qd`` (len(t), n) are sampled at four times as
        many times as there are control points, so that the fit is determined whatever the
        number of given times, from their cubic Hermite interpolant (the state of a
        Hermite-Simpson solution between its mesh points; linear interpolation of each,
        whose kinks the spline followed with accelerations, started the planar 8R's fallback
        with torques 30 times the set's). (A refined mesh takes a solution's control points
        exactly instead: :meth:`FlatTrajectory.control_points_on`.)
        """
        tf = np.linspace(0.0, T, 4 * self.K)
        path = CubicHermiteSpline(np.asarray(t, dtype=float), np.asarray(q), np.asarray(qd))
        qf, vf = path(tf), path(tf, 1)
        span, b = basis(self.breaks, self.degree, tf / T)
        # Banded rows (degree + 1 per time): solved through sparse normal equations, which
        # stay well conditioned for a B-spline basis sampled this densely.
        r = np.repeat(np.arange(len(tf)), self.degree + 1)
        c = (span[:, None] + np.arange(self.degree + 1)[None, :]).ravel()
        A = sparse.vstack([sparse.csr_matrix((b[:, 0].ravel(), (r, c)), (len(tf), self.K)),
                           sparse.csr_matrix((b[:, 1].ravel() / T, (r, c)),
                                             (len(tf), self.K))]).tocsc()
        return spsolve((A.T @ A).tocsc(), A.T @ np.vstack([qf, vf])).reshape(self.K, -1)

    def solve(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
              t_guess: float, p_guess: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              set_pad: float | np.ndarray = SET_PAD, deadline: float = np.inf,
              max_iter: int | None = None, should_stop=None, lam_g0: np.ndarray | None = None,
              lam_x0: np.ndarray | None = None, watch=None) -> FlatResult:
        """Solve from a guess.

        Parameters
        ----------
        start_value : ndarray
            Start point (m,) or joint state (2n,).
        target_value : ndarray
            Target point (m,) or joint state (2n,).
        k : float
        t_guess : float
            Final time guess (s).
        p_guess : ndarray, shape (K, n)
            Control points guess.
        lower, upper : ndarray, shape (2n,)
            State bounds (positions, then velocities; the velocity bound is ``upper[n:]``,
            symmetric).
        set_pad : float or ndarray, shape (S,)
            One pad for all samples, or one per sample.
        deadline : float
            The caller's deadline, a ``time.perf_counter()`` value (s): IPOPT stops there
            (a failed result). The one reading of the clock that may end a solve.
        max_iter : int, optional
            Stop after this many IPOPT iterations (a failed result whose message says so);
            default: the transcription's own limit. A work limit, so that the same
            request takes the same path on an idle and on a loaded machine.
        should_stop : callable, optional
            Polled every IPOPT iteration; returning True stops the solve.
        lam_g0, lam_x0 : ndarray, optional
            Multipliers to start from (:attr:`FlatResult.lam_g`, :attr:`FlatResult.lam_x`
            of a solve on this mesh); used by a ``warm="dual"`` transcription.
        watch : callable, optional
            ``watch(iteration, w, g)`` at each IPOPT iteration (0: the start) with its
            primal iterate ``w`` (control points then ``T``, shape (K n + 1,)) and its rows'
            values ``g`` (shape (rows,)); returning True stops the solve (a failed result).
            It reads the iterate only: the solve is the same with or without it.

        Returns
        -------
        FlatResult
        """
        n = self.model.n
        par = self.parameters(start_value, target_value, k)
        lbg, ubg, lbx, ubx = self.bounds(lower, upper, set_pad, (start_value, target_value))
        w0 = np.concatenate([np.asarray(p_guess).ravel(), [t_guess]])
        t0 = time.perf_counter()
        self._interrupt.arm(deadline, should_stop, max_iter, watch)
        try:
            duals = {} if lam_g0 is None else {"lam_g0": lam_g0, "lam_x0": lam_x0}
            sol = self.solver(x0=w0, p=par, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **duals)
            why = self._interrupt.reason
        finally:
            self._interrupt.arm(np.inf, None, None)
        elapsed = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.array(sol["x"]).ravel()
        return FlatResult(
            success=bool(stats["success"]), message=why or str(stats["return_status"]),
            T=float(w[-1]), P=w[:-1].reshape(self.K, n),
            residual=self._residual(w, par, lbg, ubg, lbx, ubx),
            iterations=int(stats.get("iter_count", -1)), solve_time=elapsed,
            lam_g=np.array(sol["lam_g"]).ravel(), lam_x=np.array(sol["lam_x"]).ravel())

    def residual(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
                 T: float, P: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 set_pad: float | np.ndarray = SET_PAD) -> float:
        """Largest violation of the NLP's constraints and bounds at ``(P, T)``.

        Parameters as in :meth:`solve` (``P`` (K, n) control points, ``T`` in s).
        """
        par = self.parameters(start_value, target_value, k)
        w = np.concatenate([np.asarray(P, dtype=float).ravel(), [T]])
        return self._residual(w, par, *self.bounds(lower, upper, set_pad,
                                                   (start_value, target_value)))

    def parameters(self, start_value: np.ndarray, target_value: np.ndarray, k: float
                   ) -> np.ndarray:
        """The NLP's parameter vector: start, target, ``k``, then the mesh's geometry."""
        return np.concatenate([start_value, target_value, [k], self._geo])

    def _sample_positions(self, breaks: np.ndarray) -> np.ndarray:
        """The samples' ``s`` in [0, 1] on ``breaks`` (S,): ``per_span`` a span, then 1."""
        frac = np.arange(self.per_span) / self.per_span
        return np.concatenate([(breaks[:-1, None] + frac[None, :] * np.diff(breaks)[:, None])
                               .ravel(), [1.0]])

    @property
    def samples(self) -> np.ndarray:
        """The samples' ``s`` on this transcription's breakpoints (S,): the allowance's fade."""
        return self._sample_positions(self.breaks)

    def _geometry(self, breaks: np.ndarray) -> np.ndarray:
        """The NLP's parameters that depend on the breakpoints (L + 1,).

        Raises ValueError if a sample falls outside span ``r // per_span`` (the NLP's
        structure, ``self._span``).
        """
        p, L, ps = self.degree, len(breaks) - 1, self.per_span
        s = self._sample_positions(breaks)
        span, b = basis(breaks, p, s)
        if not np.array_equal(span, self._span):
            raise ValueError("breakpoints too close together for the samples' spans")
        tk = knots(breaks, p)
        K = L + p
        c = p / (tk[p + 1:p + K] - tk[1:K])
        bcat = np.concatenate(list(b), axis=1)  # (3, (p + 1) S)
        # The first and last samples are s = 0 and s = 1: the end velocities' basis.
        geo = [bcat.ravel(order="F"), c, b[0, 1], b[-1, 1]]
        if self.acceleration is not None:  # q''(s)'s control points: (p - 1) / knot spans
            geo.append((p - 1) / (tk[p + 1:p + K - 1] - tk[2:K]))
        if self.clearance is not None:  # per sample: its step weight, its span's c (p,)
            S = len(s)
            ds = np.diff(breaks)[span] / ps
            # the last sample of a span (not the last span) protects its step forward alone
            last = np.zeros(S, bool)
            last[:-1] = span[1:] != span[:-1]
            h = np.where(last, ds, ds / 2)
            cs = c[span[:, None] + np.arange(p)[None, :]]
            geo.append(np.concatenate([h[:, None], cs], axis=1).ravel())
        return np.concatenate(geo)

    def on(self, breaks: np.ndarray) -> FlatTranscription:
        """The same NLP on other breakpoints with as many spans (no new build).

        Parameters
        ----------
        breaks : ndarray, shape (spans + 1,)
            Increasing breakpoints from 0 to 1.

        Returns
        -------
        FlatTranscription
            A view sharing this one's solver (solves through either are not concurrent).
        """
        breaks = breakpoints(breaks)
        if len(breaks) != len(self.breaks):
            raise ValueError(f"{len(breaks) - 1} spans given, the transcription has "
                             f"{self.spans}")
        other = copy.copy(self)
        other.breaks = breaks
        key = breaks.tobytes()
        geo = self._geo_cache.get(key)
        if geo is None:
            geo = other._geometry(breaks)
            if len(self._geo_cache) >= GEOMETRIES:
                self._geo_cache.clear()
            self._geo_cache[key] = geo
        other._geo = geo
        return other

    def with_speed_term(self, scale: float) -> FlatTranscription:
        """A view whose clearance rows' speed term is ``scale`` times the true one.

        The rows ask ``margin + scale h sum_j rho_ij max_k |Q'_jk|`` (``scale`` 0: the
        sampled clearance alone, not a bound between the samples); only a step of a
        continuation to the true rows (``scale`` 1, this transcription itself) may use
        another scale: its solution is not covered between the samples.

        Parameters
        ----------
        scale : float
            >= 0.

        Returns
        -------
        FlatTranscription
            A view sharing this one's solver (as :meth:`on`).
        """
        if not scale >= 0.0:
            raise ValueError(f"`scale` must be >= 0, got {scale!r}")
        if self.clearance is None or scale == 1.0:
            return self
        other = copy.copy(self)
        geo = self._geo.copy()
        per = self.degree + 1  # the last block: per sample its step weight h, then c (p,)
        # A view of geo's last block (a contiguous slice): scaled in place.
        geo[len(geo) - per * len(self.samples):].reshape(-1, per)[:, 0] *= scale
        other._geo = geo
        return other

    def with_clearance_samples(self, keep: np.ndarray) -> FlatTranscription:
        """The same NLP (options, breakpoints) with clearance rows at samples ``keep`` only.

        A new build (no compile: the clearance library is the same), not a view.
        """
        return FlatTranscription(
            self.model, self.spans, self.start_kind, self.target_kind, self.degree,
            self.per_span, self.torque_scale, self.tol, self.max_iter, self.warm, self.clearance,
            self.acceleration, self.hessian, clearance_samples=keep).on(self.breaks)

    def clearance_slack(self, start_value: np.ndarray, target_value: np.ndarray, k: float,
                        T: float, P: np.ndarray) -> np.ndarray:
        """How far each clearance row of this NLP is above its lower bound (m).

        Shape (kept samples, groups) (:attr:`clearance_samples`); ``P`` (K, n), ``T`` (s).
        """
        par = self.parameters(start_value, target_value, k)
        w = np.concatenate([np.asarray(P, dtype=float).ravel(), [T]])
        g = np.array(self.row_function(w, par)).ravel()[self._ng - self._ng_clear:]
        allow = self.clearance_allowance(start_value, target_value)[self.clearance_samples]
        return g.reshape(allow.shape) + allow

    def full_lam_g(self, lam_g: np.ndarray) -> np.ndarray:
        """Multipliers of this NLP's rows as those of every sample's rows (zeros where left out).

        ``lam_g`` (rows,) of a transcription with :attr:`clearance_samples` a subset, mapped
        to the rows of the same transcription with all samples (the multipliers of the rows
        left out, inactive at its solution, are zero).
        """
        S = len(self.samples)
        if self.clearance is None or len(self.clearance_samples) == S:
            return lam_g
        head = self._ng - self._ng_clear
        full = np.zeros((S, len(self.clearance.groups())))
        full[self.clearance_samples] = np.reshape(lam_g[head:], (len(self.clearance_samples), -1))
        return np.concatenate([lam_g[:head], full.ravel()])

    def _residual(self, w, par, lbg, ubg, lbx, ubx) -> float:
        return violation(w, buffered_rows(self)(w, par)[0], lbg, ubg, lbx, ubx)
