"""A joint path with a time scaling: the first motion's trajectory.

The path is a polynomial in the path parameter ``s`` in [0, 1] (a straight joint-space line,
or a parabola that starts along a moving start's velocity); the time scaling is TOPP-RA's
(:mod:`~tocontrol_ros.core.direct.first_motion`): squared path speeds ``x_i = sd_i^2`` at
gridpoints ``s_i``, with the path acceleration ``sdd`` constant between two gridpoints. Each
segment then takes ``h_i = 2 (s_{i+1} - s_i) / (sd_i + sd_{i+1})`` and ``s(t)`` is quadratic
in time on it, so ``q(t)`` is a polynomial on each segment, evaluated exactly; the torques
are the inverse dynamics of ``q, qd, qdd`` (viscous friction included). The path
acceleration jumps at the gridpoints, so the accelerations and torques do too (they are
taken from the segment that starts at a gridpoint).

:class:`ScaledPath` has the interface of the other trajectories
(:class:`~tocontrol_ros.core.types.trajectory.Trajectory`,
:class:`~tocontrol_ros.core.direct.flat_trajectory.FlatTrajectory`): ``T``, ``t_grid``,
``evaluate``, ``sample``, ``state``, ``control``, and ``open_loop`` for
:func:`~tocontrol_ros.core.checks.certificate.certify_open_loop`; it has no costates (``psi``,
``S`` and ``H`` are NaN).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable

import casadi as ca
import numpy as np
from numpy.polynomial import polynomial as poly

from tocontrol_ros.core.direct.flat_trajectory import (
    OPEN_LOOP_POINTS,
    integrate_segments,
    open_loop_sweep_buffered,
    polynomial_path,
    polynomial_segment_ode,
    segment_dae,
)
from tocontrol_ros.core.robot.compiled import BufferedFunction, compile_owned
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.types.law import LawParams
from tocontrol_ros.core.types.trajectory import InverseDynamicsTrajectory

__all__ = ["PolynomialPath", "ScaledPath", "mapped", "open_loop_integrator", "COMPILED_DEGREES",
           "rigid_body_terms", "inverse_dynamics", "MAP_STEP", "explicit_open_loop"]

#: model -> {(name, count): the model's function ``name`` mapped over ``count`` columns}.
_MAPPED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def mapped(model: RobotModel, name: str, count: int,
           build: Callable[[], ca.Function] | None = None) -> ca.Function:
    """``model.function(name)`` (or ``build()``) mapped over ``count`` columns, per model.

    Mapping a function builds a new one (a millisecond or more on a 7-joint arm); the first
    motion evaluates the same few sizes on every request.
    """
    table = _MAPPED.setdefault(model, {})
    key = (name, count)
    if key not in table:
        table[key] = (build() if build else model.function(name)).map(count)
    return table[key]


#: The inverse dynamics are mapped over a multiple of this many samples
#: (:meth:`ScaledPath._controls`): a few sizes, each mapped once.
MAP_STEP = 32

#: Degrees in time of the segments' polynomials whose open-loop right-hand sides are
#: compiled (one library per model): a straight path's (2) and a parabola's (4).
COMPILED_DEGREES = (2, 4)
#: model -> {(degree, rtol, atol, stiff): (right-hand side, its CVODES integrator)}.
_INTEGRATORS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _open_loop_rhs(model: RobotModel, degree: int) -> ca.Function:
    """``dx/dsigma`` on a segment whose ``q(sigma)`` is a polynomial of ``degree``.

    The model's forward dynamics under the inverse dynamics of the polynomial ``sum_j c_j
    sigma^j`` (parameters ``(vec c, h)``, ``h`` the segment's duration), with CasADi's
    dynamics signature (``t, x, z, p, u -> ode, alg, quad, zero``) so that a compiled copy
    can drive CVODES.
    """
    return segment_dae(f"first_open_loop{degree}", *polynomial_segment_ode(model, degree))


def _segment_path(model: RobotModel, degree: int) -> ca.Function:
    """``(sigma, p) -> x_path(sigma)``: the segment's polynomial path as a state (2n,).

    ``p = (vec c, h)`` as for :func:`_open_loop_rhs`; ``x_path = (q, dq/dt)`` (rad, rad/s).
    """
    sig, c, h = ca.SX.sym("sigma"), ca.SX.sym("c", model.n, degree + 1), ca.SX.sym("h")
    q, qd, _ = polynomial_path(c, sig, h)
    return ca.Function(f"segment_path{degree}", [sig, ca.vertcat(ca.vec(c), h)],
                       [ca.vertcat(q, qd)])


def _deviation_rhs(model: RobotModel, degree: int, never_inline: bool = False
                   ) -> ca.Function:
    """``de/dsigma`` of the open loop's deviation ``e = x - x_path`` from the segment's path.

    The same forward dynamics under the same torques as :func:`_open_loop_rhs`, evaluated at
    ``x_path + e``, minus the path's own derivative (``h (qd, qdd)``): ``x = x_path + e``
    solves the open loop's equation exactly when ``e`` solves this one. Along a dynamically
    consistent path ``e`` stays near zero and CVODES takes a few long steps (a median of 6
    right-hand sides a Panda segment against 28 for ``x``); any inconsistency of the
    torques with the forward dynamics drives ``e`` and is integrated as before.
    ``never_inline``: :func:`segment_dae`'s (the explicit steps call it, one copy of its
    code).
    """
    sig, x, c, h, ode = polynomial_segment_ode(model, degree)
    e = ca.SX.sym("e", 2 * model.n)
    q, qd, qdd = polynomial_path(c, sig, h)
    ode_e = ca.substitute(ode, x, ca.vertcat(q, qd) + e) - h * ca.vertcat(qd, qdd)
    return segment_dae(f"first_open_loop_dev{degree}", sig, e, c, h, ode_e, never_inline)


def _explicit_segment(model: RobotModel, degree: int, rhs: ca.Function) -> ca.Function:
    """The deviation over one segment by explicit steps, each with its error test.

    ``(x0 (2n,), p, tol (2,) = (rtol, atol)) -> (x(1) (2n,), x at the outputs (2n,
    OPEN_LOOP_POINTS), ratio)``: :data:`OPEN_LOOP_POINTS` steps of Heun's method (the
    trapezoid's explicit predictor-corrector, second order) in ``sigma``, one per output,
    on ``e = x - x_path`` from ``e(0) = x0 - x_path(0)`` (``rhs``: :func:`_deviation_rhs`,
    called, not inlined), the states ``x_path + e`` at the step ends. Each step's error
    estimate is Heun's against Euler's step (the embedded pair of order 2(1): ``dsigma (k2
    - k1) / 2``); ``ratio`` is the largest over the steps and components of that estimate
    over ``dsigma (atol + rtol |e|)`` (``|e|`` at the step's start, as CVODES weighs its
    error): at most 1 when every step's local error estimate is within the tolerance per
    unit of ``sigma`` (a segment's steps sum to at most ``atol + rtol max |e|``). No
    branch: every step is taken; the caller decides on ``ratio``.
    """
    n, size = model.n, rhs.size1_in(3)
    x0, p, tol = ca.SX.sym("x0", 2 * n), ca.SX.sym("p", size), ca.SX.sym("tol", 2)
    path, none = _segment_path(model, degree), ca.SX(0, 1)

    def f(sig, e):
        return rhs(sig, e, none, p, none)[0]

    step = 1.0 / OPEN_LOOP_POINTS
    e = x0 - path(0.0, p)
    k1 = f(0.0, e)
    states, ratios = [], []
    for j in range(OPEN_LOOP_POINTS):
        sig = j * step
        k2 = f(sig + step, e + step * k1)
        e_next = e + 0.5 * step * (k1 + k2)
        bound = step * (tol[1] + tol[0] * ca.fabs(e))
        ratios.append(ca.mmax(ca.fabs(0.5 * step * (k2 - k1)) / bound))
        e = e_next
        states.append(path(sig + step, p) + e)
        if j + 1 < OPEN_LOOP_POINTS:
            k1 = f(sig + step, e)
    ratio = ratios[0]
    for r in ratios[1:]:
        ratio = ca.fmax(ratio, r)
    out = ca.horzcat(*states)
    return ca.Function(f"explicit_open_loop{degree}", [x0, p, tol],
                       [out[:, -1], out, ratio], ["x0", "p", "tol"], ["xf", "x", "ratio"])


def _rhs_pairs(model: RobotModel, make: Callable[[RobotModel, int], ca.Function]
               ) -> list[ca.Function]:
    """``make``'s right-hand side and its Jacobian for each of :data:`COMPILED_DEGREES`.

    CVODES asks for the Jacobian at set-up, whichever iteration it uses.
    """
    out = []
    for degree in COMPILED_DEGREES:
        rhs = make(model, degree)
        out += [rhs, rhs.jacobian()]
    return out


def _compiled_rhs(model: RobotModel) -> list[ca.Function]:
    """The certificate's right-hand sides and the timing's dynamics, one library.

    First the open loop's deviation's (:func:`_deviation_rhs`) with their Jacobians, then
    its explicit segments (:func:`_explicit_segment`, calling those right-hand sides), then
    the inverse-dynamics terms TOPP-RA's coefficients take (:func:`rigid_body_terms`), last
    the inverse dynamics (friction included) that a :class:`ScaledPath`'s torques are
    (:func:`inverse_dynamics`). The state's right-hand sides (:func:`_open_loop_rhs`, the
    benchmark's comparison) are a library of their own, built when first asked for: this
    one, built by every planner's warm-up, stays the size it had.
    """
    out, explicit = [], []
    for degree in COMPILED_DEGREES:
        rhs = _deviation_rhs(model, degree, never_inline=True)
        out += [rhs, rhs.jacobian()]
        explicit.append(_explicit_segment(model, degree, rhs))
    q, qd, qdd = (ca.SX.sym(name, model.n) for name in ("q", "qd", "qdd"))
    return out + explicit + [_rigid_body_terms(model),
                  ca.Function("inverse_dynamics", [q, qd, qdd], [model.rnea_sym(q, qd, qdd)])]


def _rigid_body_terms(model: RobotModel) -> ca.Function:
    """``(q, q', q'') -> (tau(q, 0, 0), tau(q, 0, q'), tau(q, q', q''))``, no friction.

    The inverse dynamics without viscous friction (which enters a timing linearly in the
    path speed) at the three points a path's TOPP-RA coefficients need.
    """
    q, d1, d2 = (ca.SX.sym(name, model.n) for name in ("q", "d1", "d2"))
    zero = ca.SX.zeros(model.n)
    rnea = model.rnea_sym
    return ca.Function("rigid_body_terms", [q, d1, d2],
                       [rnea(q, zero, zero, friction=False), rnea(q, zero, d1, friction=False),
                        rnea(q, d1, d2, friction=False)])


def rigid_body_terms(model: RobotModel, count: int) -> BufferedFunction:
    """:func:`_rigid_body_terms` compiled with the open loop's library, mapped over ``count``.

    Called through numpy buffers: ``(q, d1, d2 (n, count)) -> [c, a, b (n, count)]``.

    The first motion's and the quick replan's coefficients evaluate it on every path they
    time (in CasADi's virtual machine about 1 ms on the Panda at 31 gridpoints).
    """
    return _compiled_mapped(model, -2, "rigid_body_terms", count)


def inverse_dynamics(model: RobotModel, count: int) -> BufferedFunction:
    """``model.function("id")`` compiled with the open loop's library, mapped over ``count``.

    Called through numpy buffers: ``(q, qd, qdd (n, count)) -> [tau (n, count)]``.

    A :class:`ScaledPath`'s torques at its samples (the fine sampling of every check, the
    published samples): in CasADi's virtual machine 2.3 ms for 256 samples of the Panda.
    """
    return _compiled_mapped(model, -1, "inverse_dynamics", count)


def explicit_open_loop(model: RobotModel, degree: int, segments: int) -> BufferedFunction:
    """:func:`_explicit_segment` over ``segments`` segments in a row, in one call, per model.

    Compiled with the open loop's library (``degree`` one of :data:`COMPILED_DEGREES`),
    chained by ``mapaccum`` (each segment from where the last ended) and called through
    numpy buffers: ``(x0 (2n,), P (params, segments), tol (2, segments)) -> [x at each
    segment's end (2n, segments), x at every output (2n, segments OPEN_LOOP_POINTS), ratio
    (segments,)]``. Made again when the optimised build of the library lands.
    """
    funs, _ = compile_owned(model, "first_open_loop", f"first_open_loop{model.n}",
                            lambda: _compiled_rhs(model))
    fun = funs[2 * len(COMPILED_DEGREES) + COMPILED_DEGREES.index(degree)]
    table = _MAPPED.setdefault(model, {})
    key = ("explicit_open_loop", degree, segments)
    if key not in table or table[key][0] is not fun:
        table[key] = (fun, BufferedFunction(fun.mapaccum("explicit_open_loop", segments)))
    return table[key][1]


def _compiled_mapped(model: RobotModel, index: int, name: str, count: int
                     ) -> BufferedFunction:
    """Function ``index`` of the open loop's library mapped over ``count``, kept per model.

    Called through numpy buffers (a plain call converts every argument to CasADi's DM and
    back: about half of a 31-point call on the Panda). Made again when the optimised build
    of the library lands.
    """
    funs, _ = compile_owned(model, "first_open_loop", f"first_open_loop{model.n}",
                            lambda: _compiled_rhs(model))
    table = _MAPPED.setdefault(model, {})
    key = (name, count)
    if key not in table or table[key][0] is not funs[index]:
        table[key] = (funs[index], BufferedFunction(funs[index].map(count)))
    return table[key][1]


def open_loop_integrator(model: RobotModel, degree: int, rtol: float, atol: float,
                         stiff: bool = False, deviation: bool = True) -> ca.Function:
    """CVODES over one segment of a :class:`ScaledPath`, output at ``OPEN_LOOP_POINTS``.

    ``(x0, p) -> xf`` (the states at the outputs, (2n, OPEN_LOOP_POINTS)). With
    ``deviation`` (default) CVODES integrates the deviation from the segment's path
    (:func:`_deviation_rhs`) from ``x0 - x_path(0)`` and the states are ``x_path + e`` at the
    outputs: the same equation, its error control (``rtol`` relative to the deviation,
    ``atol`` absolute) at least as tight on ``x`` as on ``x`` itself, and 4-5 times fewer
    right-hand sides; ``False``: ``x`` itself (:func:`_open_loop_rhs`, the certificate's
    integration before, kept for the comparison in ``bench/quick_motion.py``).

    Its right-hand side compiled to C for the degrees of :data:`COMPILED_DEGREES` (one
    library per model, cached on disk like the solver's: on the Panda three times faster
    than CasADi's virtual machine, which it falls back to without a compiler); Adams with
    functional iteration, or BDF with Newton iteration when ``stiff``. Kept per model, and
    made again when the optimised build of the library lands.
    """
    if degree in COMPILED_DEGREES:
        if deviation:
            funs, _ = compile_owned(model, "first_open_loop", f"first_open_loop{model.n}",
                                    lambda: _compiled_rhs(model))
        else:
            funs, _ = compile_owned(model, "first_open_loop_state",
                                    f"first_open_loop_state{model.n}",
                                    lambda: _rhs_pairs(model, _open_loop_rhs))
        rhs = funs[2 * COMPILED_DEGREES.index(degree)]
    else:
        rhs = None
    table = _INTEGRATORS.setdefault(model, {})
    key = (degree, rtol, atol, stiff, deviation)
    if key in table and (rhs is None or table[key][0] is rhs):
        return table[key][1]
    if rhs is None:
        rhs = (_deviation_rhs if deviation else _open_loop_rhs)(model, degree)
    method = {} if stiff else {"linear_multistep_method": "adams",
                               "nonlinear_solver_iteration": "functional"}
    grid = np.linspace(0.0, 1.0, OPEN_LOOP_POINTS + 1)[1:]
    integ = ca.integrator("scaled_open_loop", "cvodes", rhs, 0.0, grid.tolist(),
                          {"reltol": rtol, "abstol": atol, "max_num_steps": 100000, **method})
    if deviation:  # the states: x_path + e at the outputs, from e(0) = x0 - x_path(0)
        path = _segment_path(model, degree)
        x0 = ca.MX.sym("x0", 2 * model.n)
        p = ca.MX.sym("p", rhs.size1_in(3))
        e = integ(x0=x0 - path(0.0, p), p=p)["xf"]
        along = path.map(len(grid))(ca.DM(grid).T, ca.repmat(p, 1, len(grid)))
        integ = ca.Function("scaled_open_loop_dev", [x0, p], [along + e], ["x0", "p"],
                            ["xf"])
    table[key] = (rhs, integ)
    return integ


class PolynomialPath:
    """A joint path ``q(s) = sum_j c_j s^j`` for ``s`` in [0, 1].

    Parameters
    ----------
    coefficients : ndarray, shape (J + 1, n)
        ``c_0 ... c_J`` (rad, m), lowest degree first.
    """

    def __init__(self, coefficients: np.ndarray) -> None:
        self.c = np.atleast_2d(np.asarray(coefficients, dtype=float))
        self.degree = self.c.shape[0] - 1
        self.n = self.c.shape[1]
        self._derivatives = [self.c]

    @classmethod
    def straight(cls, qa: np.ndarray, qb: np.ndarray) -> PolynomialPath:
        """The straight line from ``qa`` to ``qb`` (n,), ``q(s) = qa + s (qb - qa)``."""
        qa = np.asarray(qa, dtype=float)
        return cls(np.vstack([qa, np.asarray(qb, dtype=float) - qa]))

    @classmethod
    def parabola(cls, qa: np.ndarray, qb: np.ndarray, v: np.ndarray) -> PolynomialPath:
        """From ``qa`` with tangent ``v`` to ``qb``: ``qa + v s + (qb - qa - v) s^2``."""
        qa, v = np.asarray(qa, dtype=float), np.asarray(v, dtype=float)
        return cls(np.vstack([qa, v, np.asarray(qb, dtype=float) - qa - v]))

    def __call__(self, s, order: int = 0) -> np.ndarray:
        """``d^order q / ds^order`` at ``s`` (K,), shape (K, n)."""
        if not (isinstance(s, np.ndarray) and s.ndim == 1 and s.dtype == float):
            s = np.atleast_1d(np.asarray(s, dtype=float))
        c = self.coefficients(order)
        if s.ndim != 1:
            return poly.polyval(s, c).T
        # numpy's polyval(s, c).T, its Horner steps written out: the same operations in the
        # same order (the same bits, test_first_motion), without its checks and reshapes per
        # call (a replan evaluates paths about thirty times).
        out = c[-1][:, None] + s * 0
        for cj in c[-2::-1]:
            out = cj[:, None] + out * s
        return out.T

    def coefficients(self, order: int = 0) -> np.ndarray:
        """The coefficients of ``d^order q / ds^order`` (J + 1 - order, n), lowest first."""
        while len(self._derivatives) <= order:  # each derivative's coefficients once
            last = self._derivatives[-1]
            # numpy's polyder(last, 1, axis=0): row j - 1 is j c_j (the same products)
            self._derivatives.append(np.arange(1, len(last))[:, None] * last[1:]
                                     if len(last) > 1 else np.zeros((1, self.n)))
        return self._derivatives[order]

    @staticmethod
    def evaluate_many(paths: list, s: np.ndarray, order: int = 0) -> np.ndarray:
        """``path(s, order)`` of each of ``paths`` (one degree), shape (P, K, n), at once.

        The same Horner steps as :meth:`__call__`, stacked: the same numbers.
        """
        c = np.stack([path.coefficients(order) for path in paths])
        out = c[:, -1, :, None] + s * 0
        for j in range(c.shape[1] - 2, -1, -1):
            out = c[:, j, :, None] + out * s
        return out.transpose(0, 2, 1)

    def position_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Each joint's least and greatest position on [0, 1], shapes (n,) (rad, m)."""
        low, high = PolynomialPath.position_ranges([self])
        return low[0], high[0]

    @staticmethod
    def position_ranges(paths: list) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`position_range` of each of ``paths`` (one degree), shapes (P, n): at once.

        The same numbers as one by one (the same operations, stacked).
        """
        c = np.stack([path.c for path in paths])  # (P, J + 1, n)
        count, size, n = c.shape
        degree = size - 1
        cands = [np.zeros((count, n)), np.ones((count, n))]  # one parameter value per joint
        if degree == 2:  # the vertex of each joint's parabola, where inside (0, 1)
            with np.errstate(divide="ignore", invalid="ignore"):
                vertex = -c[:, 1] / (2.0 * c[:, 2])
            cands.append(np.where(np.isfinite(vertex), np.clip(vertex, 0.0, 1.0), 0.0))
        elif degree > 2:
            cands += [np.full((count, n), s) for s in np.linspace(0.0, 1.0, 201)]
        powers = np.arange(size)[None, None, :, None]
        # sum_j c_j s^j for every candidate at once (the sum over j in order, as per candidate)
        values = np.sum(c[:, None] * np.stack(cands, axis=1)[:, :, None, :] ** powers, axis=2)
        return values.min(axis=1), values.max(axis=1)


class ScaledPath(InverseDynamicsTrajectory):
    """A :class:`PolynomialPath` timed by path speeds at gridpoints (see the module).

    Parameters
    ----------
    model : RobotModel
    path : PolynomialPath
    s : ndarray, shape (N + 1,)
        Gridpoints, increasing from 0 to 1.
    x : ndarray, shape (N + 1,)
        Squared path speeds ``sd^2`` at the gridpoints (1/s^2), >= 0, never two zeros in a
        row.
    k : float
        Exponent of the control set (for ``law``).
    torque_scale : float
        Fraction of ``tau_max`` planned against (``1 - reserve``).

    Attributes
    ----------
    T : float
        Duration (s).
    t_grid : ndarray, shape (N + 1,)
        Times of the gridpoints (s).
    """

    def __init__(self, model: RobotModel, path: PolynomialPath, s: np.ndarray, x: np.ndarray,
                 k: float, torque_scale: float) -> None:
        self._model = model
        self.path = path
        self.n = model.n
        self.joint_names = model.joint_names
        self.law = LawParams(k, 0.0, torque_scale)
        self.par = self.law.array()
        self.s = np.asarray(s, dtype=float)
        self.x = np.maximum(np.asarray(x, dtype=float), 0.0)
        self.sd = np.sqrt(self.x)
        ds = np.diff(self.s)
        with np.errstate(divide="ignore"):
            self.h = 2.0 * ds / (self.sd[:-1] + self.sd[1:])
        if not np.all(np.isfinite(self.h)):
            raise ValueError("`x` must not be zero at two gridpoints in a row")
        self.sdd = (self.x[1:] - self.x[:-1]) / (2.0 * ds)  # constant on each segment
        self.t_grid = np.concatenate([[0.0], np.cumsum(self.h)])
        self.T = float(self.t_grid[-1])
        self._scale = model.tau_max * torque_scale
        q, qd, _ = self._path(self.t_grid)
        self.z_grid = np.hstack([q, qd, np.full((len(q), 2 * self.n), np.nan)])

    def state(self, t) -> np.ndarray:
        """``(x, psi)`` at times ``t``, shape (K, 4n); ``psi`` is NaN (no costates).

        At its start and end (a replan asks for both: the running motion's end, the open
        loop's start) the row made with the gridpoints' states: the same numbers.
        """
        if np.isscalar(t) and (t == 0.0 or t == self.T):
            return self.z_grid[[0 if t == 0.0 else -1]].copy()
        return super().state(t)

    # ------------------------------------------------------------------ evaluation
    def _path(self, t, left: bool = False, seg: np.ndarray | None = None):
        """``q, qd, qdd`` (K, n) at times ``t`` (s).

        At a gridpoint, those of the segment that starts there (``left``: that ends there);
        ``seg`` (K,): each time's segment, given (the times on it, its ends included).
        """
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        if seg is None:
            side = "left" if left else "right"
            seg = np.clip(np.searchsorted(self.t_grid, t, side=side) - 1, 0, len(self.h) - 1)
        tau = t - self.t_grid[seg]
        sdd = self.sdd[seg]
        sd = self.sd[seg] + sdd * tau
        s = self.s[seg] + self.sd[seg] * tau + 0.5 * sdd * tau ** 2
        d1 = self.path(s, 1)
        q = self.path(s)
        qd = d1 * sd[:, None]
        qdd = d1 * sdd[:, None] + self.path(s, 2) * (sd ** 2)[:, None]
        return q, qd, qdd

    def _controls(self, q, qd, qdd) -> np.ndarray:
        """Normalised torques ``u = tau / (tau_max torque_scale)`` (K, n).

        The compiled inverse dynamics (:func:`inverse_dynamics`), mapped over the next
        multiple of :data:`MAP_STEP` samples (the last one repeated): a sampling's length
        changes with ``T``, and a new mapping costs as much as evaluating a hundred
        samples.
        """
        count = len(q)
        if count == 0:
            return np.zeros((0, self.n))
        size = -(-count // MAP_STEP) * MAP_STEP
        pad = size - count
        cols = [np.vstack([v, np.repeat(v[-1:], pad, axis=0)]).T if pad else v.T
                for v in (q, qd, qdd)]
        tau = inverse_dynamics(self._model, size)(*cols)[0].T[:count]
        return tau / self._scale

    def segment_samples(self, points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``u`` and ``qd`` at ``points`` >= 2 equally spaced times on every segment.

        Both ends included, each from its own segment: both sides of an acceleration jump.

        Returns
        -------
        t : ndarray, shape (N points,)
        u : ndarray, shape (N points, n)
        qd : ndarray, shape (N points, n)
        """
        frac = np.linspace(0.0, 1.0, points)
        t = (self.t_grid[:-1, None] + frac[None, :] * self.h[:, None]).ravel()
        # every time on its own segment (an end from the segment it ends), in one evaluation
        kin = self._path(t, seg=np.repeat(np.arange(len(self.h)), points))
        return t, self._controls(*kin), kin[1]

    # ------------------------------------------------------------------ open loop
    def _segment_polynomials(self) -> np.ndarray:
        """``q`` on each segment as a polynomial in ``sigma = (t - t_j) / h_j`` in [0, 1].

        Returns
        -------
        ndarray, shape (N, n, 2 J + 1)
            Coefficients, lowest degree first (``s(sigma)`` is quadratic: ``q(s(sigma))``
            has twice the path's degree).
        """
        h = self.h
        s_poly = np.column_stack([self.s[:-1], self.sd[:-1] * h, 0.5 * self.sdd * h ** 2])
        size = 2 * self.path.degree + 1
        power = np.zeros((len(h), size))
        power[:, 0] = 1.0
        out = np.zeros((len(h), self.n, size))
        for j, cj in enumerate(self.path.c):  # sum_j c_j s(sigma)^j
            out += cj[None, :, None] * power[:, None, :]
            if j < self.path.degree:
                nxt = np.zeros_like(power)
                for b in range(3):
                    nxt[:, b:] += power[:, :size - b] * s_poly[:, b:b + 1]
                power = nxt
        return out

    def _open_loop_inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The segments' polynomials, ``x(0)`` (2n,), the outputs' times and the parameters.

        ``coefs`` (N, n, 2 J + 1), ``x0``, ``times`` (N OPEN_LOOP_POINTS,) (s) and
        ``params`` ((n (2 J + 1) + 1, N): each segment's ``(vec c, h)``).
        """
        grid = np.linspace(0.0, 1.0, OPEN_LOOP_POINTS + 1)[1:]
        coefs = self._segment_polynomials()
        x0 = self.state(0.0)[0, :2 * self.n]
        times = (self.t_grid[:-1, None] + self.h[:, None] * grid[None, :]).ravel()
        params = np.vstack([coefs.reshape(len(self.h), -1, order="F").T, self.h[None, :]])
        return coefs, x0, times, params

    def open_loop_explicit(self, rtol: float, atol: float
                           ) -> tuple[np.ndarray, np.ndarray, float]:
        """The nominal torques integrated from ``x(0)`` by explicit steps with an error test.

        Every segment in one compiled call (:func:`explicit_open_loop`): on each,
        :data:`OPEN_LOOP_POINTS` steps of Heun's method on the deviation from the segment's
        path, one per output, each step's local error estimate (Heun's against Euler's)
        tested against ``dsigma (atol + rtol |e|)`` in every component. Only for the path
        degrees of :data:`COMPILED_DEGREES` (a straight path or a parabola).

        Returns
        -------
        t : ndarray, shape (N OPEN_LOOP_POINTS + 1,)
            Times (s).
        x : ndarray, shape (len(t), 2n)
            Open-loop states.
        ratio : float
            The largest error estimate over its bound, over every step and component: the
            integration meets its tolerance when ``ratio <= 1`` (NaN when a state is not
            finite).
        """
        _, x0, times, params = self._open_loop_inputs()
        segments = len(self.h)
        tol = np.tile([[rtol], [atol]], (1, segments))
        _, states, ratio = explicit_open_loop(self._model, 2 * self.path.degree,
                                              segments)(x0, params, tol)
        x = np.vstack([x0[None, :], states.T])
        worst = float(np.max(ratio)) if np.all(np.isfinite(x)) else float("nan")
        return np.concatenate([[0.0], times]), x, worst

    def open_loop(self, rtol: float, atol: float, stiff: bool = False, one_call: bool = True,
                  deviation: bool = True, explicit: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, bool]:
        """The nominal torques integrated from ``x(0)``, segment by segment.

        First, with ``explicit`` (default; with ``deviation`` and ``one_call``, a path of
        :data:`COMPILED_DEGREES` and ``atol > 0``), by explicit steps with an error test in
        one compiled call (:meth:`open_loop_explicit`), kept when every step passes its test
        (``ratio <= 1``); else by CVODES, as :meth:`~tocontrol_ros.core.direct.
        flat_trajectory.FlatTrajectory.open_loop` does (:func:`open_loop_integrator`): the
        forward dynamics under the inverse dynamics of each segment's polynomial. Adams
        first; BDF (``stiff``) when Adams fails. With ``one_call`` (default) every segment
        in one call (:func:`open_loop_sweep`), and one by one from Python only when a
        segment fails (to say where); ``False``: one by one (the benchmark's comparison).
        ``deviation``: integrate the deviation from each segment's path (default) or the
        state itself (:func:`open_loop_integrator`).

        Returns
        -------
        t : ndarray, shape (N OPEN_LOOP_POINTS + 1,)
            Times (s).
        x : ndarray, shape (len(t), 2n)
            Open-loop states.
        success : bool
        """
        degree = 2 * self.path.degree
        if explicit and deviation and one_call and not stiff and atol > 0.0 and \
                degree in COMPILED_DEGREES:
            t, x, ratio = self.open_loop_explicit(rtol, atol)
            if ratio <= 1.0:
                return t, x, True
        integ = open_loop_integrator(self._model, degree, rtol, atol, stiff, deviation)
        grid = np.linspace(0.0, 1.0, OPEN_LOOP_POINTS + 1)[1:]
        coefs, x0, times, params = self._open_loop_inputs()
        try:  # every segment in one call, through numpy buffers
            if one_call:
                _, states = open_loop_sweep_buffered(self._model, integ, len(self.h))(x0,
                                                                                     params)
                return np.concatenate([[0.0], times]), \
                    np.vstack([x0[None, :], states.T]), True
        except RuntimeError:  # a segment failed: again one by one, to say where
            pass
        segments = ((coefs[j], self.h[j], self.t_grid[j] + self.h[j] * grid)
                    for j in range(len(self.h)))
        t, x, success = integrate_segments(integ, x0, segments)
        if not success and not stiff:
            return self.open_loop(rtol, atol, stiff=True, one_call=one_call,
                                  deviation=deviation)
        return t, x, success
