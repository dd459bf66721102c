"""mcap_io without DDS: definitions, QoS YAML, exact CDR, the writer, reading back.

Independent readers (rosbags, mcap-ros2-support) check what the helpers produce.
"""

import shutil

import pytest
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from mcap.stream_reader import StreamReader
from rclpy.duration import Duration as RclpyDuration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from sensor_msgs.msg import CameraInfo, JointState
from std_msgs.msg import Empty, Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from tocontrol_ros.recording import cdr as cdr_exact
from tocontrol_ros.recording import mcap_io

rosbags_typesys = pytest.importorskip("rosbags.typesys")
mcap_ros2_dynamic = pytest.importorskip("mcap_ros2._dynamic")

DELIM = "=" * 80 + "\n"


def sample_messages():
    """One message per type the pipeline records, with arrays, strings and nesting."""
    traj = JointTrajectory(header=Header(stamp=Time(sec=5, nanosec=7), frame_id="base"),
                           joint_names=["j1", "j2", "j3"])
    traj.points = [JointTrajectoryPoint(positions=[0.1 * i, 0.2, 0.3], velocities=[1.0] * 3,
                                        accelerations=[], effort=[5.0, -4.0, 1.5],
                                        time_from_start=Duration(sec=0, nanosec=i * 1000))
                   for i in range(4)]
    status = DiagnosticStatus(level=b"\x01", name="planner", message="ok", hardware_id="h1",
                              values=[KeyValue(key="T", value="1.234"),
                                      KeyValue(key="k", value="4")])
    js = JointState(header=Header(frame_id="x"), name=["a", "bb", "ccc"],
                    position=[1.0, 2.0, 3.0], velocity=[], effort=[0.5, 0.25, 0.125])
    marker = Marker(ns="ns", id=3, type=Marker.LINE_STRIP, text="abcde")
    marker.points = [marker.pose.position] * 2
    return {
        "trajectory_msgs/msg/JointTrajectory": traj,
        "diagnostic_msgs/msg/DiagnosticStatus": status,
        "sensor_msgs/msg/JointState": js,
        "visualization_msgs/msg/MarkerArray": MarkerArray(markers=[marker, Marker()]),
        "sensor_msgs/msg/CameraInfo": CameraInfo(distortion_model="plumb_bob"),
        "std_msgs/msg/Empty": Empty(),
    }


# ---------------------------------------------------------------- definitions
def test_definition_layout_as_rosbag2():
    text = mcap_io.message_definition("sensor_msgs/msg/JointState")
    parts = text.split("\n" + DELIM)
    assert parts[0].startswith("# This is a message that holds data")
    assert [p.split("\n", 1)[0] for p in parts[1:]] == [
        "MSG: std_msgs/Header", "MSG: builtin_interfaces/Time"]
    assert "std_msgs/Header header" in parts[0]


@pytest.mark.parametrize("type_name", sorted(sample_messages()))
def test_definitions_parse_with_independent_readers(type_name):
    text = mcap_io.message_definition(type_name)
    types = rosbags_typesys.get_types_from_msg(text, type_name)
    store = rosbags_typesys.get_typestore(rosbags_typesys.Stores.EMPTY)
    store.register(types)
    reference = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
    # The type hash covers every field of every dependency: equal hashes, equal types.
    assert store.hash_rihs01(type_name) == reference.hash_rihs01(type_name)
    assert type_name in mcap_ros2_dynamic.generate_dynamic(type_name, text)


def _fake_prefix(tmp_path, monkeypatch):
    prefix = tmp_path / "prefix"
    msg_dir = prefix / "share" / "fake_msgs" / "msg"
    msg_dir.mkdir(parents=True)
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "fake_msgs").write_text("")
    (msg_dir / "Outer.msg").write_text(
        "# Outer: every field form\n"
        "int8 A=1\n"
        "string NAME=\"x\"\n"
        "Inner inner  # same-package short name; Other in a comment is ignored\n"
        "builtin_interfaces/Time stamp\n"
        "string<=10 bounded\n"
        "int32[<=3] up_to_three\n"
        "uint8[4] four\n"
        "Inner[] many\n"
        "float64 with_default 1.5\n")
    (msg_dir / "Inner.msg").write_text("builtin_interfaces/Duration d\nstring s\n")
    import os

    paths = os.environ.get("AMENT_PREFIX_PATH", "")
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{prefix}:{paths}" if paths else str(prefix))
    monkeypatch.setattr(mcap_io, "_DEFINITION_CACHE", {})


def test_definition_of_every_field_form(tmp_path, monkeypatch):
    _fake_prefix(tmp_path, monkeypatch)
    text = mcap_io.message_definition("fake_msgs/msg/Outer")
    headers = [line for line in text.splitlines() if line.startswith("MSG: ")]
    # Depth first, sorted: Inner (then its Duration), then Time.
    assert headers == ["MSG: builtin_interfaces/Time", "MSG: fake_msgs/Inner",
                       "MSG: builtin_interfaces/Duration"]
    types = rosbags_typesys.get_types_from_msg(text, "fake_msgs/msg/Outer")
    assert set(types) == {"fake_msgs/msg/Outer", "fake_msgs/msg/Inner",
                          "builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}


@pytest.mark.parametrize("name", ["JointState", "sensor_msgs/msg/", "a/b/c/D"])
def test_definition_rejects_bad_names(name):
    with pytest.raises(mcap_io.McapIOError, match="type_name"):
        mcap_io.message_definition(name)


def test_definition_missing_type_names_where_it_looked():
    with pytest.raises(mcap_io.McapIOError, match="no .msg definition.*NoSuch.msg"):
        mcap_io.message_definition("sensor_msgs/msg/NoSuch")


# ---------------------------------------------------------------- QoS
def test_qos_yaml_is_rosbag2_jazzy_format():
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    profile.deadline = RclpyDuration(seconds=1, nanoseconds=5)
    profile.lifespan = RclpyDuration(nanoseconds=2**63 - 1)  # what the graph reports
    text = mcap_io.qos_profiles_to_yaml([profile])
    assert text == (
        "- history: keep_last\n"
        "  depth: 1\n"
        "  reliability: reliable\n"
        "  durability: transient_local\n"
        "  deadline:\n    sec: 1\n    nsec: 5\n"
        "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
        "  liveliness: system_default\n"
        "  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false")
    from rosbags.rosbag2.metadata import parse_qos

    (parsed,) = parse_qos(text)
    assert parsed.durability.name == "TRANSIENT_LOCAL" and parsed.depth == 1
    assert parsed.deadline.sec == 1 and parsed.deadline.nsec == 5
    (back,) = mcap_io.qos_profiles_from_yaml(text)
    assert back["durability"] == "transient_local" and back["deadline"] == 1_000_000_005
    assert back["lifespan"] == 2**63 - 1


def test_qos_yaml_reads_version_8_integers():
    text = ("- history: 1\n  depth: 5\n  reliability: 2\n  durability: 1\n"
            "  deadline: {sec: 0, nsec: 0}\n  lifespan: {sec: 0, nsec: 0}\n  liveliness: 1\n"
            "  liveliness_lease_duration: {sec: 0, nsec: 0}\n"
            "  avoid_ros_namespace_conventions: false\n")
    (back,) = mcap_io.qos_profiles_from_yaml(text)
    assert (back["history"], back["reliability"], back["durability"], back["liveliness"]) == (
        "keep_last", "best_effort", "transient_local", "automatic")


def test_qos_rejects_non_profiles():
    with pytest.raises(mcap_io.McapIOError, match="QoS policy"):
        mcap_io.qos_profiles_to_yaml([QoSProfile(depth=1).__class__])
    assert LivelinessPolicy.AUTOMATIC.name.lower() == "automatic"


# ---------------------------------------------------------------- exact CDR
@pytest.mark.parametrize("type_name", sorted(sample_messages()))
def test_exact_cdr_matches_an_independent_serializer(type_name):
    from rclpy.serialization import serialize_message

    msg = sample_messages()[type_name]
    padded = serialize_message(msg)
    exact = cdr_exact.serialize_exact(msg)
    assert len(exact) == cdr_exact.cdr_size(padded, type(msg)) <= len(padded)
    store = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
    decoded = store.deserialize_cdr(exact, type_name)  # strict: rejects a wrong size
    assert bytes(store.serialize_cdr(decoded, type_name)) == exact


def test_cdr_size_rejects_a_short_buffer():
    exact = cdr_exact.serialize_exact(sample_messages()["sensor_msgs/msg/JointState"])
    with pytest.raises(mcap_io.McapIOError, match="shorter than its contents"):
        cdr_exact.cdr_size(exact[:-3], JointState)


# ---------------------------------------------------------------- writer
def _write(path, messages, **kwargs):
    with mcap_io.RecordingWriter(path, **kwargs) as writer:
        for i, (type_name, msg) in enumerate(messages.items()):
            topic = "/t/" + type_name.split("/")[-1]
            writer.add_topic(topic, type_name, [QoSProfile(depth=7)], "RIHS01_x")
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=1000 + i,
                         publish_time=900 + i, sequence=i)
    return writer


@pytest.mark.parametrize("compression", ["none", "zstd", "lz4"])
def test_writer_round_trip(tmp_path, compression):
    messages = sample_messages()
    path = tmp_path / "out.mcap"
    writer = _write(path, messages, compression=compression)
    assert writer.message_count == len(messages)
    channels = mcap_io.read_channels(path)
    assert {c.type for c in channels.values()} == set(messages)
    for info in channels.values():
        assert info.schema_encoding == "ros2msg" and info.message_encoding == "cdr"
        assert info.offered_qos_profiles[0]["depth"] == 7
        assert info.message_count == 1
    records = list(mcap_io.iter_records(path))
    assert [r.data for r in records] == [cdr_exact.serialize_exact(m) for m in messages.values()]
    assert [(r.log_time, r.publish_time) for r in records][0] == (1000, 900)
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        (meta,) = list(reader.iter_metadata())
    assert meta.name == "rosbag2"
    import yaml

    bag = yaml.safe_load(meta.metadata["serialized_metadata"])
    assert bag["version"] == 9 and bag["message_count"] == len(messages)


def test_writer_never_overwrites(tmp_path):
    path = tmp_path / "out.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(mcap_io.McapIOError, match=f"not overwriting: {path}"):
        mcap_io.RecordingWriter(path)
    assert path.read_bytes() == b"precious"


def test_default_output_path_is_timestamped_under_runs():
    path = mcap_io.default_output_path(now=0)
    assert path.parent.name == "runs" and path.suffix == ".mcap"
    assert len(path.stem) == len("YYYYmmdd-HHMMSS")


def _stream_messages(path):
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False)
        out = []
        try:
            for record in reader.records:
                if type(record).__name__ == "Message":
                    out.append(record)
        except Exception:  # noqa: BLE001 (a truncated tail ends the stream)
            pass
    return out


def test_flush_period_leaves_a_readable_file_while_open(tmp_path):
    now = [0.0]
    path = tmp_path / "live.mcap"
    writer = mcap_io.RecordingWriter(path, flush_period=1.0, clock=lambda: now[0])
    writer.add_topic("/js", "sensor_msgs/msg/JointState")
    data = cdr_exact.serialize_exact(sample_messages()["sensor_msgs/msg/JointState"])
    for i in range(5):
        writer.write("/js", data, log_time=i)
    copy = tmp_path / "copy.mcap"
    shutil.copy(path, copy)  # what a killed process would leave now: nothing flushed yet
    assert _stream_messages(copy) == []
    now[0] = 1.5
    writer.write("/js", data, log_time=5)  # due: the chunk goes to the file
    shutil.copy(path, copy)
    assert [m.log_time for m in _stream_messages(copy)] == list(range(6))
    writer.close()


def test_writer_rejects_bad_arguments(tmp_path):
    with pytest.raises(mcap_io.McapIOError, match="compression"):
        mcap_io.RecordingWriter(tmp_path / "a.mcap", compression="gzip")
    with mcap_io.RecordingWriter(tmp_path / "b.mcap") as writer:
        with pytest.raises(mcap_io.McapIOError, match="not added"):
            writer.write("/nope", b"\x00\x01\x00\x00", log_time=0)
