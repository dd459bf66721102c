"""The tracker node in-process, over DDS, with a private rclpy Context per test.

Each test runs the node and a probe node (publishes trajectories, records what the tracker
publishes) on one executor in a thread, in its own namespace and on its own trajectory
topic, so that latched messages of one test never reach another. The simulation runs 20
times faster than real time. Trajectories are smooth rest-to-rest motions whose torques are
the model's inverse dynamics (no solver needed).
"""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration as RclpyDuration
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.params import RobotDescriptionError
from tocontrol_ros.nodes.qos import LATCHED as QOS_LATCHED
from tocontrol_ros.nodes.tracker import (
    QOS_STATUS,
    QOS_STREAM,
    TrackerNode,
)
from tocontrol_ros.nodes.tracker_config import PAPER_START_Q

pytestmark = pytest.mark.ros

JOINTS = ["joint1", "joint2", "joint3"]
#: Every joint state, not the newest 10 (tests that look at the newest state keep QOS_STREAM:
#: with this depth the probe lags behind a tracker at 20 times real time).
EVERY_STATE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
TIME_SCALE = 20.0
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0
_ids = itertools.count()


@pytest.fixture(scope="module")
def model():
    return load_robot(default_urdf_path())


def motion_msg(model, q0, dq, duration, dt=0.01, names=JOINTS) -> JointTrajectory:
    """A rest-to-rest quintic motion as the planner would publish it."""
    t = np.linspace(0.0, duration, int(round(duration / dt)) + 1)
    s = t / duration
    d = np.asarray(dq, dtype=float)
    q = np.asarray(q0) + (10 * s**3 - 15 * s**4 + 6 * s**5)[:, None] * d
    qd = ((30 * s**2 - 60 * s**3 + 30 * s**4) / duration)[:, None] * d
    qdd = ((60 * s - 180 * s**2 + 120 * s**3) / duration**2)[:, None] * d
    tau = np.array(model.function("id")(q.T, qd.T, qdd.T)).T
    order = [JOINTS.index(n) for n in names]
    msg = JointTrajectory(joint_names=list(names))
    for i in range(t.size):
        ns = int(round(t[i] * 1e9))
        msg.points.append(JointTrajectoryPoint(
            positions=q[i, order].tolist(), velocities=qd[i, order].tolist(),
            accelerations=qdd[i, order].tolist(), effort=tau[i, order].tolist(),
            time_from_start=Duration(sec=ns // 10**9, nanosec=ns % 10**9)))
    return msg


class Harness:
    """Tracker + probe in a private context, spun in a thread."""

    def __init__(self, overrides=(), js_qos=QOS_STREAM, spin=True):
        self.ns = f"/tt{next(_ids)}"
        self.topic = f"{self.ns}/trajectory"
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        params = [Parameter("time_scale", value=TIME_SCALE),
                  Parameter("publish_rate", value=50.0),
                  Parameter("trajectory_topic", value=self.topic), *overrides]
        try:
            self.node = TrackerNode(context=self.context, namespace=self.ns,
                                    parameter_overrides=params)
        except Exception:
            rclpy.try_shutdown(context=self.context)
            raise
        self.probe = Node("probe", context=self.context, namespace=self.ns)
        self.lock = threading.Lock()
        self.joint_states, self.errors, self.statuses, self.clock = [], [], [], []
        # As the planner publishes its plans (latched, depth 1).
        self.pub = self.probe.create_publisher(JointTrajectory, self.topic, QOS_LATCHED)
        self.probe.create_subscription(JointState, f"{self.ns}/joint_states",
                                       self._keep(self.joint_states), js_qos)
        self.probe.create_subscription(JointState, f"{self.ns}/tracker/tracking_error",
                                       self._keep(self.errors), QOS_STREAM)
        self.probe.create_subscription(DiagnosticStatus, f"{self.ns}/tracker/status",
                                       self._keep(self.statuses), QOS_STATUS)
        self.probe.create_subscription(Clock, "/clock", self._keep(self.clock), QOS_STREAM)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        if spin:
            self.start()
        self.wait(lambda: self.pub.get_subscription_count() > 0, "tracker subscription")

    def start(self):
        """Spin the executor (a harness made with ``spin=False``: nothing taken until now)."""
        self.thread.start()

    def _spin(self):
        # Spun here until stop() asks, so that the executor is shut down only once no
        # callback runs: shutting it down under a running spin() raced with the callback's
        # guard condition (rclpy InvalidHandle in the spin thread, seen under load).
        while not self._stopping.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _keep(self, store):
        def callback(msg):
            with self.lock:
                store.append(msg)
        return callback

    def wait(self, condition, what, timeout=15.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if condition():
                    return
            time.sleep(0.01)
        raise AssertionError(f"timed out waiting for {what}")

    def status_with(self, fragment, level=None, timeout=15.0):
        def found():
            return [s for s in self.statuses if fragment in s.message
                    and (level is None or s.level == level)]
        self.wait(lambda: found(), f"a status containing {fragment!r}", timeout)
        with self.lock:
            return found()[0]

    def stop(self):
        self._stopping.set()
        if self.thread.is_alive():
            self.thread.join(timeout=30.0)  # a hang guard: one callback, then the loop ends
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.probe.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def harness():
    h = Harness()
    yield h
    h.stop()


def _values(status):
    return {kv.key: kv.value for kv in status.values}


def test_executes_a_trajectory_and_reports(harness, model):
    q0 = np.array(PAPER_START_Q)
    harness.wait(lambda: len(harness.joint_states) >= 3, "joint_states")
    first = harness.joint_states[0]
    assert list(first.name) == JOINTS
    np.testing.assert_allclose(first.position, q0, atol=1e-9)
    dq = [0.2, -0.2, 0.3]
    harness.pub.publish(motion_msg(model, q0, dq, 1.0))
    accepted = harness.status_with("executing trajectory")
    assert accepted.level == DiagnosticStatus.OK and _values(accepted)["points"] == "101"
    done = harness.status_with("trajectory completed")
    values = _values(done)
    assert done.level == DiagnosticStatus.OK and done.name.endswith("/tracker")
    # Identical plant, consistent torques sampled every 10 ms: PD keeps it within 1 mm.
    assert float(values["final_point_error"]) < 1e-3
    assert float(values["max_error.joint3"]) < 1e-3
    assert float(values["saturated_fraction"]) == 0.0
    assert float(values["duration"]) == pytest.approx(1.0)
    # Then it holds the final configuration: the states of one more simulated second.
    def stamp(msg):
        return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    with harness.lock:
        done_at = stamp(harness.joint_states[-1])
    harness.wait(lambda: stamp(harness.joint_states[-1]) >= done_at + 1.0,
                 "a simulated second of holding", timeout=HANG)
    with harness.lock:
        last = harness.joint_states[-1]
        errors = list(harness.errors)
    np.testing.assert_allclose(last.position, q0 + dq, atol=1e-3)
    assert np.max(np.abs(last.velocity)) < 1e-2
    assert len(last.effort) == 3 and np.all(np.abs(last.effort) <= model.tau_max)
    # Stamps are simulated time, regular at publish_rate: every step between the states
    # received is a whole number of periods (at time_scale 20 the tracker publishes 1000
    # states per second of wall time, and a loaded machine's probe drops some: a fresh-clone
    # CI run received one in 0.23 s of simulated time, median). That one is published every
    # period is the schedule's (test/nodes/test_tracker_time.py): which of them the probe
    # received is a count of real-time messages, not checked here.
    with harness.lock:
        stamps = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                  for m in harness.joint_states]
    periods = np.diff(stamps) / 0.02
    assert np.all(periods > 0.5), periods
    np.testing.assert_allclose(periods, np.round(periods), atol=1e-4)
    assert list(errors[-1].name) == JOINTS and len(errors[-1].position) == 3
    assert max(max(abs(v) for v in e.position) for e in errors) < 1e-3


def _nan(msg):
    msg.points[3].positions[1] = float("nan")
    return msg


def _backwards(msg):
    msg.points[5].time_from_start, msg.points[6].time_from_start = \
        msg.points[6].time_from_start, msg.points[5].time_from_start
    return msg


def _short_effort(msg):
    # (No effort at all is accepted: the model's inverse dynamics stand in for it.)
    msg.points[0].effort = list(msg.points[0].effort)[:2]
    return msg


@pytest.mark.parametrize("corrupt, fragment", [
    (lambda m: JointTrajectory(joint_names=["a", "b", "c"], points=m.points),
     "do not match the robot's joints"),
    (_nan, "positions must be finite; element (3, 1) is nan"),
    (_backwards, "time_from_start must be strictly increasing; t[5]"),
    (_short_effort, "point 0: effort has 2 values for 3 joints"),
    (lambda m: JointTrajectory(joint_names=JOINTS), "no points"),
])
def test_bad_trajectories_are_rejected_and_the_arm_holds(harness, model, corrupt, fragment):
    q0 = np.array(PAPER_START_Q)
    harness.pub.publish(corrupt(motion_msg(model, q0, [0.3, 0.3, 0.3], 1.0)))
    status = harness.status_with("trajectory rejected")
    assert status.level == DiagnosticStatus.ERROR
    assert fragment in status.message and "holding" in status.message
    count = len(harness.joint_states)
    harness.wait(lambda: len(harness.joint_states) > count + 5, "joint_states after")
    assert not harness.node.tracker.running
    np.testing.assert_allclose(harness.joint_states[-1].position, q0, atol=1e-9)
    # A good one afterwards still runs, in any joint order.
    harness.pub.publish(motion_msg(model, q0, [0.1, 0.0, -0.1], 1.0,
                                   names=["joint3", "joint1", "joint2"]))
    done = harness.status_with("trajectory completed")
    assert float(_values(done)["final_point_error"]) < 1e-3
    np.testing.assert_allclose(harness.node.tracker.q, q0 + [0.1, 0.0, -0.1], atol=1e-3)


def test_a_new_trajectory_preempts_from_the_current_state(model):
    # On the simulated clock, driven by the test: the first motion cannot end before the
    # second message is taken, whatever the machine's load (at time_scale 20 its 20 s took
    # 1 s of wall time, and on a loaded machine the second came too late: nothing was
    # preempted). The tracker takes new trajectories on its wall-time tick.
    h = Harness([Parameter("use_sim_time", value=True)])
    try:
        clock = h.probe.create_publisher(Clock, "/clock", QOS_STREAM)
        h.wait(lambda: clock.get_subscription_count() > 1, "tracker's /clock subscription")
        now = [1000.0]

        def advance(seconds):
            for _ in range(int(round(seconds / 0.01))):
                now[0] += 0.01
                ns = int(round(now[0] * 1e9))
                clock.publish(Clock(clock=Time(sec=ns // 10**9, nanosec=ns % 10**9)))
                time.sleep(0.004)  # a clock source's pace, not a synchronisation

        advance(0.01)
        h.wait(lambda: h.node.get_clock().now().nanoseconds > 0, "the first /clock", HANG)
        q0 = np.array(PAPER_START_Q)
        h.pub.publish(motion_msg(model, q0, [0.3, -0.2, 0.3], 20.0))
        h.status_with("executing trajectory", timeout=HANG)
        # Past 1.1 s: the summary's elapsed time is that of the last logged sample, which can
        # lag the simulation's step count by a control period.
        while h.node.tracker.trajectory_time() <= 1.1:
            assert now[0] < 1010.0, "the trajectory does not follow the clock"
            advance(0.1)
        assert h.node.tracker.running
        # As the planner does after a new goal: plan from where the arm is. The clock stands
        # still until the preemption is reported.
        q_now = h.node.tracker.q
        h.pub.publish(motion_msg(model, q_now, [-0.1, 0.1, -0.1], 1.0))
        preempted = h.status_with("preempted", timeout=HANG)
        values = _values(preempted)
        assert values["outcome"] == "preempted"
        assert float(values["duration"]) == pytest.approx(20.0)
        assert 1.0 < float(values["elapsed"]) < 20.0
        advance(1.2)
        done = h.status_with("trajectory completed", timeout=HANG)
        assert float(_values(done)["duration"]) == pytest.approx(1.0)
        np.testing.assert_allclose(h.node.tracker.q, q_now + [-0.1, 0.1, -0.1], atol=3e-3)
        with h.lock:
            executing = [s for s in h.statuses if "executing" in s.message]
        assert len(executing) == 2
    finally:
        h.stop()


def test_stamps_within_a_ticks_stretch_take_over_at_their_instants_in_order(model, monkeypatch):
    """Two trajectories taken in one tick that advances the simulation past both stamps: a
    first motion stamped 0.05 s ahead and the replan from its end (0.5 s later), stamped
    there. Each takes
    over at its own stamp, in order, without a jump: the timeline the planner assumed. (The
    tick counted stamps up to its target as past: the first started at once, off its stamp,
    and the second joined it late; in a loaded CI run a replan started at once from a holding
    arm was then overridden by a splice pending before it, and the next splice, on time,
    jumped by 6e-3 rad.) The test drives the tick itself: the node's timer is cancelled
    and its target time set, so nothing here depends on the machine's speed."""
    h = Harness([Parameter("use_sim_time", value=True)])
    try:
        node = h.node
        for timer in node.timers:
            timer.cancel()
        t0 = node.tracker.t
        target = [t0 + 1.2]
        monkeypatch.setattr(node, "_target_time", lambda: target[0])
        q0, dq = np.array(PAPER_START_Q), np.array([0.02, -0.01, 0.02])
        first, second = motion_msg(model, q0, dq, 0.5), motion_msg(model, q0 + dq, -dq, 0.5)
        for msg, at in ((first, 0.05), (second, 0.55)):
            ns = int(round((node.epoch + t0 + at) * 1e9))
            msg.header.stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
            node._parse(msg)  # what the parsing thread does, here in order
        node._on_timer()
        target[0] += 0.1  # and one more tick: whatever was left pending takes over
        node._on_timer()
        h.wait(lambda: len([s for s in h.statuses if _values(s).get("event") == "spliced"
                            or "executing trajectory:" in s.message
                            or "trajectory rejected" in s.message]) >= 2,
               "both take-overs reported", HANG)
        with h.lock:
            spliced = [_values(s) for s in h.statuses if _values(s).get("event") == "spliced"]
            other = [s.message for s in h.statuses if "executing trajectory:" in s.message
                     or "trajectory rejected" in s.message]
        assert not other, other  # neither started at once nor refused
        assert [float(v["start_time"]) - node.epoch - t0 for v in spliced] == \
            pytest.approx([0.05, 0.55], abs=1e-9)
        assert all(v["late"] == "false" and float(v["position_jump"]) < 1e-9
                   and float(v["velocity_jump"]) < 1e-9 for v in spliced), spliced
        np.testing.assert_allclose(node.tracker.commanded(node.tracker.t)[0], q0, atol=1e-9)
    finally:
        h.stop()


def test_trajectories_published_between_two_takes_are_all_executed(model):
    """Replans published faster than the tracker takes them (its executor busy on a loaded
    machine) are all parsed and started in order, not only the newest: the planner's
    publisher keeps one (latched), the tracker's subscription up to 10."""
    h = Harness(spin=False)
    try:
        q0 = np.array(PAPER_START_Q)
        durations = [0.5, 0.6, 0.7]
        for i, duration in enumerate(durations):
            h.pub.publish(motion_msg(model, q0, [0.01 * (i + 1), 0.0, 0.0], duration))
            # In the tracker's subscription (acknowledged), not taken: nothing spins yet.
            assert h.pub.wait_for_all_acked(RclpyDuration(seconds=10.0))
        h.start()
        h.wait(lambda: sum("executing" in s.message for s in h.statuses) >= len(durations),
               "every trajectory executing")
        with h.lock:
            executing = [_values(s) for s in h.statuses if "executing" in s.message]
        assert [float(v["duration"]) for v in executing] == pytest.approx(durations)
        assert all(v["stamp"] == "0.000000000" for v in executing)
    finally:
        h.stop()


def test_clock_is_published_with_simulated_time():
    h = Harness([Parameter("publish_clock", value=True)])
    try:
        h.wait(lambda: len(h.clock) > 10, "/clock")
        with h.lock:
            times = [c.clock.sec + 1e-9 * c.clock.nanosec for c in h.clock]
            stamp = h.joint_states[-1].header.stamp
        assert np.all(np.diff(times) >= 0)
        # Simulated time from zero, not the wall clock (~1.8e9 s): the first message this
        # subscriber gets comes after DDS discovery, which took 1.4 simulated seconds once.
        assert times[0] < 60.0
        assert stamp.sec < 1000
    finally:
        h.stop()


def _reset_msg(q, qd=(), names=JOINTS, stamp=(7, 5)):
    msg = JointState(name=list(names), position=[float(v) for v in q],
                     velocity=[float(v) for v in qd])
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    return msg


def test_reset_puts_the_arm_at_a_state(harness, model):
    reset = harness.probe.create_publisher(JointState, f"{harness.ns}/tracker/reset",
                                           QOS_STREAM)
    harness.wait(lambda: reset.get_subscription_count() > 0, "reset subscription")
    q0 = np.array(PAPER_START_Q)
    # 200 s (10 s of wall time; a loaded machine also drops simulated time, 1-4 s at a
    # time): still running when the reset is applied at the next tick.
    harness.pub.publish(motion_msg(model, q0, [0.3, -0.2, 0.3], 200.0, dt=1.0))
    harness.status_with("executing trajectory")
    q1 = q0 + [0.1, -0.05, 0.2]
    # Any joint order; velocities optional.
    reset.publish(_reset_msg(q1[[2, 0, 1]], names=["joint3", "joint1", "joint2"]))
    done = harness.status_with("reset to")
    assert _values(done) == {"event": "reset", "request_stamp": "7.000000005"}
    assert _values(harness.status_with("preempted"))["outcome"] == "preempted"
    assert not harness.node.tracker.running
    count = len(harness.joint_states)
    harness.wait(lambda: len(harness.joint_states) > count + 5, "joint_states after")
    with harness.lock:
        last = harness.joint_states[-1]
    np.testing.assert_allclose(last.position, q1, atol=1e-6)  # held there
    # A trajectory from there runs as on a tracker started there.
    harness.pub.publish(motion_msg(model, q1, [-0.1, 0.1, -0.1], 0.5))
    completed = harness.status_with("trajectory completed")
    assert float(_values(completed)["final_point_error"]) < 1e-3
    np.testing.assert_allclose(harness.node.tracker.q, q1 + [-0.1, 0.1, -0.1], atol=1e-3)
    # Bad requests are refused, naming what is wrong; the arm keeps holding.
    for bad, fragment in [(_reset_msg(q1, names=["a", "b", "c"]), "does not match"),
                          (_reset_msg(q1[:2], names=JOINTS), "position has 2 values"),
                          (_reset_msg(q1, qd=[0.0, float("nan"), 0.0]), "velocity is not")]:
        reset.publish(bad)
        status = harness.status_with(fragment)
        assert status.level == DiagnosticStatus.ERROR and "reset rejected" in status.message
    np.testing.assert_allclose(harness.node.tracker.q, q1 + [-0.1, 0.1, -0.1], atol=1e-3)


def test_use_sim_time_follows_the_clock(model):
    """With use_sim_time the simulation waits for /clock, follows it (not time_scale) and
    stamps with it; a clock that jumps back (a looped replay) is followed from there."""
    # Every joint state reaches the probe (reliable, deep): the waits below are for them.
    h = Harness([Parameter("use_sim_time", value=True)], js_qos=EVERY_STATE)
    try:
        clock = h.probe.create_publisher(Clock, "/clock", QOS_STREAM)
        h.wait(lambda: clock.get_subscription_count() > 1, "tracker's /clock subscription")
        assert h.node.tracker.t == 0.0 and not h.joint_states

        def stamps():
            with h.lock:
                return [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                        for m in h.joint_states]

        def run_clock(start, duration):
            """Publish /clock from ``start`` for ``duration`` s; wait for the joint state
            the tracker publishes at its end (an event, not a fixed pause)."""
            for i in range(int(round(duration / 0.01)) + 1):
                ns = int(round((start + 0.01 * i) * 1e9))
                clock.publish(Clock(clock=Time(sec=ns // 10**9, nanosec=ns % 10**9)))
                time.sleep(0.004)  # a clock source's pace, not a synchronisation
            end = start + duration
            last = h.joint_states  # read under h.lock by h.wait
            h.wait(lambda: last and abs(last[-1].header.stamp.sec
                                        + 1e-9 * last[-1].header.stamp.nanosec - end) <= 0.03,
                   f"a joint state stamped near {end}", timeout=HANG)

        run_clock(1000.0, 1.0)
        # From the first /clock the tracker saw (its 100 Hz tick reads the latest one).
        assert h.node.tracker.t == pytest.approx(1.0, abs=0.05)
        got = stamps()
        # It waited for /clock: every state it published is stamped by it.
        assert all(s >= 1000.0 for s in got), got[:5]
        assert got[0] == pytest.approx(1000.0, abs=0.05)
        assert got[-1] == pytest.approx(1001.0, abs=0.03)
        assert np.median(np.diff(got)) == pytest.approx(0.02, abs=1e-6)
        # A trajectory runs on the clock: not done until the clock has passed its end (a move
        # within the torque limits: the tracker rejects one beyond them).
        h.pub.publish(motion_msg(model, np.array(PAPER_START_Q), [0.05, 0.0, -0.05], 0.5))
        h.status_with("executing trajectory")
        run_clock(1001.0, 0.3)
        assert h.node.tracker.running
        run_clock(1001.3, 0.3)
        assert float(_values(h.status_with("trajectory completed"))["duration"]) == 0.5
        count = len(stamps())
        run_clock(500.0, 0.2)  # back in time
        # A state stamped before the jump may still arrive after ``count`` was read (the wait
        # above takes one within 0.03 s of 1001.6): from the first one stamped after the jump,
        # every state is on the new clock.
        later = stamps()[count:]
        back = next((i for i, s in enumerate(later) if s < 1000.0), None)
        assert back is not None, later
        assert all(1001.5 <= s <= 1001.63 for s in later[:back]), later
        assert all(500.0 <= s <= 500.25 for s in later[back:]), later
    finally:
        h.stop()


def test_after_a_reset_the_positions_before_it_are_no_start(harness):
    # The start tolerance accepts positions of the last START_HISTORY seconds; a reset moves
    # the arm elsewhere at once, so a plan from where it stood before is refused.
    reset = harness.probe.create_publisher(JointState, f"{harness.ns}/tracker/reset",
                                           QOS_STREAM)
    harness.wait(lambda: reset.get_subscription_count() > 0, "reset subscription")
    q0 = np.array(PAPER_START_Q)
    reset.publish(_reset_msg(q0 + [0.4, -0.4, 0.4]))
    harness.status_with("reset to")
    msg = motion_msg(harness.node.model, q0, [0.05, 0.0, -0.05], 0.5)
    harness.pub.publish(msg)
    status = harness.status_with("trajectory rejected")
    assert "more than start_tolerance" in status.message, status.message
    # Its header stamp, for a planner to match with its publication (a zero stamp: now).
    values = _values(status)
    assert values["event"] == "rejected"
    assert float(values["stamp"]) == msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


@pytest.mark.parametrize("reset_first", [False, True], ids=["first_plan", "after_reset"])
def test_start_at_first_trajectory_places_the_arm_once(model, reset_first):
    """With start_at_first_trajectory a first plan that starts far away (a free start) puts
    the arm at its first point and runs from there; the next far one is checked as usual.
    A ~/reset before any plan has already placed the arm: then the first plan is checked."""
    # In real time: at 20 times, a loaded machine starves the probe of states.
    h = Harness([Parameter("start_at_first_trajectory", value=True),
                 Parameter("time_scale", value=1.0)], js_qos=EVERY_STATE)
    try:
        q_far = np.array(PAPER_START_Q) + [1.0, -0.8, 0.6]
        if reset_first:
            reset = h.probe.create_publisher(JointState, f"{h.ns}/tracker/reset", QOS_STREAM)
            h.wait(lambda: reset.get_subscription_count() > 0, "reset subscription")
            reset.publish(_reset_msg(np.array(PAPER_START_Q)))
            h.status_with("reset to")
            h.pub.publish(motion_msg(model, q_far, [0.1, 0.1, 0.1], 1.5))
            assert "more than start_tolerance" in h.status_with("trajectory rejected").message
            return
        # The probe receives the states (so it gets every later one) before the plan.
        h.wait(lambda: len(h.joint_states) >= 3, "joint_states")
        h.pub.publish(motion_msg(model, q_far, [0.2, -0.2, 0.3], 1.5))
        start = h.status_with("executing trajectory")
        values = _values(start)
        assert "the arm placed there" in start.message
        assert [float(values[f"start_position.{j}"]) for j in JOINTS] == \
            pytest.approx(q_far, abs=1e-12)
        assert float(values["start_offset"]) == 0.0
        # The state it was placed at is published, stamped with the start.
        t_start = float(values["start_time"])

        def stamps():
            return [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in h.joint_states]

        h.wait(lambda: stamps()[-1] > t_start + 0.1, "joint_states after the start")
        with h.lock:
            at_start = [m.position for m, t in zip(h.joint_states, stamps(), strict=True)
                        if abs(t - t_start) < 1e-6]
            near = [round(t - t_start, 4) for t in stamps() if abs(t - t_start) < 0.1]
        assert at_start, f"no joint state stamped at the start; offsets of those near: {near}"
        np.testing.assert_allclose(at_start[-1], q_far, atol=1e-12)
        done = h.status_with("trajectory completed")
        assert float(_values(done)["final_point_error"]) < 1e-3
        h.pub.publish(motion_msg(model, q_far - 0.5, [0.1, 0.1, 0.1], 1.5))
        assert "more than start_tolerance" in h.status_with("trajectory rejected").message
    finally:
        h.stop()


@pytest.mark.parametrize("overrides, error", [
    ([Parameter("use_sim_time", value=True), Parameter("publish_clock", value=True)],
     ProblemError),
    ([Parameter("sim_rate", value=1500.0)], ProblemError),
    ([Parameter("kp", value=[1.0, 2.0])], ProblemError),
    ([Parameter("initial_positions", value=[0.0, 0.0])], ProblemError),
    ([Parameter("time_scale", value=0.0)], InvalidParameterValueException),
    ([Parameter("payload_mass", value=-1.0)], InvalidParameterValueException),
    ([Parameter("robot_description", value="arm " * 20000)], RobotDescriptionError),
])
def test_bad_parameters_are_refused_at_start(overrides, error):
    with pytest.raises(error):
        Harness(overrides)


# ----------------------------------------------- what the tracker checks (issue 14, item 5)
def _far_start(msg):
    for p in msg.points:
        p.positions[0] += 1e300
    return msg


def _over_effort(msg):
    msg.points[7].effort[2] = 9.0  # joint3's limit is 8 N m
    return msg


@pytest.mark.parametrize("corrupt, fragment", [
    (_far_start, "from the current position (joint1) and 1e+300 rad from every position"),
    (_over_effort, "point 7: effort 9 of joint3 exceeds its torque limit 8"),
])
def test_unsafe_trajectories_are_rejected(harness, model, corrupt, fragment):
    q0 = np.array(PAPER_START_Q)
    harness.pub.publish(corrupt(motion_msg(model, q0, [0.3, 0.3, 0.3], 1.5)))
    status = harness.status_with("trajectory rejected")
    assert fragment in status.message, status.message
    count = len(harness.joint_states)
    harness.wait(lambda: len(harness.joint_states) > count + 5, "joint_states after")
    assert not harness.node.tracker.running
    np.testing.assert_allclose(harness.joint_states[-1].position, q0, atol=1e-9)


def test_size_and_duration_are_bounded(model):
    h = Harness([Parameter("max_points", value=100), Parameter("max_duration", value=2.0)])
    try:
        q0 = np.array(PAPER_START_Q)
        h.pub.publish(motion_msg(model, q0, [0.3, 0.3, 0.3], 1.5))  # 151 points
        assert "151 points, more than max_points = 100" in h.status_with("rejected").message
        h.pub.publish(motion_msg(model, q0, [0.3, 0.3, 0.3], 2.5, dt=0.05))  # 51 points
        status = h.status_with("more than max_duration")
        assert "lasts 2.5 s" in status.message
        assert not h.node.tracker.running
    finally:
        h.stop()


def test_parsing_does_not_hold_up_the_control_loop(harness, model, monkeypatch):
    import tocontrol_ros.nodes.tracker as tracker_module

    parse = tracker_module.nominal_of  # the topic's trajectories come as bytes
    during = []

    def newest_stamp():
        with harness.lock:
            stamp = harness.joint_states[-1].header.stamp
        return stamp.sec + 1e-9 * stamp.nanosec

    def slow_parse(data, joint_names, *args):
        # Stands for the parse of a very large trajectory: it ends only once the control
        # loop has gone on for 100 more published states (publish_rate 50: 2 simulated
        # seconds, by their stamps: a loaded machine's probe drops some), which it could
        # not do if the parse held it up. The bound only catches a hang.
        before = newest_stamp()
        deadline = time.monotonic() + HANG
        while newest_stamp() - before < 100 * 0.02 and time.monotonic() < deadline:
            time.sleep(0.01)
        during.append(newest_stamp() - before)
        return parse(data, joint_names, *args)

    monkeypatch.setattr(tracker_module, "nominal_of", slow_parse)
    harness.wait(lambda: len(harness.joint_states) >= 1, "joint_states")
    harness.pub.publish(motion_msg(model, np.array(PAPER_START_Q), [0.1, 0.1, 0.1], 1.0))
    harness.status_with("executing trajectory", timeout=HANG)
    assert len(during) == 1 and during[0] >= 100 * 0.02 - 1e-9, during


#: The start history (wall s) of the next test's tracker: START_HISTORY (2 s) did not hold a
#: state "a moment ago" on a machine at a load of 12 (the tracker itself was starved).
LONG_HISTORY = 8.0


@pytest.fixture
def long_history(monkeypatch):
    from tocontrol_ros.nodes import tracker

    monkeypatch.setattr(tracker, "START_HISTORY", LONG_HISTORY)
    h = Harness()
    yield h
    h.stop()


def test_a_plan_from_a_recent_state_is_accepted_an_old_one_is_not(long_history, model):
    # A plan made from the state of a moving arm arrives after the arm has moved on: its
    # first point is a position the arm had (published on joint_states) a moment ago.
    harness = long_history
    q0 = np.array(PAPER_START_Q)
    harness.pub.publish(motion_msg(model, q0, [0.3, -0.3, 0.3], 1.5))
    harness.status_with("trajectory completed")
    assert np.max(np.abs(harness.node.tracker.q - q0)) > 0.25  # > start_tolerance (0.1)
    harness.pub.publish(motion_msg(model, q0, [0.1, 0.0, 0.0], 1.0))
    harness.status_with("executing trajectory: 101 points")
    harness.status_with("trajectory completed", timeout=15.0)
    time.sleep(LONG_HISTORY + 0.5)  # q0 is now older than the history
    harness.pub.publish(motion_msg(model, q0 + [0.3, -0.3, 0.3], [0.0, 0.0, 0.1], 1.0))
    status = harness.status_with("trajectory rejected")
    assert "more than start_tolerance" in status.message, status.message
