"""The tracker's ``~/follow_joint_trajectory`` action and ``~/controller_state``, as a JTC's.

The tracker serves ``control_msgs/action/FollowJointTrajectory`` with the semantics of ROS 2
Jazzy's ``joint_trajectory_controller`` (msg_docs/tracker_follow_joint_trajectory.md):

- a goal is checked when it arrives (:func:`~tocontrol_ros.nodes.jtc_checks.check_goal`) and
  rejected (no result, as a JTC does) when it fails, with the error code and reason on
  ``~/status``;
- an accepted goal goes through the tracker's own checks (effort within the torque limits,
  start within ``start_tolerance``, ...); one that fails them is aborted with
  ``INVALID_GOAL`` and the reason;
- while it runs: feedback at ``publish_rate``; a path tolerance broken aborts it with
  ``PATH_TOLERANCE_VIOLATED`` and the arm holds where it is; after the end it succeeds once
  within the goal tolerances (and stopped), or is aborted with ``GOAL_TOLERANCE_VIOLATED``
  when ``goal_time_tolerance`` has passed;
- a cancel ends it ``CANCELED`` (error code 0) with the arm holding where it is; a newer goal
  (or a trajectory on the topic, or ``~/reset``) preempts it: ``CANCELED`` with
  ``INVALID_GOAL`` and "preempted" in ``error_string`` (a reset: ``ABORTED``).

Everything runs on the tracker's executor thread (goal, cancel and execute callbacks and the
simulation timer), so the goal records need no lock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTrajectoryControllerState
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import GoalEvent, ServerGoalHandle
from rclpy.task import Future
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectoryPoint

from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import jtc_checks as jtc
from tocontrol_ros.nodes import qos
from tocontrol_ros.nodes.tracker_messages import jtc_completed

if TYPE_CHECKING:
    from tocontrol_ros.core.sim.nominal import NominalTrajectory
    from tocontrol_ros.core.sim.tracking import TrackingLog

__all__ = ["ACTION_NAME", "STATE_TOPIC", "GoalRecord", "FollowServer", "controller_options"]

#: The action's name, relative to the node (the JTC's).
ACTION_NAME = "~/follow_joint_trajectory"
#: The controller state topic (the JTC's).
STATE_TOPIC = "~/controller_state"


def controller_options(config) -> jtc.ControllerOptions:
    """The tracker as a Jazzy JTC: effort accepted (fed forward), derivatives optional.

    Velocities and accelerations may be empty per point; such segments are interpolated as
    a JTC does (:mod:`~tocontrol_ros.nodes.jtc_interpolation`).

    Parameters
    ----------
    config : TrackerConfig
        Its ``path_tolerance``, ``goal_tolerance``, ``stopped_velocity_tolerance`` and
        ``goal_time`` are the defaults of every goal.
    """
    return jtc.ControllerOptions(
        effort_interface=True,
        path_tolerance=config.path_tolerance, goal_tolerance=config.goal_tolerance,
        stopped_velocity_tolerance=config.stopped_velocity_tolerance,
        goal_time=config.goal_time)


def _enter_canceling(handle: ServerGoalHandle) -> None:
    """Move an executing goal to CANCELING, so that ``handle.canceled()`` may end it.

    rclpy's private API, isolated here: rclpy ends a goal CANCELED only from CANCELING,
    which its public API reaches only through a client's cancel request; a preemption (the
    JTC's "CANCELED with INVALID_GOAL, preempted") has none. rclcpp's ``canceled()`` makes
    this transition itself; rclpy (Jazzy) has no public equivalent.
    """
    handle._update_state(GoalEvent.CANCEL_GOAL)


@dataclass
class GoalRecord:
    """One accepted goal: its handle, tolerances, and when it started (tracker time, s)."""

    handle: ServerGoalHandle
    tolerances: jtc.Tolerances
    done: Future = field(default_factory=Future)
    start: float | None = None
    end: float | None = None


class FollowServer:
    """The action server and the controller state of a :class:`TrackerNode`.

    Parameters
    ----------
    node : TrackerNode
        Its public interface: ``joint_names``, ``tracker``, ``config``, ``epoch`` (the
        stamps' time at tracker time 0), ``submit_goal`` (queues a goal's trajectory for
        parsing), ``publish_status``, ``publish_summary``, and rclpy's ``create_publisher``
        and ``get_logger``.
    """

    def __init__(self, node) -> None:
        self.node = node
        self.options = controller_options(node.config)
        self.active: GoalRecord | None = None
        self._state_pub = node.create_publisher(JointTrajectoryControllerState, STATE_TOPIC,
                                                10)
        self._server = ActionServer(
            node, FollowJointTrajectory, ACTION_NAME, execute_callback=self._execute,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            goal_service_qos_profile=qos.ACTION_SERVICES,
            result_service_qos_profile=qos.ACTION_SERVICES,
            cancel_service_qos_profile=qos.ACTION_SERVICES)
        self._pending: dict[bytes, GoalRecord] = {}

    # ------------------------------------------------------------- callbacks
    def _now(self) -> float:
        return self.node.epoch + self.node.tracker.t

    def _on_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        joints = self.node.joint_names
        if len(goal.trajectory.points) > self.node.config.max_points:
            check = jtc.GoalCheck(jtc.INVALID_GOAL, f"{len(goal.trajectory.points)} points, "
                                  f"more than max_points = {self.node.config.max_points}")
        else:
            check = jtc.check_goal(goal.trajectory, joints, self._now(), self.options,
                                   list(goal.path_tolerance) + list(goal.goal_tolerance))
        if check.accepted:
            return GoalResponse.ACCEPT
        name = jtc.CODE_NAMES[check.code]
        self.node.publish_status(DiagnosticStatus.ERROR, f"goal rejected ({name}): {check.reason}",
                          {"event": "goal_rejected", "error_code": str(check.code)})
        self.node.get_logger().warning(f"goal rejected ({name}): {check.reason}")
        return GoalResponse.REJECT

    def _on_cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        return CancelResponse.ACCEPT

    async def _execute(self, handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        goal = handle.request
        record = GoalRecord(handle, jtc.resolve_tolerances(goal, self.node.joint_names,
                                                           self.options))
        self._pending[bytes(handle.goal_id.uuid)] = record
        # Velocities and accelerations filled in as a JTC interpolates, a control period apart.
        self.node.submit_goal(jtc_completed(goal.trajectory, self.node.tracker.h), record)
        return await record.done

    # ------------------------------------------------------------- outcomes
    def _finish(self, record: GoalRecord, event: str, code: int, text: str) -> None:
        """End a goal: ``event`` is ``succeed``, ``abort`` or ``canceled``."""
        self._pending.pop(bytes(record.handle.goal_id.uuid), None)
        if self.active is record:
            self.active = None
        handle = record.handle
        if handle.is_active:
            if event == "succeed":
                handle.succeed()
            elif event == "abort":
                handle.abort()
            else:
                if not handle.is_cancel_requested:
                    _enter_canceling(handle)  # a preemption
                handle.canceled()
        level = DiagnosticStatus.OK if code == jtc.SUCCESSFUL else DiagnosticStatus.WARN
        verb = {"succeed": "succeeded", "abort": "aborted", "canceled": "canceled"}[event]
        self.node.publish_status(level, f"goal {verb} ({jtc.CODE_NAMES[code]})"
                          + (f": {text}" if text else ""),
                          {"event": f"goal_{verb}", "error_code": str(code)})
        if not record.done.done():
            record.done.set_result(FollowJointTrajectory.Result(error_code=code,
                                                                error_string=text))

    def rejected(self, record: GoalRecord, reason: str) -> None:
        """The tracker refused an accepted goal's trajectory: abort it (INVALID_GOAL)."""
        self._finish(record, "abort", jtc.INVALID_GOAL, reason)

    def started(self, record: GoalRecord | None, nominal: NominalTrajectory,
                source: str = "a newer goal", elapsed: float = 0.0) -> None:
        """A trajectory started now: it preempts the active goal; ``record`` becomes it.

        ``elapsed``: how far along its own time it starts (s; a goal stamped in the future
        joins the running motion at its stamp, a JTC's replacement, and starts there).
        """
        if self.active is not None and self.active is not record:
            what = source if record is not None else "a trajectory on the topic"
            self._finish(self.active, "canceled", jtc.INVALID_GOAL, f"preempted by {what}")
        if record is not None:
            record.start = self.node.tracker.t - elapsed
            record.end = record.start + nominal.duration
            self.active = record
            if record.handle.is_cancel_requested:  # cancelled while queued: never moves
                self._hold()
                self._finish(record, "canceled", jtc.SUCCESSFUL, "canceled by the client")

    def replaced(self, record: GoalRecord | None, stamp: float) -> None:
        """A goal waiting for its stamp, replaced by one stamped ``stamp`` (s): CANCELED.

        Preempted, as a JTC's newer goal preempts; None (a topic trajectory): nothing.
        """
        if record is not None:
            self._finish(record, "canceled", jtc.INVALID_GOAL,
                         f"preempted by a goal stamped {stamp:.6f} before it took over")

    def stopped(self, reason: str, record: GoalRecord | None = None) -> None:
        """The trajectory was stopped (``~/reset``): abort the active goal, or ``record``.

        ``record``: a goal waiting for its stamp, dropped by the reset before it took over.
        """
        if record is not None:
            self._finish(record, "abort", jtc.INVALID_GOAL, reason)
        elif self.active is not None:
            self._finish(self.active, "abort", jtc.INVALID_GOAL, reason)

    def shutdown(self) -> None:
        """Abort every goal (the node is going away), then destroy the server."""
        for record in list(self._pending.values()):
            self._finish(record, "abort", jtc.INVALID_GOAL, "the tracker is shutting down")
        self._server.destroy()

    # --------------------------------------------------------------- ticks
    def update(self, log: TrackingLog, rows: np.ndarray) -> None:
        """After each simulation tick: cancel, tolerances, end, feedback and state.

        Parameters
        ----------
        log : TrackingLog
            The tick's control instants.
        rows : ndarray of int
            The instants published on ``joint_states`` (feedback and state go with them).
        """
        record = self.active
        if record is not None and len(log):
            self._check(record, log)
        if len(log):
            for i in rows:
                self._publish(log, int(i))

    def _hold(self) -> None:
        summary = self.node.tracker.hold()
        if summary is not None:
            self.node.publish_summary(summary)

    def _check(self, record: GoalRecord, log: TrackingLog) -> None:
        joints = self.node.joint_names
        if record.handle.is_cancel_requested:
            self._hold()
            self._finish(record, "canceled", jtc.SUCCESSFUL, "canceled by the client")
            return
        accel_error = np.zeros(len(joints))  # the plant's acceleration is not measured
        during = np.flatnonzero(log.t < record.end - 1e-12)
        for i in during:
            broken = jtc.path_violation(record.tolerances, log.error[i], log.error_rate[i],
                                        accel_error, joints)
            if broken is not None:
                self._hold()
                self._finish(record, "abort", jtc.PATH_TOLERANCE_VIOLATED,
                             f"at {log.t[i] - record.start:.3f} s: {broken}")
                return
        after = np.flatnonzero(log.t >= record.end - 1e-12)
        for i in after:
            missed = jtc.goal_reached(record.tolerances, log.error[i], log.qd[i],
                                      accel_error, joints)
            if missed is None:
                self._finish(record, "succeed", jtc.SUCCESSFUL, "")
                return
            if log.t[i] > record.end + record.tolerances.goal_time:
                self._finish(record, "abort", jtc.GOAL_TOLERANCE_VIOLATED,
                             f"{log.t[i] - record.end:.3f} s after the end: {missed}")
                return

    def _publish(self, log: TrackingLog, i: int) -> None:
        header = Header(stamp=conv.time_from_seconds(self.node.epoch + float(log.t[i])))
        record = self.active
        elapsed = (float(log.t[i]) - record.start) if record is not None else 0.0
        since = conv.duration_from_seconds(max(elapsed, 0.0))
        desired = JointTrajectoryPoint(positions=log.q_des[i].tolist(),
                                       velocities=log.qd_des[i].tolist(),
                                       time_from_start=since)
        actual = JointTrajectoryPoint(positions=log.q[i].tolist(),
                                      velocities=log.qd[i].tolist(), time_from_start=since)
        error = JointTrajectoryPoint(positions=log.error[i].tolist(),
                                     velocities=log.error_rate[i].tolist(),
                                     time_from_start=since)
        output = JointTrajectoryPoint(effort=log.tau[i].tolist(), time_from_start=since)
        joints = list(self.node.joint_names)
        self._state_pub.publish(JointTrajectoryControllerState(
            header=header, joint_names=joints, reference=desired, feedback=actual,
            error=error, output=output, speed_scaling_factor=1.0))
        if record is not None and record.handle.is_active:
            record.handle.publish_feedback(FollowJointTrajectory.Feedback(
                header=header, joint_names=joints, desired=desired, actual=actual,
                error=error))
