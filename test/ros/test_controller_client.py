"""The planner's controller client: with no server at its action the plan is reported rejected,
and the planner is told (``on_refused``); a burst of plans answered while the planner's
executor was starved gets every outcome.

In-process, a private rclpy Context; the wait for the server (``SERVER_WAIT``) shortened.
"""

import os

import pytest

pytestmark = pytest.mark.ros


class _Config:
    """The planner's controller parameters the client reads."""

    controller_effort = False
    controller_goal_time_tolerance = 1.0
    controller_goal_tolerance = 0.0
    controller_path_tolerance = 0.0


def _trajectory():
    """A two-point trajectory of one joint ``a``, 1 s long."""
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from tocontrol_ros.nodes import conversions as conv

    return JointTrajectory(joint_names=["a"], points=[
        JointTrajectoryPoint(positions=[0.0], velocities=[0.0], accelerations=[0.0],
                             time_from_start=conv.duration_from_seconds(t))
        for t in (0.0, 1.0)])


def test_a_plan_for_a_missing_controller_is_reported_rejected(monkeypatch):
    import rclpy

    from tocontrol_ros.nodes import controller_client

    monkeypatch.setattr(controller_client, "SERVER_WAIT", 0.3)
    context = rclpy.Context()
    rclpy.init(context=context)
    events = []
    try:
        node = rclpy.create_node("controller_client_test", context=context)
        client = controller_client.ControllerClient(
            node, "/nobody/follow_joint_trajectory",
            lambda level, message, values: events.append((level, message, values)))
        refused = []
        client.on_refused = lambda rid, reason: refused.append((rid, reason))

        traj = _trajectory()
        client.send(7, traj, _Config())
        client.destroy()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert len(events) == 1, events
    level, message, values = events[0]
    assert level == "ERROR" and values["event"] == "rejected" and values["request_id"] == 7
    assert "no FollowJointTrajectory server at /nobody/follow_joint_trajectory within 0.3 s" \
        in message
    # The planner learns of it (its service then stops continuing that motion).
    assert refused == [(7, "no controller at /nobody/follow_joint_trajectory")]


def test_a_burst_of_plans_answered_while_the_planner_was_starved_gets_every_outcome():
    """Session 35: 40 plans sent while the planner's executor did not run, answered by the
    controller before the planner takes any response (a starved executor on a loaded
    machine). Every plan gets its outcome: with rclpy's default service QoS (the last 10)
    the responses of the first 30 were overwritten and those plans never got one."""
    import rclpy
    from control_msgs.action import FollowJointTrajectory
    from rclpy.action import ActionServer, GoalResponse
    from rclpy.executors import SingleThreadedExecutor

    from tocontrol_ros.nodes import controller_client, qos

    count, name = 40, f"/burst_{os.getpid()}/follow_joint_trajectory"
    context = rclpy.Context()
    rclpy.init(context=context)
    events, accepted = [], []
    try:
        server_node = rclpy.create_node("burst_controller", context=context)
        node = rclpy.create_node("burst_planner", context=context)

        def on_goal(goal):
            accepted.append(goal)
            return GoalResponse.ACCEPT

        def execute(handle):
            handle.succeed()
            return FollowJointTrajectory.Result()

        deep = qos.profile(1000)  # the controller keeps every request: the client is tested
        server = ActionServer(server_node, FollowJointTrajectory, name, execute_callback=execute,
                              goal_callback=on_goal, goal_service_qos_profile=deep,
                              result_service_qos_profile=deep, cancel_service_qos_profile=deep)
        client = controller_client.ControllerClient(
            node, name, lambda level, message, values: events.append(values))
        planner = SingleThreadedExecutor(context=context)
        planner.add_node(node)
        controller = SingleThreadedExecutor(context=context)
        controller.add_node(server_node)
        traj = _trajectory()
        for rid in range(count):  # the first waits for the server's discovery
            client.send(rid, traj, _Config())
        for _ in range(10):  # the queued requests go out, in one burst
            planner.spin_once(timeout_sec=0.05)
        # The controller answers all of them before the planner takes any response.
        for _ in range(4000):
            if len(accepted) == count:
                break
            controller.spin_once(timeout_sec=0.05)
        assert len(accepted) == count
        for _ in range(20):  # its goals finish, their results are ready
            controller.spin_once(timeout_sec=0.01)
        outcomes = lambda: [v for v in events if v["event"] in ("executed", "rejected")]  # noqa: E731
        for _ in range(1000):
            if len(outcomes()) >= count:
                break
            planner.spin_once(timeout_sec=0.01)
            controller.spin_once(timeout_sec=0.01)
        client.destroy()
        server.destroy()
        node.destroy_node()
        server_node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert sorted(v["request_id"] for v in events if v["event"] == "sent") == list(range(count))
    done = outcomes()
    assert sorted(v["request_id"] for v in done) == list(range(count)), \
        f"{len(done)} outcomes of {count} plans"
    assert all(v["event"] == "executed" and v["goal_status"] == "SUCCEEDED" for v in done)
