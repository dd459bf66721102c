"""Recorder and replay in-process, over DDS, with a private rclpy Context per test.

Round trip: what the recorder wrote equals, byte for byte, what a raw subscription received
and the exact CDR of the published message, and decodes (rosbags, mcap-ros2-support) to the
published fields. Replay: inter-message times follow the recording at rate 1 and 10.
"""

import array
import os
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from tocontrol_ros.recording import cdr as cdr_exact
from tocontrol_ros.recording import mcap_io
from tocontrol_ros.recording.recorder import Recorder
from tocontrol_ros.recording.replay import Player

pytestmark = pytest.mark.ros
AnyReader = pytest.importorskip("rosbags.highlevel").AnyReader
DecoderFactory = pytest.importorskip("mcap_ros2.decoder").DecoderFactory

def unique(topic):
    """A topic of this test's own: parallel sessions may share the DDS domain."""
    return f"/t{uuid.uuid4().hex[:8]}{topic}"


LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def context():
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def spin_until(executor, condition, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return condition()


def _same(a, b, where="msg"):
    """Field-by-field equality of an rclpy message and a decoded one (rosbags/mcap_ros2)."""
    if hasattr(a, "get_fields_and_field_types"):
        for name in a.get_fields_and_field_types():
            _same(getattr(a, name), getattr(b, name), f"{where}.{name}")
    elif isinstance(a, bytes):  # byte/uint8 fields: rclpy bytes, decoders int
        assert list(a) == ([b] if isinstance(b, int) else list(b)), where
    elif isinstance(a, (list, tuple, np.ndarray, array.array)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(float(b), rel=0, abs=0) or (np.isnan(a) and np.isnan(b)), where
    else:
        assert a == b, where


def test_round_trip_byte_for_byte_and_field_by_field(context, tmp_path):
    from test_mcap_io import sample_messages  # noqa: PLC0415 (test helper module)

    types = ["trajectory_msgs/msg/JointTrajectory", "diagnostic_msgs/msg/DiagnosticStatus",
             "sensor_msgs/msg/JointState", "visualization_msgs/msg/MarkerArray"]
    samples = sample_messages()
    names = ["/planner/trajectory", "/planner/status", "/joint_states", "/planner/markers"]
    traj_topic, js_topic = unique(names[0]), unique(names[2])
    topics = {traj_topic: types[0], unique(names[1]): types[1], js_topic: types[2],
              unique(names[3]): types[3]}
    node = rclpy.create_node("publisher", context=context)
    pubs = {t: node.create_publisher(mcap_io.message_class(ty), t,
                                     LATCHED if t == traj_topic else 50)
            for t, ty in topics.items()}
    witness = {t: [] for t in topics}
    for t, ty in topics.items():
        node.create_subscription(mcap_io.message_class(ty), t,
                                 lambda data, info, t=t: witness[t].append((data, info)),
                                 LATCHED if t == traj_topic else 50, raw=True)
    # Published before the recorder exists: only transient local brings it in.
    pubs[traj_topic].publish(samples[types[0]])
    out = tmp_path / "rt.mcap"
    recorder = Recorder(context=context, parameter_overrides=[
        Parameter("output", value=str(out)), Parameter("topics", value=list(topics)),
        Parameter("discovery_period", value=0.05), Parameter("link_frames", value=False)])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(recorder)
    try:
        assert spin_until(executor, lambda: not recorder.pending_topics
                          and all(p.get_subscription_count() >= 2 for p in pubs.values()))
        sent = {t: [] for t in topics}
        sent[traj_topic].append(samples[types[0]])
        for i in range(20):
            for t, ty in topics.items():
                if t == traj_topic:
                    continue
                msg = samples[ty]
                if ty == types[2]:
                    msg = JointState(header=Header(frame_id=f"f{i}"), name=["a"],
                                     position=[float(i)], effort=[0.5 * i])
                pubs[t].publish(msg)
                sent[t].append(msg)
            executor.spin_once(timeout_sec=0.001)
        total = sum(len(v) for v in sent.values())
        assert spin_until(executor, lambda: recorder.writer.message_count >= total
                          and sum(len(w) for w in witness.values()) >= total)
    finally:
        recorder.close()
        executor.shutdown()
        recorder.destroy_node()
        node.destroy_node()

    channels = mcap_io.read_channels(out)
    assert {t: c.type for t, c in channels.items()} == topics
    assert channels[traj_topic].offered_qos_profiles[0]["durability"] == (
        "transient_local")
    assert channels[js_topic].type_hash.startswith("RIHS01_")
    records = {t: [r for r in mcap_io.iter_records(out) if r.topic == t] for t in topics}
    for t in topics:
        assert len(records[t]) == len(sent[t]) == len(witness[t]), t
        for rec, msg, (raw, info) in zip(records[t], sent[t], witness[t], strict=True):
            assert rec.data == raw == cdr_exact.serialize_exact(msg), t
            assert rec.publish_time == info["source_timestamp"]
            assert rec.log_time >= rec.publish_time

    with AnyReader([Path(out)]) as reader:
        decoded = {t: [] for t in topics}
        for conn, _, raw in reader.messages():
            decoded[conn.topic].append(reader.deserialize(raw, conn.msgtype))
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        mcap_decoded = {t: [] for t in topics}
        for _, channel, _, msg in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            mcap_decoded[channel.topic].append(msg)
    for t in topics:
        for msg, a, b in zip(sent[t], decoded[t], mcap_decoded[t], strict=True):
            _same(msg, a, f"{t} rosbags")
            _same(msg, b, f"{t} mcap_ros2")


def test_status_reports_subscriptions_and_first_messages(context, tmp_path):
    """~/status: started (with the topics), subscribed when a publisher appears,
    first_message once the first message is written (not before), once per topic."""
    from diagnostic_msgs.msg import DiagnosticStatus  # noqa: PLC0415

    from tocontrol_ros.recording.recorder import QOS_STATUS  # noqa: PLC0415

    js_topic, other = unique("/joint_states"), unique("/other")
    ns = unique("/ns").rsplit("/", 1)[0]
    recorder = Recorder(context=context, namespace=ns, parameter_overrides=[
        Parameter("output", value=str(tmp_path / "s.mcap")),
        Parameter("topics", value=[js_topic, other]),
        Parameter("discovery_period", value=0.05), Parameter("link_frames", value=False)])
    node = rclpy.create_node("probe", context=context)
    events = []
    node.create_subscription(DiagnosticStatus, f"{ns}/recorder/status",
                             lambda m: events.append({kv.key: kv.value for kv in m.values}),
                             QOS_STATUS)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(recorder)

    def kinds(topic):
        return [e["event"] for e in events if e.get("topic") == topic]

    try:
        assert spin_until(executor, lambda: events)
        assert events[0] == {"event": "started", "output": str(tmp_path / "s.mcap"),
                             "topics": f"{js_topic},{other}"}
        pub = node.create_publisher(JointState, js_topic, 10)
        assert spin_until(executor, lambda: kinds(js_topic) == ["subscribed"])
        assert recorder.receiving_topics == []
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
        for i in range(3):
            pub.publish(JointState(name=["a"], position=[float(i)]))
        assert spin_until(executor, lambda: recorder.writer.message_count == 3
                          and kinds(js_topic) == ["subscribed", "first_message"])
        assert recorder.receiving_topics == [js_topic]
        assert kinds(other) == []
        assert [e for e in events if e["event"] == "subscribed"][0]["type"] == (
            "sensor_msgs/msg/JointState")
    finally:
        recorder.close()
        executor.shutdown()
        recorder.destroy_node()
        node.destroy_node()


def _write_stream(path, intervals_ms, topic="/joint_states"):
    log = 1_000_000_000_000
    times = [log]
    with mcap_io.RecordingWriter(path) as writer:
        writer.add_topic(topic, "sensor_msgs/msg/JointState", [LATCHED])
        for i, dt in enumerate([0, *intervals_ms]):
            log += int(dt * 1e6)
            times.append(log)
            msg = JointState(name=["a"], position=[float(i)])
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=log)
    return np.diff(times[1:]) * 1e-9


#: Timed passes of the wall-clock replay test: each pass checks every bound, and one that
#: meets them all passes the test. A player that drifts or mis-times fails every pass; a pass
#: can also fail when the (shared, two-core) machine stalls the player's thread.
REPLAY_PASSES = 3


def _timing_errors(got, recorded, rate):
    """Reasons (empty if none) why receive times ``got`` (ns) miss the recorded intervals."""
    replayed = np.diff(got) * 1e-9
    err = np.abs(replayed - recorded / rate)
    total = (got[-1] - got[0]) * 1e-9
    # Receive times (DDS) of a local reliable topic: typically 0.1 ms off. Single late
    # wake-ups of the player are tolerated; the schedule is absolute, so they do not add up.
    checks = {"median error < 1 ms": np.median(err) < 1e-3,
              "90th percentile < 5 ms": np.quantile(err, 0.9) < 5e-3,
              "max error < 30 ms": np.max(err) < 30e-3,
              "total within 10 ms (no drift)": abs(total - recorded.sum() / rate) < 10e-3}
    return [f"{name} (errors in ms: {np.round(err * 1e3, 2).tolist()}, total {total:.4f} s)"
            for name, ok in checks.items() if not ok]


class _VirtualTime:
    """A clock that only ``sleep`` advances, optionally late by ``late`` s on given calls."""

    def __init__(self, late=None):
        self.now = 100.0
        self.calls = 0
        self.late = late or {}

    def clock(self):
        return self.now

    def sleep(self, dt):
        assert dt > 0
        self.calls += 1
        self.now += dt + self.late.get(self.calls, 0.0)


class _RecordingPublisher:
    def __init__(self, vt):
        self.vt, self.times = vt, []

    def publish(self, data):
        self.times.append(self.vt.clock())


@pytest.mark.parametrize("rate", [1.0, 10.0])
def test_replay_schedule_is_absolute_and_scaled(context, tmp_path, rate):
    """The player publishes each message at origin + (log time - first log time) / rate on
    its clock, and a late wake-up delays only the messages it holds up (no drift)."""
    rng = np.random.default_rng(0)
    intervals = rng.uniform(4.0, 16.0, 60)  # ms
    path = tmp_path / "stream.mcap"
    recorded = _write_stream(path, intervals)
    schedule = np.concatenate([[0.0], np.cumsum(recorded)]) / rate
    node = rclpy.create_node("replay_schedule", context=context)
    try:
        for late in ({}, {7: 0.030}):  # one wake-up 30 ms late (a stalled thread)
            vt = _VirtualTime(late)
            player = Player(node, path, rate=rate, clock=vt.clock, sleep=vt.sleep)
            pub = _RecordingPublisher(vt)
            player.publishers = {topic: pub for topic in player.publishers}
            assert player.play_once() == len(schedule)
            offsets = np.array(pub.times) - pub.times[0]
            if not late:
                np.testing.assert_allclose(offsets, schedule, atol=1e-9)
            else:
                lag = offsets - schedule
                assert np.all(lag >= -1e-9) and lag.max() <= 0.030 + 1e-9
                # Back on schedule once the stall is over: the last messages are on time.
                np.testing.assert_allclose(lag[-10:], 0.0, atol=1e-9)
    finally:
        node.destroy_node()


def test_replay_delivers_every_message_with_the_recorded_qos(context, tmp_path):
    path = tmp_path / "stream.mcap"
    topic = unique("/joint_states")
    _write_stream(path, np.full(20, 2.0), topic)
    node = rclpy.create_node("replay_qos", context=context)
    got = []
    node.create_subscription(JointState, topic, lambda m: got.append(m.position[0]),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    player = Player(node, path, rate=1.0)
    qos = player.publishers[topic].qos_profile
    assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        assert spin_until(executor, lambda: player.publishers[topic]
                          .get_subscription_count() == 1)
        assert player.play_once() == 21
        assert spin_until(executor, lambda: len(got) == 21)
    finally:
        executor.shutdown()
        node.destroy_node()
    assert got == [float(i) for i in range(21)]  # all, in order


@pytest.mark.slow
@pytest.mark.parametrize("rate", [1.0, 10.0])
def test_replay_keeps_wall_clock_timing(context, tmp_path, rate):
    """Receive times over DDS against the recording, on the wall clock.

    Slow-marked (``scripts/dev test-slow``): on this two-core VM the hypervisor sometimes
    stalls a thread for tens of milliseconds (a fresh-clone CI run saw 67 ms in all three
    passes), which no player can hide; the schedule itself is checked exactly, on a
    virtual clock, by test_replay_schedule_is_absolute_and_scaled in the default run.
    """
    rng = np.random.default_rng(0)
    n = 60 if rate == 1.0 else 200
    intervals = rng.uniform(4.0, 16.0, n)  # ms: 100 Hz with jitter
    path = tmp_path / "stream.mcap"
    topic = unique("/joint_states")
    recorded = _write_stream(path, intervals, topic)
    node = rclpy.create_node("replay_test", context=context)
    got = []
    node.create_subscription(JointState, topic,
                             lambda m, info: got.append(info["received_timestamp"]),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
                             raw=True)
    player = Player(node, path, rate=rate)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    failures = []
    try:
        assert spin_until(executor, lambda: player.publishers[topic]
                          .get_subscription_count() == 1)
        for _ in range(REPLAY_PASSES):
            got.clear()
            assert player.play_once() == n + 1
            assert spin_until(executor, lambda: len(got) == n + 1)
            failures.append(_timing_errors(list(got), recorded, rate))
            if not failures[-1]:
                break
    finally:
        executor.shutdown()
        node.destroy_node()
    assert not failures[-1], failures


def test_timing_check_rejects_a_drifting_or_mistimed_replay():
    """The wall-clock test's check fails a player that drifts, or ignores the rate."""
    recorded = np.full(50, 0.01)
    exact = np.concatenate([[0], np.cumsum(recorded)]) * 1e9
    assert _timing_errors(exact, recorded, 1.0) == []
    drift = np.concatenate([[0], np.cumsum(recorded * 1.03)]) * 1e9  # 3 % slow: 15 ms
    assert any("total" in r for r in _timing_errors(drift, recorded, 1.0))
    assert any("median" in r for r in _timing_errors(exact, recorded, 10.0))


def test_replay_rejects_unknown_topics(context, tmp_path):
    path = tmp_path / "stream.mcap"
    _write_stream(path, [10.0])
    node = rclpy.create_node("replay_bad", context=context)
    try:
        with pytest.raises(ValueError, match="not in"):
            Player(node, path, topics=["/nope"])
        with pytest.raises(ValueError, match="rate"):
            Player(node, path, rate=0.0)
    finally:
        node.destroy_node()


def test_relative_topics_resolve_in_the_namespace_and_diagnostics_say_so(context, tmp_path):
    """The default topics are relative (issue 52): in namespace /armN they are /armN/...;
    the recorder's /diagnostics status names the file and the topics still waiting."""
    ns = unique("")
    out = tmp_path / "ns.mcap"
    recorder = Recorder(context=context, namespace=ns, parameter_overrides=[
        Parameter("output", value=str(out)), Parameter("link_frames", value=False),
        Parameter("topics", value=["planner/trajectory", "joint_states", "/elsewhere/x"])])
    try:
        assert recorder.config.topics == (f"{ns}/planner/trajectory", f"{ns}/joint_states",
                                          "/elsewhere/x")
        assert recorder.config.joint_states_topic == f"{ns}/joint_states"
        array = recorder.diagnostics.message()
        [status] = array.status
        values = {kv.key: kv.value for kv in status.values}
        assert status.name == f"{ns}/recorder" and values["output"] == str(out)
        assert values["pending_topics"].split(",") == list(recorder.config.topics)
        from diagnostic_msgs.msg import DiagnosticStatus  # noqa: PLC0415

        assert status.level == DiagnosticStatus.WARN  # nothing published on them yet
    finally:
        recorder.close()
        recorder.destroy_node()


def test_an_invalid_topic_name_is_refused_by_name(context, tmp_path):
    with pytest.raises(ValueError, match="invalid topic name"):
        Recorder(context=context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bad.mcap")),
            Parameter("link_frames", value=False),
            Parameter("topics", value=["bad topic name!"])])
