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

The nominal trajectory (:mod:`~tocontrol_ros.core.sim.nominal`), the plant
(:mod:`~tocontrol_ros.core.sim.plant`) and the logs
(:mod:`~tocontrol_ros.core.sim.tracking_log`) live
next to this module, which holds the control law and the tracker that runs it period by
period; their names are re-exported here.

Everything here is pure numerics (numpy, CasADi); the ROS node is
:mod:`tocontrol_ros.nodes.tracker`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.sim.nominal import NominalSample, NominalTrajectory
from tocontrol_ros.core.sim.plant import PlantConfig, make_plant_model, plant_period_function
from tocontrol_ros.core.sim.tracking_log import RunStats, StepReport, TrackingLog, TrackingSummary
from tocontrol_ros.core.validate import finite_array

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
#: Largest number of control periods simulated in one call to CasADi.
MAX_CHUNK = 1024


# -------------------------------------------------------------------------- gains
#: Largest ``2 zeta w h`` (the damping term's share of one control period ``h``) that
#: :class:`TrackingGains` accepts: the sampled double integrator under PD (zero-order hold)
#: is stable for ``2 zeta w h < 2`` (Jury), and half of that keeps a margin for a plant whose
#: inertia is below the model's.
MAX_DAMPING_STEP = 1.0


@dataclass(frozen=True)
class TrackingGains:
    """PD gains: ``u = u_nom + kp e + kd de + M(q_des) (w^2 e + 2 zeta w de) / tau_max``.

    Two parts, added: per-joint gains ``kp, kd`` in normalised units (diagonal, the same at
    every configuration), and model-derived gains from a ``bandwidth`` ``w``: the
    feedback is the planning model's inertia matrix at the desired configuration times a
    critically damped (``zeta = 1`` by default) acceleration ``w^2 e + 2 zeta w de``, so that
    every mode of the arm, including the light self-motion of two aligned joint axes, closes
    at ``w`` rad/s. Per-joint diagonal gains set from the inertia's diagonal at one
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
        joint's commanded acceleration (a scalar for all, the usual choice). Bounded by the control period ``h``
        through ``2 zeta w h <= MAX_DAMPING_STEP`` (checked by :class:`Tracker`).
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

    def acceleration_gains(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The model-derived part's ``(w^2, 2 zeta w)``, each shape (n,) (1/s^2, 1/s)."""
        w = self._spread("bandwidth", self.bandwidth, n)
        return w ** 2, 2.0 * self.damping_ratio * w

    def check_rate(self, n: int, control_period: float) -> None:
        """Raise when the model-derived part is too fast for ``control_period`` (s).

        Raises
        ------
        ProblemError
            ``2 zeta w h > MAX_DAMPING_STEP``, naming the largest bandwidth allowed.
        """
        _, b = self.acceleration_gains(n)
        if b.size and float(np.max(b)) * control_period > MAX_DAMPING_STEP:
            w_max = MAX_DAMPING_STEP / (2.0 * self.damping_ratio * control_period)
            raise ProblemError(
                f"`bandwidth` {float(np.max(b)) / (2 * self.damping_ratio):g} rad/s is above "
                f"the stability bound of the control period {control_period:g} s: at most "
                f"{w_max:g} rad/s (2 zeta w h <= {MAX_DAMPING_STEP:g}, zeta = "
                f"{self.damping_ratio:g})")


# --------------------------------------------------------------------------- tracker
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
        then cached on disk; see :mod:`tocontrol_ros.core.robot.compiled`), several times faster
        per period than CasADi's virtual machine, which runs it without a C compiler.

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
        self.gains.check_rate(n, self.plant.control_period)
        self.kp_acc, self.kd_acc = self.gains.acceleration_gains(n)
        if q0 is None:
            raise ProblemError("`q0` must give the initial configuration, shape "
                               f"({n},); got None")
        q0 = finite_array("q0", q0, shape=(n,))
        qd0 = np.zeros(n) if qd0 is None else finite_array("qd0", qd0, shape=(n,))
        self.plant_model = make_plant_model(model, self.plant)
        self._period = plant_period_function(self.plant_model, self.plant.substeps,
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
        self._start_elapsed = 0.0
        self._stats: RunStats | None = None
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
        return (self.step_index - self._start_index) * self.h + self._start_elapsed

    def commanded(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The commanded position and velocity at simulation time ``t`` (s), shape (n,) each.

        The running nominal's (its hold after the end), or the held configuration at rest.
        """
        if self.nominal is None:
            return self._hold_q.copy(), np.zeros(self.model.n)
        des = self.nominal.evaluate(t - self._start_index * self.h + self._start_elapsed)
        return des.q[0], des.qd[0]

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
        de = qd_des - x[n:]
        v = u_nom + ca.DM(self.kp) * e + ca.DM(self.kd) * de
        if np.any(self.kp_acc > 0) or np.any(self.kd_acc > 0):
            # The model's inertia at the desired configuration: known ahead, smooth in time.
            inertia = self.model.mass_matrix_sym(q_des)
            acc = ca.DM(self.kp_acc) * e + ca.DM(self.kd_acc) * de
            v = v + ca.mtimes(inertia, acc) / ca.DM(self.tau_max)
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
                    from tocontrol_ros.core.robot.compiled import compile_function

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
    def start(self, nominal: NominalTrajectory, elapsed: float = 0.0
              ) -> TrackingSummary | None:
        """Execute ``nominal`` from now, from the current plant state.

        Parameters
        ----------
        nominal : NominalTrajectory
            With ``n`` joints in the model's order.
        elapsed : float
            The nominal's own time at the current instant (s, >= 0): a trajectory that took
            over between two control instants (a splice at its stamp) is this far along.

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
        if not (math.isfinite(elapsed) and elapsed >= 0.0):
            raise ProblemError(f"`elapsed` must be a finite time >= 0 (s), got {elapsed!r}")
        preempted = None
        if self._stats is not None:
            preempted = self._stats.summary("preempted", self.model)
        q_end = nominal.q[-1]
        self.nominal = nominal.with_hold_effort(self._static_control(q_end) * self.tau_max)
        self._start_index = self.step_index
        self._start_elapsed = float(elapsed)
        self._stats = RunStats(self.model.n, nominal.duration, self.t)
        return preempted

    def reset(self, q, qd=None) -> TrackingSummary | None:
        """Put the plant at ``(q, qd)`` now and hold ``q``, as after start-up.

        For re-executing a recorded run from its recorded initial state. The time goes on
        (stamps stay monotonic); the noise generator restarts from ``noise_seed``; no
        ``initial_offset`` is added (``q`` is the plant's state).

        Parameters
        ----------
        q : array_like, shape (n,)
            Plant positions (rad, m).
        qd : array_like, shape (n,), optional
            Plant velocities (rad/s, m/s); default zero.

        Returns
        -------
        TrackingSummary or None
            The summary of the trajectory it stops (outcome ``"preempted"``), if one was
            running.

        Raises
        ------
        ProblemError
            A shape that is not (n,), or a value that is not finite.
        """
        n = self.model.n
        q = finite_array("q", q, shape=(n,))
        qd = np.zeros(n) if qd is None else finite_array("qd", qd, shape=(n,))
        preempted = None
        if self._stats is not None:
            preempted = self._stats.summary("preempted", self.model)
        self.x = np.concatenate([q, qd])
        self.nominal = None
        self._stats = None
        self._hold_q = q.copy()
        self._hold_u = self._static_control(q)
        self._rng = np.random.default_rng(self.plant.noise_seed)
        return preempted

    def hold(self) -> TrackingSummary | None:
        """Stop the running trajectory and hold the current position (a controller's stop).

        The plant keeps its state; the desired state becomes the current position at rest,
        with the static torque fed forward, as after :meth:`reset` but without moving the
        plant.

        Returns
        -------
        TrackingSummary or None
            The summary of the trajectory it stops (outcome ``"preempted"``), if one was
            running.
        """
        preempted = None
        if self._stats is not None:
            preempted = self._stats.summary("preempted", self.model)
        self.nominal = None
        self._stats = None
        self._hold_q = self.q
        self._hold_u = self._static_control(self._hold_q)
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
            tau_traj = (idx - self._start_index) * self.h + self._start_elapsed
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
