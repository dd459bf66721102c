"""Executing a planned trajectory on a simulated arm: nominal torques plus PD feedback.

The paper's case for the convexified control set is that its controls stay strictly inside
the box ``|u_i| <= 1``, which leaves room for feedback, where a bang-bang control has none.
This module is the experiment: a plant (the true dynamics, which may differ from the
planning model) integrated at a fixed step, driven by

    u = clip(u_nom + Kp e + Kd de + M(q_des) (w^2 e + 2 zeta w de + ki z) / tau_max, -1, 1),
    e = q_des - q,  de = qd_des - qd,  z = integral of e while holding,

in normalised units (``u = tau / tau_max`` of the *planning* model), computed once per
control period and held over it (zero-order hold), the applied torque being
``tau = u tau_max`` plus optional actuator noise. The gains
(:mod:`~tocontrol_ros.core.sim.gains`) are per joint (``Kp, Kd``), or derived from the
planning model's inertia and a bandwidth ``w`` (``M`` above; the integral ``z`` only while
holding a configuration, from zero at each hold), or both.

Timing, per control period ``[t_k, t_k + h]``:

- the feedback uses the state measured at ``t_k`` and the desired state at ``t_k``;
- the feedforward ``u_nom`` is the nominal torque at the *middle* of the period,
  ``t_k + h/2``. The plan is known ahead of time, so this costs nothing on a real controller,
  and it makes the hold a midpoint rule: second-order accurate in ``h``, where holding the
  value at ``t_k`` would delay the torques by ``h/2`` (a first-order error);
- the plant integrates the true dynamics with classical RK4 at the simulation step
  (``sim_rate``, an integer multiple of ``control_rate``), the torque constant.

The nominal trajectory (:mod:`~tocontrol_ros.core.sim.nominal`), the gains, the plant
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
from tocontrol_ros.core.sim.gains import TrackingGains
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
        self.kp_acc, self.kd_acc, self.ki_acc = self.gains.acceleration_gains(n)
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
        #: The hold's integral of the position error, shape (n,) (rad s); zero in motion.
        self._integral = np.zeros(n)
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
        """One control period: ``(xz, q_des, qd_des, u_nom, noise, hold) -> (xz, u, sat)``.

        ``xz`` is the plant state and the hold's error integral, shape (3n,); ``hold`` is 1
        while holding (the integral runs), 0 in motion. Gains, limits and the
        continuous-joint mask are baked in as constants.
        """
        n = self.model.n
        xz = ca.SX.sym("xz", 3 * n)
        x, z = xz[:2 * n], xz[2 * n:]
        hold = ca.SX.sym("hold")
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
            acc = (ca.DM(self.kp_acc) * e + ca.DM(self.kd_acc) * de
                   + hold * ca.DM(self.ki_acc) * z)
            v = v + ca.mtimes(inertia, acc) / ca.DM(self.tau_max)
        u = ca.fmin(ca.fmax(v, -1.0), 1.0)
        saturated = ca.fabs(v) > 1.0 + SATURATION_TOL
        x_next = self._period(x, u * ca.DM(self.tau_max) + noise)
        # Conditional integration (no wind-up): frozen while any joint saturates.
        runs = hold * (1 - ca.mmax(saturated))
        z_next = z + runs * self.h * e
        return ca.Function("tracking_period", [xz, q_des, qd_des, u_nom, noise, hold],
                           [ca.vertcat(x_next, z_next), u, saturated])

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

    def _simulate_chunks(self, q_des, qd_des, u_nom, noise, hold):
        """Run the law over ``K`` periods from ``self.x`` and the integral, in few calls.

        Chunks of power-of-two sizes (``mapaccum``), so that the per-period cost is the
        compiled graph's, not Python's.

        Returns
        -------
        x_next : ndarray, shape (K, 3n)
            State at the end of each period, then the hold's error integral.
        u : ndarray, shape (K, n)
        saturated : ndarray of bool, shape (K, n)
        """
        count = q_des.shape[0]
        xs, us, sats = [], [], []
        x = np.concatenate([self.x, self._integral])
        done = 0
        while done < count:
            size = min(MAX_CHUNK, 1 << ((count - done).bit_length() - 1))
            rows = slice(done, done + size)
            fun = self._chunk_function(size)
            x_out, u, sat = fun(x, q_des[rows].T, qd_des[rows].T, u_nom[rows].T,
                                noise[rows].T, hold[rows][None, :])
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
            With ``n`` joints in the model's order. Without its own ``inverse_dynamics``, it
            gets the planning model's: the torque between samples is that of the
            interpolated state (plus the samples' residual), not the chord between samples.
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
        if nominal.inverse_dynamics is None:
            # Between samples, the torque of the planned state (not a chord of the samples).
            nominal = nominal.with_inverse_dynamics(self.model.function("id"))
        q_end = nominal.q[-1]
        self.nominal = nominal.with_hold_effort(self._static_control(q_end) * self.tau_max)
        self._start_index = self.step_index
        self._start_elapsed = float(elapsed)
        self._integral = np.zeros(self.model.n)
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
        self._integral = np.zeros(n)
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
        self._integral = np.zeros(self.model.n)
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
        xz_next, u_log, sat_log = self._simulate_chunks(q_des, qd_des, u_nom, noise,
                                                        (~active).astype(float))
        x_next = xz_next[:, :2 * n]
        states = np.vstack([self.x[None, :], x_next[:-1]])
        q_log, qd_log = states[:, :n], states[:, n:]
        tau_log = u_log * self.tau_max + noise
        self.x = x_next[-1].copy()
        self._integral = xz_next[-1, 2 * n:].copy()
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
