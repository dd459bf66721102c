"""The planner's plans, executed on a controller through ``FollowJointTrajectory``.

With ``controller_action`` set, the planner sends every trajectory it publishes on
``~/trajectory`` to that ``control_msgs/action/FollowJointTrajectory`` action (the tracker's,
or a ros2_control ``joint_trajectory_controller``'s) and reports the outcome on ``~/status``
(events ``sent``, ``rejected``, ``executed``; msg_docs/controller_execution.md).

What is sent is what a default-configured Jazzy JTC accepts (:func:`controller_goal`):
``header.stamp`` zero (start now), or a replan's future hand-off (the JTC joins it to the
running trajectory there), the last point's velocities and accelerations exactly zero,
effort only with ``controller_effort``. A newer plan preempts the goal being executed (the
controller cancels it, as a JTC does).

``control_msgs`` is imported when a controller is used (``controller_action`` set, or
:func:`controller_goal` called): a pip install without it still plans (issue 52);
:func:`control_msgs_types` names what is missing.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

from builtin_interfaces.msg import Time
from trajectory_msgs.msg import JointTrajectory

from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.action_calls import SerialActionClient
from tocontrol_ros.nodes.jtc_checks import CODE_NAMES

__all__ = ["controller_goal", "control_msgs_types", "ControllerClient", "GOAL_STATUS_NAMES",
           "MissingInterfaceError"]

#: How long (s) a plan waits for the controller's action server to be discovered before it
#: is reported ``rejected``: a controller started with the planner (or on a loaded machine)
#: may not be discovered when the first plan is ready (seen in CI: the planner's first plan
#: found no server though the test's own client had found it). The planner's worker waits
#: only while the server is not yet known.
SERVER_WAIT = 10.0
#: ``action_msgs/msg/GoalStatus`` codes -> names.
GOAL_STATUS_NAMES = {0: "UNKNOWN", 1: "ACCEPTED", 2: "EXECUTING", 3: "CANCELING",
                     4: "SUCCEEDED", 5: "CANCELED", 6: "ABORTED"}


class MissingInterfaceError(ValueError):
    """A feature was asked for whose interface package is not installed."""


def control_msgs_types() -> tuple[type, type]:
    """``(FollowJointTrajectory, JointTolerance)``, imported now.

    Raises
    ------
    MissingInterfaceError
        ``control_msgs`` is not importable: the message says how to get it.
    """
    try:
        from control_msgs.action import FollowJointTrajectory
        from control_msgs.msg import JointTolerance
    except ImportError as exc:
        raise MissingInterfaceError(
            f"`controller_action` needs the control_msgs interfaces ({exc}): install "
            "ros-jazzy-control-msgs (a ROS install), or build interfaces/control_msgs into "
            "the environment (scripts/dev setup, interfaces/README.md); leave "
            "controller_action empty to plan without a controller") from exc
    return FollowJointTrajectory, JointTolerance


def controller_goal(trajectory: JointTrajectory, effort: bool = False,
                    goal_time_tolerance: float = 0.0, goal_tolerance: float = 0.0,
                    path_tolerance: float = 0.0, now_ns: int | None = None):
    """A ``FollowJointTrajectory`` goal of a planned trajectory, as a Jazzy JTC accepts it.

    Parameters
    ----------
    trajectory : trajectory_msgs.msg.JointTrajectory
        The planner's ``~/trajectory`` (not modified).
    effort : bool
        Keep the nominal torques (a controller with an effort command interface).
    goal_time_tolerance : float
        s; 0 = the controller's default.
    goal_tolerance, path_tolerance : float
        Position tolerance of every joint (rad, m); 0 = the controller's default.
    now_ns : int, optional
        The controller's clock now (ns): a trajectory stamped after it (a replan, stamped
        with its hand-off) keeps its stamp, and a JTC joins it to the running trajectory
        there (shared/DESIGN.md, "How a trajectory controller splices"). Default (None), or a
        stamp not after it: stamp zero.

    Returns
    -------
    FollowJointTrajectory.Goal
        ``header.stamp`` zero (start when received) or the future hand-off, the last
        point's velocities and
        accelerations exactly zero (the plan ends at rest to the solver's accuracy; a JTC
        refuses a non-zero end velocity by default), no effort unless ``effort``.
    """
    follow_joint_trajectory, joint_tolerance = control_msgs_types()
    msg = copy.deepcopy(trajectory)
    if now_ns is None or conv.nanoseconds(msg.header.stamp) <= now_ns:
        msg.header.stamp = Time()
    if not effort:
        for point in msg.points:
            point.effort = []
    if msg.points:
        last = msg.points[-1]
        last.velocities = [0.0] * len(last.velocities)
        last.accelerations = [0.0] * len(last.accelerations)

    def tolerances(value: float) -> list:
        if value <= 0.0:
            return []
        return [joint_tolerance(name=name, position=value) for name in msg.joint_names]

    return follow_joint_trajectory.Goal(
        trajectory=msg, goal_tolerance=tolerances(goal_tolerance),
        path_tolerance=tolerances(path_tolerance),
        goal_time_tolerance=conv.duration_from_seconds(goal_time_tolerance))


class ControllerClient:
    """Sends plans to a ``FollowJointTrajectory`` action and reports what became of them.

    Parameters
    ----------
    node : rclpy.node.Node
    action_name : str
        The controller's action; empty: none (:meth:`send` does nothing, and
        ``control_msgs`` is not imported).
    publish_status : callable
        ``publish_status(level, message, values)``: the planner's ``~/status``; ``values``
        carry ``request_id`` and ``event``.

    Raises
    ------
    MissingInterfaceError
        ``action_name`` is set but ``control_msgs`` is not installed.
    """

    def __init__(self, node, action_name: str,
                 publish_status: Callable[[str, str, dict], None]) -> None:
        self.action_name = action_name
        self._now_ns = lambda: node.get_clock().now().nanoseconds
        # Requests made on the executor: rclpy's race would lose a response (action_calls).
        self._client = SerialActionClient(node, control_msgs_types()[0], action_name) \
            if action_name else None
        self._publish_status = publish_status
        #: Told ``(request_id, reason)`` when the controller refuses a plan, or aborts it
        #: with an error (the planning service's ``controller_refused``); None: nobody.
        self.on_refused: Callable[[int, str], None] | None = None

    def _refused(self, request_id: int, reason: str) -> None:
        if self.on_refused is not None:
            self.on_refused(request_id, reason)

    def _report(self, request_id: int, level: str, event: str, message: str,
                values: dict) -> None:
        self._publish_status(level, message, {"request_id": request_id, "event": event,
                                              **values})

    def send(self, request_id: int, trajectory: JointTrajectory, config) -> None:
        """Send one plan (from any thread); the outcome comes on ``~/status``.

        Parameters
        ----------
        request_id : int
        trajectory : trajectory_msgs.msg.JointTrajectory
            As published on ``~/trajectory``.
        config : PlannerConfig
            Its ``controller_*`` values.
        """
        if self._client is None:
            return
        values = {"controller_action": self.action_name, "points": len(trajectory.points)}
        if not self._client.wait_for_server(SERVER_WAIT):  # at once when known
            self._report(request_id, "ERROR", "rejected",
                         f"request {request_id}: no FollowJointTrajectory server at "
                         f"{self.action_name} within {SERVER_WAIT:g} s; the plan was not "
                         f"executed", values)
            self._refused(request_id, f"no controller at {self.action_name}")
            return
        # The clock read after the wait: a stamp still ahead now is a replan's hand-off.
        goal = controller_goal(trajectory, config.controller_effort,
                               config.controller_goal_time_tolerance,
                               config.controller_goal_tolerance,
                               config.controller_path_tolerance, now_ns=self._now_ns())
        future = self._client.send_goal(goal)
        future.add_done_callback(lambda f: self._on_response(request_id, f, values))
        self._report(request_id, "OK", "sent", f"request {request_id}: plan sent to "
                     f"{self.action_name}", values)

    def _on_response(self, request_id: int, future, values: dict) -> None:
        handle = future.result()
        if handle is None or not handle.accepted:
            self._report(request_id, "ERROR", "rejected",
                         f"request {request_id}: the controller at {self.action_name} "
                         f"rejected the plan (see its log for the reason)", values)
            self._refused(request_id, f"the controller at {self.action_name} rejected it")
            return
        self._client.get_result(handle).add_done_callback(
            lambda f: self._on_result(request_id, f, values))

    def _on_result(self, request_id: int, future, values: dict) -> None:
        response = future.result()
        status = GOAL_STATUS_NAMES.get(response.status, str(response.status))
        code = response.result.error_code
        text = response.result.error_string
        level = "OK" if status == "SUCCEEDED" and code == 0 else "WARN"
        self._report(request_id, level, "executed",
                     f"request {request_id}: execution {status.lower()} "
                     f"({CODE_NAMES.get(code, str(code))})" + (f": {text}" if text else ""),
                     {**values, "goal_status": status, "error_code": code,
                      "error_string": text})
        if status == "ABORTED":  # a goal preempted by a newer one ends CANCELED
            self._refused(request_id, f"the controller at {self.action_name} ended it "
                          f"{status.lower()} ({CODE_NAMES.get(code, str(code))})")

    def destroy(self) -> None:
        """Destroy the action client."""
        if self._client is not None:
            self._client.destroy()
