"""The planner's controller client with no server at its action: the plan is reported rejected,
and the planner is told (``on_refused``).

In-process, a private rclpy Context; the wait for the server (``SERVER_WAIT``) shortened.
"""

import pytest

pytestmark = pytest.mark.ros


def test_a_plan_for_a_missing_controller_is_reported_rejected(monkeypatch):
    import rclpy
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from tocontrol_ros.nodes import controller_client
    from tocontrol_ros.nodes import conversions as conv

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

        class Config:
            controller_effort = False
            controller_goal_time_tolerance = 1.0
            controller_goal_tolerance = 0.0
            controller_path_tolerance = 0.0

        traj = JointTrajectory(joint_names=["a"], points=[
            JointTrajectoryPoint(positions=[0.0], velocities=[0.0], accelerations=[0.0],
                                 time_from_start=conv.duration_from_seconds(t))
            for t in (0.0, 1.0)])
        client.send(7, traj, Config())
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
