"""What a ROS 2 Jazzy ``joint_trajectory_controller`` (JTC) checks, as pure functions.

Written from the controller's documentation (ros2_controllers, Jazzy): the checks a goal of
``control_msgs/action/FollowJointTrajectory`` must pass to be accepted, how the goal's
tolerances combine with the controller's defaults, and when a running goal is over. The
tracker's action server (:mod:`tocontrol_ros.nodes.follow_action`) applies them, and the
tests pass the planner's goals through them. Nothing here spins a node.

Error codes (``FollowJointTrajectory.Result.error_code``): ``INVALID_GOAL`` (-1),
``INVALID_JOINTS`` (-2), ``OLD_HEADER_TIMESTAMP`` (-3), ``PATH_TOLERANCE_VIOLATED`` (-4),
``GOAL_TOLERANCE_VIOLATED`` (-5); ``SUCCESSFUL`` (0). A JTC rejects a goal that fails a
check (the action's goal response; no result), logging the reason: :func:`check_goal`
returns the code that names the failure class and the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tocontrol_ros.nodes import conversions as conv

__all__ = ["SUCCESSFUL", "INVALID_GOAL", "INVALID_JOINTS", "OLD_HEADER_TIMESTAMP",
           "PATH_TOLERANCE_VIOLATED", "GOAL_TOLERANCE_VIOLATED", "CODE_NAMES", "GoalCheck",
           "ControllerOptions", "Tolerances", "check_goal", "resolve_tolerances",
           "path_violation", "goal_reached"]

SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5
#: Error code -> its constant's name in the action definition.
CODE_NAMES = {SUCCESSFUL: "SUCCESSFUL", INVALID_GOAL: "INVALID_GOAL",
              INVALID_JOINTS: "INVALID_JOINTS", OLD_HEADER_TIMESTAMP: "OLD_HEADER_TIMESTAMP",
              PATH_TOLERANCE_VIOLATED: "PATH_TOLERANCE_VIOLATED",
              GOAL_TOLERANCE_VIOLATED: "GOAL_TOLERANCE_VIOLATED"}
#: The tolerance components of ``control_msgs/JointTolerance``, in its field order.
COMPONENTS = ("position", "velocity", "acceleration")


@dataclass(frozen=True)
class GoalCheck:
    """Outcome of :func:`check_goal`: ``code`` 0 (accepted) or an error code, and why."""

    code: int
    reason: str = ""

    @property
    def accepted(self) -> bool:
        """True when the goal passed every check."""
        return self.code == SUCCESSFUL


@dataclass(frozen=True)
class ControllerOptions:
    """A JTC's settings that decide goals; the defaults are a default-configured Jazzy JTC.

    Attributes
    ----------
    effort_interface : bool
        The controller commands effort: points may carry ``effort`` (else a point with effort
        is refused).
    allow_partial_joints_goal : bool
        Goals may name a subset of the joints.
    allow_nonzero_velocity_at_trajectory_end : bool
        The last point may have a non-zero velocity (false by default in Jazzy).
    path_tolerance, goal_tolerance : float
        Default position tolerance of every joint (rad, m) during the motion and at its end;
        0 = not checked (the JTC's ``constraints.<joint>.trajectory`` and ``.goal``).
    stopped_velocity_tolerance : float
        Largest joint velocity (rad/s, m/s) at which the end counts as reached (0.01).
    goal_time : float
        Default time after the trajectory's end (s) within which the goal tolerance must be
        met; 0 = no limit (the JTC's ``constraints.goal_time``).
    """

    effort_interface: bool = False
    allow_partial_joints_goal: bool = False
    allow_nonzero_velocity_at_trajectory_end: bool = False
    path_tolerance: float = 0.0
    goal_tolerance: float = 0.0
    stopped_velocity_tolerance: float = 0.01
    goal_time: float = 0.0


@dataclass(frozen=True)
class Tolerances:
    """A goal's tolerances per joint, the controller's order; ``inf`` = not checked.

    Attributes
    ----------
    path : ndarray, shape (n, 3)
        Position, velocity and acceleration tolerances during the motion (rad, rad/s,
        rad/s^2).
    goal : ndarray, shape (n, 3)
        The same at the end (the velocity tolerance is at most the stopped velocity).
    goal_time : float
        Time after the end within which the goal tolerance must be met (s); ``inf``: no limit.
    """

    path: np.ndarray
    goal: np.ndarray
    goal_time: float


def _check_joint_names(names: list[str], joints: Sequence[str],
                       options: ControllerOptions) -> GoalCheck | None:
    if not names:
        return GoalCheck(INVALID_JOINTS, "the trajectory names no joints (joint_names is "
                                         "empty)")
    if len(set(names)) != len(names):
        return GoalCheck(INVALID_JOINTS, f"joint_names has duplicates: {names}")
    unknown = [j for j in names if j not in joints]
    if unknown:
        return GoalCheck(INVALID_JOINTS, f"joints {unknown} are not the controller's joints "
                                         f"{list(joints)}")
    if not options.allow_partial_joints_goal and len(names) != len(joints):
        missing = [j for j in joints if j not in names]
        return GoalCheck(INVALID_JOINTS, f"the trajectory lacks joints {missing} "
                                         f"(allow_partial_joints_goal is false)")
    return None


def _check_points(points, n: int, options: ControllerOptions) -> GoalCheck | None:
    if not points:
        return GoalCheck(INVALID_GOAL, "the trajectory has no points")
    previous = -math.inf
    for i, point in enumerate(points):
        t = conv.seconds(point.time_from_start)
        if t <= previous:
            return GoalCheck(INVALID_GOAL, f"time_from_start is not strictly increasing: "
                                           f"point {i} at {t:.9g} s follows {previous:.9g} s")
        previous = t
        if len(point.positions) != n:
            return GoalCheck(INVALID_GOAL, f"point {i}: positions has {len(point.positions)} "
                                           f"values for {n} joints")
        for field in ("velocities", "accelerations"):
            size = len(getattr(point, field))
            if size not in (0, n):
                return GoalCheck(INVALID_GOAL, f"point {i}: {field} has {size} values, "
                                               f"needs 0 or {n}")
        if len(point.effort) and not options.effort_interface:
            return GoalCheck(INVALID_GOAL, f"point {i} has effort, but the controller has no "
                                           f"effort command interface")
        if len(point.effort) not in (0, n):
            return GoalCheck(INVALID_GOAL, f"point {i}: effort has {len(point.effort)} "
                                           f"values for {n} joints")
        for field in ("positions", "velocities", "accelerations", "effort"):
            values = np.asarray(getattr(point, field), dtype=float)
            if not np.all(np.isfinite(values)):
                return GoalCheck(INVALID_GOAL, f"point {i}: {field} is not finite: "
                                               f"{values.tolist()}")
    return None


def check_goal(trajectory, joints: Sequence[str], now: float,
               options: ControllerOptions = ControllerOptions(), tolerances=(),
               ) -> GoalCheck:
    """Whether a JTC accepts a goal's trajectory, and if not, its error code and why.

    Parameters
    ----------
    trajectory : trajectory_msgs.msg.JointTrajectory
        The goal's ``trajectory``.
    joints : sequence of str
        The controller's joints.
    now : float
        The controller's time (s, the clock of ``header.stamp``).
    options : ControllerOptions
    tolerances : iterable of control_msgs.msg.JointTolerance
        The goal's ``path_tolerance`` and ``goal_tolerance`` entries (their names are
        checked).

    Returns
    -------
    GoalCheck
        ``INVALID_JOINTS``: no joint names, duplicates, a joint that is not the controller's,
        a missing joint (unless ``allow_partial_joints_goal``), a tolerance for an unknown
        joint. ``OLD_HEADER_TIMESTAMP``: a non-zero ``header.stamp`` with the whole
        trajectory in the past. ``INVALID_GOAL``: no points, ``time_from_start`` not strictly
        increasing, a field of the wrong size or not finite, effort without an effort
        interface, a non-zero velocity at the last point (unless
        ``allow_nonzero_velocity_at_trajectory_end``).
    """
    names = list(trajectory.joint_names)
    failed = _check_joint_names(names, joints, options)
    if failed is None:
        failed = _check_points(trajectory.points, len(names), options)
    if failed is not None:
        return failed
    stamp = conv.seconds(trajectory.header.stamp)
    end = stamp + conv.seconds(trajectory.points[-1].time_from_start)
    if stamp > 0.0 and end < now:
        return GoalCheck(OLD_HEADER_TIMESTAMP, f"the trajectory starts at {stamp:.9f} s and "
                                               f"ends at {end:.9f} s, before now ({now:.9f} "
                                               f"s); stamp 0 means start now")
    last = trajectory.points[-1]
    if not options.allow_nonzero_velocity_at_trajectory_end:
        moving = [(names[j], v) for j, v in enumerate(last.velocities) if v != 0.0]
        if moving:
            return GoalCheck(INVALID_GOAL, f"the last point's velocity is not zero: "
                                           f"{moving[0][0]} = {moving[0][1]!r} "
                                           f"(allow_nonzero_velocity_at_trajectory_end is "
                                           f"false)")
    unknown = [t.name for t in tolerances if t.name not in joints]
    if unknown:
        return GoalCheck(INVALID_JOINTS, f"tolerances name joints {unknown} that are not "
                                         f"the controller's {list(joints)}")
    return GoalCheck(SUCCESSFUL)


def _table(default: Sequence[float], entries, joints: Sequence[str]) -> np.ndarray:
    """Tolerances per joint: > 0 sets one, 0 keeps the default, < 0 removes the check."""
    table = np.tile(np.where(np.asarray(default) > 0.0, default, np.inf), (len(joints), 1))
    for entry in entries:
        j = list(joints).index(entry.name)
        for c, field in enumerate(COMPONENTS):
            value = float(getattr(entry, field))
            if value > 0.0:
                table[j, c] = value
            elif value < 0.0:
                table[j, c] = np.inf
    return table


def resolve_tolerances(goal, joints: Sequence[str],
                       options: ControllerOptions = ControllerOptions()) -> Tolerances:
    """The tolerances a goal runs with: its own where given, the controller's elsewhere.

    Parameters
    ----------
    goal : control_msgs.action.FollowJointTrajectory.Goal
        Already checked by :func:`check_goal` (every tolerance names a joint).
    joints : sequence of str
        The controller's joints (the order of the result's rows).
    options : ControllerOptions

    Returns
    -------
    Tolerances
    """
    path = _table((options.path_tolerance, 0.0, 0.0), goal.path_tolerance, joints)
    goal_table = _table((options.goal_tolerance, options.stopped_velocity_tolerance, 0.0),
                        goal.goal_tolerance, joints)
    goal_time = conv.seconds(goal.goal_time_tolerance) or options.goal_time
    return Tolerances(path=path, goal=goal_table,
                      goal_time=goal_time if goal_time > 0.0 else math.inf)


def _violation(table: np.ndarray, errors: Sequence[np.ndarray], joints: Sequence[str]
               ) -> str | None:
    for c, error in enumerate(errors):
        over = np.abs(np.asarray(error, dtype=float)) > table[:, c]
        if np.any(over):
            j = int(np.argmax(over))
            return (f"{joints[j]} {COMPONENTS[c]} error {float(error[j]):.6g} exceeds its "
                    f"tolerance {table[j, c]:.6g}")
    return None


def path_violation(tolerances: Tolerances, error: np.ndarray, rate_error: np.ndarray,
                   acceleration_error: np.ndarray, joints: Sequence[str]) -> str | None:
    """The first path tolerance an instant of the motion breaks, or None.

    Parameters
    ----------
    tolerances : Tolerances
    error, rate_error, acceleration_error : ndarray, shape (n,)
        Desired minus actual position (rad, m), velocity and acceleration.
    joints : sequence of str

    Returns
    -------
    str or None
        Which joint and component, its error and its tolerance.
    """
    return _violation(tolerances.path, (error, rate_error, acceleration_error), joints)


def goal_reached(tolerances: Tolerances, error: np.ndarray, velocity: np.ndarray,
                 acceleration_error: np.ndarray, joints: Sequence[str]) -> str | None:
    """None when an instant after the end is within the goal tolerances, else why not.

    The velocity is the joint's own (the desired one is zero at the end).
    """
    return _violation(tolerances.goal, (error, velocity, acceleration_error), joints)
