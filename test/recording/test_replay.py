"""Replay as users run it: waiting for subscribers, /clock, remapping, pause and step, and the
recorded initial state that ``--reexecute`` sends to the tracker.

Schedules are checked on a virtual clock (exactly, whatever the machine's load); delivery
over DDS with the replay as a real process (``python -m tocontrol_ros.replay``, as the
installed ``replay`` wrapper runs it).
"""

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from tocontrol_ros.recording import cdr as cdr_exact
from tocontrol_ros.recording import mcap_io
from tocontrol_ros.recording.replay import Player, parse_remaps, recorded_initial_state

pytestmark = pytest.mark.ros
REPO = Path(__file__).resolve().parents[2]
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
T0 = 1_000_000_000_000  # first log time (ns)


def unique(topic):
    return f"/r{uuid.uuid4().hex[:8]}{topic}"


@pytest.fixture
def context():
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def write_stream(path, times_ms, topic="/joint_states", qos=RELIABLE, end_ms=None):
    """JointState messages (position = index) at the given log times (ms after T0)."""
    with mcap_io.RecordingWriter(path) as writer:
        writer.add_topic(topic, "sensor_msgs/msg/JointState", [qos])
        for i, t in enumerate(times_ms):
            msg = JointState(name=["a"], position=[float(i)])
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=T0 + int(t * 1e6))
        if end_ms is not None:
            writer.add_topic("/other", "sensor_msgs/msg/JointState", [qos])
            writer.write("/other", cdr_exact.serialize_exact(JointState()),
                         log_time=T0 + int(end_ms * 1e6))


class VirtualTime:
    """A clock that only ``sleep`` advances; ``hooks[call]`` runs at that sleep call."""

    def __init__(self, hooks=None):
        self.now, self.calls, self.hooks = 100.0, 0, dict(hooks or {})

    def clock(self):
        return self.now

    def sleep(self, dt):
        assert dt > 0
        self.calls += 1
        self.now += dt
        if self.calls in self.hooks:
            self.hooks[self.calls]()


class Capture:
    def __init__(self, vt):
        self.vt, self.times, self.data = vt, [], []

    def publish(self, msg):
        self.times.append(self.vt.clock())
        self.data.append(msg)


def test_clock_follows_the_recorded_time_to_the_end(context, tmp_path):
    """--clock: /clock every period of playback time and at each message's log time, from
    the first replayed message to the recording's end (past the last replayed one)."""
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0, 100.0, 250.0], end_ms=1000.0)
    node = rclpy.create_node("replay_clock", context=context)
    try:
        for rate in (1.0, 2.0):
            vt = VirtualTime()
            player = Player(node, path, topics=["/joint_states"], rate=rate, clock_rate=50.0,
                            clock=vt.clock, sleep=vt.sleep)
            pub, clock = Capture(vt), Capture(vt)
            player.publishers = {"/joint_states": pub}
            player.clock_publisher = clock
            assert player.play_once() == 3
            # The clock first shows the first message's time, one clock period before it.
            sent = np.array(pub.times) - 100.02
            np.testing.assert_allclose(sent, np.array([0.0, 0.1, 0.25]) / rate, atol=1e-9)
            wall = np.array(clock.times) - 100.02
            value = np.array([c.clock.sec + 1e-9 * c.clock.nanosec for c in clock.data]) - 1000
            assert wall[0] == pytest.approx(-0.02) and value[0] == 0.0
            # Then the recorded time: log time = first + rate * wall time.
            np.testing.assert_allclose(value[1:-1], wall[1:-1] * rate, atol=1e-6)
            assert np.all(np.diff(value) >= 0)
            assert np.max(np.diff(wall)) <= 0.02 + 1e-9  # 50 Hz of wall time, at least
            assert value[-1] == pytest.approx(1.0)  # up to the recording's end
            for t in (0.0, 0.1, 0.25):  # and each message's own time
                assert np.min(np.abs(value - t)) < 1e-9
    finally:
        node.destroy_node()


def test_pause_holds_the_schedule_and_step_publishes_the_next(context, tmp_path):
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0, 100.0, 200.0, 300.0])
    node = rclpy.create_node("replay_pause", context=context)
    try:
        vt = VirtualTime()
        player = Player(node, path, clock=vt.clock, sleep=vt.sleep)
        pub = Capture(vt)
        player.publishers = {"/joint_states": pub}
        marks = {}

        def pause():
            marks["paused"] = vt.now
            player.toggle_pause()

        def step():
            marks["step"] = vt.now
            player.step()

        def resume():
            marks["resumed"] = vt.now
            player.toggle_pause()

        # Pause after the first message, step once 1 s later, resume 1 s after that.
        vt.hooks = {1: pause, 22: step, 43: resume}
        assert player.play_once() == 4
        sent = np.array(pub.times)
        assert sent[0] == 100.0
        assert marks["paused"] < 100.1
        # The second message only on the step, the third 0.1 s after the resume.
        assert marks["step"] <= sent[1] < marks["step"] + 0.051
        assert sent[2] == pytest.approx(marks["resumed"] + 0.1, abs=0.051)
        assert sent[3] - sent[2] == pytest.approx(0.1, abs=1e-9)
    finally:
        node.destroy_node()


def test_remap_publishes_under_another_name(context, tmp_path):
    topic, other = unique("/joint_states"), unique("/elsewhere")
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0, 5.0, 10.0], topic=topic)
    node = rclpy.create_node("replay_remap", context=context)
    got = []
    node.create_subscription(JointState, other, lambda m: got.append(m.position[0]), RELIABLE)
    player = Player(node, path, remap=parse_remaps([f"{topic}:={other}"]))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        assert player.publishers[topic].topic_name == other
        assert player.wait_for_subscribers(5.0) == []
        assert player.play_once() == 3
        deadline = time.monotonic() + 5.0
        while len(got) < 3 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert got == [0.0, 1.0, 2.0]
        with pytest.raises(ValueError, match="not among the replayed topics"):
            Player(node, path, remap={"/nope": "/x"})
    finally:
        executor.shutdown()
        node.destroy_node()


@pytest.mark.parametrize("items, match", [
    (["/a=/b"], "FROM:=/TO"), (["a:=/b"], "absolute"), (["/a:=b"], "absolute")])
def test_bad_remaps_are_named(items, match):
    with pytest.raises(ValueError, match=match) as info:
        parse_remaps(items)
    assert items[0] in str(info.value)


def _replay(args, **kwargs):
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "tocontrol_ros.replay", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            **kwargs)


def test_replay_waits_for_a_subscriber_that_comes_late(context, tmp_path):
    """The issue's first try: the replay starts before anyone subscribes. Every message must
    still arrive (the old replay published after a fixed 0.5 s: all into the void)."""
    topic = unique("/planner/trajectory")
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0, 50.0, 100.0], topic=topic)  # volatile, reliable
    # A generous wait for subscribers: the late one comes once the replay's publisher is
    # seen, however long a loaded machine takes (the default 10 s only bounds a hang here).
    proc = _replay([str(path), "--no-keys", "--wait-for-subscribers", "120"])
    try:
        node = rclpy.create_node("late_subscriber", context=context)
        # The replay process is up and waiting: its publisher is in the graph (an event).
        deadline = time.monotonic() + 120.0
        while node.count_publishers(topic) == 0 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()[0]
            time.sleep(0.05)
        assert node.count_publishers(topic) == 1, "the replay never advertised its topic"
        got = []
        node.create_subscription(JointState, topic, lambda m: got.append(m.position[0]),
                                 RELIABLE)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 20.0
        while (len(got) < 3 or proc.poll() is None) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
        node.destroy_node()
        out = proc.communicate(timeout=10)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert got == [0.0, 1.0, 2.0], out
    assert "published 3 messages" in out and "no subscriber" not in out


def test_replay_warns_when_no_subscriber_appears(tmp_path):
    topic = unique("/planner/trajectory")
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0], topic=topic)
    proc = _replay([str(path), "--wait-for-subscribers", "0.5", "--no-keys"])
    out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, out
    assert "no subscriber matched after 0.5 s" in out and topic in out, out


def test_replay_reexecute_without_a_tracker_fails_clearly(tmp_path):
    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        writer.add_topic("/joint_states", "sensor_msgs/msg/JointState", [RELIABLE])
        writer.add_topic("/planner/trajectory", "trajectory_msgs/msg/JointTrajectory",
                         [RELIABLE])
        writer.write("/joint_states", cdr_exact.serialize_exact(
            JointState(name=["a"], position=[0.0])), log_time=T0)
    tracker = unique("/tracker")
    proc = _replay([str(path), "--reexecute", "--tracker", tracker,
                    "--wait-for-subscribers", "0.5", "--no-keys"])
    out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 1, out
    assert f"no tracker subscribes to {tracker}/reset" in out, out


def _stamp(t):
    ns = int(round(t * 1e9))
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


def write_run(path, state_stamps, start_time, start_state=False):
    """Joint states (position = stamp) and, if `start_time`, the tracker's start event (with
    the state it started from if `start_state`: positions 7, -7)."""
    with mcap_io.RecordingWriter(path) as writer:
        writer.add_topic("/joint_states", "sensor_msgs/msg/JointState", [RELIABLE])
        writer.add_topic("/tracker/status", "diagnostic_msgs/msg/DiagnosticStatus",
                         [RELIABLE])
        events = []
        if start_time is not None:
            events.append((start_time, DiagnosticStatus(
                message="executing trajectory: 3 points", values=[
                    KeyValue(key="start_time", value=f"{start_time:.9f}")] + ([
                        KeyValue(key=f"start_{f}.{n}", value=v) for f, n, v in [
                            ("position", "a", "7.0"), ("position", "b", "-7.0"),
                            ("velocity", "a", "0.5"), ("velocity", "b", "0")]]
                        if start_state else []))))
        items = [(t, JointState(header=Header(stamp=_stamp(t)), name=["a", "b"],
                                position=[t, -t], velocity=[0.5, 0.0]))
                 for t in state_stamps] + events
        for t, msg in sorted(items, key=lambda item: item[0]):
            topic = "/joint_states" if isinstance(msg, JointState) else "/tracker/status"
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=int(t * 1e9) + 1000)


@pytest.mark.parametrize("stamps, start, start_state, want, source", [
    ([10.05, 10.06], 10.025, True, 7.0, "the tracker's state at the first trajectory's start"),
    ([10.0, 10.01, 10.02, 10.03], 10.025, False, 10.02, "/joint_states at the first"),
    ([10.0, 10.01], None, False, 10.0, "no tracker start recorded"),
    ([10.05, 10.06], 10.025, False, 10.05, "not in the file"),
])
def test_recorded_initial_state(tmp_path, stamps, start, start_state, want, source):
    path = tmp_path / "run.mcap"
    write_run(path, stamps, start, start_state)
    state = recorded_initial_state(path)
    assert list(state.msg.position) == [want, -want]
    assert list(state.msg.name) == ["a", "b"] and list(state.msg.velocity) == [0.5, 0.0]
    assert source in state.source


def test_recorded_initial_state_needs_joint_states(tmp_path):
    path = tmp_path / "run.mcap"
    write_stream(path, [0.0], topic="/other")
    with pytest.raises(ValueError, match="has no /joint_states and no tracker start"):
        recorded_initial_state(path)
