"""What a tracking run records: one row per control period, a summary per trajectory.

:class:`~tocontrol_ros.core.sim.tracking.Tracker` fills them; the tracker node publishes them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["StepReport", "TrackingLog", "TrackingSummary"]


@dataclass(frozen=True)
class TrackingLog:
    """What happened over ``K`` control periods, one row per period (values at its start).

    Attributes
    ----------
    t : ndarray, shape (K,)
        Simulation time at the start of each period (s).
    q, qd : ndarray, shape (K, n)
        Plant state at ``t`` (rad, rad/s).
    q_des, qd_des : ndarray, shape (K, n)
        Desired state at ``t``.
    error, error_rate : ndarray, shape (K, n)
        ``q_des - q`` (continuous joints wrapped into (-pi, pi]) and ``qd_des - qd``.
    u_nom : ndarray, shape (K, n)
        Feedforward (normalised), the nominal torque at the period's middle / ``tau_max``.
    u : ndarray, shape (K, n)
        Applied control (normalised), held over the period; ``|u| <= 1``.
    tau : ndarray, shape (K, n)
        Torque acting on the plant over the period (N m): ``u tau_max`` plus noise.
    saturated : ndarray of bool, shape (K, n)
        Where the command before clipping exceeded the bound.
    active : ndarray of bool, shape (K,)
        Inside a trajectory (False while holding).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    q_des: np.ndarray
    qd_des: np.ndarray
    error: np.ndarray
    error_rate: np.ndarray
    u_nom: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    saturated: np.ndarray
    active: np.ndarray

    def __len__(self) -> int:
        return self.t.size

    @staticmethod
    def concatenate(logs, n: int) -> TrackingLog:
        """One log from several consecutive ones."""
        logs = list(logs)
        names = [f.name for f in dataclasses.fields(TrackingLog)]
        if not logs:
            empty = {name: np.zeros((0, n)) for name in names}
            empty["t"] = np.zeros(0)
            empty["active"] = np.zeros(0, dtype=bool)
            empty["saturated"] = np.zeros((0, n), dtype=bool)
            return TrackingLog(**empty)
        return TrackingLog(**{name: np.concatenate([getattr(g, name) for g in logs])
                              for name in names})


@dataclass(frozen=True)
class TrackingSummary:
    """Metrics of one trajectory's execution, from its start to its end (or preemption).

    Errors are over the control instants inside the trajectory, ``0 <= t - t_start < T``,
    plus the first instant at or after its end, where the final errors are taken.

    Attributes
    ----------
    outcome : str
        ``"completed"`` or ``"preempted"``.
    duration : float
        Planned duration ``T`` (s).
    elapsed : float
        Time the trajectory actually ran (s).
    samples : int
        Control instants counted.
    max_error, rms_error : ndarray, shape (n,)
        Max and root-mean-square ``|q_des - q|`` per joint (rad).
    max_rate_error, rms_rate_error : ndarray, shape (n,)
        The same for ``qd_des - qd`` (rad/s).
    final_point_error : float
        ``|P(q) - P(q_des)|`` at the last instant counted (m), kinematics of the planning
        model (mass and friction mismatch leave kinematics alone).
    final_error : ndarray, shape (n,)
        ``q_des - q`` there (rad).
    saturated_fraction : float
        Fraction of the instants at which some joint's command was clipped.
    saturated_fraction_joint : ndarray, shape (n,)
        The same per joint.
    max_feedback : float
        Largest feedback share used, ``max |u_i - u_nom_i|`` (normalised).
    max_abs_u : float
        Largest ``|u_i|`` applied (never above 1).
    """

    outcome: str
    duration: float
    elapsed: float
    samples: int
    max_error: np.ndarray
    rms_error: np.ndarray
    max_rate_error: np.ndarray
    rms_rate_error: np.ndarray
    final_point_error: float
    final_error: np.ndarray
    saturated_fraction: float
    saturated_fraction_joint: np.ndarray
    max_feedback: float
    max_abs_u: float

    def as_dict(self, joint_names=None) -> dict[str, float | str]:
        """Flat key/value pairs (per-joint values keyed ``<metric>.<joint>``)."""
        n = self.max_error.size
        names = list(joint_names) if joint_names is not None else [str(i) for i in range(n)]
        out: dict[str, float | str] = {
            "outcome": self.outcome, "duration": self.duration, "elapsed": self.elapsed,
            "samples": float(self.samples), "final_point_error": self.final_point_error,
            "saturated_fraction": self.saturated_fraction,
            "max_feedback": self.max_feedback, "max_abs_u": self.max_abs_u}
        per_joint = {"max_error": self.max_error, "rms_error": self.rms_error,
                     "max_rate_error": self.max_rate_error,
                     "rms_rate_error": self.rms_rate_error, "final_error": self.final_error,
                     "saturated_fraction": self.saturated_fraction_joint}
        for key, values in per_joint.items():
            for name, v in zip(names, values, strict=True):
                out[f"{key}.{name}"] = float(v)
        return out


class RunStats:
    """Running sums of one trajectory's execution (memory independent of its length)."""

    def __init__(self, n: int, duration: float, t_start: float) -> None:
        self.duration, self.t_start = duration, t_start
        self.count = 0
        self.sum_sq = np.zeros(n)
        self.max_abs = np.zeros(n)
        self.sum_sq_rate = np.zeros(n)
        self.max_abs_rate = np.zeros(n)
        self.saturated_any = 0
        self.saturated_joint = np.zeros(n)
        self.max_feedback = 0.0
        self.max_abs_u = 0.0
        self.last_q = self.last_q_des = None
        self.last_t = t_start

    def add(self, log: TrackingLog, rows: np.ndarray) -> None:
        if not np.any(rows):
            return
        e, de = log.error[rows], log.error_rate[rows]
        self.count += int(rows.sum())
        self.sum_sq += np.sum(e**2, axis=0)
        self.max_abs = np.maximum(self.max_abs, np.abs(e).max(axis=0))
        self.sum_sq_rate += np.sum(de**2, axis=0)
        self.max_abs_rate = np.maximum(self.max_abs_rate, np.abs(de).max(axis=0))
        sat = log.saturated[rows]
        self.saturated_any += int(np.any(sat, axis=1).sum())
        self.saturated_joint += sat.sum(axis=0)
        self.max_feedback = max(self.max_feedback,
                                float(np.abs(log.u[rows] - log.u_nom[rows]).max()))
        self.max_abs_u = max(self.max_abs_u, float(np.abs(log.u[rows]).max()))
        last = np.flatnonzero(rows)[-1]
        self.last_q, self.last_q_des = log.q[last], log.q_des[last]
        self.last_error = log.error[last]
        self.last_t = float(log.t[last])

    def summary(self, outcome: str, model: RobotModel) -> TrackingSummary:
        count = max(self.count, 1)
        n = self.sum_sq.size
        if self.last_q is None:
            point_error, final = float("nan"), np.full(n, np.nan)
        else:
            point_error = float(np.linalg.norm(model.point(self.last_q)
                                               - model.point(self.last_q_des)))
            final = self.last_error
        return TrackingSummary(
            outcome=outcome, duration=self.duration, elapsed=self.last_t - self.t_start,
            samples=self.count, max_error=self.max_abs.copy(),
            rms_error=np.sqrt(self.sum_sq / count), max_rate_error=self.max_abs_rate.copy(),
            rms_rate_error=np.sqrt(self.sum_sq_rate / count), final_point_error=point_error,
            final_error=np.array(final, dtype=float),
            saturated_fraction=self.saturated_any / count,
            saturated_fraction_joint=self.saturated_joint / count,
            max_feedback=self.max_feedback, max_abs_u=self.max_abs_u)


@dataclass(frozen=True)
class StepReport:
    """What :meth:`Tracker.advance` did.

    Attributes
    ----------
    log : TrackingLog
        One row per control period simulated.
    summaries : tuple of TrackingSummary
        Trajectories that ended during the advance (at most one, normally).
    """

    log: TrackingLog
    summaries: tuple[TrackingSummary, ...] = ()
