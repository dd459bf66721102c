"""Two arms side by side: the launch file twice, ``namespace:=`` apart (issue 52).

Each launch's planner and tracker run as ``ros2 launch`` would start them (test/launch_stubs),
in ``/<ns>_a`` and ``/<ns>_b``, with the default (relative) topics: each planner plans from
its own arm's ``joint_states`` and each tracker executes its own planner's trajectory; arm a
through the topic, arm b through its tracker's ``FollowJointTrajectory`` given as a relative
``controller_action``. Both goals are planned and executed, nothing crosses between the
arms, and ``/diagnostics`` carries a status of every node.
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from launch_stubs import launched_nodes, load_launch_file, ros_args
from node_process import NodeProcess
from planner_harness import PAPER_TARGET, PlannerClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

pytestmark = pytest.mark.ros
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0


def _launch(monkeypatch, tmp_path, namespace, **arguments):
    share = Path(sys.prefix) / "share"
    module = load_launch_file(monkeypatch, share=str(share))
    urdf = share / "tocontrol_ros" / "config" / "galicki_3r.urdf"
    nodes = launched_nodes(module, robot=str(urdf), namespace=namespace, record="false",
                           **arguments)
    assert [n["namespace"] for n in nodes] == [namespace, namespace]
    log_dir = tmp_path / namespace
    log_dir.mkdir()
    return [NodeProcess(n["executable"], ros_args(n), log_dir) for n in nodes]


def test_two_arms_in_two_namespaces_plan_execute_and_report(monkeypatch, tmp_path):
    base = f"arms{os.getpid()}"
    arm_a, arm_b = f"{base}_a", f"{base}_b"
    processes = (_launch(monkeypatch, tmp_path, arm_a)
                 + _launch(monkeypatch, tmp_path, arm_b,
                           controller_action="tracker/follow_joint_trajectory"))
    clients = {}
    try:
        clients = {ns: PlannerClient(f"/{ns}/planner") for ns in (arm_a, arm_b)}
        client = clients[arm_a]
        diagnostics: dict[str, DiagnosticStatus] = {}
        tracker_events: dict[str, list[str]] = {arm_a: [], arm_b: []}
        lock = threading.Lock()

        def on_diagnostics(msg: DiagnosticArray) -> None:
            with lock:
                for status in msg.status:
                    diagnostics[status.name] = status

        def on_tracker(ns):
            def record(msg: DiagnosticStatus) -> None:
                with lock:
                    tracker_events[ns].append(msg.message)
            return record

        client.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 100)
        latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        for ns in (arm_a, arm_b):
            client.node.create_subscription(DiagnosticStatus, f"/{ns}/tracker/status",
                                            on_tracker(ns), latched)
        names = {f"/{ns}/{node}" for ns in (arm_a, arm_b) for node in ("planner", "tracker")}

        def ready():
            with lock:
                return all(diagnostics.get(f"/{ns}/planner") is not None and
                           diagnostics[f"/{ns}/planner"].message == "ready"
                           for ns in (arm_a, arm_b)) and names <= set(diagnostics)
        try:
            client.wait_for(ready, HANG, "both planners ready and every node on /diagnostics")
        except AssertionError:
            raise AssertionError([p.log.read_text()[-1500:] for p in processes]) from None
        since = {ns: len(c.status_list()) for ns, c in clients.items()}
        for c in clients.values():
            c.wait_subscribed(c.goal_pub, HANG)
            c.wait_joint_states(HANG)
            c.send_goal(PAPER_TARGET)
        for ns, c in clients.items():
            status = c.final_status(since[ns], HANG)
            assert status.event == "solved", (ns, status.message)
            # Planned from its own arm's joint state (the tracker's start), not the other's.
            assert status.values.get("start_q") not in (None, "None"), status.values
        # Arm b's plan went to its own tracker's action, named relative to its namespace.
        executed = clients[arm_b].wait_for(
            lambda: next((s for s in clients[arm_b].status_list()
                          if s.event in ("executed", "rejected")), None),
            HANG, "arm b's execution")
        assert executed.values.get("goal_status") == "SUCCEEDED", executed.message
        assert executed.values.get("controller_action") == "tracker/follow_joint_trajectory"
        # Both trackers completed one motion each: their own planner's.
        for ns in (arm_a, arm_b):
            client.wait_for(lambda ns=ns: any(m.startswith("trajectory completed")
                                              for m in tracker_events[ns]),
                            HANG, f"{ns}'s tracker to complete the motion")
        with lock:
            received = {ns: diagnostics[f"/{ns}/tracker"] for ns in (arm_a, arm_b)}
        for status in received.values():
            values = {kv.key: kv.value for kv in status.values}
            assert values["trajectory_topic"] in ("planner/trajectory", "~/unused"), values
        assert {kv.key for kv in diagnostics[f"/{arm_a}/planner"].values} >= {
            "state", "requests_waiting", "compile_builds_pending", "last_T", "plan_motion"}
    finally:
        for c in clients.values():
            c.close()
        codes = [p.stop() for p in processes]
    assert codes == [0] * len(processes), [p.log.read_text()[-2000:] for p in processes]
