"""What every solution answers: a sample of states, torques and costates, at any times.

:class:`TrajectorySample` is the common shape of a sampled motion (whatever method made it);
:class:`InverseDynamicsTrajectory` is the base of a joint path whose torques are its inverse
dynamics (the bounded B-spline solutions, the first motions, a path timed by TOPP-RA). The
maximum principle's solution, evaluated from its canonical state, is
:class:`~tocontrol_ros.core.indirect.trajectory.Trajectory`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

__all__ = ["Motion", "TrajectorySample", "InverseDynamicsTrajectory", "sample_times"]


def sample_times(duration: float, dt: float) -> np.ndarray:
    """Times every ``dt`` seconds from 0 to ``duration`` (s), always ending at ``duration``.

    Raises
    ------
    ValueError
        ``dt`` not positive and finite.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"`dt` must be positive and finite, got {dt!r}")
    t = np.arange(0.0, duration, dt)
    if len(t) == 0 or duration - t[-1] > 1e-12:
        t = np.append(t, duration)
    else:
        t[-1] = duration
    return t


@dataclass(frozen=True)
class TrajectorySample:
    """Values of a trajectory at ``len(t)`` times.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Times (s).
    q, qd, qdd : ndarray, shape (K, n)
        Joint positions (rad, m), velocities (rad/s) and accelerations (rad/s^2).
    u : ndarray, shape (K, n)
        Normalised controls, ``sum u_i^(2k) = 1``.
    tau : ndarray, shape (K, n)
        Nominal joint torques (N m): ``u * tau_max * (1 - reserve)``.
    psi : ndarray, shape (K, 2n)
        Costates.
    S : ndarray, shape (K, n)
        Switching functions.
    H : ndarray, shape (K,)
        Hamiltonian (zero along an exact solution).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    psi: np.ndarray
    S: np.ndarray
    H: np.ndarray


class Motion(Protocol):
    """What a planned motion answers, whichever method made it (the method contract's).

    Attributes
    ----------
    T : float
        Duration (s).
    n : int
        Joints.
    joint_names : tuple of str
    """

    T: float
    n: int

    def state(self, t) -> np.ndarray:
        """``x = (q, qd)`` at times ``t`` (s), shape (K, 2n)."""

    def evaluate(self, t) -> TrajectorySample:
        """Everything at times ``t`` (s, shape (K,))."""

    def sample(self, dt: float) -> TrajectorySample:
        """Everything every ``dt`` (s) from 0 to ``T``, ``T`` included."""

    def control(self, t: float) -> np.ndarray:
        """Normalised torques at one time ``t`` (s), shape (n,)."""


class InverseDynamicsTrajectory:
    """What a joint path whose torques are its inverse dynamics answers: states, samples.

    The bounded B-spline solutions and the first motions share it. A subclass sets ``T``
    (s), ``n`` and ``_scale`` (``tau_max`` times the torque scale, (n,)) and defines
    ``_path(t)`` (``q``, ``qd``, ``qdd`` at times ``t`` (K,), each (K, n)) and
    ``_controls(q, qd, qdd)`` (the normalised torques, (K, n)). It has no costates
    (``psi``, ``S`` and ``H`` are NaN).
    """

    def state(self, t) -> np.ndarray:
        """``(x, psi)`` at times ``t``, shape (K, 4n); ``psi`` is NaN (no costates)."""
        q, qd, _ = self._path(np.atleast_1d(np.asarray(t, dtype=float)))
        return np.hstack([q, qd, np.full((len(q), 2 * self.n), np.nan)])

    def evaluate(self, t) -> TrajectorySample:
        """All quantities at times ``t`` (s), scalar or shape (K,)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        q, qd, qdd = self._path(t)
        u = self._controls(q, qd, qdd)
        nan = np.full((len(t), self.n), np.nan)
        return TrajectorySample(t=t, q=q, qd=qd, qdd=qdd, u=u, tau=u * self._scale,
                                psi=np.hstack([nan, nan]), S=nan, H=np.full(len(t), np.nan))

    def sample(self, dt: float) -> TrajectorySample:
        """Samples every ``dt`` seconds from 0, always including ``T``."""
        return self.evaluate(sample_times(self.T, dt))

    def control(self, t: float) -> np.ndarray:
        """Normalised control at one time, shape (n,)."""
        return self._controls(*self._path(np.atleast_1d(float(t))))[0]
