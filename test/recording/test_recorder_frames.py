"""A recording you can watch: the recorder writes /robot_description, /tf_static and /tf.

In-process, over DDS, with a private rclpy Context: joint states are published, the
recorder records them and computes the link frames; the file is then read by readers that
are not the project's (``mcap``'s reader with ``mcap_ros2`` decoding, and ``rosbags``). The
transforms are checked against the chain model's forward kinematics (``load_robot``, built
by another path through the URDF than :func:`joint_frames`), for the bundled planar arm
and for the Panda of example-robot-data (a spatial arm with fixed joints and fingers that
no joint state names).
"""

from pathlib import Path

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from skip_policy import panda_urdf
from std_msgs.msg import Header
from test_recorder import context, spin_until, unique  # noqa: F401 (fixture)

from tocontrol_ros.core.robot.kinematics import tip_pose
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.robot.urdf import default_urdf_path
from tocontrol_ros.recording.recorder import Recorder

pytestmark = pytest.mark.ros
DecoderFactory = pytest.importorskip("mcap_ros2.decoder").DecoderFactory
AnyReader = pytest.importorskip("rosbags.highlevel").AnyReader
#: Joint states published per test (the /tf count must equal it).
COUNT = 12



def _rotation(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w) (textbook formula)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _pose_in(base, link, edges):
    """Pose (R, p) of `link` in `base` by composing tf edges child -> (parent, R, p)."""
    rot, pos = np.eye(3), np.zeros(3)
    while link != base:
        parent, r, p = edges[link]
        rot, pos = r @ rot, r @ pos + p
        link = parent
    return rot, pos


def _read_foreign(path):
    """topic -> [(log_time, decoded message)] with mcap's reader and mcap_ros2's decoder."""
    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((message.log_time, decoded))
    return out


ARMS = {
    "bundled planar arm": lambda: (default_urdf_path(), None),
    "panda": lambda: (panda_urdf(), "panda_hand"),
}


@pytest.mark.parametrize("arm", list(ARMS))
def test_recording_holds_the_robot_and_its_link_frames(context, tmp_path, arm):  # noqa: F811
    urdf_path, tip = ARMS[arm]()
    urdf = Path(urdf_path).read_text()
    model = load_robot(str(urdf_path), **({"tip_link": tip} if tip else {}))
    names = list(model.joint_names)
    js_topic = unique("/joint_states")
    out = tmp_path / "frames.mcap"
    node = rclpy.create_node("arm", context=context)
    pub = node.create_publisher(JointState, js_topic, 50)
    recorder = Recorder(context=context, parameter_overrides=[
        Parameter("output", value=str(out)), Parameter("topics", value=[js_topic]),
        Parameter("joint_states_topic", value=js_topic),
        Parameter("robot_description_file", value=str(urdf_path)),
        Parameter("discovery_period", value=0.05)])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(recorder)
    rng = np.random.default_rng(7)
    lower = np.maximum(model.q_lower, -np.pi)
    upper = np.minimum(model.q_upper, np.pi)
    sent = [lower + (upper - lower) * rng.random(len(names)) for _ in range(COUNT)]
    try:
        assert spin_until(executor, lambda: recorder.receiving_topics == []
                          and not recorder.pending_topics
                          and pub.get_subscription_count() >= 1)
        for i, q in enumerate(sent):
            pub.publish(JointState(header=Header(stamp=Time(sec=100 + i, nanosec=5)),
                                   name=names, position=q.tolist()))
            executor.spin_once(timeout_sec=0.001)
        assert spin_until(executor, lambda: recorder.writer.topics.get(js_topic, ("", 0))[1]
                          >= COUNT)
    finally:
        recorder.close()
        executor.shutdown()
        recorder.destroy_node()
        node.destroy_node()

    got = _read_foreign(out)
    assert set(got) == {js_topic, "/robot_description", "/tf_static", "/tf"}
    assert [m.data for _, m in got["/robot_description"]] == [urdf]
    assert len(got["/tf_static"]) == 1
    # One /tf per joint state, with its stamp and its log time.
    assert len(got["/tf"]) == len(got[js_topic]) == COUNT
    for (t_js, js), (t_tf, tf) in zip(got[js_topic], got["/tf"], strict=True):
        assert t_tf == t_js
        assert {(t.header.stamp.sec, t.header.stamp.nanosec) for t in tf.transforms} == {
            (js.header.stamp.sec, js.header.stamp.nanosec)}
    edges = {}
    for t in got["/tf_static"][0][1].transforms:
        r = t.transform.rotation
        v = t.transform.translation
        edges[t.child_frame_id] = (t.header.frame_id, _rotation((r.x, r.y, r.z, r.w)),
                                   np.array([v.x, v.y, v.z]))
    for q, (_, tf) in zip(sent, got["/tf"], strict=True):
        for t in tf.transforms:
            r = t.transform.rotation
            v = t.transform.translation
            assert np.linalg.norm([r.x, r.y, r.z, r.w]) == pytest.approx(1.0, abs=1e-12)
            edges[t.child_frame_id] = (t.header.frame_id, _rotation((r.x, r.y, r.z, r.w)),
                                       np.array([v.x, v.y, v.z]))
        rot, pos = _pose_in(model.base_link, model.tip_link, edges)
        want_rot, want_pos = tip_pose(model, q)
        np.testing.assert_allclose(pos, want_pos, atol=1e-12)
        np.testing.assert_allclose(rot, want_rot, atol=1e-12)
    # Every link of the URDF gets a frame (the Panda's fingers too).
    from urdf_parser_py.urdf import URDF

    links = {link.name for link in URDF.from_xml_string(urdf.encode()).links}
    assert set(edges) | {model.base_link} == links

    # rosbags reads the same file (its own CDR decoder, the schemas in the file).
    with AnyReader([out]) as reader:
        counts = {}
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert counts == {js_topic: COUNT, "/tf": COUNT, "/tf_static": 1, "/robot_description": 1}


def test_topics_the_recorder_writes_itself_cannot_also_be_recorded(context, tmp_path):  # noqa: F811
    with pytest.raises(ValueError, match="link_frames"):
        Recorder(context=context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "x.mcap")),
            Parameter("topics", value=["/joint_states", "/tf"])])
    assert not (tmp_path / "x.mcap").exists()
