"""The launch file's nodes for the Panda URDF, started as `ros2 launch` would start them.

`launch` is not installable here, so the launch file runs with stand-ins
(``launch_stubs``): its own ``_nodes`` gives each node's executable, name and parameters
(the package's YAML, the launch arguments, the user's parameters file), and each becomes a
process with the same ``--ros-args``. Arguments: ``robot:=panda.urdf``,
``controller_action:=/tracker/follow_joint_trajectory``, ``params_file:=`` (the Panda's tip,
gains and start), ``record:=true``. A goal on ``/planner/goal`` is planned and executed
through the tracker's action: ``~/status`` reports ``executed``, ``SUCCEEDED``. The recording
is one you can watch (read by mcap's reader, not the project's): the Panda's URDF on
``/robot_description``, ``/tf`` at the joint states' rate, ``/tf_static``, and the topics the
Foxglove layout reads.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from launch_stubs import launched_nodes, load_launch_file, ros_args
from mcap.reader import make_reader
from node_process import NodeProcess
from planner_harness import PlannerClient
from sensor_msgs.msg import JointState
from skip_policy import panda_urdf

from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.nodes import qos

pytestmark = [pytest.mark.ros, pytest.mark.slow]

Q0 = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]
#: The goal is the hand point of Q1. (test_your_own_arm's Q1 = [0.9, 0.3, ...] gives a plan
#: ending with panda_joint2 at 0.11 rad, joints 1 and 3 nearly aligned, where the tracker's
#: gains chatter at saturation after the end, +-2 rad/s on joints 1 and 3 while the positions
#: hold to 0.03 rad: a JTC-like goal check then reports GOAL_TOLERANCE_VIOLATED, rightly.)
Q1 = [0.9, 0.6, -0.4, -1.5, 0.5, 1.5, -0.2]
#: test_your_own_arm's gains and sample period (the README's "Your own arm").
KP = [10.0, 20.0, 13.0, 10.0, 2.4, 4.0, 0.5]
KD = [0.47, 0.91, 0.6, 0.49, 0.11, 0.19, 0.023]
FIRST_PLAN = 600.0
PARAMS = f"""/planner:
  ros__parameters:
    tip_link: panda_hand
    starts: 4
    candidates: 1
    sample_period: 0.002
    time_limit: {FIRST_PLAN}
    controller_goal_time_tolerance: 3.0
/tracker:
  ros__parameters:
    tip_link: panda_hand
    initial_positions: {Q0}
    kp: {KP}
    kd: {KD}
"""



def test_launch_with_the_panda_plans_and_executes_a_goal(tmp_path, monkeypatch):
    urdf = panda_urdf()
    params = tmp_path / "panda.yaml"
    params.write_text(PARAMS)
    module = load_launch_file(monkeypatch, share=str(Path(sys.prefix) / "share"))
    nodes = launched_nodes(module, robot=str(urdf), params_file=str(params),
                           controller_action="/tracker/follow_joint_trajectory",
                           record="true", output=str(tmp_path / "panda.mcap"))
    assert [n["executable"] for n in nodes] == ["planner", "tracker", "recorder"]
    processes = [NodeProcess(n["executable"], ros_args(n), tmp_path) for n in nodes]
    client = PlannerClient("/planner")
    try:
        deadline = time.monotonic() + FIRST_PLAN
        while not client.plan_client.wait_for_service(timeout_sec=1.0):
            for p in processes:
                assert p.proc.poll() is None, p.log.read_text()[-3000:]
            assert time.monotonic() < deadline
        states: list = []
        client.node.create_subscription(JointState, "/joint_states", states.append,
                                        qos.RELIABLE)
        tracker_status: list = []
        client.node.create_subscription(DiagnosticStatus, "/tracker/status",
                                        tracker_status.append, qos.status_profile(20, True))
        client.wait_for(lambda: len(states) >= 5, 120.0, "the tracker's joint states")
        client.wait_subscribed(client.goal_pub, 60.0)
        client.wait_joint_states(120.0)
        since = len(client.status_list())
        model = load_robot(str(urdf), tip_link="panda_hand")
        client.send_goal(model.point(np.array(Q1)), frame="panda_link0")
        solved = client.final_status(since, FIRST_PLAN + 60.0)
        assert solved.event == "solved", (solved.message, processes[0].log.read_text()[-3000:])
        executed = client.wait_for(
            lambda: next((s for s in client.status_list()[since:]
                          if s.event in ("executed", "rejected")
                          and s.request_id == solved.request_id), None),
            120.0, "the execution's outcome")
        assert executed.values.get("goal_status") == "SUCCEEDED", (
            executed.message, [m.message for m in tracker_status])
        assert "robot_description_file" in " ".join(ros_args(nodes[0]))
    finally:
        client.close()
        codes = [p.stop() for p in processes]
    assert codes == [0, 0, 0], [p.log.read_text()[-2000:] for p in processes]
    from test_demo import assert_watchable  # noqa: PLC0415 (test helper module)

    assert_watchable(tmp_path / "panda.mcap", urdf.read_text())
    layout = json.loads((Path(sys.prefix) / "share/tocontrol_ros/config/"
                         "foxglove_layout.json").read_text())
    with open(tmp_path / "panda.mcap", "rb") as f:
        recorded = {c.topic for c in make_reader(f).get_summary().channels.values()}
    plotted = {p["value"].split(".")[0] for pid, c in layout["configById"].items()
               if pid.startswith("Plot!") for p in c["paths"]}
    assert plotted <= recorded
