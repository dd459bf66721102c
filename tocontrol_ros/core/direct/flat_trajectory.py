"""A bounded solve's motion: the B-spline path, its torques, and where its mesh is refined.

:class:`FlatTrajectory` evaluates a :class:`~tocontrol_ros.core.direct.flat.FlatResult`
(states, torques, the control set along the path) and re-integrates its torques open loop
for the certificate; :func:`refined_breaks` halves the spans at junctions of arcs.
"""

from __future__ import annotations

import copy
import threading
import weakref

import casadi as ca
import numpy as np
from scipy.interpolate import BSpline

from tocontrol_ros.core.direct.bspline import knots
from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.tuning import REFINE_JUMP, SPEED_BOUND_SLACK
from tocontrol_ros.core.robot.compiled import BufferedFunction, compile_owned
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.types.law import LawParams
from tocontrol_ros.core.types.trajectory import InverseDynamicsTrajectory

__all__ = ["FlatTrajectory", "OPEN_LOOP_POINTS", "SET_POINTS", "compile_open_loop",
           "integrate_segments", "open_loop_sweep_buffered",
           "mapped_controls", "open_loop_sweep", "polynomial_path", "polynomial_segment_ode",
           "refined_breaks", "segment_dae"]

#: Output times per span of the open-loop re-integration (:meth:`FlatTrajectory.open_loop`).
OPEN_LOOP_POINTS = 8
#: Times per span of the control set's check between the samples
#: (:meth:`FlatTrajectory.set_values`).
SET_POINTS = 32


def _read_only(values: np.ndarray) -> np.ndarray:
    """``values`` as a float array that cannot be written (kept and shared)."""
    values = np.array(values, dtype=float)
    values.setflags(write=False)
    return values


#: CVODES integrators of the open loop, per model, degree and tolerances (with the DAE
#: function they were made from).
_OPEN_LOOP: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def polynomial_segment_ode(model: RobotModel, degree: int
                           ) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX]:
    """The forward dynamics under the inverse dynamics of a polynomial path (SX).

    On a segment of duration ``h`` whose path is ``q(sigma) = sum_j c_j sigma^j`` in its
    normalised time ``sigma`` in [0, 1], the state ``x = (q, qd)`` (2n,) obeys
    ``dx/dsigma = h f(x, tau)``, ``tau`` the inverse dynamics of the path (forward dynamics
    through the factorised mass matrix, not the inverse dynamics that made the torques).

    Returns
    -------
    sigma, x, c, h, ode
        The symbols (``c`` of shape (n, degree + 1)) and ``dx/dsigma`` (2n,).
    """
    n, d1 = model.n, degree + 1
    x, c, h = ca.SX.sym("x", 2 * n), ca.SX.sym("c", n, d1), ca.SX.sym("h")
    sig = ca.SX.sym("sigma")
    q, qd, qdd = polynomial_path(c, sig, h)
    tau = model.rnea_sym(q, qd, qdd)
    return sig, x, c, h, h * ca.vertcat(x[n:], model.forward_dynamics_sym(x[:n], x[n:], tau))


def polynomial_path(c: ca.SX, sig: ca.SX, h: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
    """The path ``q(sigma) = sum_j c_j sigma^j`` and its time derivatives (SX).

    ``c`` of shape (n, degree + 1), ``sigma`` the segment's normalised time in [0, 1], ``h``
    its duration (s). Returns ``q, dq/dt, d2q/dt2``, each (n,).
    """
    d1 = c.shape[1]
    pw = [sig ** j for j in range(d1)]
    q = sum(c[:, j] * pw[j] for j in range(d1))
    qd = sum(j * c[:, j] * pw[j - 1] for j in range(1, d1)) / h
    qdd = sum(j * (j - 1) * c[:, j] * pw[j - 2] for j in range(2, d1)) / h ** 2
    return q, qd, qdd


def segment_dae(name: str, sig: ca.SX, state: ca.SX, c: ca.SX, h: ca.SX, ode: ca.SX,
                never_inline: bool = False) -> ca.Function:
    """``ode`` (``d state / d sigma``) as a segment's CasADi DAE function, what CVODES takes.

    The dynamics signature ``t, x, z, p, u -> ode, alg, quad, zero`` with ``t = sigma``,
    ``x = state``, ``p = (vec c, h)`` and no ``z`` nor ``u``. ``never_inline``: a symbolic
    call of it stays a call (CasADi's option), so that a function evaluating it many times
    generates its code once.
    """
    none = ca.SX(0, 1)
    opts = {"never_inline": True} if never_inline else {}
    return ca.Function(name, [sig, state, none, ca.vertcat(ca.vec(c), h), none],
                       [ode, none, none, none], ca.dyn_in(), ca.dyn_out(), opts)


def integrate_segments(integ: ca.Function, x0: np.ndarray, segments
                       ) -> tuple[np.ndarray, np.ndarray, bool]:
    """An open loop integrated segment after segment, each from where the last one ended.

    Parameters
    ----------
    integ : casadi.Function
        ``(x0, p) -> xf`` over one segment, ``p = (vec c, h)`` (the integrators of
        :func:`polynomial_segment_ode`'s right-hand side), ``xf`` at :data:`OPEN_LOOP_POINTS`
        times.
    x0 : ndarray, shape (2n,)
        State at the first segment's start.
    segments : iterable of (ndarray, float, ndarray)
        Per segment: its path's coefficients ``c`` (n, degree + 1), its duration ``h`` (s)
        and the times (s) of its :data:`OPEN_LOOP_POINTS` outputs.

    Returns
    -------
    t : ndarray, shape (1 + outputs,)
        Times (s), 0 first.
    x : ndarray, shape (len(t), 2n)
        States.
    success : bool
        False when CVODES failed on a segment (the states up to the last segment that
        ended).
    """
    ts, xs = [np.zeros(1)], [np.asarray(x0)[None, :]]
    x = x0
    try:
        for coef, h, times in segments:
            out = integ(x0=x, p=np.concatenate([coef.ravel(order="F"), [h]]))
            path = np.array(out["xf"]).T
            xs.append(path)
            ts.append(times)
            x = path[-1]
    except RuntimeError:
        return np.concatenate(ts), np.vstack(xs), False
    return np.concatenate(ts), np.vstack(xs), True


#: model -> {(integrator id, segments): (integrator, its sweep over the segments)}.
_SWEEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def open_loop_sweep(model: RobotModel, integ: ca.Function, segments: int) -> ca.Function:
    """``integ`` over ``segments`` segments in a row, in one call (``mapaccum``).

    ``(x0 (2n,), P (params, segments)) -> (x at each segment's end (2n, segments), x at
    every output (2n, segments OPEN_LOOP_POINTS))``: each segment starts where the last
    ended, as :func:`integrate_segments` does from Python; the same CVODES calls, one Python
    call instead of one per segment (on the Panda's 30 segments 13 ms -> 7.6 ms on a loaded
    machine, the states equal to the bit). Kept per model and integrator; used by
    :meth:`FlatTrajectory.open_loop` and
    :meth:`~tocontrol_ros.core.direct.scaled_path.ScaledPath.open_loop`.
    """
    return _sweep_entry(model, integ, segments)[1]


def open_loop_sweep_buffered(model: RobotModel, integ: ca.Function, segments: int
                             ) -> BufferedFunction:
    """:func:`open_loop_sweep` called through numpy buffers, kept with it.

    The same evaluation and the same states (to the bit), without converting its inputs and
    its (2n, segments OPEN_LOOP_POINTS) states to and from CasADi's ``DM``; a segment that
    fails raises ``RuntimeError`` as the plain call does. Used by
    :meth:`~tocontrol_ros.core.direct.scaled_path.ScaledPath.open_loop` (a replan's
    certificate).
    """
    entry = _sweep_entry(model, integ, segments)
    if entry[2] is None:
        entry[2] = BufferedFunction(entry[1])
    return entry[2]


def _sweep_entry(model: RobotModel, integ: ca.Function, segments: int) -> list:
    """``[integ, its mapaccum over segments, its buffered call or None]``, per model."""
    table = _SWEEPS.setdefault(model, {})
    key = (id(integ), segments)
    if key not in table or table[key][0] is not integ:
        x = ca.MX.sym("x", integ.size1_in("x0"))
        p = ca.MX.sym("p", integ.size1_in("p"))
        out = integ(x0=x, p=p)["xf"]
        step = ca.Function("open_loop_segment", [x, p], [out[:, -1], out])
        table[key] = [integ, step.mapaccum("open_loop_sweep", segments), None]
    return table[key]


def compile_open_loop(model: RobotModel, degree: int = 3) -> tuple[ca.Function, str]:
    """The open loop's right-hand side compiled, once per model and degree.

    :func:`polynomial_segment_ode` as a CasADi DAE function (``t, x, z, p, u -> ode, alg,
    quad, zero``) and its Jacobian (what CVODES asks for, and Newton's iteration uses),
    compiled through :func:`~tocontrol_ros.core.robot.compiled.compile_owned`: CVODES
    evaluates it thousands of times a certificate, and CasADi's virtual machine ran it
    seven times slower (4.1 ms a Panda span against 0.56 ms, the states equal to the bit).
    Inside :func:`~tocontrol_ros.core.robot.compiled.parallel_builds` this only starts the
    build.

    Returns
    -------
    function, how
        The DAE function (compiled, or symbolic while it builds or without a compiler) and
        how it was obtained (:func:`~tocontrol_ros.core.robot.compiled.compile_owned`).
    """
    def build() -> list[ca.Function]:
        dae = segment_dae(f"flat_open_loop_ode{degree}",
                          *polynomial_segment_ode(model, degree))
        return [dae, dae.jacobian()]

    funs, how = compile_owned(model, ("flat_open_loop", degree),
                              f"flat_open_loop{model.n}p{degree}", build)
    return funs[0], how


def _open_loop_integrator(model: RobotModel, degree: int, rtol: float, atol: float,
                          stiff: bool = False) -> ca.Function:
    """CVODES over one span: the model's forward dynamics under the span's torques.

    The torques are the inverse dynamics of the span's path, a polynomial
    ``q(sigma) = sum_j c_j sigma^j`` in the span's normalised time ``sigma`` in [0, 1]
    (parameters ``(vec c, h)``, ``h`` the span's duration); the state is integrated with
    ``dx/dsigma = h f(x, tau)`` (forward dynamics through the factorised mass matrix, not
    the inverse dynamics that made the torques), output at :data:`OPEN_LOOP_POINTS` times.
    Adams with functional iteration (no Jacobians: the motion is not stiff), or BDF with
    Newton iteration when ``stiff``. The right-hand side compiled
    (:func:`compile_open_loop`); kept with the function it was made from, and made again
    when that changes (the library landed after a quick build or while it was built).
    """
    key = (degree, rtol, atol, stiff)
    cached = _OPEN_LOOP.setdefault(model, {})
    dae, _ = compile_open_loop(model, degree)
    if key in cached and cached[key][0] is dae:
        return cached[key][1]
    grid = np.linspace(0.0, 1.0, OPEN_LOOP_POINTS + 1)[1:]
    method = {} if stiff else {"linear_multistep_method": "adams",
                               "nonlinear_solver_iteration": "functional"}
    integ = ca.integrator("flat_open_loop", "cvodes", dae, 0.0, grid.tolist(),
                          {"reltol": rtol, "abstol": atol, "max_num_steps": 100000, **method})
    cached[key] = (dae, integ)  # made again once the library (another function) has landed
    return integ


class FlatTrajectory(InverseDynamicsTrajectory):
    """A bounded B-spline solution: states from the spline, torques its inverse dynamics.

    Same interface as :class:`~tocontrol_ros.core.types.trajectory.Trajectory` for sampling and
    verification; it has no costates (``psi``, ``S`` and ``H`` are NaN).

    Parameters
    ----------
    transcription : FlatTranscription
    result : FlatResult
    k : float
    set_values : ndarray, shape (L SET_POINTS,), optional
        :meth:`set_values` of this result at :data:`SET_POINTS` times a span, where they are
        known already (a warm state's, from the check of the plan that made it): kept, not
        evaluated again.
    """

    def __init__(self, transcription: FlatTranscription, result: FlatResult, k: float,
                 set_values: np.ndarray | None = None) -> None:
        # Only what evaluating needs: not the transcription (its NLP solver is large, and a
        # refined mesh's transcription serves one motion).
        model = transcription.model
        self._model = model
        self.n = model.n
        self.joint_names = model.joint_names
        self.law = LawParams(k, 0.0, transcription.torque_scale)
        self.par = self.law.array()
        self.breaks, self._degree = transcription.breaks, transcription.degree
        self._id = transcription._id
        self._scale = transcription.scale
        self._set_result(result, set_values)

    def with_result(self, result: FlatResult, set_values: np.ndarray | None = None
                    ) -> FlatTrajectory:
        """The same mesh and model with other control points and ``T`` (e.g. to test).

        ``set_values``: the new result's :meth:`set_values` where already known (as
        :meth:`slower_set_values` gives them for a time stretch).
        """
        other = copy.copy(self)
        other._set_result(result, set_values)
        return other

    def _set_result(self, result: FlatResult, set_values: np.ndarray | None = None) -> None:
        # The set's values at SET_POINTS times a span, once evaluated (read-only).
        self._set_known = None if set_values is None else _read_only(set_values)
        self.result = result
        self.T = result.T
        self._P = result.P
        self._spl = BSpline(knots(self.breaks, self._degree), result.P, self._degree)
        self._d1 = self._spl.derivative(1)
        self._d2 = self._spl.derivative(2)
        self._higher = (self._spl, self._d1, self._d2)  # more by _derivatives
        self.t_grid = self.breaks * self.T
        x = self._path(self.t_grid)[:2]
        self.z_grid = np.hstack([x[0], x[1], np.full((len(self.t_grid), 2 * self.n), np.nan)])

    def control_points_on(self, breaks: np.ndarray) -> np.ndarray:
        """The same path's control points (K', n) on finer breakpoints (exact).

        ``breaks`` must hold this path's breakpoints: the new ones are inserted as knots
        (Boehm), which keeps the path, its velocities and accelerations, and so its torques,
        exactly, where a least-squares fit on a mesh with short spans changes the
        accelerations (a fit's constraint violation was 425 at the start of a refined
        Panda solve, and IPOPT then wandered off).
        """
        spl = self._spl
        for x in np.setdiff1d(breaks, self.breaks):
            spl = spl.insert_knot(float(x))
        if len(spl.t) != len(breaks) + 2 * self._degree or not np.allclose(
                spl.t, knots(breaks, self._degree), rtol=0.0, atol=1e-14):
            raise ValueError("`breaks` must contain the path's own breakpoints")
        return np.asarray(spl.c)

    def _path(self, t: np.ndarray, T: float | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The path at times ``t`` (s) when run in ``T`` (s; default this motion's)."""
        T = self.T if T is None else T
        s = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, T) / T
        return self._spl(s), self._d1(s) / T, self._d2(s) / T ** 2

    def _controls(self, q, qd, qdd) -> np.ndarray:
        if len(q) == 1:  # the integrators' path: one time per call
            return np.array(self._id(q[0], qd[0], qdd[0], self._scale)).T
        return mapped_controls(self._model, self._id, len(q))(q.T, qd.T, qdd.T, self._scale)[0].T

    def open_loop(self, rtol: float, atol: float, stiff: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, bool]:
        """The published torques integrated from ``x(0)``, span by span (CVODES).

        Adams first; BDF (``stiff``) when Adams fails.

        Returns
        -------
        t : ndarray, shape (L OPEN_LOOP_POINTS + 1,)
            Times (s).
        x : ndarray, shape (len(t), 2n)
            Open-loop states.
        success : bool
        """
        integ = _open_loop_integrator(self._model, self._degree, rtol, atol, stiff)
        br, L = self.breaks, len(self.breaks) - 1
        d1 = self._degree + 1
        fact = np.array([np.prod(np.arange(1, i + 1)) for i in range(d1)], dtype=float)
        grid = np.linspace(0, 1, OPEN_LOOP_POINTS + 1)[1:]
        ds = np.diff(br)
        # Taylor coefficients at each span's start (right-hand derivatives), in sigma:
        # (L, n, d1), each derivative's spline made once and evaluated at every start.
        derivs = np.stack([spl(br[:-1]) for spl in self._derivatives(d1)], axis=2)
        coefs = derivs * (ds[:, None] ** np.arange(d1))[:, None, :] / fact
        times = self.T * (br[:-1, None] + ds[:, None] * grid[None, :])
        x0 = self.state(0.0)[0, :2 * self.n]
        try:  # every span in one call (open_loop_sweep, buffered), the same CVODES calls
            params = np.vstack([coefs.reshape(L, -1, order="F").T, self.T * ds[None, :]])
            _, states = open_loop_sweep_buffered(self._model, integ, L)(x0, params)
            return np.concatenate([[0.0], times.ravel()]), \
                np.vstack([x0[None, :], states.T]), True
        except RuntimeError:  # a span failed: again one by one, to say where
            pass
        spans = ((coefs[j], ds[j] * self.T, times[j]) for j in range(L))
        t, x, success = integrate_segments(integ, x0, spans)
        if not success and not stiff:
            return self.open_loop(rtol, atol, stiff=True)
        return t, x, success

    def _derivatives(self, count: int) -> list:
        """The path's spline and its first ``count - 1`` derivatives' splines.

        The first two are the trajectory's own; a higher one is the last one's derivative
        (scipy differentiates a B-spline one order at a time: the same coefficients as
        ``derivative(i)`` of the path, to the bit), kept for the next call.
        """
        splines = getattr(self, "_higher", (self._spl, self._d1, self._d2))
        if len(splines) < count:  # a new tuple: a thread that races only repeats the work
            more = list(splines)
            while len(more) < count:
                more.append(more[-1].derivative(1))
            self._higher = splines = tuple(more)
        return list(splines[:count])

    def set_values(self, points: int = SET_POINTS) -> np.ndarray:
        """``sum_i |u_i|^(2k)`` at ``points`` equally spaced times per span, shape (L points,).

        At :data:`SET_POINTS` evaluated once and kept (read-only): the answer's check, a pad
        round's widening and the warm state of the plan ask for the same values.
        """
        known = self.known_set_values()
        if points == SET_POINTS and known is not None:
            return known
        u = self.control_at(self.set_fractions(points) * self.T)
        values = np.sum(np.abs(u) ** (2 * self.law.k), axis=1)
        if points == SET_POINTS:
            self._set_known = values = _read_only(values)
        return values

    def known_set_values(self) -> np.ndarray | None:
        """:meth:`set_values` at :data:`SET_POINTS` where evaluated already, else None."""
        return getattr(self, "_set_known", None)  # (None in one pickled before it kept them)

    def set_fractions(self, points: int) -> np.ndarray:
        """The times of :meth:`set_values` as fractions of ``T``, shape (L points,)."""
        br = self.breaks
        frac = (np.arange(points) + 0.5) / points
        return (br[:-1, None] + frac[None, :] * np.diff(br)[:, None]).ravel()

    def slower_set_values(self, durations, points: int = SET_POINTS) -> np.ndarray:
        """:meth:`set_values` of the same path run in each of ``durations``, in one call.

        The same numbers to the bit as ``with_result(replace(result, T=T)).set_values()``
        for each ``T`` (the path's samples taken the same way, the inverse dynamics' one
        compiled kernel mapped over all of them at once): the time stretches of the
        bounded solve (``checked.stretched``) are checked together.

        Parameters
        ----------
        durations : sequence of float
            Final times ``T`` (s), any number ``m >= 1``.
        points : int
            Equally spaced times per span.

        Returns
        -------
        ndarray, shape (m, L points)
        """
        s = self.set_fractions(points)
        q, qd, qdd = (np.vstack(a) for a in zip(*(self._path(s * T, T) for T in durations),
                                                strict=True))
        u = self._controls(q, qd, qdd)
        return np.sum(np.abs(u) ** (2 * self.law.k), axis=1).reshape(len(durations), len(s))

    def control_at(self, t: np.ndarray) -> np.ndarray:
        """Normalised controls at times ``t`` (K,), shape (K, n)."""
        return self._controls(*self._path(t))

    def joint_speed_bounds(self, t: np.ndarray) -> np.ndarray:
        """A rigorous bound of each joint's speed on each interval between times ``t``.

        On a span of the spline, ``dq/ds`` and ``d2q/ds2`` lie in the convex hull of the
        span's control points of the first and second derivative splines (B-splines' convex
        hull property). On ``[t0, t1]`` (``h = t1 - t0``) with ``|qdd| <= A`` on the spans it
        touches, ``|qd(t)| <= min(|qd(t0)| + A (t - t0), |qd(t1)| + A (t1 - t)) <=
        (|qd(t0)| + |qd(t1)|) / 2 + A h / 2``; the bound is the smaller of that and the
        hull of ``qd`` itself there, raised by
        :data:`~tocontrol_ros.core.direct.tuning.SPEED_BOUND_SLACK` for rounding. The
        clearance certificate's between-samples bound uses it (a motion at rest moves its
        links slowly, where the joint velocity limits would allow them to move fast).

        Parameters
        ----------
        t : ndarray, shape (K,)
            Increasing times in ``[0, T]`` (s), ``K >= 2``.

        Returns
        -------
        ndarray, shape (K - 1, n)
            ``max |qd_j|`` over ``[t_k, t_k+1]`` is at most this (rad/s, m/s).
        """
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or len(t) < 2 or np.any(np.diff(t) < 0):
            raise ValueError(f"`t` must be increasing times, shape (K >= 2,), got {t.shape}")
        T, br, p = self.T, self.breaks, self._degree
        last = len(br) - 2
        s = np.clip(t / T, 0.0, 1.0)
        first = np.clip(np.searchsorted(br, s[:-1], side="right") - 1, 0, last)
        final = np.clip(np.searchsorted(br, s[1:], side="left") - 1, first, last)

        def hull(order: int) -> np.ndarray:  # (L, n): max |coefficient| on each span
            c = np.abs(np.asarray(self._spl.derivative(order).c))
            width = p - order + 1  # the span's coefficients: i ... i + p - order
            return np.max(np.stack([c[j:j + last + 1] for j in range(width)]), axis=0)

        def over_intervals(per_span: np.ndarray) -> np.ndarray:  # max over touched spans
            out = per_span[first]
            for d in range(1, int(np.max(final - first, initial=0)) + 1):
                out = np.maximum(out, per_span[np.minimum(first + d, final)])
            return out

        speed = over_intervals(hull(1)) / T
        qd = np.abs(self._path(t)[1])
        if p >= 2:
            acc = over_intervals(hull(2)) / T ** 2
            ends = 0.5 * (qd[:-1] + qd[1:]) + 0.5 * acc * np.diff(t)[:, None]
            speed = np.minimum(speed, ends)
        return speed * (1.0 + SPEED_BOUND_SLACK) + SPEED_BOUND_SLACK


#: model -> {count: (its inverse dynamics function, mapped over count times and buffered)},
#: the :data:`MAPPED_KEEP` most recently made per model (sampled motions have any length).
_MAPPED_CONTROLS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_MAPPED_LOCK = threading.Lock()
MAPPED_KEEP = 16


def mapped_controls(model: RobotModel, fun: ca.Function, count: int) -> BufferedFunction:
    """``fun`` (the normalised inverse dynamics) mapped over ``count`` times, buffered.

    ``(q (n, count), qd, qdd, scale (n,)) -> [u (n, count)]``. Kept per model and count:
    made per trajectory, the map and the conversion of its arguments to ``DM`` cost more
    than the evaluation (the between-samples check's 768 times on the Panda's 24 spans:
    1.9 ms, 0.4 ms buffered, the same bits).
    """
    with _MAPPED_LOCK:
        table = _MAPPED_CONTROLS.setdefault(model, {})
        entry = table.pop(count, None)
        if entry is None or entry[0] is not fun:
            # The torque scale (the last argument) is the same at every time: not repeated.
            entry = (fun, BufferedFunction(fun.map(f"{fun.name()}_map", "serial", count,
                                                   [fun.n_in() - 1], [])))
        table[count] = entry  # the most recently used last
        while len(table) > MAPPED_KEEP:
            del table[next(iter(table))]
        return entry[1]


def refined_breaks(trajectory: FlatTrajectory, threshold: float = REFINE_JUMP) -> np.ndarray:
    """The breakpoints with every span halved where the motion changes its acceleration.

    A span is halved when, for some joint, the acceleration at its two ends differs by more
    than ``threshold`` times that joint's largest acceleration along the motion.

    Returns
    -------
    ndarray, shape (L' + 1,)
        New breakpoints on [0, 1] (the old ones when no span needs halving).
    """
    br = trajectory.breaks
    T = trajectory.T
    fine = trajectory._path(np.linspace(0.0, T, 20 * len(br)))[2]
    scale = np.maximum(np.max(np.abs(fine), axis=0), 1e-9)
    acc = trajectory._path(br * T)[2] / scale
    jump = np.max(np.abs(np.diff(acc, axis=0)), axis=1)
    split = jump > threshold
    return np.union1d(br, 0.5 * (br[:-1] + br[1:])[split])
