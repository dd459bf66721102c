"""Pure conversions between ROS messages and the core's objects (no node, no spinning).

Requests in: a ``geometry_msgs/Point`` in the planner's frame becomes a task-space point
(:func:`point_from_msg`), a ``sensor_msgs/JointState`` becomes ``(q, qd)`` in the model's
joint order (:func:`joint_state_from_msg`). Results out: a sampled trajectory becomes a
``trajectory_msgs/JointTrajectory`` (:func:`trajectory_msg`), the end-effector path a
``nav_msgs/Path`` (:func:`path_msg`), snapshots of the arm a
``visualization_msgs/MarkerArray`` (:func:`markers_msg`), an outcome a
``diagnostic_msgs/DiagnosticStatus`` (:func:`status_msg`).

The values and summary of a plan's status (:func:`result_values`, :func:`result_message`,
:func:`stamp_text`) are ROS-free, in :mod:`tocontrol_ros.nodes.outcomes`, re-exported here.

Bad input raises :class:`ConversionError` with a message that names the offending field.
Forward kinematics (:func:`link_positions`, :func:`tip_pose`, from
:mod:`tocontrol_ros.core.robot.kinematics`) is plain numpy on the model's body data, so these
functions may run on any thread.
"""

from __future__ import annotations

import array
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from nav_msgs.msg import Path
from std_msgs.msg import ColorRGBA, Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.robot.kinematics import link_positions, tip_pose, tip_poses
from tocontrol_ros.nodes.outcomes import (
    ROUTINE_NOTE,
    certificate_values,
    result_message,
    result_values,
    stamp_text,
)

__all__ = ["ConversionError", "TaskFrame", "task_frame", "link_positions", "tip_pose",
           "point_from_msg", "joint_state_from_msg", "embed_point", "time_from_ns", "nanoseconds",
           "time_from_seconds",
           "duration_from_seconds", "seconds", "add_seconds", "trajectory_msg", "path_msg",
           "empty_path", "point_path", "markers_msg", "status_msg", "status_values",
           "certificate_values", "result_values", "result_message", "ROUTINE_NOTE", "stamp_text",
           "LEVELS"]

#: Non-task coordinates of a request must match the arm's constant value within this (m):
#: loose enough for hand-typed numbers, tight enough to catch a point from another plane.
OFF_PLANE_TOL = 1e-3
#: A non-task coordinate counts as constant when it varies by less than this (m) over
#: random configurations (numerical noise of the forward kinematics is ~1e-15).
CONSTANT_TOL = 1e-9
#: Status levels by name (``DiagnosticStatus.level`` is a byte in rclpy).
LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN,
          "ERROR": DiagnosticStatus.ERROR, "STALE": DiagnosticStatus.STALE}
_AXES = "xyz"


class ConversionError(TocontrolError, ValueError):
    """A message that cannot become a planning request; the message names the field."""


def _quaternion(rot: np.ndarray) -> Quaternion:
    """Unit quaternion of a rotation matrix (Shepperd's method, largest pivot)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, \
            (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, \
            (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, \
            (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, \
            (m[1, 2] + m[2, 1]) / s, 0.25 * s
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    return Quaternion(x=x / norm, y=y / norm, z=z / norm, w=w / norm)


# ---------------------------------------------------------- requests in
@dataclass(frozen=True)
class TaskFrame:
    """How a 3D point in the planner's frame relates to the model's task space.

    Attributes
    ----------
    frame_id : str
        The only frame accepted (no tf lookup).
    task_axes : tuple of int
        Base-frame coordinates that form the task point (0 = x, 1 = y, 2 = z).
    fixed : tuple of (int, float)
        Non-task coordinates that are the same for every configuration (e.g. the plane's
        height of a planar arm) and their value (m): a request must match them.
        Non-task coordinates not listed here vary with the configuration and are ignored.
    tolerance : float
        Allowed mismatch of a fixed coordinate (m).
    """

    frame_id: str
    task_axes: tuple[int, ...]
    fixed: tuple[tuple[int, float], ...] = ()
    tolerance: float = OFF_PLANE_TOL


def task_frame(model, frame_id: str, samples: int = 32, seed: int = 0,
               tolerance: float = OFF_PLANE_TOL) -> TaskFrame:
    """Work out which non-task coordinates of the tip are constant (e.g. a planar arm's z).

    Parameters
    ----------
    model : RobotModel
    frame_id : str
        The planner's frame.
    samples : int
        Random configurations (within the joint limits; continuous joints in [-pi, pi]).
    seed : int
        Seed of the random configurations (the answer does not depend on it in practice).
    tolerance : float
        Stored as :attr:`TaskFrame.tolerance` (m).

    Returns
    -------
    TaskFrame
    """
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(model.q_lower), model.q_lower, -np.pi)
    hi = np.where(np.isfinite(model.q_upper), model.q_upper, np.pi)
    tips = np.array([tip_pose(model, rng.uniform(lo, hi))[1] for _ in range(samples)])
    fixed = []
    for axis in range(3):
        if axis in model.task_axes:
            continue
        column = tips[:, axis]
        if np.ptp(column) < CONSTANT_TOL:
            fixed.append((axis, float(np.mean(column))))
    return TaskFrame(frame_id=frame_id, task_axes=tuple(model.task_axes), fixed=tuple(fixed),
                     tolerance=tolerance)


def point_from_msg(point: Point, frame_id: str, frame: TaskFrame, name: str) -> np.ndarray:
    """The task-space point of a ``geometry_msgs/Point`` given in ``frame_id``.

    Parameters
    ----------
    point : geometry_msgs.msg.Point
    frame_id : str
        The frame the point is stamped with.
    frame : TaskFrame
    name : str
        The field, for error messages (e.g. ``"goal.pose.position"``).

    Returns
    -------
    ndarray, shape (m,)
        The task coordinates (m).

    Raises
    ------
    ConversionError
        A frame other than the planner's, a NaN or infinite coordinate, a fixed coordinate
        (e.g. a planar arm's z) off its value.
    """
    if frame_id != frame.frame_id:
        raise ConversionError(f"`{name}`: frame_id {frame_id!r} is not the planner's frame "
                              f"{frame.frame_id!r} (no tf lookup; send points in "
                              f"{frame.frame_id!r})")
    xyz = (point.x, point.y, point.z)
    for axis, value in enumerate(xyz):
        if not math.isfinite(value):
            raise ConversionError(f"`{name}.{_AXES[axis]}` must be finite, got {value!r}")
    for axis, value in frame.fixed:
        if abs(xyz[axis] - value) > frame.tolerance:
            raise ConversionError(
                f"`{name}.{_AXES[axis]}` = {xyz[axis]:.6g} m is off the arm's reachable set: "
                f"its tip always has {_AXES[axis]} = {value:.6g} m (tolerance "
                f"{frame.tolerance:g} m)")
    return np.array([xyz[axis] for axis in frame.task_axes], dtype=float)


def embed_point(frame: TaskFrame, p) -> np.ndarray:
    """A task point as a 3D point: fixed coordinates filled in, free ones 0 (m), shape (3,)."""
    out = np.zeros(3)
    for axis, value in frame.fixed:
        out[axis] = value
    out[list(frame.task_axes)] = np.asarray(p, dtype=float)
    return out


def joint_state_from_msg(msg, joint_names: Sequence[str],
                         field: str = "joint_states") -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of the model's joints from a ``sensor_msgs/JointState``.

    Joints are matched by name (any order); extra joints in the message (other parts of the
    robot) are ignored. An empty ``velocity`` array means at rest (some publishers, e.g.
    joint_state_publisher, leave it empty).

    Parameters
    ----------
    msg : sensor_msgs.msg.JointState
    joint_names : sequence of str
        The model's joints, in the model's order.
    field : str
        The message's name in errors (e.g. ``"target_joints"``).

    Returns
    -------
    q, qd : ndarray, shape (n,)
        Positions (rad, m) and velocities (rad/s, m/s).

    Raises
    ------
    ConversionError
        A model joint missing from ``name``, arrays of the wrong length, duplicate names, a
        NaN or infinite value.
    """
    names = list(msg.name)
    if len(set(names)) != len(names):
        raise ConversionError(f"`{field}.name` has duplicates: {names}")
    missing = [j for j in joint_names if j not in names]
    if missing:
        raise ConversionError(f"`{field}.name` lacks the planner's joint(s) {missing} "
                              f"(got {names}; expected {list(joint_names)})")
    if len(msg.position) != len(names):
        raise ConversionError(f"`{field}.position` has {len(msg.position)} entries for "
                              f"{len(names)} names")
    if len(msg.velocity) not in (0, len(names)):
        raise ConversionError(f"`{field}.velocity` has {len(msg.velocity)} entries for "
                              f"{len(names)} names (empty means at rest)")
    index = [names.index(j) for j in joint_names]
    q = np.array([msg.position[i] for i in index], dtype=float)
    qd = np.array([msg.velocity[i] for i in index], dtype=float) if len(msg.velocity) \
        else np.zeros(len(index))
    for label, values in (("position", q), ("velocity", qd)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            j = int(bad[0])
            raise ConversionError(f"`{field}.{label}` of joint {joint_names[j]!r} must be "
                                  f"finite, got {values[j]!r}")
    return q, qd


# ------------------------------------------------------------------ time
def time_from_ns(ns: int) -> Time:
    """A ``builtin_interfaces/Time`` from integer nanoseconds (ns >= 0)."""
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def nanoseconds(stamp) -> int:
    """Integer nanoseconds of a ``Time`` (or ``Duration``)."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def time_from_seconds(t: float) -> Time:
    """A ``builtin_interfaces/Time`` from seconds (t >= 0)."""
    return time_from_ns(int(round(t * 1e9)))


def duration_from_seconds(t: float) -> Duration:
    """A ``builtin_interfaces/Duration`` from seconds (t >= 0)."""
    ns = int(round(t * 1e9))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds(stamp) -> float:
    """Seconds of a ``Time`` or ``Duration``."""
    return stamp.sec + stamp.nanosec * 1e-9


def add_seconds(stamp: Time, dt: float) -> Time:
    """``stamp + dt`` (dt >= 0 s), exact to the nanosecond."""
    return time_from_ns(nanoseconds(stamp) + int(round(dt * 1e9)))


# ----------------------------------------------------------- results out
def trajectory_msg(sample, joint_names: Sequence[str], frame_id: str,
                   stamp: Time) -> JointTrajectory:
    """A sampled trajectory as a ``trajectory_msgs/JointTrajectory``.

    Parameters
    ----------
    sample : TrajectorySample
        ``t`` (K,), ``q``, ``qd``, ``qdd``, ``tau`` (K, n); the last sample is the final time.
    joint_names : sequence of str
    frame_id : str
    stamp : builtin_interfaces.msg.Time
        Start time of the motion (``time_from_start`` counts from it).

    Returns
    -------
    JointTrajectory
        One point per sample: positions (rad, m), velocities, accelerations, effort = the
        nominal torques (N m, N).
    """
    msg = JointTrajectory(header=Header(stamp=stamp, frame_id=frame_id),
                          joint_names=list(joint_names))
    # Each field's samples in one array.array, a point's slice of it given to the message as
    # is (rclpy takes an array.array('d') without checking each value), and the times to
    # whole nanoseconds in numpy (duration_from_seconds' rounding): 200 Panda points in
    # about 1.0 ms against 1.2 ms point by point from lists (the same message), most of
    # what is left being the message constructors.
    count, n = np.shape(sample.q)
    q, qd, qdd, tau = (array.array("d", np.ascontiguousarray(a, dtype=float).tobytes())
                       for a in (sample.q, sample.qd, sample.qdd, sample.tau))
    ns = np.round(np.asarray(sample.t, dtype=float) * 1e9).astype(np.int64)
    secs, nsecs = (ns // 1_000_000_000).tolist(), (ns % 1_000_000_000).tolist()
    msg.points = [
        JointTrajectoryPoint(positions=q[a:a + n], velocities=qd[a:a + n],
                             accelerations=qdd[a:a + n], effort=tau[a:a + n],
                             time_from_start=Duration(sec=secs[i], nanosec=nsecs[i]))
        for i, a in zip(range(count), range(0, count * n, n), strict=True)]
    return msg


def path_msg(model, sample, frame_id: str, stamp: Time) -> Path:
    """The end-effector path of a sampled trajectory as a ``nav_msgs/Path``.

    Each pose is the tip frame (position in m, orientation from the forward kinematics)
    stamped ``stamp + t``: the planned time at which the tip passes there.
    """
    header = Header(stamp=stamp, frame_id=frame_id)
    rots, positions = tip_poses(model, sample.q)
    poses = []
    for t, rot, pos in zip(sample.t, rots, positions.tolist(), strict=True):
        pose = Pose(position=Point(x=pos[0], y=pos[1], z=pos[2]), orientation=_quaternion(rot))
        poses.append(PoseStamped(header=Header(stamp=add_seconds(stamp, float(t)),
                                               frame_id=frame_id), pose=pose))
    return Path(header=header, poses=poses)


def point_path(frame: TaskFrame, p, frame_id: str, stamp: Time) -> Path:
    """A one-pose ``nav_msgs/Path`` at the task-space point ``p`` (shape (m,), m), at ``stamp``.

    The answer of ``~/plan`` when there is nothing to plan (T = 0).
    """
    x, y, z = (float(v) for v in embed_point(frame, p))
    header = Header(stamp=stamp, frame_id=frame_id)
    pose = Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(w=1.0))
    return Path(header=header, poses=[PoseStamped(header=header, pose=pose)])


def empty_path(frame_id: str, stamp: Time) -> Path:
    """The failure answer of ``~/plan``: a path without poses."""
    return Path(header=Header(stamp=stamp, frame_id=frame_id))


def _color(fraction: float, alpha: float = 1.0) -> ColorRGBA:
    """Blue at the start of the motion to red at its end."""
    f = min(max(fraction, 0.0), 1.0)
    return ColorRGBA(r=f, g=0.2, b=1.0 - f, a=alpha)


def markers_msg(model, q_snapshots, ee_points, start, target, frame_id: str,
                stamp: Time) -> MarkerArray:
    """Snapshots of the arm along a motion, as in the paper's Figure 4.

    Parameters
    ----------
    model : RobotModel
    q_snapshots : array_like, shape (S, n)
        Configurations at the snapshot times, first to last (rad, m).
    ee_points : array_like, shape (K, 3)
        End-effector path (m).
    start, target : array_like, shape (3,)
        End points (m).
    frame_id : str
    stamp : builtin_interfaces.msg.Time

    Returns
    -------
    MarkerArray
        A ``DELETEALL`` (clears the previous plan), then per snapshot ``arm`` (LINE_STRIP
        through base, joints and tip) and ``joints`` (SPHERE_LIST), one ``ee_path``
        LINE_STRIP and ``endpoints`` (start green, target red).
    """
    header = Header(stamp=stamp, frame_id=frame_id)
    out = [Marker(header=header, action=Marker.DELETEALL)]
    snaps = np.atleast_2d(np.asarray(q_snapshots, dtype=float))
    count = len(snaps)
    for i, q in enumerate(snaps):
        pts = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
               for p in link_positions(model, q)]
        frac = i / max(count - 1, 1)
        common = {"header": header, "id": i, "action": Marker.ADD, "points": pts,
                  "pose": Pose(orientation=Quaternion(w=1.0))}
        arm = Marker(ns="arm", type=Marker.LINE_STRIP, color=_color(frac, 0.8), **common)
        arm.scale.x = 0.03
        joints = Marker(ns="joints", type=Marker.SPHERE_LIST, color=_color(frac, 0.8),
                        **common)
        joints.scale.x = joints.scale.y = joints.scale.z = 0.08
        out += [arm, joints]
    path = Marker(header=header, ns="ee_path", id=0, type=Marker.LINE_STRIP,
                  action=Marker.ADD, pose=Pose(orientation=Quaternion(w=1.0)),
                  color=ColorRGBA(r=0.1, g=0.1, b=0.1, a=1.0),
                  points=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
                          for p in np.asarray(ee_points, dtype=float)])
    path.scale.x = 0.015
    ends = Marker(header=header, ns="endpoints", id=0, type=Marker.SPHERE_LIST,
                  action=Marker.ADD, pose=Pose(orientation=Quaternion(w=1.0)),
                  points=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
                          for p in (np.asarray(start, float), np.asarray(target, float))],
                  colors=[ColorRGBA(r=0.0, g=0.8, b=0.0, a=1.0),
                          ColorRGBA(r=0.9, g=0.0, b=0.0, a=1.0)])
    ends.scale.x = ends.scale.y = ends.scale.z = 0.12
    out += [path, ends]
    return MarkerArray(markers=out)


def _format(value) -> str:
    if isinstance(value, bool) or isinstance(value, str):
        return str(value).lower() if isinstance(value, bool) else value
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.9g}"
    arr = np.asarray(value, dtype=float).ravel()
    return "[" + ", ".join(f"{v:.9g}" for v in arr) + "]"


def status_values(values: Mapping[str, object]) -> list[KeyValue]:
    """``KeyValue`` pairs; floats with 9 significant digits, arrays as ``[a, b]``."""
    return [KeyValue(key=str(k), value=_format(v)) for k, v in values.items()
            if v is not None]


def status_msg(level: str, name: str, message: str, hardware_id: str,
               values: Mapping[str, object]) -> DiagnosticStatus:
    """A ``diagnostic_msgs/DiagnosticStatus``.

    Parameters
    ----------
    level : {"OK", "WARN", "ERROR", "STALE"}
    name : str
        The reporting node's name.
    message : str
    hardware_id : str
        The robot's name.
    values : mapping of str to object
        Converted by :func:`status_values` (None values are left out).
    """
    if level not in LEVELS:
        raise ValueError(f"`level` must be one of {sorted(LEVELS)}, got {level!r}")
    return DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                            hardware_id=hardware_id, values=status_values(values))
