"""Pontryagin's maximum principle on the strictly convex control set ``sum u_i^(2k) <= 1``.

Notation of the paper (Galicki): state ``x = (q, qd)`` of size 2n, costate ``psi`` of size
2n, dynamics ``xd = f(x, u) = A(x) + B(x) u`` (5), Hamiltonian (9)

    H = -1 + <A(x), psi> + sum_i S_i u_i,   S = B(x)^T psi = diag(tau_max) M(q)^-1 psi_qd,

the control that maximises ``H`` on the set (8) (eq. 15, odd roots keep the sign)

    u_i = sign(S_i) |S_i|^(1/(2k-1)) / (sum_j |S_j|^(2k/(2k-1)))^(1/(2k)),

and the canonical system (16): ``xd = dH/dpsi``, ``psid = -dH/dx``. Because ``u*`` maximises
``H`` over a set that does not depend on ``x``, ``dH/dx`` is the partial derivative at fixed
``u`` evaluated at ``u*`` (envelope theorem), which is what is built here.

Smoothing: for k > 1 the map ``S -> u`` has an infinite slope where some ``S_i = 0``. The
solver may replace ``|S_i|`` by ``a_i = sqrt(S_i^2 + delta^2 |S|^2)``; ``delta`` is relative to
``|S|`` so that the law stays homogeneous of degree 0 in ``S`` like (15). ``delta = 0`` is
the paper's law exactly; the solver drives ``delta`` to 0.

Time is normalised, ``t = T tau`` with ``tau`` in [0, 1], so that the free final time is a
parameter: ``dz/dtau = T F(z)`` with ``z = (x, psi)``.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict

import casadi as ca
import numpy as np

from tocontrol_ros.core.robot.compiled import (
    BufferedFunction,
    bind_buffers,
    c_name,
    compile_function,
)
from tocontrol_ros.core.robot.model import RobotModel, spd_solve

__all__ = ["BufferedFunction", "CanonicalSystem", "control_law"]


def control_law(s, k, delta=0.0):
    """The maximising control (15), optionally smoothed, for symbolic or numeric ``S``.

    Parameters
    ----------
    s : casadi.SX or ndarray, shape (n,) or (n, N)
        Switching functions ``S_i`` (columns are time samples for arrays).
    k : float or casadi.SX
        Convexification exponent, ``k >= 1``.
    delta : float or casadi.SX
        Relative smoothing; 0 gives (15) exactly.

    Returns
    -------
    Same type as ``s``
        Normalised controls with ``sum u_i^(2k) = 1`` (``< 1`` when ``delta > 0``).
    """
    p = 1.0 / (2 * k - 1)
    if isinstance(s, (ca.SX, ca.MX)):
        norm2 = ca.sumsqr(s)
        a = ca.sqrt(s * s + delta**2 * norm2)
        # One power per component: a^(p - 1) = a^p / a and a^(2kp) = a^(1 + p) = a a^p
        # (pow dominates the right-hand side).
        ap = a ** p
        den = ca.sum1(a * ap) ** (1.0 / (2 * k))
        return s * ap / a / den
    s = np.asarray(s, dtype=float)
    norm2 = np.sum(s * s, axis=0)
    a = np.sqrt(s * s + delta**2 * norm2)
    with np.errstate(divide="ignore", invalid="ignore"):
        num = np.where(a > 0, s * a ** (p - 1), 0.0)
    den = np.sum(a ** (2 * k * p), axis=0) ** (1.0 / (2 * k))
    return num / den


class CanonicalSystem:
    """Symbolic canonical system of one model, and the compiled functions built on it.

    Parameters
    ----------
    model : RobotModel

    Attributes
    ----------
    z : casadi.SX, shape (4n, 1)
        ``(q, qd, psi_q, psi_qd)``.
    par : casadi.SX, shape (3, 1)
        ``(k, delta, torque_scale)`` (:meth:`LawParams.array`); ``torque_scale = 1 - reserve``
        multiplies ``tau_max``.
    rhs : casadi.SX, shape (4n, 1)
        ``F(z)`` in physical time (per second).
    u, s, ham : casadi.SX
        Control (n), switching functions (n) and Hamiltonian (scalar) at ``z``.
    """

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        n = model.n
        self.n = n
        self.z = ca.SX.sym("z", 4 * n)
        self.par = ca.SX.sym("par", 3)
        k, delta, scale = self.par[0], self.par[1], self.par[2]
        q, qd = self.z[:n], self.z[n:2 * n]
        psi = self.z[2 * n:]
        x = self.z[:2 * n]
        tau_max = ca.DM(model.tau_max) * scale
        mass = model.mass_matrix_sym(q)
        bias = model.bias_sym(q, qd)
        lam = spd_solve(mass, psi[n:])  # M^-1 psi_qd
        self.s = tau_max * lam
        self.u = control_law(self.s, k, delta)
        qdd = spd_solve(mass, tau_max * self.u - bias)
        self.ham = -1 + ca.dot(psi[:n], qd) + ca.dot(psi[n:], qdd)
        # -dH/dx at fixed u (envelope theorem) through the inverse dynamics
        # R(q, qd, a) = M(q) a + b(q, qd): from M qdd = tau - b, d(qdd) = -M^-1 dR|a, so
        # -dH/dq = lam^T dR/dq and -dH/dqd = -psi_q + lam^T dR/dqd, with a = qdd and
        # lam = M^-1 psi_qd held fixed. The same numbers as differentiating H through
        # M^-1 (to rounding), in fewer operations.
        acc, adj = ca.SX.sym("a", n), ca.SX.sym("lam", n)
        grad = ca.Function("dR", [q, qd, acc, adj], [ca.gradient(
            ca.dot(adj, model.rnea_sym(q, qd, acc)), x)])(q, qd, qdd, lam)
        self.rhs = ca.vertcat(qd, qdd, grad[:n], grad[n:] - psi[:n])
        self._cache: dict = {}
        self._sized: OrderedDict = OrderedDict()
        self._buffer_lock = threading.Lock()
        self.compile_status = "not compiled yet"

    @property
    def function_cache(self) -> dict:
        """The functions built of this system, by key, shared by the modules that build them.

        The shooting grid's boundary conditions and switching functions, the certificate's
        kinematics and its adaptive integrator keep theirs here beside the system's own, so
        that a model's functions are built once per system.
        """
        return self._cache

    def scratch(self) -> CanonicalSystem:
        """A copy sharing this system's symbolic expressions, without compiled functions."""
        other = copy.copy(self)
        other._cache = {  # the symbolic entries only
            key: value for key, value in self._cache.items()
            if key in ("rhs", "stagewise") or (isinstance(key, tuple) and key[0] == "step_sx")}
        other._sized = OrderedDict()
        other._buffer_lock = threading.Lock()
        return other

    def pointwise(self) -> ca.Function:
        """``(z, par) -> (F, u, S, H)`` at one point (physical time); maps over columns.

        Compiled and cached like the step function: it samples every result and serves
        the verification's re-integration.
        """
        if "pointwise" not in self._cache:
            name = c_name(self.model.name)
            fun = ca.Function(
                f"tocontrol_pointwise_{name}_{self.n}", [self.z, self.par],
                [self.rhs, self.u, self.s, self.ham], ["z", "par"], ["F", "u", "S", "H"])
            self._cache["pointwise"] = compile_function(fun)[0]
        return self._cache["pointwise"]

    def pointwise_map(self, count: int) -> ca.Function:
        """:meth:`pointwise` mapped over ``count`` columns (kept per size, like the steps)."""
        return self.sized(("pointwise_map", count),
                          lambda: self.pointwise().map(count, "serial"))

    def pointwise_batch(self, z: np.ndarray, par: np.ndarray) -> tuple[np.ndarray, ...]:
        """:meth:`pointwise` at every row of ``z``, through a numpy evaluation buffer.

        Rows are evaluated in chunks of the sizes :data:`POINT_CHUNKS` (the last one padded).

        Parameters
        ----------
        z : ndarray, shape (K, 4n)
        par : ndarray, shape (3,)

        Returns
        -------
        F : ndarray, shape (K, 4n)
        u, S : ndarray, shape (K, n)
        H : ndarray, shape (K,)
        """
        if len(z) not in POINT_CHUNKS:  # a few buffer sizes serve every call
            return _chunked(lambda zc: self.pointwise_batch(zc, par), z)
        count, n = len(z), self.n
        with self._buffer_lock:
            _, evaluate, (zin, pin), outs = self.sized(("pointwise_buffer", count),
                                                       lambda: bind_buffers(
                self.pointwise_map(count),
                (np.zeros((count, 4 * n)), np.zeros((count, 3))),
                (np.zeros((count, 4 * n)), np.zeros((count, n)), np.zeros((count, n)),
                 np.zeros((count, 1)))))
            zin[:] = z
            pin[:] = par
            evaluate()
            return outs[0].copy(), outs[1].copy(), outs[2].copy(), outs[3][:, 0].copy()

    def step_rows(self, z: np.ndarray, h: np.ndarray, par: np.ndarray) -> np.ndarray:
        """One RK4 step (no Jacobians) from every row of ``z``, in chunks (:data:`POINT_CHUNKS`).

        Parameters
        ----------
        z : ndarray, shape (K, 4n)
        h : ndarray, shape (K,)
            Physical steps (s).
        par : ndarray, shape (3,)

        Returns
        -------
        ndarray, shape (K, 4n)
        """
        return _chunked(lambda zc, hc: (self.step_batch(zc.T, hc[None, :], par, False)[0].T,),
                        z, h)[0]

    def rhs_function(self) -> ca.Function:
        """``(z, par) -> F(z)``, physical time."""
        if "rhs" not in self._cache:
            self._cache["rhs"] = ca.Function("F", [self.z, self.par], [self.rhs])
        return self._cache["rhs"]

    def _step_sx(self, sensitivities: bool) -> ca.Function:
        """The RK4 step as an (uncompiled) SX function; see :meth:`step_function`."""
        key = ("step_sx", sensitivities)
        if key not in self._cache:
            z0 = ca.SX.sym("z0", 4 * self.n)
            h = ca.SX.sym("h")
            name = c_name(self.model.name)
            if not sensitivities:
                f = self.rhs_function()
                k1 = f(z0, self.par)
                k2 = f(z0 + 0.5 * h * k1, self.par)
                k3 = f(z0 + 0.5 * h * k2, self.par)
                k4 = f(z0 + h * k3, self.par)
                z1 = z0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
                fun = ca.Function(f"tocontrol_rk4_{name}_{self.n}", [z0, h, self.par], [z1],
                                  ["z0", "h", "par"], ["z1"])
            else:
                # The Jacobian chained through the four stages (as in step_batch's stagewise
                # branch): far fewer operations than AD through the whole step.
                fj = ca.Function("FJ", [self.z, self.par],
                                 [self.rhs, ca.jacobian(self.rhs, self.z)])
                f1, j1 = fj(z0, self.par)
                f2, j2 = fj(z0 + 0.5 * h * f1, self.par)
                f3, j3 = fj(z0 + 0.5 * h * f2, self.par)
                f4, j4 = fj(z0 + h * f3, self.par)
                eye = ca.SX.eye(4 * self.n)
                d2 = ca.mtimes(j2, eye + 0.5 * h * j1)
                d3 = ca.mtimes(j3, eye + 0.5 * h * d2)
                d4 = ca.mtimes(j4, eye + h * d3)
                e2 = 0.5 * ca.mtimes(j2, f1)  # dK_i/dh
                e3 = ca.mtimes(j3, 0.5 * f2 + 0.5 * h * e2)
                e4 = ca.mtimes(j4, f3 + h * e3)
                slope = (f1 + 2 * f2 + 2 * f3 + f4) / 6.0
                # Dense outputs: the evaluation buffers below hold full arrays.
                fun = ca.Function(f"tocontrol_rk4j_{name}_{self.n}", [z0, h, self.par],
                                  [z0 + h * slope,
                                   ca.densify(eye + h / 6.0 * (j1 + 2 * d2 + 2 * d3 + d4)),
                                   ca.densify(slope + h / 6.0 * (2 * e2 + 2 * e3 + e4))],
                                  ["z0", "h", "par"], ["z1", "dz1_dz0", "dz1_dh"])
            self._cache[key] = fun
        return self._cache[key]

    def step_function(self, sensitivities: bool = True) -> ca.Function:
        """One RK4 step: ``(z, h, par) -> (z1, dz1/dz, dz1/dh)``, or ``-> z1`` alone.

        ``h`` is the physical step (s). Compiled to C and cached on disk (see
        :mod:`tocontrol_ros.core.robot.compiled`); the version without Jacobians is several times
        cheaper and serves line searches, error estimates and sampling.
        """
        key = ("step", sensitivities)
        if key not in self._cache:
            self._cache[key], status = compile_function(self._step_sx(sensitivities))
            if sensitivities:
                self.compile_status = status
        return self._cache[key]

    def interval_function(self, steps: int, sensitivities: bool = True) -> ca.Function:
        """``steps`` RK4 steps in one compiled call, their Jacobians chained in C.

        ``(z0, h, c, par) -> (z1, dz1/dz0, dz1/dT)`` with ``h`` (steps,) the physical step
        lengths (s) and ``c`` (steps,) their derivatives ``dh/dT`` (the steps of an
        interval are ``T`` times its normalised step lengths, so ``c = h / T``); without
        sensitivities ``(z0, h, par) -> Z``, the state after every step (4n, steps). One
        call per interval instead of one per step (with numpy chaining the step Jacobians)
        removes most of the per-step overhead of
        :func:`~tocontrol_ros.core.indirect.shooting.integrate`. Compiled and cached like
        :meth:`step_function` (one library per step count).
        """
        key = ("interval", steps, sensitivities)
        if key not in self._cache:
            step = self._step_sx(sensitivities)
            nz = 4 * self.n
            z = z0 = ca.MX.sym("z0", nz)
            h = ca.MX.sym("h", steps)
            c = ca.MX.sym("c", steps)
            par = ca.MX.sym("par", 3)
            a_tot = b_tot = None
            states = []
            for s in range(steps):
                if not sensitivities:
                    z = step(z, h[s], par)
                    states.append(z)
                    continue
                z, a_s, b_s = step(z, h[s], par)
                if s == 0:
                    a_tot, b_tot = a_s, b_s * c[s]
                else:
                    a_tot = ca.mtimes(a_s, a_tot)
                    b_tot = ca.mtimes(a_s, b_tot) + b_s * c[s]
            name = c_name(self.model.name)
            if sensitivities:
                fun = ca.Function(f"tocontrol_rk4ij_{name}_{self.n}_{steps}",
                                  [z0, h, c, par], [z, a_tot, b_tot],
                                  ["z0", "h", "c", "par"], ["z1", "dz1_dz0", "dz1_dT"])
            else:
                fun = ca.Function(f"tocontrol_rk4i_{name}_{self.n}_{steps}", [z0, h, par],
                                  [ca.horzcat(*states)], ["z0", "h", "par"], ["z"])
            self._cache[key], status = compile_function(fun)
            if sensitivities:
                self.compile_status = status
        return self._cache[key]

    def interval_batch(self, z: np.ndarray, h: np.ndarray, c: np.ndarray | None,
                       par: np.ndarray, sensitivities: bool = True, dense: bool = False):
        """:meth:`interval_function` on every row: ``steps`` RK4 steps from each state.

        Parameters
        ----------
        z : ndarray, shape (N, 4n)
            Start states.
        h : ndarray, shape (N, steps)
            Physical step lengths (s).
        c : ndarray, shape (N, steps) or None
            ``dh/dT`` (needed with sensitivities).
        par : ndarray, shape (3,)
        sensitivities : bool
        dense : bool
            Without sensitivities: return the states after every step, (N, steps, 4n),
            in place of ``z1``.

        Returns
        -------
        z1 : ndarray, shape (N, 4n)
        a : ndarray, shape (N, 4n, 4n) or None
            ``dz1/dz0`` per row.
        b : ndarray, shape (N, 4n) or None
            ``dz1/dT`` per row.
        """
        count, steps = h.shape
        nz = 4 * self.n

        def bind():
            fun = self.interval_function(steps, sensitivities).map(count, "serial")
            if sensitivities:  # (z0, h, c, par) -> (z1, dz1/dz0, dz1/dT)
                ins = [np.zeros((count, nz)), np.zeros((count, steps)),
                       np.zeros((count, steps)), np.zeros((count, 3))]
                outs = [np.zeros((count, nz)), np.zeros((count, nz, nz)), np.zeros((count, nz))]
            else:  # (z0, h, par) -> states after every step
                ins = [np.zeros((count, nz)), np.zeros((count, steps)), np.zeros((count, 3))]
                outs = [np.zeros((count, steps, nz))]
            return bind_buffers(fun, ins, outs)

        with self._buffer_lock:
            _, evaluate, ins, outs = self.sized(("interval_buffer", count, steps, sensitivities),
                                                bind)
            ins[0][:] = z
            ins[1][:] = h
            if sensitivities:
                ins[2][:] = c
            ins[-1][:] = par
            evaluate()
            if not sensitivities:
                return (outs[0].copy() if dense else outs[0][:, -1].copy()), None, None
            # Column-major (CasADi) blocks: outs[1][j] holds dz1/dz0 of row j transposed.
            return outs[0].copy(), outs[1].transpose(0, 2, 1).copy(), outs[2].copy()

    def step_map(self, count: int, sensitivities: bool = True) -> ca.Function:
        """:meth:`step_function` mapped over ``count`` columns (one step per interval)."""
        return self.sized(("step_map", count, sensitivities),
                          lambda: self.step_function(sensitivities).map(count, "serial"))

    def sized(self, key, make):
        """The per-size object under ``key``, made by ``make()`` when it is not kept.

        Mapped functions, their evaluation buffers, a shooting grid's sparsity pattern:
        mesh refinement meets many interval counts, and a long-running planner would
        otherwise keep one of each for every count it ever saw, so the least recently used
        are evicted beyond :data:`SIZED_CACHE`.
        """
        value = self._sized.get(key)
        if value is None:
            value = self._sized[key] = make()
            while len(self._sized) > SIZED_CACHE:
                self._sized.popitem(last=False)
        self._sized.move_to_end(key)
        return value

    def _buffer(self, count: int, sensitivities: bool):
        """Evaluation buffer of :meth:`step_map`: numpy arrays CasADi reads and writes.

        Skips the conversions through CasADi's ``DM`` (about half the time of a call).
        Inputs and outputs are the column-major layouts, i.e. C-ordered ``(count, ...)``.
        """
        nz = 4 * self.n

        def bind():
            ins = (np.zeros((count, nz)), np.zeros((count, 1)), np.zeros((count, 3)))
            outs = [np.zeros((count, nz))]
            if sensitivities:
                outs += [np.zeros((count, nz, nz)), np.zeros((count, nz))]
            return bind_buffers(self.step_map(count, sensitivities), ins, outs)

        return self.sized(("buffer", count, sensitivities), bind)

    @property
    def stagewise(self) -> bool:
        """Whether the step Jacobian is chained stage by stage in numpy (large models).

        The whole-step Jacobian as one expression grows like ``4 (4n)`` times the right-hand
        side: fine for the 3R arm (about 30 thousand operations), but a million for a
        7-joint arm, which a C compiler takes many minutes over. Above
        :data:`WHOLE_STEP_LIMIT` operations the solver compiles only ``F`` and ``dF/dz``
        and chains the four RK4 stages and their Jacobians in numpy (same numbers).
        """
        if "stagewise" not in self._cache:
            estimate = self.rhs_function().n_instructions() * 4 * (4 * self.n + 1)
            self._cache["stagewise"] = estimate > WHOLE_STEP_LIMIT
        return self._cache["stagewise"]

    @stagewise.setter
    def stagewise(self, value: bool) -> None:
        # Forces one path (the tests compare the two on a small model).
        self._cache["stagewise"] = bool(value)

    def rhs_jacobian_function(self) -> ca.Function:
        """``(z, par) -> (F(z), dF/dz)``, compiled and cached like the step function."""
        if "fj" not in self._cache:
            name = c_name(self.model.name)
            fun = ca.Function(f"tocontrol_fj_{name}_{self.n}", [self.z, self.par],
                              [self.rhs, ca.jacobian(self.rhs, self.z)],
                              ["z", "par"], ["F", "dF_dz"])
            self._cache["fj"], self.compile_status = compile_function(fun)
        return self._cache["fj"]

    def step_batch(self, z: np.ndarray, h: np.ndarray, par: np.ndarray,
                   sensitivities: bool = True):
        """One RK4 step for each column of ``z``.

        Parameters
        ----------
        z : ndarray, shape (4n, N)
            States.
        h : ndarray, shape (1, N)
            Physical steps (s).
        par : ndarray, shape (3,)
            ``(k, delta, torque_scale)``.
        sensitivities : bool

        Returns
        -------
        z1 : ndarray, shape (4n, N)
        a : ndarray, shape (N, 4n, 4n) or None
            ``dz1/dz`` per column.
        b : ndarray, shape (N, 4n) or None
            ``dz1/dh`` per column.
        """
        count = z.shape[1]
        nz = 4 * self.n
        if not sensitivities or not self.stagewise:
            with self._buffer_lock:
                _, evaluate, (zin, hin, pin), outs = self._buffer(count, sensitivities)
                zin[:] = z.T
                hin[:, 0] = np.ravel(h)
                pin[:] = par
                evaluate()
                if not sensitivities:
                    return outs[0].T.copy(), None, None
                # Column-major (CasADi) blocks: outs[1][j] holds dz1/dz0 of column j
                # transposed.
                return outs[0].T.copy(), outs[1].transpose(0, 2, 1).copy(), outs[2].copy()
        fj = self.sized(("fj_map", count),
                        lambda: self.rhs_jacobian_function().map(count, "serial"))
        hv = np.asarray(h, dtype=float).ravel()
        eye = np.eye(nz)

        def stage(zs):
            f, jac = fj(zs, par)
            return np.array(f), np.array(jac).reshape(nz, count, nz).transpose(1, 0, 2)

        f1, j1 = stage(z)
        f2, j2 = stage(z + 0.5 * hv * f1)
        f3, j3 = stage(z + 0.5 * hv * f2)
        f4, j4 = stage(z + hv * f3)
        z1 = z + hv / 6.0 * (f1 + 2 * f2 + 2 * f3 + f4)
        hh = hv[:, None, None]
        d1 = j1                                   # dK_i/dz, (N, nz, nz)
        d2 = j2 @ (eye + 0.5 * hh * d1)
        d3 = j3 @ (eye + 0.5 * hh * d2)
        d4 = j4 @ (eye + hh * d3)
        a = eye + hh / 6.0 * (d1 + 2 * d2 + 2 * d3 + d4)
        # dK_i/dh, (N, nz): K2 = F(z + h/2 K1), so dK2/dh = J2 K1 / 2, and so on.
        e2 = 0.5 * np.einsum("nij,nj->ni", j2, f1.T)
        e3 = np.einsum("nij,nj->ni", j3, 0.5 * f2.T + 0.5 * hv[:, None] * e2)
        e4 = np.einsum("nij,nj->ni", j4, f3.T + hv[:, None] * e3)
        b = (f1 + 2 * f2 + 2 * f3 + f4).T / 6.0 + hv[:, None] / 6.0 * (2 * e2 + 2 * e3 + e4)
        return z1, a, b


#: Rows per evaluation of :meth:`CanonicalSystem.pointwise_batch` and
#: :meth:`CanonicalSystem.step_rows`: a few sizes, so that their buffers stay cached and a
#: short call (the ~20 nodes of a new mesh) does not pay for 256 rows.
POINT_CHUNKS = (16, 64, 256)


def _chunked(fn, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """``fn`` on chunks of ``arrays``' rows (sizes from POINT_CHUNKS); outputs concatenated.

    Full chunks of the largest size, then the smallest size that holds the rest, padded by
    repeating its last row (the padding is cut off again).
    """
    count = len(arrays[0])
    parts = []
    start = 0
    while start < count:
        rest = count - start
        size = next((c for c in POINT_CHUNKS if c >= rest), POINT_CHUNKS[-1])
        take = min(size, rest)
        chunk = [a[start:start + take] for a in arrays]
        if take < size:
            chunk = [np.concatenate([c, np.repeat(c[-1:], size - take, axis=0)]) for c in chunk]
        parts.append([out[:take] for out in fn(*chunk)])
        start += take
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


#: Per-size mapped functions and buffers kept (least recently used evicted first).
SIZED_CACHE = 64
#: Operations of the whole-step Jacobian above which it is chained stage by stage.
WHOLE_STEP_LIMIT = 200_000
