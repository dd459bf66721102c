"""On-line replanning end to end (issue 33): a target moving at 10 Hz, planner and tracker as
deployed (separate processes, joint states flowing), the arm following with spliced replans.

Nothing here asserts on elapsed time or on how many messages arrived in real time beyond
what the issue asks: every goal is counted as answered when a trajectory was published for
it (its own ``solved`` status with ``published: optimum``), which the planner guarantees by
construction (goals queue behind a running solve instead of superseding it, and a replan that
would arrive late is solved again from a later hand-off). Waits are bounded. At 10 Hz
each move along the circle is over before the next goal's hand-off, so the circle's
replans mostly start at rest; a far goal and a goal near it while its motion runs add a
splice into a moving motion.
"""

import math
import os
import time

import numpy as np
import pytest
from node_process import NodeProcess
from planner_harness import PlannerClient, hold_splices_to_the_bar

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

pytestmark = pytest.mark.ros
#: The issue's target: 10 Hz for 5 s, along a circle (centre, radius in m), once around.
RATE, DURATION = 10.0, 5.0
CENTRE, RADIUS = (1.8, 1.2), 0.15
#: A goal far from the circle (a motion of 1.2 s from it), then one near it.
FAR, NEAR = (-3.0, -1.0), (-2.97, -0.98)
#: The arm counts as arrived within this of a goal (m); the final error is held to 1e-4 m.
SETTLE_TOL = 1e-3


def circle(i: int, count: int) -> tuple[float, float]:
    """Goal ``i`` of ``count`` on the circle (m)."""
    a = 2 * math.pi * i / count
    return CENTRE[0] + RADIUS * math.cos(a), CENTRE[1] + RADIUS * math.sin(a)


# replan_quick:=false runs with the slow tests (each case a minute of replans under load):
# the default run keeps the default replan_quick:=true (the same circle, far and near goals,
# splices and torque checks; each quick motion's optimum tried after it), and
# test_moving_target_action.py the replans through the controller's action.
@pytest.mark.parametrize("quick", [True, pytest.param(False, marks=pytest.mark.slow)],
                         ids=["quick_first", "optimum_only"])
def test_moving_target_followed_with_spliced_replans(tmp_path, quick):
    """Goals on a circle at 10 Hz, then a far goal and a near one while it runs: every goal
    answered (80 %), spliced without a jump, inside the torque set; with ``replan_quick``
    (the default) the replans' first publications are certified quick motions."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    ns = f"/replan_{os.getpid()}"
    args = ["--ros-args", "-r", f"__ns:={ns}"]
    # goal_max_backlog at its maximum: the oldest waiting goals give way to the newest only
    # after an hour of backlog, so every goal is solved in turn however long a loaded
    # machine takes (with the default 3 s, one CI run under load answered 7 of 50: a count
    # that depended on the machine's speed). Giving way is test/nodes/test_replanning.py's.
    planner_args = ["-p", "goal_max_backlog:=3600.0", "-p", f"replan_quick:={str(quick).lower()}"]
    procs = [NodeProcess(name, args + extra, tmp_path, env={"OPENBLAS_NUM_THREADS": "1"})
             for name, extra in (("planner", planner_args), ("tracker", [
                 "-p", f"trajectory_topic:={ns}/planner/trajectory"]))]
    client = PlannerClient(f"{ns}/planner")
    tracker_status, states = [], []
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client.node.create_subscription(
        DiagnosticStatus, f"{ns}/tracker/status",
        lambda m: tracker_status.append({kv.key: kv.value for kv in m.values}
                                        | {"message": m.message}), reliable)
    client.node.create_subscription(JointState, f"{ns}/joint_states",
                                    lambda m: states.append(list(m.position)), 10)
    count = int(RATE * DURATION)
    goals = [circle(i, count) for i in range(count)]
    model = load_robot(default_urdf_path())
    try:
        client.wait_ready(180.0)
        # "ready" is a volatile status event, lost when discovery completes after it: its log
        # line says it too.
        client.wait_for(lambda: any(s.event == "ready" for s in client.status_list())
                        or "ready after" in (tmp_path / "planner.log").read_text(), 180.0,
                        "the planner's warm-up")
        client.wait_subscribed(client.goal_pub)
        client.wait_for(lambda: states, 30.0, "joint states")
        client.wait_joint_states(180.0)
        since = len(client.status_list())
        t_next = time.monotonic()
        for goal in goals:  # 10 Hz: the next goal does not wait for an answer
            t_next += 1.0 / RATE
            client.send_goal(goal)
            time.sleep(max(0.0, t_next - time.monotonic()))

        def answered():
            finals = [s for s in client.status_list()[since:]
                      if s.event in ("solved", "failed", "superseded", "cancelled")]
            return finals if len(finals) >= count else None
        finals = client.wait_for(answered, 180.0, "an outcome for every goal")

        def settled(goal, what):
            # The arm at rest at the goal: the last trajectory (the one for that goal) ran to
            # its end. Nothing here counts messages (tracker statuses may come late); a
            # trajectory the tracker dropped or refused leaves the arm elsewhere.
            def at_goal():
                if len(states) <= 5 or np.max(np.abs(np.subtract(states[-1], states[-5]))) > 1e-9:
                    return False
                return np.linalg.norm(model.point(np.array(states[-1])) - goal) < SETTLE_TOL
            try:
                client.wait_for(at_goal, 60.0, what)
            except AssertionError as exc:
                tail = [s["message"][:120] for s in tracker_status[-12:]]
                raise AssertionError(f"{exc}; the tracker's last statuses: {tail}") from None
        # A goal's answer: the optimum, or the quick motion that stands (replan_quick).
        answer = next((s for s in reversed(finals)
                       if s.values.get("published") in ("optimum", "first")), None)
        assert answer is not None, [s.message for s in finals]
        settled(np.array(answer.vector("target")), "the arm at rest at the last goal answered")
        time.sleep(0.5)  # a few more joint states at rest
        # At 10 Hz each 1.9 cm move is over before the next goal's hand-off, so the circle's
        # replans start at rest (kind "rest"). A splice into a motion under way: a far goal
        # (a new motion of about a second), and a goal near it while that motion runs.
        splices_before = len([s for s in tracker_status if s.get("event") == "spliced"])
        since_far = len(client.status_list())
        tracker_since = len(tracker_status)
        client.send_goal(FAR)
        far = client.wait_for(lambda: next((s for s in client.status_list()[since_far:]
                                            if s.event in ("solved", "failed")), None),
                              120.0, "the far goal's plan")
        # NEAR once the far motion runs (its splice or start on the tracker): about a second
        # of it left, far more than a replan's lead.
        client.wait_for(lambda: any("executing" in s["message"]
                                    for s in tracker_status[tracker_since:]),
                        30.0, "the far motion's start")
        since_near = len(client.status_list())
        client.send_goal(NEAR)
        near = client.wait_for(lambda: next((s for s in client.status_list()[since_near:]
                                             if s.event in ("solved", "failed")), None),
                               120.0, "the near goal's replan")
        # Its status's start is the hand-off state: the first point of its motion.
        near_motion = near.event == "solved" and client.wait_for(
            lambda: next(
                (m for m in reversed(client.trajectories)
                 if abs(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                        - float(near.values["handoff"])) < 1e-6), None),
            10.0, "the near replan's trajectory")
        # With replan_quick the near goal's quick motion runs about a second: once the worker
        # is idle its optimum is tried, and either published from a later hand-off
        # ("improved", its trajectory starting at that hand-off's state) or not ("kept",
        # saying why).
        after = None
        if quick and near.event == "solved":
            after = client.wait_for(lambda: next(
                (s for s in client.status_list()[since_near:]
                 if s.event in ("improved", "kept")
                 and s.values.get("request_id") == near.values.get("request_id")), None),
                120.0, "the near goal's optimum tried")
            if after.event == "improved":
                improved = client.wait_for(lambda: next(
                    (m for m in reversed(client.trajectories)
                     if abs(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                            - float(after.values["handoff"])) < 1e-6), None),
                    10.0, "the improved trajectory")
                np.testing.assert_allclose(improved.points[0].positions,
                                           after.vector("start_q"), atol=1e-8)
                assert after.values.get("certified") == "true", after.message
                assert float(after.values["T"]) < float(after.values["quick_T"])
            else:
                assert "the quick motion stands" in after.message, after.message
        last = NEAR
        settled(np.array(NEAR), "the arm at rest at the near goal")
        time.sleep(0.5)
    finally:
        client.close()
        codes = [proc.stop() for proc in procs]
    events = [s.event for s in finals]
    # The quick motions published first: certified, each a replan from a hand-off; one
    # that could not be made says so (WARN, published none) and the optimum followed.
    firsts = [s for s in client.status_list()[since:] if s.event == "first"
              and s.values.get("published") == "first"]
    if quick:
        assert firsts and all(s.values.get("certified") == "true" and s.values.get("replan")
                              for s in firsts), [s.message for s in firsts][:5]
        # Where each one's latency went (issue 47): parts of the goal -> trajectory time
        # that do not overlap, each measured on the node's clock.
        parts = ("wait_time", "handoff_time", "problem_time", "solve_time", "sample_time",
                 "send_time")
        for s in firsts:
            values = [float(s.values[k]) for k in parts]
            assert min(values) >= 0.0 and float(s.values["verify_time"]) <= \
                float(s.values["solve_time"]), s.values
            assert sum(values) <= float(s.values["publish_latency"]), s.values
    else:
        assert not [s for s in client.status_list()[since:] if s.event == "first"]
    published = [s for s in finals if s.event == "solved"
                 and s.values.get("published") in ("optimum", "first")]
    replans = [s for s in published if s.values.get("replan")]
    splices = [s for s in tracker_status if s.get("event") == "spliced"]
    print(f"{len(published)}/{count} goals answered ({len(replans)} replans, "
          f"{sum(s.values.get('replan') == 'warm' for s in replans)} warm); events "
          f"{ {e: events.count(e) for e in set(events)} }; {len(splices)} splices")
    # The far goal a new motion, the near one a replan of it, spliced in: into the running
    # far motion (a warm or cold replan) unless its lead, adapted to the replan latencies
    # measured (a loaded machine: up to a second), outlasts it (then a rest replan at its
    # end). Every splice, of either kind, is held to the jump bar below.
    assert far.event == "solved", far.message
    assert near.event == "solved" and near.values.get("replan"), near.message
    print(f"far: {far.message}\nnear: {near.message}\nthen: {after and after.message}")
    # (~/status writes floats with 9 significant digits)
    np.testing.assert_allclose(near_motion.points[0].positions, near.vector("start_q"),
                               atol=1e-8)
    assert len(splices) > splices_before
    assert len(published) >= 0.8 * count, [s.message for s in finals if s not in published]
    # None rejected (a goal the planner refused, a trajectory the tracker refused); a solve
    # that fails numerically or stays late counts against the 80 %.
    assert not [s.message for s in finals if "rejected" in s.message]
    assert not [s["message"] for s in tracker_status if "rejected" in s["message"]]
    assert replans and splices
    hold_splices_to_the_bar(splices)
    # Inside the torque set throughout: every published plan's largest |u_i| below 1.
    assert max(float(s.values["max_abs_u"]) for s in published) < 1.0
    error = float(np.linalg.norm(model.point(np.array(states[-1])) - np.array(last)))
    print(f"final end-effector error {error:.2e} m")
    assert error < 1e-4
    assert codes == [0, 0]
