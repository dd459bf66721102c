"""The planner's ``~/plan_motion`` action and ``~/goal_joints`` topic, in-process (issue 52).

A planner node of its own per test (the paper's arm, private context), a client node with an
rclpy ``ActionClient``: goals with feedback, cancel, the result's trajectory checked against
the model (forward kinematics, the torque limits), bad goals refused with the field named.
Solves are held at the gate (test/solve_gate.py) where a test needs an event to happen during
one: no test relies on a solve being slow or fast.
"""

import threading

import numpy as np
import pytest
from planner_harness import PAPER_START, PAPER_TARGET
from sensor_msgs.msg import JointState
from solve_gate import SolveGate
from test_planner_node import JOINTS, PublishedAtTheNode, ready_planner

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.action_calls import SerialActionClient
from tocontrol_ros.nodes.conversions import seconds

pytestmark = pytest.mark.ros
PlanMotion = pytest.importorskip("tocontrol_msgs.action").PlanMotion
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0


@pytest.fixture(scope="module")
def model():
    return load_robot(default_urdf_path())


class ActionUser:
    """What ``ros2 action send_goal --feedback`` does: send, collect feedback, get the result."""

    def __init__(self, client, planner: str):
        self.client = client
        self.action = SerialActionClient(client.node, PlanMotion, f"{planner}/plan_motion")
        assert self.action.wait_for_server(HANG), "no ~/plan_motion server"
        self.feedback = []
        self._lock = threading.Lock()

    def _on_feedback(self, msg):
        with self._lock:
            self.feedback.append(msg.feedback)

    def feedback_list(self):
        with self._lock:
            return list(self.feedback)

    def send(self, goal):
        future = self.action.send_goal(goal, feedback_callback=self._on_feedback)
        self.client.wait_for(future.done, HANG, "the goal's acceptance")
        handle = future.result()
        assert handle.accepted
        return handle

    def result(self, handle):
        future = self.action.get_result(handle)
        self.client.wait_for(future.done, HANG, "the action's result")
        return future.result()


def point_goal(xy, frame="base_link", **options):
    goal = PlanMotion.Goal(target_type=PlanMotion.Goal.TARGET_POINT, **options)
    goal.target_point.header.frame_id = frame
    goal.target_point.point.x, goal.target_point.point.y = float(xy[0]), float(xy[1])
    return goal


def pose_goal(position, quaternion, frame="base_link", start_q=None, **options):
    goal = PlanMotion.Goal(target_type=PlanMotion.Goal.TARGET_POSE, **options)
    goal.target_pose.header.frame_id = frame
    p, o = goal.target_pose.pose.position, goal.target_pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
    if start_q is not None:
        goal.start_type = PlanMotion.Goal.START_JOINTS
        goal.start_state = JointState(name=list(JOINTS), position=[float(v) for v in start_q])
    return goal


def joints_goal(q, start_q=None, names=JOINTS, **options):
    goal = PlanMotion.Goal(target_type=PlanMotion.Goal.TARGET_JOINTS, **options)
    goal.target_joints = JointState(name=list(names), position=[float(v) for v in q])
    if start_q is not None:
        goal.start_type = PlanMotion.Goal.START_JOINTS
        goal.start_state = JointState(name=list(names), position=[float(v) for v in start_q])
    return goal


def positions(trajectory) -> np.ndarray:
    return np.array([p.positions for p in trajectory.points])


def check_motion(result, model, start_q=None):
    """The result's trajectory is a motion of the model: efforts within the torque limits,
    at rest at both ends, the duration its last time; returns the end configuration."""
    traj = result.trajectory
    assert list(traj.joint_names) == list(JOINTS)
    assert seconds(traj.points[-1].time_from_start) == pytest.approx(result.duration, abs=1e-9)
    effort = np.array([p.effort for p in traj.points])
    assert effort.shape == (len(traj.points), model.n)
    assert np.all(np.abs(effort) <= model.tau_max * (1 + 1e-9)) and np.any(effort != 0.0)
    np.testing.assert_allclose(traj.points[-1].velocities, 0.0, atol=1e-6)
    if start_q is not None:
        np.testing.assert_allclose(traj.points[0].positions, start_q, atol=1e-9)
    return np.array(traj.points[-1].positions)


def test_point_goal_with_feedback_and_no_execution(monkeypatch, model):
    published = PublishedAtTheNode(monkeypatch)
    gate = SolveGate.install(monkeypatch)
    with ready_planner("action_point") as (running, client):
        user = ActionUser(client, running.node.get_fully_qualified_name())
        gate.arm()
        start_q = model_ik(model, PAPER_START)
        handle = user.send(point_goal(PAPER_TARGET, start_type=PlanMotion.Goal.START_JOINTS,
                                      start_state=JointState(name=list(JOINTS),
                                                             position=start_q.tolist())))
        assert gate.held.wait(HANG), "the goal's solve never started"
        client.wait_for(lambda: any(f.stage == "planning" for f in user.feedback_list()),
                        HANG, "feedback while the solve is held")
        gate.open()
        response = user.result(handle)
        result = response.result
        assert response.status == 4, result.message  # SUCCEEDED
        assert result.code == PlanMotion.Result.SUCCESS and result.status == "SUCCESS"
        assert result.certified, result.message
        assert {kv.key for kv in result.certificate} >= {"cert_failed", "cert_tolerances"}
        end = check_motion(result, model, start_q)
        np.testing.assert_allclose(model.point(end), PAPER_TARGET, atol=1e-6)
        held = [f for f in user.feedback_list() if f.stage == "planning"]
        assert all(f.elapsed >= 0.0 and f.best_duration == 0.0 for f in held)
        # execute is false: a plan only, nothing published on ~/trajectory.
        assert published.of(running.node) == []
        # The same goal with execute: published, the same motion.
        response = user.result(user.send(point_goal(
            PAPER_TARGET, execute=True, start_type=PlanMotion.Goal.START_JOINTS,
            start_state=JointState(name=list(JOINTS), position=start_q.tolist()))))
        assert response.result.code == PlanMotion.Result.SUCCESS, response.result.message
        [sent] = published.of(running.node)
        np.testing.assert_allclose(positions(sent), positions(response.result.trajectory),
                                   atol=1e-12)


def model_ik(model, p):
    from tocontrol_ros.core.robot.ik import solve_ik

    q = solve_ik(model, np.asarray(p, dtype=float))
    assert q is not None
    return q


def test_joint_goal_reaches_the_joints(model):
    with ready_planner("action_joints") as (running, client):
        user = ActionUser(client, running.node.get_fully_qualified_name())
        start_q, target_q = [0.3, 1.0, -0.5], [1.2, -0.4, 0.7]
        response = user.result(user.send(joints_goal(target_q, start_q)))
        result = response.result
        assert result.code == PlanMotion.Result.SUCCESS, result.message
        assert result.certified
        end = check_motion(result, model, start_q)
        np.testing.assert_allclose(end, target_q, atol=1e-6)


def test_pose_goal_reaches_the_pose_and_reports_its_errors(model):
    """A pose in the arm's plane (that of a configuration): reached within the tolerances,
    checked here by the forward kinematics of the result's last point."""
    from scipy.spatial.transform import Rotation

    from tocontrol_ros.core.robot.kinematics import tip_pose

    rotation, position = tip_pose(model, [1.2, -0.4, 0.7])
    quaternion = Rotation.from_matrix(rotation).as_quat()
    with ready_planner("action_pose") as (running, client):
        user = ActionUser(client, running.node.get_fully_qualified_name())
        start_q = [0.3, 1.0, -0.5]
        response = user.result(user.send(pose_goal(position, quaternion, start_q=start_q)))
        result = response.result
        assert response.status == 4 and result.code == PlanMotion.Result.SUCCESS, \
            result.message
        assert result.certified and "pose reached within" in result.message
        end = check_motion(result, model, start_q)
        rot, pos = tip_pose(model, end)
        assert np.linalg.norm(pos - position) <= 1e-4
        assert np.linalg.norm(Rotation.from_matrix(rot.T @ rotation).as_rotvec()) <= 1e-3
        errors = {kv.key: float(kv.value) for kv in result.certificate
                  if kv.key.startswith("pose_")}
        assert errors["pose_position_error"] <= 1e-4
        assert errors["pose_orientation_error"] <= 1e-3


def test_cancel_returns_the_first_motion_or_says_there_is_none(monkeypatch, model):
    gate = SolveGate.install(monkeypatch)
    with ready_planner("action_cancel") as (running, client):
        user = ActionUser(client, running.node.get_fully_qualified_name())
        start = JointState(name=list(JOINTS), position=model_ik(model, PAPER_START).tolist())
        # Without a first motion: the cancel stops the held solve, no motion, stated.
        gate.arm()
        handle = user.send(point_goal(PAPER_TARGET, start_type=1, start_state=start))
        assert gate.held.wait(HANG)
        cancel = user.action.cancel(handle)
        client.wait_for(cancel.done, HANG, "the cancel's response")
        response = user.result(handle)
        assert response.status == 5, response.result.message  # CANCELED
        assert response.result.code == PlanMotion.Result.FAILED
        assert "no certified motion was known" in response.result.message
        assert response.result.trajectory.points == []
        # With publish: first_then_optimum, the first motion is known before the optimum's
        # solve: a cancel then returns it, certified, as a partial result.
        client.set_parameters(publish="first_then_optimum")
        gate.arm()
        handle = user.send(point_goal(PAPER_TARGET, start_type=1, start_state=start))
        assert gate.held.wait(HANG)
        client.wait_for(lambda: any(f.best_duration > 0.0 for f in user.feedback_list()),
                        HANG, "feedback with the first motion's duration")
        user.action.cancel(handle)
        response = user.result(handle)
        gate.open()
        result = response.result
        assert response.status == 5 and result.code == PlanMotion.Result.PARTIAL, \
            result.message
        assert result.certified and "returned: the first motion" in result.message
        end = check_motion(result, model, start.position)
        np.testing.assert_allclose(model.point(end), PAPER_TARGET, atol=1e-6)
        best = max(f.best_duration for f in user.feedback_list())
        assert result.duration == pytest.approx(best, rel=1e-12)


BAD_GOALS = [
    ("frame", lambda: point_goal(PAPER_TARGET, frame="map"), "frame_id 'map'"),
    ("nan", lambda: point_goal((float("nan"), 1.0)), "`target_point.point.x` must be finite"),
    ("pose frame", lambda: pose_goal((2.37, 4.76, 0.0), (0.0, 0.0, 0.0, 1.0), frame="map"),
     "`target_pose.header.frame_id` 'map' is not a frame of this planner (no tf lookup); "
     "accepted: base_link, link1, link2, link3, tool"),
    ("pose nan", lambda: pose_goal((2.37, 4.76, 0.0), (0.0, 0.0, float("nan"), 1.0)),
     "`target_pose.pose.orientation` must be finite"),
    ("pose not unit", lambda: pose_goal((2.37, 4.76, 0.0), (0.0, 0.0, 0.0, 0.0)),
     "`target_pose.pose.orientation` is not a unit quaternion: |q| = 0"),
    ("names", lambda: joints_goal([0.1, 0.2, 0.3], names=("a", "b", "c")),
     "`target_joints.name` lacks the planner's joint(s)"),
    ("moving", lambda: PlanMotion.Goal(
        target_type=2, target_joints=JointState(name=list(JOINTS), position=[0.1, 0.2, 0.3],
                                                velocity=[0.0, 1.0, 0.0])),
     "`target_joints.velocity` must be empty or zero"),
    ("k", lambda: point_goal(PAPER_TARGET, k=100.0), "goal options"),
    ("start", lambda: joints_goal([0.1, 0.2, 0.3], start_q=[0.1, float("inf"), 0.0]),
     "`start_state.position` of joint 'joint2' must be finite"),
    ("target_type", lambda: PlanMotion.Goal(target_type=7), "`target_type` must be"),
]


def test_bad_goals_are_refused_naming_the_field_and_the_node_keeps_serving(model):
    with ready_planner("action_bad") as (running, client):
        user = ActionUser(client, running.node.get_fully_qualified_name())
        for name, make, fragment in BAD_GOALS:
            response = user.result(user.send(make()))
            assert response.status == 6, name  # ABORTED
            assert response.result.code == PlanMotion.Result.FAILED, name
            assert fragment in response.result.message, (name, response.result.message)
        response = user.result(user.send(joints_goal([1.2, -0.4, 0.7], [0.3, 1.0, -0.5])))
        assert response.result.code == PlanMotion.Result.SUCCESS, response.result.message


def test_goal_joints_topic(monkeypatch, model):
    published = PublishedAtTheNode(monkeypatch)
    with ready_planner("goal_joints") as (running, client):
        pub = client.node.create_publisher(JointState, f"{running.node.get_fully_qualified_name()}"
                                           "/goal_joints", 10)
        client.wait_subscribed(pub)
        client.wait_subscribed(client.joint_pub)
        start_q, target_q = [0.3, 1.0, -0.5], [1.2, -0.4, 0.7]
        since = len(client.status_list())
        client.wait_for(lambda: client.send_joint_state(JOINTS, start_q) or
                        running.node.service.arm.latest(running.node.config)[1] is not None,
                        HANG, "the planner to receive a joint state")
        pub.publish(JointState(name=list(reversed(JOINTS)),
                               position=list(reversed(target_q))))
        status = client.final_status(since, HANG, match=lambda s: s.values.get("source") ==
                                     "goal_joints")
        assert status.event == "solved", status.message
        [msg] = published.of(running.node)
        np.testing.assert_allclose(msg.points[0].positions, start_q, atol=1e-9)
        np.testing.assert_allclose(msg.points[-1].positions, target_q, atol=1e-6)
        # A bad one: named, and the node goes on.
        since = len(client.status_list())
        pub.publish(JointState(name=["x"], position=[0.0]))
        status = client.final_status(since, HANG, match=lambda s: s.values.get("source") ==
                                     "goal_joints")
        assert status.event == "failed" and "`goal_joints.name` lacks" in status.message
