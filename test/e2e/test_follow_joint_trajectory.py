"""FollowJointTrajectory end to end: the planner executes its plan on the tracker's action.

Two processes as deployed (their installed executables): the tracker serving
``~/follow_joint_trajectory`` and the planner with ``controller_action`` pointing at it. A
goal on the planner's ``~/goal`` is planned from the tracker's joint states, sent to the
action and succeeds within the planner's tolerances; then a client sends goals to the
tracker directly: rejected goals, preemption by a newer goal, cancel, a broken path
tolerance and a missed goal tolerance end with the codes a Jazzy joint_trajectory_controller
gives. Both processes live for the module (about 10 s of start-up, mostly the planner's).
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance, JointTrajectoryControllerState
from node_process import NodeProcess
from planner_harness import PlannerClient
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tocontrol_ros.core.examples import PAPER_TARGET
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import jtc_checks as jtc
from tocontrol_ros.nodes.action_calls import SerialActionClient
from tocontrol_ros.nodes.controller_client import controller_goal

pytestmark = pytest.mark.ros
JOINTS = ["joint1", "joint2", "joint3"]
#: The planner's tolerances for its goals (rad): the identical simulated plant tracks its
#: plans to well under a milliradian.
GOAL_TOLERANCE = 0.01
PATH_TOLERANCE = 0.05


class Nodes:
    """The two processes and a client node: planner client, action client, joint states."""

    def __init__(self, tmp_path) -> None:
        self.ns = f"/fjt_{os.getpid()}"
        ros = ["--ros-args", "-r", f"__ns:={self.ns}"]
        self.tracker = NodeProcess("tracker", ros + [
            "-p", f"trajectory_topic:={self.ns}/no_topic_input"], tmp_path)
        self.planner = NodeProcess("planner", ros + [
            "-p", f"controller_action:={self.ns}/tracker/follow_joint_trajectory",
            "-p", "starts:=1", "-p", "candidates:=1",
            "-p", f"controller_goal_tolerance:={GOAL_TOLERANCE}",
            "-p", f"controller_path_tolerance:={PATH_TOLERANCE}"], tmp_path)
        self.client = PlannerClient(f"{self.ns}/planner")
        node = self.client.node
        self._lock = threading.Lock()
        self.joint_state: JointState | None = None
        self.states: list[JointTrajectoryControllerState] = []
        node.create_subscription(JointState, f"{self.ns}/joint_states", self._on_joints,
                                 QoSProfile(depth=10))
        node.create_subscription(JointTrajectoryControllerState,
                                 f"{self.ns}/tracker/controller_state", self._on_state,
                                 QoSProfile(depth=10))
        # Requests on the executor: rclpy 7.1's race loses a fast response (a rejected goal)
        # when the request is made from this thread (nodes/action_calls.py).
        self.action = SerialActionClient(node, FollowJointTrajectory,
                                         f"{self.ns}/tracker/follow_joint_trajectory")
        self.feedback: list = []

    def _on_joints(self, msg: JointState) -> None:
        with self._lock:
            self.joint_state = msg

    def _on_state(self, msg: JointTrajectoryControllerState) -> None:
        with self._lock:
            self.states.append(msg)

    def logs(self) -> str:
        return "\n".join(f"--- {p.log.name}\n{p.log.read_text()[-3000:]}"
                         for p in (self.tracker, self.planner))

    def q(self) -> np.ndarray:
        self.client.wait_for(lambda: self.joint_state is not None, 30.0, "joint states")
        with self._lock:
            return np.array(self.joint_state.position)

    def send(self, goal: FollowJointTrajectory.Goal):
        future = self.action.send_goal(
            goal, feedback_callback=lambda f: self.feedback.append(f))
        self.client.wait_for(future.done, 10.0, "the goal response")
        return future.result()

    def result(self, handle, timeout: float = 20.0):
        future = self.action.get_result(handle)
        self.client.wait_for(future.done, timeout, "the goal's result")
        return future.result()

    def stop(self) -> list[int]:
        self.client.close()
        return [self.planner.stop(), self.tracker.stop()]


@pytest.fixture(scope="module")
def nodes(tmp_path_factory):
    n = Nodes(tmp_path_factory.mktemp("fjt"))
    try:
        assert n.action.wait_for_server(60.0), n.logs()
        n.client.wait_ready(120.0)
        yield n
    finally:
        codes = n.stop()
    assert codes == [0, 0], n.logs()


def move(q0, dq, duration: float, points: int = 21, names=JOINTS) -> JointTrajectory:
    """A rest-to-rest quintic move from ``q0`` by ``dq`` (rad) in ``duration`` s."""
    q0, dq = np.asarray(q0, dtype=float), np.asarray(dq, dtype=float)
    traj = JointTrajectory(joint_names=list(names))
    for t in np.linspace(0.0, duration, points):
        s = t / duration
        pos = 10 * s**3 - 15 * s**4 + 6 * s**5
        vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
        acc = (60 * s - 180 * s**2 + 120 * s**3) / duration**2
        traj.points.append(JointTrajectoryPoint(
            positions=(q0 + dq * pos).tolist(), velocities=(dq * vel).tolist(),
            accelerations=(dq * acc).tolist(), time_from_start=conv.duration_from_seconds(t)))
    return traj


def test_the_planners_plan_executes_on_the_trackers_action(nodes):
    client = nodes.client
    nodes.q()  # the tracker is up: the planner plans from its joint states
    client.wait_joint_states(120.0)  # once it receives them
    since = len(client.status_list())
    client.send_goal(PAPER_TARGET)
    solved = client.final_status(since, 120.0)
    assert solved.event == "solved", (solved.message, nodes.logs())
    rid = solved.request_id
    executed = client.wait_for(
        lambda: next((s for s in client.status_list()[since:]
                      if s.event in ("executed", "rejected") and s.request_id == rid), None),
        30.0, "the execution's outcome")
    assert executed.event == "executed", (executed.message, nodes.logs())
    assert executed.values["goal_status"] == "SUCCEEDED", executed.message
    assert executed.values["error_code"] == "0"
    # The plan as sent: what a default Jazzy JTC accepts (no effort, end at rest, stamp 0).
    published = client.wait_for(lambda: client.trajectories[-1:], 10.0, "the trajectory")[0]
    goal = controller_goal(published, effort=False)
    assert jtc.check_goal(goal.trajectory, JOINTS, 0.0).accepted
    # The arm is at the target within the goal tolerance, and the state topic says so.
    final = np.array(published.points[-1].positions)
    assert np.max(np.abs(nodes.q() - final)) < GOAL_TOLERANCE
    state = nodes.client.wait_for(lambda: nodes.states[-1:], 10.0, "controller state")[0]
    assert list(state.joint_names) == JOINTS and state.speed_scaling_factor == 1.0


def test_a_newer_goal_preempts_and_a_cancel_stops(nodes):
    q = nodes.q()
    first = nodes.send(FollowJointTrajectory.Goal(trajectory=move(q, [0.2, 0.0, 0.0], 4.0)))
    assert first.accepted
    count = len(nodes.feedback)
    nodes.client.wait_for(lambda: len(nodes.feedback) > count, 10.0, "feedback of the goal")
    second = nodes.send(FollowJointTrajectory.Goal(trajectory=move(nodes.q(), [-0.2, 0, 0], 4.0)))
    assert second.accepted
    preempted = nodes.result(first)
    assert preempted.status == GoalStatus.STATUS_CANCELED
    assert preempted.result.error_code == jtc.INVALID_GOAL
    assert "preempted by a newer goal" in preempted.result.error_string
    cancel = nodes.action.cancel(second)
    nodes.client.wait_for(cancel.done, 10.0, "the cancel response")
    canceled = nodes.result(second)
    assert canceled.status == GoalStatus.STATUS_CANCELED
    assert canceled.result.error_code == jtc.SUCCESSFUL


@pytest.mark.parametrize("change, reason", [
    (lambda t: setattr(t.points[-1], "velocities", [0.1, 0.0, 0.0]), "velocity is not zero"),
    (lambda t: setattr(t, "joint_names", ["joint1", "joint2", "elbow"]), "elbow"),
    (lambda t: setattr(t.points[3], "velocities", [0.0, 0.0]), "velocities has 2 values"),
])
def test_bad_goals_are_rejected_and_the_reason_is_on_status(nodes, change, reason):
    trajectory = move(nodes.q(), [0.05, 0.0, 0.0], 0.5)
    change(trajectory)
    assert not nodes.send(FollowJointTrajectory.Goal(trajectory=trajectory)).accepted
    # the tracker's ~/status says why (and keeps serving: the next test's goals run)
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.qos import DurabilityPolicy

    got = []
    sub = nodes.client.node.create_subscription(
        DiagnosticStatus, f"{nodes.ns}/tracker/status", got.append,
        QoSProfile(depth=20, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    try:
        nodes.client.wait_for(lambda: any(reason in m.message for m in got), 10.0,
                              "the rejection on the tracker's ~/status")
    finally:
        nodes.client.node.destroy_subscription(sub)


@pytest.mark.parametrize("kept", [("positions",), ("positions", "velocities")])
def test_goals_without_velocities_or_accelerations_succeed_as_on_a_jtc(nodes, kept):
    """A Jazzy JTC takes points whose velocities and accelerations are empty, and interpolates
    each segment with what its ends have (a line, a cubic); so does the tracker's action: the
    simplest goals a user writes succeed, error_code 0, the arm at the last point."""
    trajectory = move(nodes.q(), [0.1, -0.05, 0.05], 2.0, points=11)
    for point in trajectory.points:
        point.accelerations = []
        if "velocities" not in kept:
            point.velocities = []
    handle = nodes.send(FollowJointTrajectory.Goal(
        trajectory=trajectory, goal_tolerance=[JointTolerance(name=j, position=GOAL_TOLERANCE)
                                               for j in JOINTS],
        goal_time_tolerance=conv.duration_from_seconds(1.0)))
    assert handle.accepted
    result = nodes.result(handle, 60.0)
    assert result.status == GoalStatus.STATUS_SUCCEEDED, result.result.error_string
    assert result.result.error_code == jtc.SUCCESSFUL
    final = np.array(trajectory.points[-1].positions)
    assert np.max(np.abs(nodes.q() - final)) < GOAL_TOLERANCE


def test_a_broken_path_tolerance_aborts(nodes):
    q = nodes.q()
    start = q + np.array([0.05, 0.0, 0.0])  # within start_tolerance, outside the path's
    trajectory = move(start, [0.0, 0.0, 0.0], 1.0)
    handle = nodes.send(FollowJointTrajectory.Goal(
        trajectory=trajectory, path_tolerance=[JointTolerance(name="joint1", position=0.01)]))
    assert handle.accepted
    result = nodes.result(handle)
    assert result.status == GoalStatus.STATUS_ABORTED
    assert result.result.error_code == jtc.PATH_TOLERANCE_VIOLATED
    assert "joint1 position error" in result.result.error_string


def test_a_missed_goal_tolerance_aborts_after_the_goal_time(nodes):
    # The tracking error of a move does not fall to 1e-12 rad within 0.05 s of its end.
    trajectory = move(nodes.q(), [0.05, -0.05, 0.05], 1.0)
    handle = nodes.send(FollowJointTrajectory.Goal(
        trajectory=trajectory, goal_tolerance=[JointTolerance(name=j, position=1e-12)
                                               for j in JOINTS],
        goal_time_tolerance=conv.duration_from_seconds(0.05)))
    assert handle.accepted
    result = nodes.result(handle)
    assert result.status == GoalStatus.STATUS_ABORTED
    assert result.result.error_code == jtc.GOAL_TOLERANCE_VIOLATED
    assert "after the end" in result.result.error_string


def test_an_accepted_goal_the_tracker_cannot_run_is_aborted(nodes):
    # Passes the JTC's checks, but its torques (the model's inverse dynamics) exceed the arm's
    # limits: the tracker refuses it after acceptance, with the reason.
    handle = nodes.send(FollowJointTrajectory.Goal(
        trajectory=move(nodes.q(), [0.3, -0.3, 0.3], 0.2)))
    assert handle.accepted
    result = nodes.result(handle)
    assert result.status == GoalStatus.STATUS_ABORTED
    assert result.result.error_code == jtc.INVALID_GOAL
    assert "exceeds its torque limit" in result.result.error_string


def test_a_reset_ends_a_goal_waiting_for_its_stamp(nodes):
    """A goal stamped ahead waits for its instant; a ~/reset before then drops it, and its
    client gets ABORTED with the reason (it was left active forever before)."""
    q = nodes.q()
    trajectory = move(q, [0.1, 0.0, 0.0], 1.0)
    ahead = nodes.client.node.get_clock().now().nanoseconds + 20 * 10**9  # within the horizon
    trajectory.header.stamp = conv.time_from_seconds(ahead * 1e-9)
    handle = nodes.send(FollowJointTrajectory.Goal(trajectory=trajectory))
    assert handle.accepted
    reset = nodes.client.node.create_publisher(JointState, f"{nodes.ns}/tracker/reset", 10)
    nodes.client.wait_for(lambda: reset.get_subscription_count() > 0, 30.0, "~/reset")
    reset.publish(JointState(name=JOINTS, position=q.tolist()))
    result = nodes.result(handle)
    assert result.status == GoalStatus.STATUS_ABORTED
    assert result.result.error_code == jtc.INVALID_GOAL
    assert "stopped by ~/reset before it took over" in result.result.error_string
