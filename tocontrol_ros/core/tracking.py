"""Executing a planned trajectory on a simulated arm: nominal torques plus PD feedback.

The paper's case for the convexified control set is that its controls stay strictly inside
the box ``|u_i| <= 1``, which leaves room for feedback, where a bang-bang control has none.
This module is the experiment: a plant (the true dynamics, which may differ from the
planning model) integrated at a fixed step, driven by

    u = clip(u_nom + Kp e + Kd de, -1, 1),    e = q_des - q,  de = qd_des - qd,

in normalised units (``u = tau / tau_max`` of the *planning* model), computed once per
control period and held over it (zero-order hold), the applied torque being
``tau = u tau_max`` plus optional actuator noise.

Timing, per control period ``[t_k, t_k + h]``:

- the feedback uses the state measured at ``t_k`` and the desired state at ``t_k``;
- the feedforward ``u_nom`` is the nominal torque at the *middle* of the period,
  ``t_k + h/2``. The plan is known ahead of time, so this costs nothing on a real controller,
  and it makes the hold a midpoint rule: second-order accurate in ``h``, where holding the
  value at ``t_k`` would delay the torques by ``h/2`` (a first-order error);
- the plant integrates the true dynamics with classical RK4 at the simulation step
  (``sim_rate``, an integer multiple of ``control_rate``), the torque constant.

Interpolation of the nominal trajectory (:class:`NominalTrajectory`): between two samples the
position is the quintic Hermite polynomial that matches ``q, qd, qdd`` at both ends (so
``q`` is C2 and velocities and accelerations are its derivatives, consistent with samples
of one smooth motion, which is what the planner publishes); the nominal torque is linear
between samples (its error is at most ``dt^2/8 max|tau''|`` for a sample spacing ``dt``:
sample finely where the feedforward alone must be accurate). After the last sample the
trajectory holds the last position at rest; the tracker then feeds forward the planning
model's static torque there (gravity), not the last nominal torque (which, for a
time-optimal motion, is braking).

Everything here is pure numerics (numpy, CasADi); the ROS node is
:mod:`tocontrol_ros.tracker`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .errors import ProblemError
from .model import Body, RobotModel

__all__ = [
    "NominalSample",
    "NominalTrajectory",
    "PlantConfig",
    "TrackingGains",
    "make_plant_model",
    "TrackingLog",
    "TrackingSummary",
    "StepReport",
    "Tracker",
    "TrackingResult",
    "simulate",
]

#: A run is counted as saturated at a control instant when some joint's unclipped command
#: exceeds the bound by more than this (round-off of a nominal control sitting at 1).
SATURATION_TOL = 1e-12
#: RK4 substeps per control period up to which the period is one unrolled expression;
#: beyond, a single step is mapped (smaller graph, a little more call overhead).
MAX_UNROLLED_SUBSTEPS = 16
#: Largest number of control periods simulated in one call to CasADi.
MAX_CHUNK = 1024
#: Upper bound of ``sim_rate / control_rate`` (a guard against typos such as 1e6).
MAX_SUBSTEPS = 1000


def _array(name: str, value, shape: tuple[int, ...] | None = None,
           ndim: int | None = None) -> np.ndarray:
    """A finite float array, with the argument named in every error."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"`{name}` must be numeric, got {value!r}") from exc
    if shape is not None and arr.shape != shape:
        raise ProblemError(f"`{name}` must have shape {shape}, got {arr.shape}")
    if ndim is not None and arr.ndim != ndim:
        raise ProblemError(f"`{name}` must be {ndim}-dimensional, got shape {arr.shape}")
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        raise ProblemError(f"`{name}` must be finite; element {tuple(int(i) for i in bad[0])} "
                           f"is {float(arr[tuple(bad[0])])}")
    return arr


# --------------------------------------------------------------- nominal trajectory
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

    Raises
    ------
    ProblemError
        Wrong shapes, no samples, NaN or infinite values, times that are negative or not
        strictly increasing; the message names the argument and the first offending entry.

    Notes
    -----
    ``evaluate(t)`` uses, on each interval, the quintic Hermite polynomial through
    ``(q, qd, qdd)`` at both ends (C2 across samples) and linear interpolation for
    ``effort``. Before ``t[0]`` it returns the first sample; after ``t[-1]`` it holds the last
    position with zero velocity and acceleration and ``hold_effort``.
    """

    def __init__(self, t, q, qd, qdd, effort, hold_effort=None, joint_names=None) -> None:
        t = _array("t", t, ndim=1)
        if t.size == 0:
            raise ProblemError("`t` must hold at least one sample, got none")
        k = t.size
        q = _array("q", q, ndim=2)
        if q.shape[0] != k:
            raise ProblemError(f"`q` must have shape ({k}, n) to match `t`, got {q.shape}")
        n = q.shape[1]
        if n == 0:
            raise ProblemError("`q` must have at least one joint (column), got shape "
                               f"{q.shape}")
        qd = _array("qd", qd, shape=(k, n))
        qdd = _array("qdd", qdd, shape=(k, n))
        effort = _array("effort", effort, shape=(k, n))
        if t[0] < 0:
            raise ProblemError(f"`t` must start at a time >= 0, got t[0] = {float(t[0])!r}")
        steps = np.diff(t)
        bad = np.flatnonzero(steps <= 0)
        if bad.size:
            i = int(bad[0])
            raise ProblemError(f"`t` must be strictly increasing; t[{i}] = {float(t[i])!r} "
                               f"is followed by t[{i + 1}] = {float(t[i + 1])!r}")
        hold = np.zeros(n) if hold_effort is None else _array("hold_effort", hold_effort,
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

    @property
    def duration(self) -> float:
        """Time of the last sample (s)."""
        return float(self.t[-1])

    def __len__(self) -> int:
        return self.t.size

    def with_hold_effort(self, hold_effort) -> NominalTrajectory:
        """The same samples with another torque held after the end, shape (n,) (N m)."""
        return NominalTrajectory(self.t, self.q, self.qd, self.qdd, self.effort,
                                 hold_effort=hold_effort, joint_names=self.joint_names)

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
            out_e[inside] = (1 - s) * self.effort[idx] + s * self.effort[idx + 1]
        return NominalSample(t=t, q=out_q, qd=out_qd, qdd=out_qdd, effort=out_e)


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


# ------------------------------------------------------------------- plant and gains
@dataclass(frozen=True)
class PlantConfig:
    """The simulated plant: how the true arm differs from the planning model, and its timing.

    The defaults make the plant identical to the planning model, without noise.

    Attributes
    ----------
    mass_scale : float
        Factor on every body's mass (> 0). Centres of mass stay; the rotational inertia
        about them is scaled by ``inertia_scale`` only (set both for uniformly heavier
        links).
    inertia_scale : float
        Factor on every body's inertia tensor about its centre of mass (> 0).
    friction_scale : float
        Factor on the viscous friction (URDF damping) of every joint (>= 0).
    payload_mass : float
        Point mass (kg, >= 0) at the tip frame's origin, lumped into the last body
        (parallel-axis theorem).
    torque_noise : float
        Standard deviation of Gaussian torque noise, as a fraction of ``tau_max`` (>= 0);
        one draw per joint and control period, added to the applied torque.
    noise_seed : int
        Seed of the noise.
    initial_offset : tuple of float
        Added to the plant's initial state: ``n`` position offsets (rad, m), or ``2n``
        values (positions, then velocities). Empty: none.
    sim_rate : float
        Integration rate of the plant (Hz): fixed-step RK4 with step ``1 / sim_rate``.
    control_rate : float
        Rate of the control law (Hz); ``sim_rate`` must be an integer multiple of it.

    Raises
    ------
    ProblemError
        A value out of range, or rates whose ratio is not an integer.
    """

    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    friction_scale: float = 1.0
    payload_mass: float = 0.0
    torque_noise: float = 0.0
    noise_seed: int = 0
    initial_offset: tuple[float, ...] = ()
    sim_rate: float = 2000.0
    control_rate: float = 1000.0

    def __post_init__(self) -> None:
        checks = {"mass_scale": "positive", "inertia_scale": "positive",
                  "friction_scale": "non-negative", "payload_mass": "non-negative",
                  "torque_noise": "non-negative", "sim_rate": "positive",
                  "control_rate": "positive"}
        for name, kind in checks.items():
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError) as exc:
                raise ProblemError(f"`{name}` must be a number, got {value!r}") from exc
            ok = math.isfinite(value) and (value > 0 if kind == "positive" else value >= 0)
            if not ok:
                raise ProblemError(f"`{name}` must be {kind} and finite, got "
                                   f"{getattr(self, name)!r}")
            object.__setattr__(self, name, value)
        if isinstance(self.noise_seed, bool) or not isinstance(self.noise_seed,
                                                               (int, np.integer)):
            raise ProblemError(f"`noise_seed` must be an integer, got {self.noise_seed!r}")
        offset = _array("initial_offset", self.initial_offset, ndim=1)
        object.__setattr__(self, "initial_offset", tuple(float(v) for v in offset))
        ratio = self.sim_rate / self.control_rate
        if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
            raise ProblemError(f"`sim_rate` ({self.sim_rate:g} Hz) must be an integer multiple "
                               f"of `control_rate` ({self.control_rate:g} Hz)")
        if round(ratio) > MAX_SUBSTEPS:
            raise ProblemError(f"`sim_rate` / `control_rate` must be at most {MAX_SUBSTEPS}, "
                               f"got {ratio:g}")

    @property
    def substeps(self) -> int:
        """RK4 steps per control period."""
        return int(round(self.sim_rate / self.control_rate))

    @property
    def control_period(self) -> float:
        """Control period (s)."""
        return 1.0 / self.control_rate

    @property
    def identical(self) -> bool:
        """True when the plant's dynamics are the planning model's (offset and noise aside)."""
        return (self.mass_scale == 1.0 and self.inertia_scale == 1.0
                and self.friction_scale == 1.0 and self.payload_mass == 0.0)

    def offset(self, n: int) -> np.ndarray:
        """Initial-state offset for ``n`` joints, shape (2n,).

        Raises
        ------
        ProblemError
            When ``initial_offset`` has neither 0, ``n`` nor ``2n`` values.
        """
        off = np.asarray(self.initial_offset, dtype=float)
        if off.size == 0:
            return np.zeros(2 * n)
        if off.size == n:
            return np.concatenate([off, np.zeros(n)])
        if off.size == 2 * n:
            return off.copy()
        raise ProblemError(f"`initial_offset` must have 0, {n} (positions) or {2 * n} "
                           f"(positions, velocities) values, got {off.size}")


@dataclass(frozen=True)
class TrackingGains:
    """PD gains in normalised units: ``u = u_nom + kp e + kd de``.

    Attributes
    ----------
    kp : float or tuple of float
        Per joint, in 1/rad (1/m for prismatic joints): the control (fraction of
        ``tau_max``) per unit position error. A scalar applies to every joint.
    kd : float or tuple of float
        Per joint, in s/rad (s/m). A scalar applies to every joint.

    Raises
    ------
    ProblemError
        Negative or non-finite gains; :meth:`per_joint` also for a wrong number of them.
    """

    kp: float | tuple[float, ...] = 0.0
    kd: float | tuple[float, ...] = 0.0

    def __post_init__(self) -> None:
        for name in ("kp", "kd"):
            value = getattr(self, name)
            arr = _array(name, value)
            if arr.ndim > 1:
                raise ProblemError(f"`{name}` must be a number or a sequence of numbers, got "
                                   f"shape {arr.shape}")
            if np.any(arr < 0):
                raise ProblemError(f"`{name}` must be >= 0, got {arr.tolist()}")
            object.__setattr__(self, name, float(arr) if arr.ndim == 0
                               else tuple(float(v) for v in arr))

    def per_joint(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(kp, kd)`` spread to ``n`` joints, each shape (n,)."""
        out = []
        for name in ("kp", "kd"):
            value = getattr(self, name)
            if isinstance(value, float):
                out.append(np.full(n, value))
            elif len(value) == 1:
                out.append(np.full(n, value[0]))
            elif len(value) == n:
                out.append(np.array(value))
            else:
                raise ProblemError(f"`{name}` must be one value or {n} (one per joint), got "
                                   f"{len(value)}")
        return out[0], out[1]


def make_plant_model(model: RobotModel, plant: PlantConfig) -> RobotModel:
    """The true arm: ``model`` with the masses, inertias, friction and payload of ``plant``.

    Parameters
    ----------
    model : RobotModel
        The planning model.
    plant : PlantConfig

    Returns
    -------
    RobotModel
        ``model`` itself when ``plant.identical``; else a new model (its own function cache).
    """
    if plant.identical:
        return model
    bodies = [dataclasses.replace(b, mass=b.mass * plant.mass_scale,
                                  inertia=b.inertia * plant.inertia_scale)
              for b in model.bodies]
    if plant.payload_mass > 0:
        bodies[-1] = _add_point_mass(bodies[-1], plant.payload_mass,
                                     np.asarray(model.tip_translation, dtype=float))
    return dataclasses.replace(model, bodies=tuple(bodies),
                               damping=model.damping * plant.friction_scale)


def _add_point_mass(body: Body, mass: float, where: np.ndarray) -> Body:
    """``body`` with a point mass (kg) at ``where`` (its frame, m) lumped in."""
    total = body.mass + mass
    com = (body.mass * body.com + mass * where) / total

    def shift(m, d):
        return m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))

    inertia = body.inertia + shift(body.mass, body.com - com) + shift(mass, where - com)
    return dataclasses.replace(body, mass=total, com=com, inertia=inertia)


# ------------------------------------------------------------------- logs and summary
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


class _RunStats:
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


# --------------------------------------------------------------------------- tracker
def _plant_period_function(plant_model: RobotModel, substeps: int, h: float) -> ca.Function:
    """``(x, tau) -> x`` after ``substeps`` RK4 steps of length ``h`` with ``tau`` held."""
    n = plant_model.n
    fd = plant_model.function("fd")
    x = ca.SX.sym("x", 2 * n)
    tau = ca.SX.sym("tau", n)

    def f(z):
        return ca.vertcat(z[n:], fd(z[:n], z[n:], tau))

    def rk4(z):
        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        return z + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

    if substeps <= MAX_UNROLLED_SUBSTEPS:
        z = x
        for _ in range(substeps):
            z = rk4(z)
        return ca.Function("plant_period", [x, tau], [z], ["x", "tau"], ["x_next"])
    step = ca.Function("plant_step", [x, tau], [rk4(x)], ["x", "tau"], ["x_next"])
    acc = step.mapaccum("plant_steps", substeps)
    xm = ca.MX.sym("x", 2 * n)
    tm = ca.MX.sym("tau", n)
    traj = acc(xm, ca.repmat(tm, 1, substeps))
    return ca.Function("plant_period", [xm, tm], [traj[:, -1]], ["x", "tau"], ["x_next"])


class Tracker:
    """A simulated arm under the tracking law, advanced in whole control periods.

    Parameters
    ----------
    model : RobotModel
        The planning model: its ``tau_max`` normalises the controls, its static torque is
        fed forward while holding, its kinematics measure end-effector errors.
    plant : PlantConfig
        The true arm and the timing.
    gains : TrackingGains
        PD gains (zero: feedforward only).
    q0 : array_like, shape (n,)
        Configuration the plant starts at, before ``plant.initial_offset`` (rad, m); it is
        also the configuration held until the first trajectory.
    qd0 : array_like, shape (n,), optional
        Initial velocity (default zero).
    compile : bool
        Compile the control period (law and RK4 substeps) to C on first use (about 0.3 s,
        then cached on disk; see :mod:`tocontrol_ros.core.compiled`): about 4 us per period
        instead of 12 for the paper's arm. Without a C compiler CasADi's virtual machine runs
        it.

    Notes
    -----
    The time ``t`` always sits on a control instant. :meth:`start` switches to a new
    trajectory at the current instant, from the current plant state (the old one is
    summarised as preempted). :meth:`advance` simulates the periods up to a time.
    """

    def __init__(self, model: RobotModel, plant: PlantConfig | None = None,
                 gains: TrackingGains | None = None, q0=None, qd0=None,
                 compile: bool = True) -> None:
        self.model = model
        self._compile = compile
        #: How the period function runs: "compiled", "cached", "virtual machine (...)".
        self.compile_status = "virtual machine (not compiled)"
        self.plant = plant if plant is not None else PlantConfig()
        self.gains = gains if gains is not None else TrackingGains()
        n = model.n
        self.kp, self.kd = self.gains.per_joint(n)
        if q0 is None:
            raise ProblemError("`q0` must give the initial configuration, shape "
                               f"({n},); got None")
        q0 = _array("q0", q0, shape=(n,))
        qd0 = np.zeros(n) if qd0 is None else _array("qd0", qd0, shape=(n,))
        self.plant_model = make_plant_model(model, self.plant)
        self._period = _plant_period_function(self.plant_model, self.plant.substeps,
                                              1.0 / self.plant.sim_rate)
        self.h = self.plant.control_period
        self.tau_max = np.asarray(model.tau_max, dtype=float)
        self._continuous = (~np.isfinite(model.q_lower)) & np.array(
            [b.kind == "revolute" for b in model.bodies])
        self._rng = np.random.default_rng(self.plant.noise_seed)
        self._noise_std = self.plant.torque_noise * self.tau_max
        self.x = np.concatenate([q0, qd0]) + self.plant.offset(n)
        self.step_index = 0
        self.nominal: NominalTrajectory | None = None
        self._start_index = 0
        self._stats: _RunStats | None = None
        self._hold_q = q0.copy()
        self._hold_u = self._static_control(q0)
        self._chunks: dict = {}

    # ------------------------------------------------------------------ state
    @property
    def t(self) -> float:
        """Simulation time (s), a multiple of the control period."""
        return self.step_index * self.h

    @property
    def q(self) -> np.ndarray:
        """Plant positions, shape (n,)."""
        return self.x[:self.model.n].copy()

    @property
    def qd(self) -> np.ndarray:
        """Plant velocities, shape (n,)."""
        return self.x[self.model.n:].copy()

    @property
    def running(self) -> bool:
        """True while a trajectory is being executed (not yet at its end)."""
        return self._stats is not None

    def trajectory_time(self) -> float:
        """Time since the current trajectory started (s); NaN without one."""
        if self.nominal is None:
            return float("nan")
        return (self.step_index - self._start_index) * self.h

    def _static_control(self, q: np.ndarray) -> np.ndarray:
        """Normalised torque that holds ``q`` at rest in the planning model (gravity)."""
        tau = self.model.bias(q, np.zeros(self.model.n))
        return tau / self.tau_max

    def _law_function(self) -> ca.Function:
        """One control period with the law: ``(x, q_des, qd_des, u_nom, noise) -> (x, u, sat)``.

        Gains, limits and the continuous-joint mask are baked in as constants.
        """
        n = self.model.n
        x = ca.SX.sym("x", 2 * n)
        q_des, qd_des, u_nom, noise = (ca.SX.sym(name, n) for name in
                                       ("q_des", "qd_des", "u_nom", "noise"))
        e = q_des - x[:n]
        two_pi = 2 * math.pi
        wrapped = math.pi - ((math.pi - e) - two_pi * ca.floor((math.pi - e) / two_pi))
        cont = ca.DM(self._continuous.astype(float))
        e = cont * wrapped + (1 - cont) * e
        v = u_nom + ca.DM(self.kp) * e + ca.DM(self.kd) * (qd_des - x[n:])
        u = ca.fmin(ca.fmax(v, -1.0), 1.0)
        saturated = ca.fabs(v) > 1.0 + SATURATION_TOL
        x_next = self._period(x, u * ca.DM(self.tau_max) + noise)
        return ca.Function("tracking_period", [x, q_des, qd_des, u_nom, noise],
                           [x_next, u, saturated])

    def _chunk_function(self, size: int) -> ca.Function:
        """``size`` control periods in one call (``mapaccum`` of the period law)."""
        if size not in self._chunks:
            if "law" not in self._chunks:
                law = self._law_function()
                if self._compile:
                    from .compiled import compile_function

                    law, self.compile_status = compile_function(law)
                self._chunks["law"] = law
            self._chunks[size] = self._chunks["law"].mapaccum(f"tracking_{size}", size)
        return self._chunks[size]

    def _simulate_chunks(self, q_des, qd_des, u_nom, noise):
        """Run the law over ``K`` periods from ``self.x``, in few calls to CasADi.

        Chunks of power-of-two sizes (``mapaccum``), so that the per-period cost is the
        compiled graph's, not Python's.

        Returns
        -------
        x_next : ndarray, shape (K, 2n)
            State at the end of each period.
        u : ndarray, shape (K, n)
        saturated : ndarray of bool, shape (K, n)
        """
        count = q_des.shape[0]
        xs, us, sats = [], [], []
        x = self.x
        done = 0
        while done < count:
            size = min(MAX_CHUNK, 1 << ((count - done).bit_length() - 1))
            rows = slice(done, done + size)
            fun = self._chunk_function(size)
            x_out, u, sat = fun(x, q_des[rows].T, qd_des[rows].T, u_nom[rows].T,
                                noise[rows].T)
            x_out = np.array(x_out).T
            xs.append(x_out)
            us.append(np.array(u).T)
            sats.append(np.array(sat).T > 0.5)
            x = x_out[-1]
            done += size
        return np.vstack(xs), np.vstack(us), np.vstack(sats)

    def prepare(self) -> None:
        """Build (and compile) the control-period function now rather than on first use."""
        self._chunk_function(1)

    # ---------------------------------------------------------------- commands
    def start(self, nominal: NominalTrajectory) -> TrackingSummary | None:
        """Execute ``nominal`` from now, from the current plant state.

        Parameters
        ----------
        nominal : NominalTrajectory
            With ``n`` joints in the model's order.

        Returns
        -------
        TrackingSummary or None
            The summary of the trajectory it preempts, if one was running.
        """
        if not isinstance(nominal, NominalTrajectory):
            raise ProblemError(f"`nominal` must be a NominalTrajectory, got "
                               f"{type(nominal).__name__}")
        if nominal.n != self.model.n:
            raise ProblemError(f"`nominal` has {nominal.n} joints; the model has "
                               f"{self.model.n}")
        preempted = None
        if self._stats is not None:
            preempted = self._stats.summary("preempted", self.model)
        q_end = nominal.q[-1]
        self.nominal = nominal.with_hold_effort(self._static_control(q_end) * self.tau_max)
        self._start_index = self.step_index
        self._stats = _RunStats(self.model.n, nominal.duration, self.t)
        return preempted

    def advance(self, until: float) -> StepReport:
        """Simulate every control period that starts before ``until`` (s).

        Returns
        -------
        StepReport
            Empty log when ``until`` is not past the current time.
        """
        steps = int(math.ceil((until - self.t) / self.h - 1e-9))
        return self.run_periods(max(steps, 0))

    def run_periods(self, count: int) -> StepReport:
        """Simulate ``count`` control periods."""
        n = self.model.n
        if count <= 0:
            return StepReport(TrackingLog.concatenate([], n))
        idx = self.step_index + np.arange(count)
        t = idx * self.h
        if self.nominal is None:
            q_des = np.tile(self._hold_q, (count, 1))
            qd_des = np.zeros((count, n))
            u_nom = np.tile(self._hold_u, (count, 1))
            tau_traj = np.full(count, np.inf)
        else:
            tau_traj = (idx - self._start_index) * self.h
            des = self.nominal.evaluate(tau_traj)
            mid = self.nominal.evaluate(tau_traj + 0.5 * self.h)
            q_des, qd_des = des.q, des.qd
            u_nom = mid.effort / self.tau_max
        duration = self.nominal.duration if self.nominal is not None else 0.0
        active = tau_traj < duration - 1e-12

        noise = (self._rng.standard_normal((count, n)) * self._noise_std
                 if self.plant.torque_noise > 0 else np.zeros((count, n)))
        x_next, u_log, sat_log = self._simulate_chunks(q_des, qd_des, u_nom, noise)
        states = np.vstack([self.x[None, :], x_next[:-1]])
        q_log, qd_log = states[:, :n], states[:, n:]
        tau_log = u_log * self.tau_max + noise
        self.x = x_next[-1].copy()
        self.step_index += count

        error = q_des - q_log
        cont = self._continuous
        if cont.any():
            error[:, cont] = np.pi - np.mod(np.pi - error[:, cont], 2 * np.pi)
        log = TrackingLog(t=t, q=q_log, qd=qd_log, q_des=q_des, qd_des=qd_des, error=error,
                          error_rate=qd_des - qd_log, u_nom=u_nom, u=u_log, tau=tau_log,
                          saturated=sat_log, active=active)
        summaries = ()
        if self._stats is not None:
            ending = np.flatnonzero(~active)
            if ending.size:
                # Counted up to and including the first instant at or after the end.
                rows = np.arange(count) <= ending[0]
                self._stats.add(log, rows)
                summaries = (self._stats.summary("completed", self.model),)
                self._stats = None
            else:
                self._stats.add(log, np.ones(count, dtype=bool))
        return StepReport(log=log, summaries=summaries)


# ------------------------------------------------------------------ one-shot
@dataclass(frozen=True)
class TrackingResult:
    """Outcome of :func:`simulate`.

    Attributes
    ----------
    log : TrackingLog
        Every control period, from the start to the end of the hold.
    summary : TrackingSummary
        The trajectory's metrics (to its end; the hold after it is not counted).
    wall_time : float
        Wall time of the simulation (s), for speed figures.
    """

    log: TrackingLog
    summary: TrackingSummary
    wall_time: float = field(default=0.0)


def simulate(model: RobotModel, nominal: NominalTrajectory, plant: PlantConfig | None = None,
             gains: TrackingGains | None = None, hold: float = 0.0) -> TrackingResult:
    """Execute one trajectory from its own start state (plus the plant's initial offset).

    Parameters
    ----------
    model : RobotModel
        The planning model.
    nominal : NominalTrajectory
    plant : PlantConfig, optional
        Default: identical to ``model``, no noise.
    gains : TrackingGains, optional
        Default: zero (feedforward only).
    hold : float
        Time to keep simulating after the end (s), holding the final configuration.

    Returns
    -------
    TrackingResult
    """
    import time

    if not (math.isfinite(hold) and hold >= 0):
        raise ProblemError(f"`hold` must be >= 0 and finite, got {hold!r}")
    tracker = Tracker(model, plant, gains, q0=nominal.q[0], qd0=nominal.qd[0])
    start = time.perf_counter()
    tracker.start(nominal)
    logs, summary = [], None
    # One period past the end, so that the final instant is counted.
    report = tracker.advance(nominal.duration + tracker.h)
    logs.append(report.log)
    if report.summaries:
        summary = report.summaries[0]
    if hold > 0:
        logs.append(tracker.advance(tracker.t + hold).log)
    wall = time.perf_counter() - start
    if summary is None:  # pragma: no cover - advance always passes the end above
        raise RuntimeError("simulate: the trajectory did not finish")
    return TrackingResult(log=TrackingLog.concatenate(logs, model.n), summary=summary,
                          wall_time=wall)
