"""Pose goals on the Panda of example-robot-data, across processes, as a user sends them.

One planner process (the installed executable, ``robot_description_file`` the Panda's URDF,
``tip_link:=panda_hand``: its URDF limits bind) serves the module. A pose goal goes through
``~/plan_motion`` as ``ros2 action send_goal --feedback`` sends it (the YAML of msg_docs;
:class:`test_plan_motion_cli.Cli` does what the command does), its solve held at the gate
until feedback was printed; another through ``~/goal_pose`` from the joint state this client
publishes. Each published motion's last sample is checked here against the pose by the
numeric forward kinematics. Bad poses (a frame the planner does not have, a NaN quaternion, a
non-unit quaternion, an unreachable pose) end with a message naming what was wrong, and the
node keeps serving (a good goal after them).
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from planner_harness import PlannerClient
from scipy.spatial.transform import Rotation
from skip_policy import panda_urdf
from test_plan_motion_cli import Cli
from test_planner_process import PlannerProcess, _wait_warm

from tocontrol_ros.core.robot.kinematics import tip_pose
from tocontrol_ros.core.robot.model import load_robot

pytestmark = [pytest.mark.ros, pytest.mark.slow]
pytest.importorskip("tocontrol_msgs.action")
#: A wait that only catches a hang (s); the first plan of the Panda may compile its
#: functions (minutes on a loaded machine).
HANG = 600.0
ACTION_TYPE = "tocontrol_msgs/action/PlanMotion"
#: The start (at rest) and the configuration whose hand pose is the goal.
Q0 = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]
Q1 = [0.9, 0.3, -0.4, -1.5, 0.5, 1.5, -0.2]
POSITION_TOL, ORIENTATION_TOL = 1e-4, 1e-3
#: Goals sent before the planner has heard the joint states (each refused at once).
MAX_TRIES = 50


@pytest.fixture(scope="module")
def model():
    return load_robot(str(panda_urdf()), tip_link="panda_hand")


@pytest.fixture(scope="module")
def process(tmp_path_factory, model):
    proc = PlannerProcess(tmp_path_factory.mktemp("pose"), f"/pose_{os.getpid()}", {
        "robot_description_file": str(panda_urdf()), "tip_link": "panda_hand",
        "starts": 4, "candidates": 1, "pose_candidates": 1, "time_limit": HANG,
        "service_timeout": HANG})
    yield proc
    code, _ = proc.stop()
    assert code == 0, proc.log()


@pytest.fixture(scope="module")
def client(process):
    c = PlannerClient(process.name)
    _wait_warm(c, process, HANG)
    yield c
    c.close()


def _pose_yaml(position, quaternion, frame="panda_link0") -> str:
    (x, y, z), (qx, qy, qz, qw) = (map(float, position)), (map(float, quaternion))
    return (f"{{start_type: 1, start_state: {{name: [panda_joint1, panda_joint2, panda_joint3, "
            f"panda_joint4, panda_joint5, panda_joint6, panda_joint7], position: {Q0}}}, "
            f"target_type: 1, target_pose: {{header: {{frame_id: {frame}}}, pose: {{position: "
            f"{{x: {x!r}, y: {y!r}, z: {z!r}}}, orientation: {{x: {qx!r}, y: {qy!r}, "
            f"z: {qz!r}, w: {qw!r}}}}}}}}}")


def _goal_pose(model):
    rotation, position = tip_pose(model, Q1)
    return rotation, position, Rotation.from_matrix(rotation).as_quat()


def _errors(model, q_end, rotation, position) -> tuple[float, float]:
    rot, pos = tip_pose(model, q_end)
    return (float(np.linalg.norm(pos - position)),
            float(np.linalg.norm(Rotation.from_matrix(rot.T @ rotation).as_rotvec())))


def test_pose_goal_through_the_action_with_feedback(process, client, model):
    rotation, position, quat = _goal_pose(model)
    cli = Cli(client)
    process.gate.arm()

    def feedback_then_open():
        client.wait_for(process.gate.held, HANG, "the solve held at the gate")
        client.wait_for(lambda: any(line.startswith("Feedback:") for line in cli.printed()),
                        HANG, "printed feedback")
        process.gate.open()

    response = cli.send_goal(f"{process.name}/plan_motion", ACTION_TYPE,
                             _pose_yaml(position, quat), on_accepted=feedback_then_open)
    process.gate.disarm()
    printed = "\n".join(cli.printed())
    assert "Goal accepted" in printed and "stage='planning'" in printed, printed
    result = response.result
    assert response.status == 4 and result.code in (0, 1) and result.certified, result.message
    assert "pose reached within" in result.message, result.message
    points = result.trajectory.points
    np.testing.assert_allclose(points[0].positions, Q0, atol=1e-9)
    pos_err, ang_err = _errors(model, np.array(points[-1].positions), rotation, position)
    assert pos_err <= POSITION_TOL and ang_err <= ORIENTATION_TOL, (pos_err, ang_err)
    reported = {kv.key: float(kv.value) for kv in result.certificate
                if kv.key.startswith("pose_")}
    assert reported["pose_position_error"] <= POSITION_TOL
    assert reported["pose_orientation_error"] <= ORIENTATION_TOL
    assert all(np.all(np.abs(p.velocities) <= model.qd_max + 1e-6) for p in points)


def test_pose_goal_on_the_topic_from_the_current_joint_state(process, client, model):
    rotation, position, quat = _goal_pose(model)
    names = model.joint_names
    publisher = client.node.create_publisher(PoseStamped, f"{process.name}/goal_pose", 10)
    client.wait_subscribed(publisher)
    client.wait_subscribed(client.joint_pub)  # the planner hears the joint states
    since = len(client.status_list())
    # The arm's state streams, as a robot's joint_states do, until the goal has an outcome.
    done = threading.Event()

    def stream():
        while not done.wait(0.05):
            client.send_joint_state(names, Q0)

    streamer = threading.Thread(target=stream, daemon=True)
    streamer.start()
    try:
        # A goal takes the latest joint state received (and waits briefly for one after it).
        msg = PoseStamped()
        msg.header.frame_id = "panda_link0"
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = map(float, quat)
        n_traj = len(client.trajectories)
        # Until the planner has heard the stream (matched is not yet delivered): a goal
        # before it is refused for want of a joint state, and sent again, as a user would.
        for _ in range(MAX_TRIES):
            publisher.publish(msg)
            status = client.final_status(since, HANG, lambda s: s.values.get("source") ==
                                         "goal_pose")
            if "no recent joint state" not in status.message:
                break
            since = len(client.status_list())
    finally:
        done.set()
        streamer.join(5.0)
    assert status.event == "solved", status.message
    traj = client.wait_for(lambda: client.trajectories[n_traj:], 30.0, "the trajectory")[-1]
    assert list(traj.joint_names) == list(names)
    np.testing.assert_allclose(traj.points[0].positions, Q0, atol=1e-6)
    pos_err, ang_err = _errors(model, np.array(traj.points[-1].positions), rotation, position)
    assert pos_err <= POSITION_TOL and ang_err <= ORIENTATION_TOL, (pos_err, ang_err)
    assert float(status.values["position_error"]) <= POSITION_TOL


@pytest.mark.parametrize("case, frame, quat, position, match", [
    ("frame", "world", None, None, "'world' is not a frame of this planner"),
    ("nan quaternion", "panda_link0", (float("nan"), 0.0, 0.0, 1.0), None,
     "`target_pose.pose.orientation` must be finite"),
    ("non-unit quaternion", "panda_link0", (0.0, 0.0, 0.0, 2.0), None,
     "is not a unit quaternion: |q| = 2"),
    ("unreachable", "panda_link0", None, (1.5, 0.0, 0.5),
     "is unreachable within the joint limits"),
])
def test_bad_pose_goals_are_refused_and_the_node_keeps_serving(process, client, model, case,
                                                                frame, quat, position, match):
    _, good_position, good_quat = _goal_pose(model)
    cli = Cli(client)
    response = cli.send_goal(f"{process.name}/plan_motion", ACTION_TYPE, _pose_yaml(
        good_position if position is None else position,
        good_quat if quat is None else quat, frame))
    result = response.result
    assert result.code == 2 and len(result.trajectory.points) == 0, result.message
    assert match in result.message, result.message
    assert response.status == 6  # ABORTED
    assert process.proc.poll() is None


def test_the_node_still_plans_a_pose_after_bad_goals(process, client, model):
    rotation, position, quat = _goal_pose(model)
    response = Cli(client).send_goal(f"{process.name}/plan_motion", ACTION_TYPE,
                                     _pose_yaml(position, quat, "panda_link0"))
    assert response.result.code in (0, 1), response.result.message
    pos_err, ang_err = _errors(model, np.array(response.result.trajectory.points[-1].positions),
                               rotation, position)
    assert pos_err <= POSITION_TOL and ang_err <= ORIENTATION_TOL
