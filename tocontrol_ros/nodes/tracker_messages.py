"""The tracker's message conversions and checks (pure functions, no node).

A planned ``trajectory_msgs/JointTrajectory`` to the simulation's nominal trajectory, its
torque and duration limits, a ``~/reset`` request, and a run summary as a
``diagnostic_msgs/DiagnosticStatus``. :mod:`tocontrol_ros.nodes.tracker` uses them (and
re-exports them under its own name).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.sim.tracking import NominalTrajectory, TrackingSummary
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.jtc_interpolation import jtc_samples
from tocontrol_ros.nodes.splice import is_late
from tocontrol_ros.nodes.trajectory_cdr import (
    POINT_FIELDS,
    PointCountError,
    TrajectoryArrays,
    read_trajectory_cdr,
)

__all__ = ["TrajectoryRejectedError", "EFFORT_MARGIN", "nominal_from_msg", "nominal_from_cdr",
           "nominal_from_arrays", "nominal_of", "jtc_completed",
           "check_limits",
           "reset_state_from_msg", "summary_status",
           "start_event", "start_state_values", "state_msgs", "status_msg", "ResetRequest",
           "reset_request", "rest_row", "splice_event", "rejected_status", "replaced_status"]


class TrajectoryRejectedError(ProblemError):
    """A trajectory message the tracker cannot execute; the message says why."""


def nominal_from_msg(msg: JointTrajectory, joint_names: Sequence[str],
                     inverse_dynamics=None) -> NominalTrajectory:
    """The nominal trajectory of a ``trajectory_msgs/JointTrajectory``, in the model's order.

    Every point needs positions, velocities, accelerations and effort (the nominal torques,
    N m) for all joints; ``time_from_start`` must increase strictly. The joints may come in
    any order. With ``inverse_dynamics`` (a callable ``(q, qd, qdd) -> tau``, each shape
    (n,)), a trajectory whose points all lack effort (as sent to a controller without an
    effort interface) gets the model's torques as its effort.

    Raises
    ------
    TrajectoryRejectedError
        Names that are not the model's joints, missing or short fields, NaN, times that do
        not increase; the message names the point and the field.
    """
    return nominal_from_arrays(_arrays_of(msg), joint_names, inverse_dynamics)


def nominal_from_cdr(data: bytes, joint_names: Sequence[str], inverse_dynamics=None,
                     max_points: int | None = None) -> tuple[NominalTrajectory, float]:
    """:func:`nominal_from_msg` of a raw subscription's bytes, and the header's stamp (s).

    The bytes are read into arrays (:func:`~tocontrol_ros.nodes.trajectory_cdr.
    read_trajectory_cdr`), without a message object per point; the same checks follow.

    Raises
    ------
    TrajectoryRejectedError
        More than ``max_points`` points, bytes that are not a ``JointTrajectory``, or what
        :func:`nominal_from_msg` refuses.
    """
    try:
        arrays = read_trajectory_cdr(data, max_points)
    except PointCountError as exc:
        raise TrajectoryRejectedError(str(exc)) from exc
    except ValueError as exc:
        raise TrajectoryRejectedError(f"cannot be read as a JointTrajectory: {exc}") from exc
    sec, nanosec = divmod(arrays.stamp_ns, 1_000_000_000)
    return nominal_from_arrays(arrays, joint_names, inverse_dynamics), sec + nanosec * 1e-9


def nominal_of(msg: JointTrajectory | bytes, joint_names: Sequence[str],
               inverse_dynamics=None, max_points: int | None = None
               ) -> tuple[NominalTrajectory, float]:
    """The nominal trajectory and the header's stamp (s) of a message or of its bytes.

    Bytes (the tracker's raw subscription): :func:`nominal_from_cdr`, at most
    ``max_points`` points; a message (an action goal's, whose point count the action
    checked): :func:`nominal_from_msg`.
    """
    if isinstance(msg, bytes | bytearray | memoryview):
        return nominal_from_cdr(bytes(msg), joint_names, inverse_dynamics, max_points)
    return nominal_from_msg(msg, joint_names, inverse_dynamics), conv.seconds(msg.header.stamp)


def _arrays_of(msg: JointTrajectory) -> TrajectoryArrays:
    """A message's points as :class:`TrajectoryArrays` (its stamp left out)."""
    points = msg.points
    counts, values = {}, {}
    for field in POINT_FIELDS:
        rows = [getattr(p, field) for p in points]
        counts[field] = np.array([len(row) for row in rows], dtype=int)
        c = counts[field]
        values[field] = np.array(rows, dtype=float).reshape(len(rows), int(c[0])) \
            if c.size and np.all(c == c[0]) else [np.asarray(row, dtype=float) for row in rows]
    t = np.array([conv.seconds(p.time_from_start) for p in points], dtype=float)
    return TrajectoryArrays(0, msg.header.frame_id, list(msg.joint_names), t, counts, values)


def nominal_from_arrays(arrays: TrajectoryArrays, joint_names: Sequence[str],
                        inverse_dynamics=None) -> NominalTrajectory:
    """:func:`nominal_from_msg` of a trajectory read into arrays (the same checks)."""
    names = list(arrays.joint_names)
    want = list(joint_names)
    if len(set(names)) != len(names):
        raise TrajectoryRejectedError(f"joint_names has duplicates: {names}")
    if sorted(names) != sorted(want):
        raise TrajectoryRejectedError(f"joint_names {names} do not match the robot's joints "
                                      f"{want}")
    count = len(arrays.t)
    if not count:
        raise TrajectoryRejectedError("the trajectory has no points")
    order = [names.index(j) for j in want]
    n = len(want)
    fields = list(POINT_FIELDS)
    computed = inverse_dynamics is not None and not np.any(arrays.counts["effort"])
    if computed:
        fields.remove("effort")
    out = {}
    for field in fields:
        short = np.flatnonzero(arrays.counts[field] != n)
        if short.size:
            i = int(short[0])
            raise TrajectoryRejectedError(
                f"point {i}: {field} has {arrays.counts[field][i]} values for {n} joints (the "
                f"tracker needs positions, velocities, accelerations and effort)")
        out[field] = np.asarray(arrays.values[field], dtype=float).reshape(count, n)[:, order]
    if computed:
        out["effort"] = np.array([
            inverse_dynamics(q, qd, qdd) for q, qd, qdd in
            zip(out["positions"], out["velocities"], out["accelerations"], strict=True)
        ]).reshape(count, n)
    try:
        return NominalTrajectory(arrays.t, out["positions"], out["velocities"],
                                 out["accelerations"], out["effort"], joint_names=want)
    except ProblemError as exc:
        text = str(exc).replace("`t`", "time_from_start").replace(
            "`q`", "positions").replace("`qd`", "velocities").replace(
            "`qdd`", "accelerations").replace("`effort`", "effort")
        raise TrajectoryRejectedError(text) from exc


def jtc_completed(msg: JointTrajectory, period: float) -> JointTrajectory:
    """An action goal's trajectory with every point's velocities and accelerations.

    A goal whose points all carry them is returned as it is. Otherwise (positions only, or
    positions and velocities, in any point) the segments are interpolated as a Jazzy JTC
    does, by what both of their ends carry (:mod:`~tocontrol_ros.nodes.jtc_interpolation`),
    sampled every ``period`` (s): the tracker then follows the JTC's motion. The effort of
    such a goal is left out (the tracker feeds forward the model's inverse dynamics); a point
    with a field of the wrong size is left to :func:`nominal_from_msg`, which names it.
    """
    points, n = msg.points, len(msg.joint_names)
    if all(len(p.velocities) == n and len(p.accelerations) == n for p in points) or \
            any(len(p.positions) != n or len(p.velocities) not in (0, n)
                or len(p.accelerations) not in (0, n) for p in points):
        return msg
    t, q, qd, qdd = jtc_samples(
        [conv.seconds(p.time_from_start) for p in points], [list(p.positions) for p in points],
        [list(p.velocities) if len(p.velocities) == n else None for p in points],
        [list(p.accelerations) if len(p.accelerations) == n else None for p in points],
        period)
    out = JointTrajectory(header=msg.header, joint_names=list(msg.joint_names))
    out.points = [JointTrajectoryPoint(positions=q[i].tolist(), velocities=qd[i].tolist(),
                                       accelerations=qdd[i].tolist(),
                                       time_from_start=conv.duration_from_seconds(t[i]))
                  for i in range(len(t))]
    return out


#: Effort may exceed the torque limit by this fraction (rounding in the planner's samples).
EFFORT_MARGIN = 1e-6


def check_limits(nominal: NominalTrajectory, tau_max, max_duration: float) -> None:
    """Reject a trajectory whose effort exceeds the torque limits or that lasts too long.

    Parameters
    ----------
    nominal : NominalTrajectory
    tau_max : array_like, shape (n,)
        Torque limits (N m, N).
    max_duration : float
        Longest duration (s).

    Raises
    ------
    TrajectoryRejectedError
        Naming the first point and joint over its limit, or the duration.
    """
    if nominal.duration > max_duration:
        raise TrajectoryRejectedError(f"it lasts {nominal.duration:.6g} s, more than "
                                      f"max_duration = {max_duration:g} s")
    limit = np.asarray(tau_max, dtype=float) * (1.0 + EFFORT_MARGIN)
    over = np.abs(nominal.effort) > limit
    if np.any(over):
        i, j = (int(v) for v in np.argwhere(over)[0])
        name = nominal.joint_names[j] if nominal.joint_names else f"joint {j}"
        raise TrajectoryRejectedError(
            f"point {i}: effort {nominal.effort[i, j]:.6g} of {name} exceeds its torque "
            f"limit {float(np.asarray(tau_max)[j]):.6g}")


def reset_state_from_msg(msg: JointState,
                         joint_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (zero if none given) of a ``~/reset`` request, model order.

    Raises
    ------
    TrajectoryRejectedError
        Names that are not the model's joints, a position or velocity count that does not
        match them, a value that is not finite.
    """
    names, want = list(msg.name), list(joint_names)
    if len(set(names)) != len(names) or sorted(names) != sorted(want):
        raise TrajectoryRejectedError(f"name {names} does not match the robot's joints {want}")
    order = [names.index(j) for j in want]
    fields = {}
    for field in ("position", "velocity"):
        values = np.asarray(getattr(msg, field), dtype=float)
        if field == "velocity" and values.size == 0:
            values = np.zeros(len(want))
        elif values.size != len(want):
            raise TrajectoryRejectedError(f"{field} has {values.size} values for {len(want)} "
                                          f"joints")
        if not np.all(np.isfinite(values)):
            raise TrajectoryRejectedError(f"{field} is not finite: {values.tolist()}")
        fields[field] = values[order]
    return fields["position"], fields["velocity"]


class ResetRequest(NamedTuple):
    """A parsed ``~/reset`` request (``error``: why it is refused, else None)."""

    q: np.ndarray | None
    qd: np.ndarray | None
    stamp: str
    error: str | None


def reset_request(msg: JointState, joint_names: Sequence[str]) -> ResetRequest:
    """A ``~/reset`` request parsed (:func:`reset_state_from_msg`), its stamp as text."""
    stamp = f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"
    try:
        q, qd = reset_state_from_msg(msg, joint_names)
    except TrajectoryRejectedError as exc:
        return ResetRequest(None, None, stamp, str(exc))
    return ResetRequest(q, qd, stamp, None)


def summary_status(summary: TrackingSummary, name: str, hardware_id: str,
                   joint_names: Sequence[str]) -> DiagnosticStatus:
    """A run summary as a ``DiagnosticStatus`` (level OK; values as key/value pairs)."""
    worst = int(np.argmax(summary.max_error))
    verb = "completed" if summary.outcome == "completed" else (
        f"preempted after {summary.elapsed:.3f} s of {summary.duration:.3f} s")
    message = (f"trajectory {verb}: final end-effector error {summary.final_point_error:.3g} "
               f"m, max tracking error {summary.max_error[worst]:.3g} rad "
               f"({joint_names[worst]}), saturated {100 * summary.saturated_fraction:.1f} % "
               f"of the time, largest feedback share {summary.max_feedback:.3g}")
    values = [KeyValue(key=key, value=value if isinstance(value, str) else f"{value:.9g}")
              for key, value in summary.as_dict(joint_names).items()]
    return DiagnosticStatus(level=DiagnosticStatus.OK, name=name, message=message,
                            hardware_id=hardware_id, values=values)


def status_msg(level: bytes, name: str, message: str, hardware_id: str,
               values: Mapping[str, str] = ()) -> DiagnosticStatus:
    """A tracker event as a ``DiagnosticStatus`` (``values`` already text)."""
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in dict(values).items()])


def start_event(nominal: NominalTrajectory, stamp: float, offset: float, placed: bool,
                start_time: float, state: Mapping[str, str]) -> tuple[str, dict[str, str]]:
    """The message and values of a trajectory's start on ``~/status``.

    ``stamp``: its header's (s); ``offset``: its first point from the arm's position (rad);
    ``placed``: the arm was put there (``start_at_first_trajectory``); ``start_time``: now
    on the stamps' clock (s); ``state``: :func:`start_state_values`.
    """
    message = (f"executing trajectory: {len(nominal)} points, T = {nominal.duration:.4f} s, "
               f"start {offset:.3g} rad from the current position"
               + (" (the arm placed there: start_at_first_trajectory)" if placed else ""))
    return message, {"points": str(len(nominal)), "duration": f"{nominal.duration:.9g}",
                     "stamp": f"{stamp:.9f}", "start_offset": f"{offset:.9g}",
                     "start_time": f"{start_time:.9f}", **state}


def start_state_values(joint_names: Sequence[str], q: np.ndarray,
                       qd: np.ndarray) -> dict[str, str]:
    """The state a trajectory starts from as status values, for re-execution.

    ``start_position.<joint>`` and ``start_velocity.<joint>`` (rad, rad/s), 17 digits.
    """
    return {f"start_{field}.{name}": f"{value:.17g}"
            for field, values in (("position", q), ("velocity", qd))
            for name, value in zip(joint_names, values, strict=True)}


def state_msgs(joint_names: Sequence[str], stamp: float,
               row: Mapping[str, np.ndarray]) -> tuple[JointState, JointState]:
    """``joint_states`` and ``~/tracking_error`` of one control instant, stamped ``stamp`` (s).

    ``row``: ``q``, ``qd``, ``tau`` (the state and the torque acting) and ``error``,
    ``error_rate``, ``feedback`` (``q_des - q``, ``qd_des - qd``, the feedback torque).
    """
    header = Header(stamp=conv.time_from_seconds(stamp), frame_id="")
    names = list(joint_names)
    joints = JointState(header=header, name=names, position=np.asarray(row["q"]).tolist(),
                        velocity=np.asarray(row["qd"]).tolist(),
                        effort=np.asarray(row["tau"]).tolist())
    error = JointState(header=header, name=names, position=np.asarray(row["error"]).tolist(),
                       velocity=np.asarray(row["error_rate"]).tolist(),
                       effort=np.asarray(row["feedback"]).tolist())
    return joints, error


def rest_row(t: float, q: np.ndarray, qd: np.ndarray) -> dict[str, object]:
    """A :func:`state_msgs` row of the arm held at ``q``, ``qd``: no error, no torque."""
    zero = np.zeros(len(q))
    return {"t": t, "q": q, "qd": qd, "error": zero, "error_rate": zero, "feedback": zero,
            "tau": zero}


def rejected_status(text: str, running: bool, stamp: float | None
                    ) -> tuple[bytes, str, dict[str, str]]:
    """A ``trajectory rejected`` status: (level, message, values) for ``publish_status``.

    ``text``: ``trajectory rejected: <reason>``; ``running``: whether the tracker goes on
    with the current trajectory (else it holds). The values: ``event`` ``rejected`` and, when
    known, ``stamp``: the refused trajectory's ``header.stamp`` (s), known once it was
    parsed; a planner matches it with its last publication or a motion that one continues
    (msg_docs/tracker_status.md).
    """
    message = f"{text}; {'continuing the current trajectory' if running else 'holding'}"
    values = {"event": "rejected"} | ({} if stamp is None else {"stamp": f"{stamp:.9f}"})
    return DiagnosticStatus.ERROR, message, values


def replaced_status(old_stamp: float, stamp: float) -> tuple[str, dict]:
    """The message and values of a pending splice replaced before it took over, on ``~/status``.

    ``old_stamp``: its stamp (s); ``stamp``: the newer trajectory's (s).
    """
    return (f"trajectory stamped {old_stamp:.6f} replaced before it took over by one stamped "
            f"{stamp:.6f}", {"event": "splice_replaced", "stamp": f"{old_stamp:.9f}"})


def splice_event(splice, dq: float, dqd: float, start_time: float, h: float
                 ) -> tuple[str, dict]:
    """The message and values of a stamped trajectory spliced in, on ``~/status``.

    ``splice``: a :class:`~tocontrol_ros.nodes.splice.Splice`; ``dq``, ``dqd``: the
    command's jumps (rad, rad/s); ``start_time``: now on the stamps' clock (s); ``h``: the
    control period (s). ``late`` is ``true`` when it took over a control period or more
    after its stamp (it came after its hand-off: joined as far along as the stamp says).
    """
    nominal = splice.nominal
    late = is_late(splice, h)
    when = f"{splice.elapsed:.4f} s after its stamp (late)" if late else "at its stamp"
    message = (f"executing trajectory spliced in {when}: {len(nominal)} points, T = "
               f"{nominal.duration:.4f} s; command jumps {dq:.3g} rad, {dqd:.3g} rad/s")
    return message, {"event": "spliced", "points": str(len(nominal)),
                     "duration": f"{nominal.duration:.9g}", "stamp": f"{splice.stamp:.9f}",
                     "start_time": f"{start_time:.9f}", "position_jump": f"{dq:.9g}",
                     "velocity_jump": f"{dqd:.9g}", "late": "true" if late else "false",
                     "elapsed": f"{splice.elapsed:.9f}"}
