"""A compiled Dormand-Prince 5(4) pair with step-size control, over chains of segments.

The certificate's integrator (:mod:`tocontrol_ros.core.indirect.certificate`): a different
method from the solver's fixed-step RK4. It integrates ``y = (z, x)``: the canonical state
``z`` (4n) under (16) with the control law (15), and the model's state ``x`` (2n) under the
torques of that law. Each segment starts ``z`` anew from a given state; ``x`` runs on from
the previous segment. The adaptive loop is compiled too: a trial step is a real branch in C
(idle once the segment's end is reached), folded over a budget of trials per segment, and
:data:`CHUNK` segments are chained in one call.
"""

from __future__ import annotations

import threading

import casadi as ca
import numpy as np

from tocontrol_ros.core.indirect.pmp import BufferedFunction, CanonicalSystem
from tocontrol_ros.core.indirect.tuning import BUDGETS, MIN_STEP
from tocontrol_ros.core.robot.compiled import c_name, compile_function
from tocontrol_ros.core.types.law import LawParams

__all__ = ["AdaptiveIntegrator", "integrator", "CHUNK"]

# Dormand-Prince 5(4) (Hairer, Norsett, Wanner, *Solving ODEs I*, Table 5.2): 5th-order
# solution, FSAL (the last stage is the next step's first), error from the embedded 4th. The
# systems are autonomous, so the stage times are not needed.
_A = ((),
      (1 / 5,),
      (3 / 40, 9 / 40),
      (44 / 45, -56 / 15, 32 / 9),
      (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
      (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
      (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84))
_E = (71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40)
#: Step-size controller: safety factor, bounds of the change per step, PI exponent (Hairer's
#: DOPRI5 code).
_SAFETY, _SHRINK, _GROW, _BETA = 0.9, 0.2, 5.0, 0.04
#: Scalars in front of (y, k1) in the trial step's accumulator.
_ACC = 6
#: Segments per compiled call (the last call padded with empty segments).
CHUNK = 16


class AdaptiveIntegrator:
    """Dormand-Prince 5(4) with step-size control, compiled, over chains of segments.

    The integrated state is ``y = (z, x)``: the canonical state ``z`` (4n) under (16) and
    the model's state ``x`` (2n) under the torques of the control law at ``z``. Each
    segment starts ``z`` anew from the grid; ``x`` runs on from the previous segment.

    Parameters
    ----------
    system : CanonicalSystem
    rtol, atol : float
        Per step: max over components of ``|err_i| / (atol + rtol max(|y_i|, |y_new_i|))``
        must be at most 1.
    """

    def __init__(self, system: CanonicalSystem, rtol: float, atol: float) -> None:
        self.system = system
        self.n = system.n
        self.ny = 6 * system.n
        self.rtol, self.atol = float(rtol), float(atol)
        self._chunks: dict[int, BufferedFunction] = {}

    def _rhs(self) -> ca.Function:
        """``(y, par) -> dy/dt``; ``par = (k, delta, torque_scale, open-loop torque_scale)``."""
        sy, n = self.system, self.n
        x = ca.SX.sym("x", 2 * n)
        par = ca.SX.sym("par", 4)
        # The open loop applies the torques u tau_max torque_scale of the problem, whatever
        # scale the trajectory was solved with.
        xd = sy.model.state_derivative_sym(x, sy.u * par[3])
        fun = ca.Function("cert_rhs_sx", [sy.z, x, sy.par, par[3]], [ca.vertcat(sy.rhs, xd)])
        y = ca.SX.sym("y", 6 * n)
        return ca.Function("cert_rhs", [y, par], [fun(y[:4 * n], y[4 * n:], par[:3], par[3])])

    def _trial(self, rhs: ca.Function) -> ca.Function:
        """One trial step of a segment of length ``L``, from the accumulator to the next.

        The accumulator is ``(t, h, prev, rejected_last, y, k1, accepted, rejected)``, with
        ``prev`` the error norm of the last accepted step.
        """
        ny = self.ny
        acc = ca.MX.sym("acc", _ACC + 2 * ny)
        length, par = ca.MX.sym("L"), ca.MX.sym("par", 4)
        t, h, prev, rej_last = acc[0], acc[1], acc[2], acc[3]
        y, k1 = acc[4:4 + ny], acc[4 + ny:4 + 2 * ny]
        n_acc, n_rej = acc[4 + 2 * ny], acc[5 + 2 * ny]
        rest = length - t
        hs = ca.fmin(h, rest)
        active = rest > 0
        ks = [k1]
        for i in range(1, 7):
            yi = y + hs * sum(a * kj for a, kj in zip(_A[i], ks, strict=False) if a != 0.0)
            ks.append(rhs(yi, par))
        y_new = y + hs * sum(a * kj for a, kj in zip(_A[6], ks, strict=False) if a != 0.0)
        err = hs * sum(e * kj for e, kj in zip(_E, ks, strict=True) if e != 0.0)
        scale = self.atol + self.rtol * ca.fmax(ca.fabs(y), ca.fabs(y_new))
        # Non-finite values must fail the step (max over components in C ignores a NaN).
        finite = ca.fabs(ca.sum1(y_new) + ca.sum1(err)) < np.inf
        norm = ca.if_else(finite, ca.mmax(ca.fabs(err) / scale), np.inf)
        ok = ca.logic_and(norm <= 1.0, active)
        # PI step-size control (Hairer's DOPRI5): fewer rejections where the solution's
        # smoothness changes (the switches of the control law), no growth right after one.
        base = _SAFETY * norm ** (-(0.2 - 0.75 * _BETA))
        grow = ca.fmin(_GROW, ca.fmax(_SHRINK, base * prev ** _BETA))
        grow = ca.if_else(rej_last, ca.fmin(grow, 1.0), grow)
        # A non-finite error (the state blew up) shrinks the step as much as allowed.
        shrink = ca.if_else(norm <= 1e300, ca.fmax(_SHRINK, ca.fmin(1.0, base)), _SHRINK)
        last = hs >= rest  # this step reaches the segment's end
        t_new = ca.if_else(ok, ca.if_else(last, length, t + hs), t)
        # After the last step of a segment keep the step length the controller allows.
        h_ok = ca.if_else(last, ca.fmax(h, hs * grow), hs * grow)
        h_new = ca.if_else(active, ca.if_else(ok, h_ok, hs * shrink), h)
        # Give up below a step of MIN_STEP of the segment: h = 0 makes every later trial
        # idle, and the segment is reported unfinished.
        h_new = ca.if_else(h_new < MIN_STEP * length, 0.0, h_new)
        out = ca.vertcat(t_new, h_new, ca.if_else(ok, ca.fmax(norm, 1e-4), prev),
                         ca.logic_and(active, ca.logic_not(ok)),
                         ca.if_else(ok, y_new, y), ca.if_else(ok, ks[6], k1),
                         n_acc + ok, n_rej + ca.logic_and(active, ca.logic_not(ok)))
        step = ca.Function("cert_step", [acc, length, par], [out])
        # A real branch in C: the trials left after a segment's end cost a copy, not a step.
        idle = ca.Function("cert_idle", [acc, length, par], [acc])
        branch = ca.Function.conditional("cert_branch", [idle], step)
        acc2, length2, par2 = ca.MX.sym("acc", _ACC + 2 * ny), ca.MX.sym("L"), \
            ca.MX.sym("par", 4)
        busy = ca.logic_and(length2 - acc2[0] > 0, acc2[1] > 0)
        return ca.Function("cert_trial", [acc2, length2, par2],
                           [branch(busy, acc2, length2, par2)])

    def _chunk(self, budget: int) -> BufferedFunction:
        """``CHUNK`` segments with ``budget`` trial steps each, in one compiled call.

        ``(x0 (2n), h0, Z (CHUNK, 4n), L (CHUNK), par) -> (X (CHUNK, 2n), H (CHUNK),
        Zend (CHUNK, 4n), stats (CHUNK, 3: time left, accepted, rejected))``.
        """
        with _LOCK:
            if budget not in self._chunks:
                self._chunks[budget] = self._make_chunk(budget)
            return self._chunks[budget]

    def _make_chunk(self, budget: int) -> BufferedFunction:
        n, ny = self.n, self.ny
        rhs = self._rhs()
        trials = self._trial(rhs).fold(budget)
        x0, h0 = ca.MX.sym("x0", 2 * n), ca.MX.sym("h0")
        z0, length, par = ca.MX.sym("z0", 4 * n), ca.MX.sym("L"), ca.MX.sym("par", 4)
        y0 = ca.vertcat(z0, x0)
        acc = trials(ca.vertcat(0.0, h0, 1e-4, 0.0, y0, rhs(y0, par), 0.0, 0.0), length, par)
        y1 = acc[4:4 + ny]
        seg = ca.Function("cert_segment", [x0, h0, z0, length, par],
                          [y1[4 * n:], acc[1], y1[:4 * n],
                           ca.vertcat(length - acc[0], acc[4 + 2 * ny], acc[5 + 2 * ny])])
        sy = self.system
        chunk = seg.mapaccum("cert_chunk", CHUNK, 2)
        # One broadcast par: wrap so that the buffer's inputs are dense and of fixed size.
        xs, hs_, zs = ca.MX.sym("x0", 2 * n), ca.MX.sym("h0"), ca.MX.sym("Z", 4 * n, CHUNK)
        ls, ps = ca.MX.sym("L", 1, CHUNK), ca.MX.sym("par", 4)
        outs = chunk(xs, hs_, zs, ls, ca.repmat(ps, 1, CHUNK))
        fun = ca.Function(f"tocontrol_cert_{c_name(sy.model.name)}_{n}_{budget}_{CHUNK}_"
                          f"{self.rtol:.0e}_{self.atol:.0e}".replace("-", "m").replace(
                              "+", "p").replace(".", "_"),
                          [xs, hs_, zs, ls, ps], outs)
        return BufferedFunction(compile_function(fun)[0])

    def run(self, starts: np.ndarray, lengths: np.ndarray, x0: np.ndarray, law: LawParams,
            torque_scale: float, h0: float) -> tuple[np.ndarray, np.ndarray, dict]:
        """Integrate a chain of segments.

        Parameters
        ----------
        starts : ndarray, shape (S, 4n)
            Canonical state at each segment start.
        lengths : ndarray, shape (S,)
            Segment durations (s), >= 0.
        x0 : ndarray, shape (2n,)
            Open-loop state at the start of the first segment.
        law : LawParams
            The control law of the canonical system (the trajectory's).
        torque_scale : float
            Fraction of ``tau_max`` the open loop applies (the problem's
            :attr:`~tocontrol_ros.core.types.problem.Problem.torque_scale`).
        h0 : float
            First trial step (s).

        Returns
        -------
        z_end : ndarray, shape (S, 4n)
            Canonical state at each segment end (re-integrated from its start).
        x_end : ndarray, shape (S, 2n)
            Open-loop state at each segment end (carried from ``x0``).
        stats : dict
            ``steps`` and ``rejected`` (all tries), ``finished`` (bool), ``budget``.
        """
        par = np.append(law.array(), torque_scale)
        count = len(lengths)
        pad = -count % CHUNK
        z_all = np.concatenate([starts, np.repeat(starts[-1:], pad, axis=0)])
        l_all = np.concatenate([lengths, np.zeros(pad)])
        steps = rejected = 0
        for budget in BUDGETS:
            fun = self._chunk(budget)
            x, h = np.asarray(x0, dtype=float), float(h0)
            z_out, x_out, left = [], [], []
            for c in range(0, count + pad, CHUNK):
                xs, hs, zend, st = fun(x, h, z_all[c:c + CHUNK].T, l_all[c:c + CHUNK], par)
                x, h = xs[:, -1], float(np.ravel(hs)[-1])
                z_out.append(zend.T)
                x_out.append(xs.T)
                left.append(st[0])
                steps += int(st[1].sum())
                rejected += int(st[2].sum())
            left = np.concatenate(left)[:count]
            finished = bool(np.all(left <= 1e-12 * np.maximum(l_all[:count], 1e-300)))
            if finished:
                break
        return (np.concatenate(z_out)[:count], np.concatenate(x_out)[:count],
                {"steps": steps, "rejected": rejected, "finished": finished, "budget": budget})


_LOCK = threading.Lock()


def integrator(system: CanonicalSystem, rtol: float, atol: float) -> AdaptiveIntegrator:
    """The system's integrator for these tolerances (kept with its other functions)."""
    key = ("adaptive", rtol, atol)
    with _LOCK:
        if key not in system.function_cache:
            system.function_cache[key] = AdaptiveIntegrator(system, rtol, atol)
        return system.function_cache[key]
