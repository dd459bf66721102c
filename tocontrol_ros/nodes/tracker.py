"""The tracker node: executes planned trajectories on a simulated arm, nominal torques + PD.

Run as ``ros2 run tocontrol_ros tracker`` (either install route), ``tocontrol-tracker`` (pip)
or ``python -m tocontrol_ros.tracker``; parameters from ``config/tracker.yaml`` with
``--ros-args --params-file``. The simulation and the control law are
:mod:`tocontrol_ros.core.sim.tracking`; this node converts messages, keeps the clock and
publishes. Interfaces (one page each in ``msg_docs/``):

- subscribed: the planner's ``trajectory_msgs/msg/JointTrajectory`` (parameter
  ``trajectory_topic``, default ``/planner/trajectory``; reliable, transient local, so the
  planner's latched last plan arrives on start-up). A trajectory stamped ahead of the
  tracker's time (at most 60 s) is spliced in at that control instant (a replan,
  :mod:`tocontrol_ros.nodes.splice`); otherwise it starts when it is received and replaces
  the running one from the current plant state;
  with ``start_at_first_trajectory`` the first one puts the arm at its first point (a
  free-start plan, whose start configuration the planner chooses);
- published: ``joint_states`` (``sensor_msgs/msg/JointState``: position, velocity,
  effort = torque acting on the joint), ``~/tracking_error`` (``sensor_msgs/msg/JointState``:
  position = ``q_des - q``, velocity = ``qd_des - qd``, effort = feedback torque
  ``(u - u_nom) tau_max``), ``~/status`` (``diagnostic_msgs/msg/DiagnosticStatus``: accepted,
  rejected, completed and preempted trajectories, with the run summary; a start event carries
  the plant state it starts from, ``start_position.<joint>`` and ``start_velocity.<joint>``),
  and ``/clock`` (``rosgraph_msgs/msg/Clock``) when ``publish_clock`` is true;
- served: ``~/follow_joint_trajectory`` (``control_msgs/action/FollowJointTrajectory``, a
  joint_trajectory_controller's goal checks, tolerances, results, cancel and preemption) and
  published ``~/controller_state``: :mod:`tocontrol_ros.nodes.follow_action`;
- subscribed: ``~/reset`` (``sensor_msgs/msg/JointState``: names, positions, optional
  velocities): puts the plant at that state now and holds it, stopping a running trajectory
  (``replay --reexecute`` re-executes a recorded run from its recorded initial state); the
  ``~/status`` event (key ``event`` = ``reset``) echoes the request's stamp.

Time: a wall-clock timer (``update_rate``) advances the simulation by the wall time elapsed
times ``time_scale``, in whole control periods. Messages are stamped with the simulated
time: offset from the node's start time (so that with ``time_scale = 1`` stamps follow the
node's clock), or from zero when ``publish_clock`` is true, and then ``/clock`` carries the
same time (other nodes follow it with ``use_sim_time``). With ``use_sim_time`` true the
simulation follows the ROS clock on ``/clock`` instead (``time_scale`` is then unused): it
waits for the first ``/clock``, stamps with that time, and counts again from the clock if
it jumps back (a looped replay). ``joint_states`` and ``~/tracking_error`` are published
every ``1 / publish_rate`` seconds of simulated time.
"""

from __future__ import annotations

import argparse
import sys
import threading
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.sim.tracking import (
    NominalTrajectory,
    Tracker,
    TrackingSummary,
)
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import qos
from tocontrol_ros.nodes.diagnostics import Diagnostics, tracker_state
from tocontrol_ros.nodes.follow_action import FollowServer, GoalRecord
from tocontrol_ros.nodes.node_main import run_node
from tocontrol_ros.nodes.params import (
    declare_all,
    parameters_parser,
    robot_from_topic,
)
from tocontrol_ros.nodes.splice import (
    Splice,
    jumps,
    schedule,
    take_over_elapsed,
    take_over_instant,
)
from tocontrol_ros.nodes.tracker_config import PARAMETERS, TrackerConfig, plant_text
from tocontrol_ros.nodes.tracker_messages import (
    ResetRequest,
    TrajectoryRejectedError,
    check_limits,
    nominal_from_msg,
    nominal_of,
    rejected_status,
    replaced_status,
    reset_request,
    reset_state_from_msg,
    rest_row,
    splice_event,
    start_event,
    start_state_values,
    state_msgs,
    status_msg,
    summary_status,
)
from tocontrol_ros.nodes.tracker_time import (
    START_HISTORY,
    PositionHistory,
    PublishSchedule,
    SimClock,
)

__all__ = ["TrackerNode", "TrajectoryRejectedError",
           "nominal_from_msg", "check_limits", "reset_state_from_msg", "summary_status",
           "build_parser", "main"]


#: The planner's trajectory is latched (its publisher keeps the last plan for a tracker that
#: starts late). The subscription keeps up to 10 unread ones: replans 100 ms apart that
#: arrive while a timer tick runs (a loaded machine) are all parsed, not only the newest (a
#: replan dropped here breaks the chain of splices planned from each other).
QOS_TRAJECTORY = qos.profile(10, latched=True)
#: Streams: reliable publishers match both reliable and best-effort subscribers.
QOS_STREAM = qos.RELIABLE
#: Status events; the last few are kept for late subscribers.
QOS_STATUS = qos.status_profile(20, latched=True)


class _Goal(NamedTuple):
    """An action goal's trajectory in the parsing queue: parsed (or refused) and its goal."""

    item: Any
    record: GoalRecord


# -------------------------------------------------------------------------- node
class TrackerNode(Node):
    """Simulated arm under the tracking law; see the module docstring for its interfaces.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).
    """

    def __init__(self, node_name: str = "tracker", **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.config = TrackerConfig.from_values(
            robot_from_topic(self, declare_all(self, PARAMETERS)))
        self.model, bundled = self.config.load_model()
        self.joint_names = list(self.model.joint_names)
        q0 = self.config.start_configuration(self.model, bundled)
        self.tracker = Tracker(self.model, self.config.plant, self.config.gains, q0=q0)
        self.tracker.prepare()  # compile the control period now, not in the first tick

        self._pub_joints = self.create_publisher(JointState, "joint_states", QOS_STREAM)
        self._pub_error = self.create_publisher(JointState, "~/tracking_error", QOS_STREAM)
        self._pub_status = self.create_publisher(DiagnosticStatus, "~/status", QOS_STATUS)
        self._pub_clock = (self.create_publisher(Clock, "/clock", QOS_STREAM)
                           if self.config.publish_clock else None)
        # Raw: the bytes, read in the parser thread (no message objects on the executor).
        self.create_subscription(JointTrajectory, self.config.trajectory_topic,
                                 self._on_trajectory, QOS_TRAJECTORY, raw=True)
        self.create_subscription(JointState, "~/reset", self._on_reset, QOS_STREAM)
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        if self._sim_time and self.config.publish_clock:
            raise ProblemError("`use_sim_time` and `publish_clock` cannot both be true (the "
                               "tracker would follow its own clock)")
        self._time = SimClock(self.config.time_scale, 0.0 if self.config.publish_clock
                              or self._sim_time else self.get_clock().now().nanoseconds * 1e-9)
        self._schedule = PublishSchedule(self.config.publish_rate)
        self.trajectories_received = 0
        self._parser = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tracker-parse")
        self._parsed_lock = threading.Lock()
        self._parsed: list = []  # NominalTrajectory, rejection or reset, in arrival order
        self._splices: list[Splice] = []  # stamped trajectories waiting for their instant
        self._history = PositionHistory(START_HISTORY)  # positions published
        # Until the first motion or reset: the next trajectory places the arm at its start.
        self._place_at_start = self.config.start_at_first_trajectory
        if not self._sim_time:
            self._publish_state(self._initial_row())
        # Wall time even with use_sim_time: the tick reads the ROS clock (a sim-time timer
        # would not fire at all before the first /clock).
        self.create_timer(1.0 / self.config.update_rate, self._on_timer,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self._follow = FollowServer(self)  # ~/follow_joint_trajectory, ~/controller_state
        self.diagnostics = Diagnostics(self, self.model.name, lambda: tracker_state(self))
        self.get_logger().info(
            f"tracking on {self.model.name!r} ({self.model.n} joints) from "
            f"{self.config.trajectory_topic}; plant: {plant_text(self.config.plant)}; "
            f"time_scale {self.config.time_scale:g}")

    # ------------------------------------------- the action server's interface
    @property
    def epoch(self) -> float:
        """The stamps' time (s) at the simulation's time 0: a stamp is ``epoch + t``."""
        return self._time.epoch

    def publish_status(self, level: bytes, message: str,
                       values: Mapping[str, str] = ()) -> None:
        """A ``~/status`` event (``level``: a ``DiagnosticStatus`` level)."""
        self._pub_status.publish(status_msg(level, self.get_fully_qualified_name(), message,
                                            self.model.name, values))

    def publish_summary(self, summary: TrackingSummary | None) -> None:
        """A run's summary on ``~/status`` (completed, preempted, held); None: nothing."""
        if summary is not None:
            self._pub_status.publish(summary_status(
                summary, self.get_fully_qualified_name(), self.model.name, self.joint_names))

    def _initial_row(self) -> dict:
        return rest_row(self.tracker.t, self.tracker.q, self.tracker.qd)

    # -------------------------------------------------------------- callbacks
    def _on_trajectory(self, data: bytes) -> None:
        # The serialized message: reading it (its size checked first) runs off the executor,
        # so that a large trajectory never holds up the control loop (the timer picks the
        # result up).
        self.trajectories_received += 1
        try:
            self._parser.submit(self._parse, data)
        except RuntimeError:  # the node is shutting down
            return

    def submit_goal(self, msg: JointTrajectory, record: GoalRecord) -> None:
        """Queue an accepted action goal's trajectory (parsed like the topic's)."""
        try:
            self._parser.submit(self._parse, msg, record)
        except RuntimeError:  # the node is shutting down
            self._follow.rejected(record, "the tracker is shutting down")

    def _parse(self, msg: JointTrajectory | bytes, record: GoalRecord | None = None) -> None:
        try:
            nominal, stamp = nominal_of(msg, self.joint_names, self.model.inverse_dynamics,
                                        self.config.max_points)
            check_limits(nominal, self.tracker.tau_max, self.config.max_duration)
            item = (nominal, stamp)
        except TrajectoryRejectedError as exc:
            item = exc
        except Exception as exc:  # noqa: BLE001  (a bug must not lose the message silently)
            item = TrajectoryRejectedError(f"cannot be parsed: {exc!r}")
        if record is not None:
            item = _Goal(item, record)
        with self._parsed_lock:
            self._parsed.append(item)

    def _reject(self, reason: str, record: GoalRecord | None = None, stamp=None) -> None:
        text = f"trajectory rejected: {reason}"
        if record is not None:
            self._follow.rejected(record, text)
        self.publish_status(*rejected_status(text, self.tracker.running, stamp))
        self.get_logger().warning(text)

    def _start_parsed(self) -> None:
        """Start (or reject) the trajectories parsed since the last tick, in arrival order."""
        with self._parsed_lock:
            items, self._parsed = self._parsed, []
        for item in items:
            record = None
            if isinstance(item, _Goal):
                item, record = item
            if isinstance(item, TrajectoryRejectedError):
                self._reject(str(item), record)
                continue
            if isinstance(item, ResetRequest):
                self._apply_reset(item)
                continue
            nominal, stamp = item
            if self._sim_time:
                self._follow_clock()  # a trajectory right after the first /clock: stamp with it
            if self._schedule_splice(nominal, stamp, record):
                continue
            placed = self._place_at_start
            if placed:
                self._place_at(nominal)
            # Planned from a state the arm had (published in the last START_HISTORY s).
            offset, refused = self._history.start_gap(nominal.q[0], self.tracker.q,
                                                      self.config.start_tolerance,
                                                      self.joint_names)
            if refused and not placed:
                self._reject(refused, record, stamp)
                continue
            # The state it starts from, for re-execution (the status is latched: a recorder
            # that subscribes late still gets it).
            state = start_state_values(self.joint_names, self.tracker.q, self.tracker.qd)
            self._place_at_start = False
            self._drop_pending(self._splices, stamp)  # planned before it: it replaces them
            self._splices = []
            self.publish_summary(self.tracker.start(nominal))  # the one it preempted
            self._follow.started(record, nominal)
            self.publish_status(DiagnosticStatus.OK, *start_event(
                nominal, stamp, offset, placed, self.epoch + self.tracker.t, state))

    def _schedule_splice(self, nominal: NominalTrajectory, stamp: float, record=None) -> bool:
        """A stamp ahead of the simulation's time: queue it (and its goal) for then (True)."""
        t = self.tracker  # its time, not the tick's target: a stamp within the tick is ahead
        instant = None if self._target_time() is None or self._place_at_start else \
            take_over_instant(stamp, self.epoch, t.t, t.h, t.running, record is not None)
        if instant is None:
            return False
        self._splices, dropped = schedule(self._splices,
                                          Splice(nominal, instant[0], instant[1], stamp, record))
        self._drop_pending(dropped, stamp)
        return True

    def _drop_pending(self, dropped: list[Splice], stamp: float) -> None:
        """Report pending splices replaced by a trajectory stamped ``stamp`` (s)."""
        for old in dropped:
            self._follow.replaced(old.record, stamp)  # a JTC's newer goal preempts it
            self.publish_status(DiagnosticStatus.WARN, *replaced_status(old.stamp, stamp))

    def _splice(self, splice: Splice) -> None:
        """The stamped trajectory takes over now (the tracker is at its instant)."""
        tracker = self.tracker
        old = tracker.commanded(tracker.t)
        elapsed = take_over_elapsed(splice, tracker.running, tracker.h)
        des = splice.nominal.evaluate(elapsed)
        dq, dqd = jumps(old, (des.q[0], des.qd[0]))
        if dq > self.config.start_tolerance:
            self._reject(f"stamped {splice.stamp:.6f}: at its take-over its position is "
                         f"{dq:.3g} rad from the commanded one, more than start_tolerance = "
                         f"{self.config.start_tolerance:g}", splice.record, splice.stamp)
            return
        self.publish_summary(tracker.start(splice.nominal, elapsed))  # the one preempted
        self._follow.started(splice.record, splice.nominal, elapsed=elapsed)
        self.publish_status(DiagnosticStatus.OK,
                            *splice_event(splice, dq, dqd, self.epoch + tracker.t, tracker.h))

    def _on_reset(self, msg: JointState) -> None:
        # Through the parsing thread's queue: a reset takes effect after the trajectories
        # received before it, never before (the timer applies both in arrival order).
        try:
            self._parser.submit(self._parse_reset, msg)
        except RuntimeError:  # the node is shutting down
            return

    def _parse_reset(self, msg: JointState) -> None:
        item = reset_request(msg, self.joint_names)
        with self._parsed_lock:
            self._parsed.append(item)

    def _apply_reset(self, item: ResetRequest) -> None:
        if item.error is not None:
            self.publish_status(DiagnosticStatus.ERROR, f"reset rejected: {item.error}",
                                {"event": "reset_rejected"})
            self.get_logger().warning(f"reset rejected: {item.error}")
            return
        q, qd = item.q, item.qd
        self._place_at_start = False
        for record in [s.record for s in self._splices if s.record is not None]:
            self._follow.stopped("stopped by ~/reset before it took over", record)
        self._splices, preempted = [], self.tracker.reset(q, qd)
        if preempted is not None:
            self.publish_summary(preempted)
        self._follow.stopped("stopped by ~/reset")
        self.publish_status(DiagnosticStatus.OK,
                            f"reset to positions {np.round(q, 6).tolist()}, velocities "
                            f"{np.round(qd, 6).tolist()}; holding",
                            {"event": "reset", "request_stamp": item.stamp})
        # The arm was put elsewhere: the positions it had before are no start for a plan.
        self._history.clear()
        self._publish_state(self._initial_row())

    def _place_at(self, nominal: NominalTrajectory) -> None:
        """``start_at_first_trajectory``: the plant at the trajectory's first point."""
        n = self.model.n
        offset = self.config.plant.offset(n)
        self.tracker.reset(nominal.q[0] + offset[:n], nominal.qd[0] + offset[n:])
        self._history.clear()
        # The state it is put at, stamped now: the recorded motion starts from it.
        self._publish_state(self._initial_row())
        self.get_logger().info(f"start_at_first_trajectory: arm placed at "
                               f"{np.round(self.tracker.q, 6).tolist()}")

    def destroy_node(self) -> None:
        """Stop the parsing thread, then destroy the node."""
        self._parser.shutdown(wait=False, cancel_futures=True)
        self._follow.shutdown()
        super().destroy_node()

    def _target_time(self) -> float | None:
        """Simulated time to advance to; None while waiting for the first /clock."""
        if not self._sim_time:
            return self._time.wall_target()
        return self._time.ros_target(self._follow_clock())

    def _follow_clock(self) -> float | None:
        """With use_sim_time: the ROS time (s), the epoch set from it; None before /clock."""
        now, first = self._time.follow(self.get_clock().now().nanoseconds * 1e-9,
                                       self.tracker.t, self.tracker.h)
        if first:
            self._publish_state(self._initial_row())
        return now

    def _on_timer(self) -> None:
        self._start_parsed()
        target = self._target_time()
        if target is None:
            return
        tracker = self.tracker
        # Cannot keep up with time_scale: simulate what one tick may, drop the rest.
        target, dropped = self._time.limit(target, tracker.t, tracker.h)
        if dropped:
            self.get_logger().warning(
                f"the simulation cannot keep up with time_scale {self.config.time_scale:g}; "
                f"dropped {dropped:.3f} s of simulated time", throttle_duration_sec=5.0)
        while self._splices and self._splices[0].at <= target + 1e-9:
            splice = self._splices.pop(0)
            self._publish_report(tracker.advance(splice.at))
            self._splice(splice)
        self._publish_report(tracker.advance(target))
        if self._pub_clock is not None:
            self._pub_clock.publish(Clock(clock=conv.time_from_seconds(self.epoch + tracker.t)))

    def _publish_report(self, report) -> None:
        """The states and run summaries of one stretch of simulation."""
        tracker = self.tracker
        log = report.log
        rows = self._schedule.rows(log.t) if len(log) else np.zeros(0, dtype=int)
        for i in rows:
            self._publish_state({
                "t": log.t[i], "q": log.q[i], "qd": log.qd[i], "error": log.error[i],
                "error_rate": log.error_rate[i],
                "feedback": (log.u[i] - log.u_nom[i]) * tracker.tau_max, "tau": log.tau[i]})
        self._follow.update(log, rows)
        # After the states: whoever acts on "completed" (e.g. sends the next goal, which the
        # planner plans from the latest joint state) has seen the final state by then.
        for summary in report.summaries:
            self.publish_summary(summary)

    def _publish_state(self, row: Mapping[str, Any]) -> None:
        self._history.add(row["q"])
        joints, error = state_msgs(self.joint_names, self.epoch + float(row["t"]), row)
        self._pub_joints.publish(joints)
        self._pub_error.publish(error)


def build_parser() -> argparse.ArgumentParser:
    """Command line of ``ros2 run tocontrol_ros tracker``: only ``--help`` (ROS parameters)."""
    return parameters_parser(
        "tracker",
        "Execute planned trajectories on a simulated arm: nominal torques plus "
        "PD feedback, saturated to |u_i| <= 1. Settings are ROS parameters "
        "(--ros-args -p name:=value or --params-file config/tracker.yaml).",
        PARAMETERS)


def main(args=None) -> int:
    """Spin a :class:`TrackerNode` (``ros2 run tocontrol_ros tracker``) until it is stopped.

    ``args`` (the command line, program name first; ``sys.argv`` if None) and the exit
    status are :func:`~tocontrol_ros.nodes.node_main.run_node`'s.
    """
    return run_node("tracker", args, TrackerNode, parser=build_parser())


if __name__ == "__main__":
    sys.exit(main())
