"""A goal behind an obstacle, through the nodes (issue 51): ~/scene, the plan, the tracked motion.

The planner and the tracker run as processes with the Panda of example-robot-data (its SRDF
as ``robot_description_semantic``). A ball is put where the obstacle-free optimum passes
(found in this process with the core, the node's k and reserve); a malformed scene message
is refused with the reason and the scene kept; the goal's plan avoids the ball (its
clearance on ``~/status``), and the tracker's executed joint states, checked here with Coal
on the URDF's geometry, stay clear of it. The recorder records the run beside them, and the
report on its file gives the executed motion's clearance (the scene from the planner's
markers): the figure it names is Coal's distance at the recorded joint state it names.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from node_process import NodeProcess
from planner_harness import PlannerClient
from sensor_msgs.msg import JointState
from skip_policy import panda_srdf, panda_urdf
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from tocontrol_ros.core import SolverOptions, plan
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.geometry.collision import collision_model
from tocontrol_ros.core.geometry.scene import scene_from_dict
from tocontrol_ros.core.robot.kinematics import tip_pose
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.nodes import qos
from tocontrol_ros.recording import mcap_io, report

pytestmark = [pytest.mark.ros, pytest.mark.slow]

Q0 = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]
Q1 = [0.9, 0.6, -0.4, -1.5, 0.5, 1.5, -0.2]
SAMPLE = 0.002
FIRST_PLAN = 600.0
#: The node's defaults (config/planner.yaml), used for the obstacle-free plan here.
K, RESERVE = 4.0, 0.1
RADIUS = 0.05


def _ball(center) -> Marker:
    return Marker(header=Header(frame_id="panda_link0"), ns="cell", id=0, type=Marker.SPHERE,
                  action=Marker.ADD,
                  pose=Pose(position=Point(x=float(center[0]), y=float(center[1]),
                                           z=float(center[2])),
                            orientation=Quaternion(w=1.0)),
                  scale=Vector3(x=2 * RADIUS, y=2 * RADIUS, z=2 * RADIUS))


def test_a_goal_behind_an_obstacle_is_planned_around_it_and_tracked_clear(tmp_path):
    urdf_path = panda_urdf()
    srdf = panda_srdf()
    model = load_robot(str(urdf_path), tip_link="panda_hand")
    goal = model.point(np.array(Q1))
    free = plan(Problem(model, joint_state(Q0), point(goal), k=K, reserve=RESERVE),
                SolverOptions(starts=4, candidates=1, time_limit=FIRST_PLAN))
    assert free.success, free.message
    _, center = tip_pose(model, free.trajectory.evaluate(np.array([free.T / 2])).q[0])
    col = collision_model(model, urdf_path, srdf).with_scene(scene_from_dict({"obstacles": [
        {"name": "cell/0", "type": "sphere", "radius": RADIUS, "position": center.tolist()}]}))
    blocked = Problem(model, joint_state(Q0), point(goal), k=K, reserve=RESERVE, collision=col)
    assert not certify_open_loop(blocked, free.trajectory).item("clearance").passed

    urdf = urdf_path.read_text()
    planner = NodeProcess("planner", [
        "--ros-args", "-r", "__node:=planner", "-p", f"robot_description:={urdf}",
        "-p", f"robot_description_semantic:={srdf}", "-p", "tip_link:=panda_hand",
        "-p", f"time_limit:={FIRST_PLAN}", "-p", "starts:=4", "-p", "candidates:=1",
        "-p", f"sample_period:={SAMPLE}"], tmp_path)
    tracker = NodeProcess("tracker", [
        "--ros-args", "-r", "__node:=tracker", "-p", f"robot_description:={urdf}",
        "-p", "tip_link:=panda_hand", "-p", f"initial_positions:={Q0}"], tmp_path)
    recording = tmp_path / "run.mcap"
    recorder = NodeProcess("recorder", [
        "--ros-args", "-r", "__node:=recorder", "-p", f"robot_description:={urdf}",
        "-p", f"output:={recording}"], tmp_path)
    client = PlannerClient("/planner")
    recorded: list = []
    client.node.create_subscription(DiagnosticStatus, "/recorder/status", recorded.append,
                                    qos.status_profile(100, latched=True))
    try:
        deadline = time.monotonic() + FIRST_PLAN
        while not client.plan_client.wait_for_service(timeout_sec=1.0):
            assert planner.proc.poll() is None, planner.log.read_text()[-3000:]
            assert time.monotonic() < deadline, planner.log.read_text()[-3000:]
        scene_pub = client.node.create_publisher(MarkerArray, "/planner/scene", qos.RELIABLE)
        client.wait_subscribed(scene_pub, 60.0)
        # A malformed message first: refused whole, with the reason.
        since = len(client.status_list())
        bad = _ball(center)
        bad.type = Marker.ARROW
        scene_pub.publish(MarkerArray(markers=[_ball(center), bad]))
        refused = client.wait_for(lambda: next((s for s in client.status_list()[since:]
                                                if s.event == "scene_refused"), None),
                                  60.0, "the refusal")
        assert "SPHERE (2) or CYLINDER (3)" in refused.message
        since = len(client.status_list())
        scene_pub.publish(MarkerArray(markers=[_ball(center)]))
        client.wait_for(lambda: any(s.event == "scene" for s in client.status_list()[since:]),
                        60.0, "the scene accepted")

        states: list = []
        tracker_statuses: list = []
        client.node.create_subscription(JointState, "/joint_states", states.append,
                                        qos.RELIABLE)
        client.node.create_subscription(DiagnosticStatus, "/tracker/status",
                                        tracker_statuses.append,
                                        qos.status_profile(20, latched=True))
        client.wait_subscribed(client.goal_pub, 60.0)
        client.wait_for(lambda: len(states) >= 5, FIRST_PLAN, "the tracker's joint states")
        client.wait_joint_states(FIRST_PLAN)
        client.wait_for(lambda: {("first_message", "/joint_states"),
                                 ("subscribed", "/tracker/status")} <= {
            (v.get("event"), v.get("topic")) for v in ({kv.key: kv.value for kv in s.values}
                                                       for s in recorded)},
            60.0, "the recorder's joint states and its subscription to the tracker's status")
        since = len(client.status_list())
        start = len(states)
        client.send_goal(goal, frame="panda_link0")
        status = client.final_status(since, FIRST_PLAN + 60.0)
        assert status.event == "solved", (status.message, planner.log.read_text()[-3000:])
        assert float(status.values["min_clearance"]) >= col.margin, status.values
        assert status.values["cert_clearance"]
        traj = client.wait_for(lambda: client.trajectories, 10.0, "the trajectory")[-1]
        planned = np.array([p.positions for p in traj.points])
        duration = traj.points[-1].time_from_start.sec + \
            1e-9 * traj.points[-1].time_from_start.nanosec
        # The scene the plan avoided is drawn with it.
        client.wait_for(lambda: any(m.ns == "scene" for msg in client.markers
                                    for m in msg.markers), 10.0, "the scene's markers")
        # The executed motion: the joint states from the goal until the tracker reports
        # the trajectory completed.
        client.wait_for(lambda: any(s.message.startswith("trajectory completed")
                                    for s in tracker_statuses), duration + 120.0,
                        "the tracker's completion")
        names = list(states[-1].name)
        order = [names.index(j) for j in model.joint_names]
        executed = np.array([[s.position[i] for i in order] for s in states[start:]])
        assert len(executed) > 100
        assert np.linalg.norm(model.point(executed[-1]) - goal) < 1e-2
        exact = col.clearance(executed[::2])
        assert exact.minimum > 0.0, (exact.minimum, exact.pair)
        near_ball = exact.pair_distances
        assert min(d.min() for pair, d in near_ball.items() if "cell/0" in pair) > 0.0
        assert col.clearance(planned[::5]).minimum >= col.margin - 1e-6
        # The states after the completion (the report shows report.HOLD_SHOWN of them) came
        # while the checks above ran; the recorder takes what is queued when it stops.
        assert recorder.stop() == 0, recorder.log.read_text()[-2000:]
    finally:
        client.close()
        codes = (planner.stop(), tracker.stop(), recorder.stop())
    assert codes == (0, 0, 0), (planner.log.read_text()[-2000:],
                                tracker.log.read_text()[-2000:])
    _check_the_report(tmp_path, recording, srdf, col, exact)


def _check_the_report(tmp_path, recording, srdf, col, exact):
    """The report of the recorded run: the executed motion's clearance, checked here."""
    out = tmp_path / "report"
    assert report.main([str(recording), "--out", str(out), "--tip-link", "panda_hand",
                        "--srdf", str(srdf)]) == 0
    summary = (out / "summary.txt").read_text()
    assert "scene from /planner/markers" in summary, summary
    (line,) = [s for s in summary.splitlines() if s.startswith("motion 1 clearance: min ")]
    words = line.split()
    minimum, pair, at = float(words[4]), words[6].strip("()"), float(words[10])
    assert ("margin held" in line) == (minimum >= col.margin), line
    assert (out / "clearance_1.png").is_file()
    # The recorded joint state at the reported time (the execution's start from the
    # tracker's status), decoded here, and Coal's distances there by the core's check.
    from rclpy.serialization import deserialize_message

    start = None
    for record in mcap_io.iter_records(recording, topics=["/tracker/status"]):
        msg = deserialize_message(record.data, DiagnosticStatus)
        values = {kv.key: kv.value for kv in msg.values}
        if msg.message.startswith("executing trajectory"):
            start = float(values["start_time"])
    assert start is not None
    q = None
    for record in mcap_io.iter_records(recording, topics=["/joint_states"]):
        msg = deserialize_message(record.data, JointState)
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if abs(stamp - start - at) < 5e-4:
            order = [list(msg.name).index(j) for j in col.model.joint_names]
            q = np.array([msg.position[i] for i in order])
    assert q is not None, line
    here = col.clearance(q[None, :])
    assert here.minimum == pytest.approx(minimum, abs=6e-5), (line, here.pair)
    assert "/".join(here.pair) == pair
    # What the test saw of the execution (every other state) is never closer than that.
    assert exact.minimum >= minimum - 1e-4, (exact.minimum, line)
