"""The nominal trajectory a tracker follows: samples of ``q, qd, qdd`` and torques.

Interpolation of the nominal trajectory (:class:`NominalTrajectory`): between two samples the
position is the quintic Hermite polynomial that matches ``q, qd, qdd`` at both ends (so
``q`` is C2 and velocities and accelerations are its derivatives, consistent with samples
of one smooth motion, which is what the planner publishes). The nominal torque between
samples is, given the model's inverse dynamics, that of the interpolated state plus the
linear interpolation of the samples' residual ``effort - ID(q, qd, qdd)``: it equals the
published effort at every sample, and between samples follows the torque the planner
computed (for a plan consistent with the model, ``ID`` of the planned state *is* the planned
torque; the quintic's acceleration errs by ``O(dt^4)``), where the linear interpolation of
the effort alone, the fallback without a model, errs by up to ``dt^2/8 max|tau''|`` (the
Panda's torques change within milliseconds where arcs meet). After the last sample the
trajectory holds the last position at rest; the tracker then feeds forward the planning
model's static torque there (gravity), not the last nominal torque (which, for a
time-optimal motion, is braking).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.validate import finite_array

__all__ = ["NominalSample", "NominalTrajectory"]


@dataclass(frozen=True)
class NominalSample:
    """A nominal trajectory evaluated at ``K`` times.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Times (s).
    q, qd, qdd : ndarray, shape (K, n)
        Positions (rad, m), velocities (rad/s) and accelerations (rad/s^2).
    effort : ndarray, shape (K, n)
        Nominal torques (N m) or forces (N).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    effort: np.ndarray


class NominalTrajectory:
    """Samples of a planned motion, interpolated at any time.

    Parameters
    ----------
    t : array_like, shape (K,)
        Sample times (s) from the start of the motion: ``t[0] >= 0``, strictly increasing.
    q, qd, qdd : array_like, shape (K, n)
        Positions (rad, m), velocities and accelerations at the samples.
    effort : array_like, shape (K, n)
        Nominal torques (N m) or forces (N) at the samples.
    hold_effort : array_like, shape (n,), optional
        Torque fed forward after the end, while holding the last position (default zero).
    joint_names : sequence of str, optional
        Names of the ``n`` joints, for messages.
    inverse_dynamics : callable, optional
        ``(q, qd, qdd) -> tau`` of the model, each argument shape (n, K) and the result
        (n, K) (a CasADi function such as ``model.function("id")``): the torque between
        samples follows it (module docstring). Default: linear interpolation of ``effort``.

    Raises
    ------
    ProblemError
        Wrong shapes, no samples, NaN or infinite values, times that are negative or not
        strictly increasing; the message names the argument and the first offending entry.

    Notes
    -----
    ``evaluate(t)`` uses, on each interval, the quintic Hermite polynomial through
    ``(q, qd, qdd)`` at both ends (C2 across samples) and, for ``effort``, the inverse
    dynamics of that state plus the linearly interpolated residual at the samples (or, without
    ``inverse_dynamics``, linear interpolation). Before ``t[0]`` it returns the first sample;
    after ``t[-1]`` it holds the last position with zero velocity and acceleration and
    ``hold_effort``.
    """

    def __init__(self, t, q, qd, qdd, effort, hold_effort=None, joint_names=None,
                 inverse_dynamics=None) -> None:
        t = finite_array("t", t, ndim=1)
        if t.size == 0:
            raise ProblemError("`t` must hold at least one sample, got none")
        k = t.size
        q = finite_array("q", q, ndim=2)
        if q.shape[0] != k:
            raise ProblemError(f"`q` must have shape ({k}, n) to match `t`, got {q.shape}")
        n = q.shape[1]
        if n == 0:
            raise ProblemError("`q` must have at least one joint (column), got shape "
                               f"{q.shape}")
        qd = finite_array("qd", qd, shape=(k, n))
        qdd = finite_array("qdd", qdd, shape=(k, n))
        effort = finite_array("effort", effort, shape=(k, n))
        if t[0] < 0:
            raise ProblemError(f"`t` must start at a time >= 0, got t[0] = {float(t[0])!r}")
        steps = np.diff(t)
        bad = np.flatnonzero(steps <= 0)
        if bad.size:
            i = int(bad[0])
            raise ProblemError(f"`t` must be strictly increasing; t[{i}] = {float(t[i])!r} "
                               f"is followed by t[{i + 1}] = {float(t[i + 1])!r}")
        hold = np.zeros(n) if hold_effort is None else finite_array("hold_effort", hold_effort,
                                                               shape=(n,))
        if joint_names is not None:
            joint_names = tuple(str(j) for j in joint_names)
            if len(joint_names) != n:
                raise ProblemError(f"`joint_names` must name the {n} joints, got "
                                   f"{len(joint_names)}: {list(joint_names)}")
        self.t, self.q, self.qd, self.qdd, self.effort = t, q, qd, qdd, effort
        self.hold_effort = hold
        self.joint_names = joint_names
        self.n = n
        self._coef = _quintic_coefficients(t, q, qd, qdd)
        self.inverse_dynamics = inverse_dynamics
        #: ``effort - ID`` at the samples, shape (K, n); None without a model.
        self._residual = None
        if inverse_dynamics is not None:
            self._residual = effort - _call(inverse_dynamics, q, qd, qdd)

    @property
    def duration(self) -> float:
        """Time of the last sample (s)."""
        return float(self.t[-1])

    def __len__(self) -> int:
        return self.t.size

    def with_hold_effort(self, hold_effort) -> NominalTrajectory:
        """The same samples with another torque held after the end, shape (n,) (N m)."""
        return NominalTrajectory(self.t, self.q, self.qd, self.qdd, self.effort,
                                 hold_effort=hold_effort, joint_names=self.joint_names,
                                 inverse_dynamics=self.inverse_dynamics)

    def with_inverse_dynamics(self, inverse_dynamics) -> NominalTrajectory:
        """The same samples, the torque between them following ``inverse_dynamics``."""
        return NominalTrajectory(self.t, self.q, self.qd, self.qdd, self.effort,
                                 hold_effort=self.hold_effort, joint_names=self.joint_names,
                                 inverse_dynamics=inverse_dynamics)

    def evaluate(self, t) -> NominalSample:
        """Interpolated values at times ``t`` (s), scalar or shape (K,).

        Returns
        -------
        NominalSample
            Arrays of shape (K, n) (K = 1 for a scalar).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        n, grid = self.n, self.t
        out_q = np.empty((t.size, n))
        out_qd = np.empty((t.size, n))
        out_qdd = np.empty((t.size, n))
        out_e = np.empty((t.size, n))
        before = t <= grid[0]
        after = t >= grid[-1]
        inside = ~(before | after)
        out_q[before], out_qd[before] = self.q[0], self.qd[0]
        out_qdd[before], out_e[before] = self.qdd[0], self.effort[0]
        out_q[after], out_qd[after], out_qdd[after] = self.q[-1], 0.0, 0.0
        out_e[after] = self.hold_effort
        # Exactly at the last sample the sample itself, not the hold.
        last = t == grid[-1]
        out_qd[last], out_qdd[last], out_e[last] = self.qd[-1], self.qdd[-1], self.effort[-1]
        if np.any(inside):
            ti = t[inside]
            idx = np.clip(np.searchsorted(grid, ti, side="right") - 1, 0, grid.size - 2)
            h = (grid[idx + 1] - grid[idx])[:, None]
            s = ((ti - grid[idx]) / h[:, 0])[:, None]
            c = self._coef[idx]  # (K, 6, n)
            powers = (s ** np.arange(6))[:, :, None]  # (K, 6, 1)
            out_q[inside] = np.sum(c * powers, axis=1)
            d1 = np.arange(1, 6)[None, :, None]
            out_qd[inside] = np.sum(c[:, 1:] * d1 * powers[:, :5], axis=1) / h
            d2 = (np.arange(2, 6) * np.arange(1, 5))[None, :, None]
            out_qdd[inside] = np.sum(c[:, 2:] * d2 * powers[:, :4], axis=1) / h**2
            if self._residual is None:
                out_e[inside] = (1 - s) * self.effort[idx] + s * self.effort[idx + 1]
            else:
                out_e[inside] = (_call(self.inverse_dynamics, out_q[inside], out_qd[inside],
                                       out_qdd[inside])
                                 + (1 - s) * self._residual[idx] + s * self._residual[idx + 1])
        return NominalSample(t=t, q=out_q, qd=out_qd, qdd=out_qdd, effort=out_e)


def _call(inverse_dynamics, q, qd, qdd) -> np.ndarray:
    """``inverse_dynamics`` on rows of states, each shape (K, n): the torques, (K, n).

    Raises
    ------
    ProblemError
        A result that is not ``n`` torques per state.
    """
    tau = np.asarray(inverse_dynamics(q.T, qd.T, qdd.T), dtype=float)
    if tau.size != q.size:
        raise ProblemError(f"`inverse_dynamics` must map (n, K) arrays to shape "
                           f"{q.T.shape}, got {tau.shape}")
    return tau.reshape(q.shape[1], q.shape[0]).T


def _quintic_coefficients(t, q, qd, qdd) -> np.ndarray:
    """Coefficients ``c_j`` of ``q(s) = sum_j c_j s^j``, ``s`` in [0, 1] per interval.

    Returns
    -------
    ndarray, shape (K - 1, 6, n)
    """
    if t.size < 2:
        return np.zeros((0, 6, q.shape[1]))
    h = np.diff(t)[:, None]
    p0, p1 = q[:-1], q[1:]
    v0, v1 = qd[:-1] * h, qd[1:] * h
    a0, a1 = qdd[:-1] * h**2, qdd[1:] * h**2
    dp = p1 - p0
    c3 = 10 * dp - 6 * v0 - 4 * v1 - 1.5 * a0 + 0.5 * a1
    c4 = -15 * dp + 8 * v0 + 7 * v1 + 1.5 * a0 - a1
    c5 = 6 * dp - 3 * v0 - 3 * v1 - 0.5 * a0 + 0.5 * a1
    return np.stack([p0, v0, 0.5 * a0, c3, c4, c5], axis=1)
