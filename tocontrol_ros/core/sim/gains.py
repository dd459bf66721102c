"""The tracker's feedback gains, and the stability of the sampled loop they close.

Per-joint gains in normalised units (``kp, kd``: fraction of ``tau_max`` per rad and per
rad/s, the same at every configuration) and model-derived gains (``bandwidth``: the
planning model's inertia matrix at the desired configuration times a critically damped
acceleration, plus integral action while holding). :func:`hold_spectral_radius` tells
whether a set of gains holds a configuration at a control period: the spectral radius of the
sampled closed loop (zero-order hold, state measured at each control instant), linearised at
rest there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.validate import finite_array

__all__ = ["INTEGRAL_RATIO", "MAX_DAMPING_STEP", "TrackingGains", "hold_spectral_radius"]

#: Largest ``2 zeta w h`` (the damping term's share of one control period ``h``) that
#: :class:`TrackingGains` accepts: the sampled double integrator under PD (zero-order hold)
#: is stable for ``2 zeta w h < 2`` (Jury), and half of that keeps a margin for a plant whose
#: inertia is below the model's.
MAX_DAMPING_STEP = 1.0
#: The hold's integral action runs at ``bandwidth / INTEGRAL_RATIO``: slow enough that the
#: PD's poles near ``-w`` stay dominant (Routh: stable for any ratio above 1 / (2 zeta)), fast
#: enough to remove a gravity mismatch within a second at ``w`` = 50 rad/s.
INTEGRAL_RATIO = 4.0


@dataclass(frozen=True)
class TrackingGains:
    """PD gains: ``u = u_nom + kp e + kd de + M(q_des) (w^2 e + 2 zeta w de + ki z) / tau_max``.

    Two parts, added: per-joint gains ``kp, kd`` in normalised units (diagonal, the same at
    every configuration), and model-derived gains from a ``bandwidth`` ``w``: the
    feedback is the planning model's inertia matrix at the desired configuration times a
    critically damped (``zeta = 1`` by default) acceleration ``w^2 e + 2 zeta w de``, so that
    every mode of the arm, including the light self-motion of two aligned joint axes, closes
    at ``w`` rad/s. While holding (after a trajectory's end, and before the first), the
    model-derived part adds integral action, ``ki = w^2 w / INTEGRAL_RATIO`` on
    ``z = integral of e dt`` (from zero at each hold, frozen while a joint saturates), so that
    the arm comes to rest on the held configuration even where the model's gravity is not the
    plant's. Per-joint diagonal gains set from the inertia's diagonal at one
    configuration do not: where two axes align (the Panda's joints 1 and 3), the inertia of
    their difference is a small fraction of either diagonal entry, and such gains exceed the
    control rate's stability bound there.

    Attributes
    ----------
    kp : float or tuple of float
        Per joint, in 1/rad (1/m for prismatic joints): the control (fraction of
        ``tau_max``) per unit position error. A scalar applies to every joint.
    kd : float or tuple of float
        Per joint, in s/rad (s/m). A scalar applies to every joint.
    bandwidth : float or tuple of float
        ``w``, rad/s (>= 0; zero: no model-derived part): per joint, the gains of that
        joint's commanded acceleration (a scalar for all, the usual choice). Bounded by the
        control period ``h`` through ``2 zeta w h <= MAX_DAMPING_STEP`` (checked by
        :class:`~tocontrol_ros.core.sim.tracking.Tracker`).
    damping_ratio : float
        ``zeta`` (> 0) of the model-derived part.

    Raises
    ------
    ProblemError
        Negative or non-finite gains; :meth:`per_joint` also for a wrong number of them.
    """

    kp: float | tuple[float, ...] = 0.0
    kd: float | tuple[float, ...] = 0.0
    bandwidth: float | tuple[float, ...] = 0.0
    damping_ratio: float = 1.0

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "bandwidth"):
            value = getattr(self, name)
            arr = finite_array(name, value)
            if arr.ndim > 1:
                raise ProblemError(f"`{name}` must be a number or a sequence of numbers, got "
                                   f"shape {arr.shape}")
            if np.any(arr < 0):
                raise ProblemError(f"`{name}` must be >= 0, got {arr.tolist()}")
            object.__setattr__(self, name, float(arr) if arr.ndim == 0
                               else tuple(float(v) for v in arr))
        zeta = finite_array("damping_ratio", self.damping_ratio)
        if zeta.ndim != 0 or not zeta > 0:
            raise ProblemError(f"`damping_ratio` must be a number > 0, got "
                               f"{self.damping_ratio!r}")
        object.__setattr__(self, "damping_ratio", float(zeta))

    @staticmethod
    def _spread(name: str, value, n: int) -> np.ndarray:
        if isinstance(value, float):
            return np.full(n, value)
        if len(value) == 1:
            return np.full(n, value[0])
        if len(value) == n:
            return np.array(value)
        raise ProblemError(f"`{name}` must be one value or {n} (one per joint), got "
                           f"{len(value)}")

    def per_joint(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(kp, kd)`` spread to ``n`` joints, each shape (n,)."""
        return self._spread("kp", self.kp, n), self._spread("kd", self.kd, n)

    def acceleration_gains(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The model-derived ``(w^2, 2 zeta w, ki)``, each shape (n,) (1/s^2, 1/s, 1/s^3)."""
        w = self._spread("bandwidth", self.bandwidth, n)
        return w ** 2, 2.0 * self.damping_ratio * w, w ** 3 / INTEGRAL_RATIO

    def check_rate(self, n: int, control_period: float) -> None:
        """Raise when the model-derived part is too fast for ``control_period`` (s).

        Raises
        ------
        ProblemError
            ``2 zeta w h > MAX_DAMPING_STEP``, naming the largest bandwidth allowed.
        """
        _, b, _ = self.acceleration_gains(n)
        if b.size and float(np.max(b)) * control_period > MAX_DAMPING_STEP:
            w_max = MAX_DAMPING_STEP / (2.0 * self.damping_ratio * control_period)
            raise ProblemError(
                f"`bandwidth` {float(np.max(b)) / (2 * self.damping_ratio):g} rad/s is above "
                f"the stability bound of the control period {control_period:g} s: at most "
                f"{w_max:g} rad/s (2 zeta w h <= {MAX_DAMPING_STEP:g}, zeta = "
                f"{self.damping_ratio:g})")


def hold_spectral_radius(model, gains: TrackingGains, q, control_period: float) -> float:
    """Spectral radius of the sampled PD loop holding ``q`` at rest (below 1: stable).

    The plant is the model linearised at rest at ``q`` (inertia ``M(q)``, viscous friction;
    gravity cancelled by the fed-forward static torque), the torque
    ``tau = -(K_p dq + K_d dqd)`` on the deviation from rest at ``q``, computed from the state
    at each control instant and held over the period;
    ``K_p = diag(kp tau_max) + M(q) diag(w^2)``, ``K_d`` likewise (the hold's slow integral
    action left out).

    Parameters
    ----------
    model : RobotModel
    gains : TrackingGains
    q : array_like, shape (n,)
        The held configuration (rad, m).
    control_period : float
        ``h`` (s).

    Returns
    -------
    float
        The largest modulus of the closed loop's eigenvalues over one period.
    """
    n = model.n
    q = finite_array("q", q, shape=(n,))
    tau_max = np.asarray(model.tau_max, dtype=float)
    kp, kd = gains.per_joint(n)
    kp_acc, kd_acc, _ = gains.acceleration_gains(n)
    inertia = model.mass_matrix(q)
    stiff = np.diag(kp * tau_max) + inertia * kp_acc[None, :]
    damp = np.diag(kd * tau_max) + inertia * kd_acc[None, :]
    inv = np.linalg.inv(inertia)
    # [q, qd, tau]' = F [q, qd, tau] with tau constant: its exponential is the ZOH step.
    f = np.zeros((3 * n, 3 * n))
    f[:n, n:2 * n] = np.eye(n)
    f[n:2 * n, n:2 * n] = -inv @ np.diag(np.asarray(model.damping, dtype=float))
    f[n:2 * n, 2 * n:] = inv
    step = expm(f * float(control_period))
    closed = step[:2 * n, :2 * n] - step[:2 * n, 2 * n:] @ np.hstack([stiff, damp])
    return float(np.max(np.abs(np.linalg.eigvals(closed))))
