"""The planner's trajectory bytes: the CDR of the message it replaced, byte for byte."""

from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from trajectory_msgs.msg import JointTrajectory

from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.trajectory_cdr import trajectory_cdr
from tocontrol_ros.recording.cdr import serialize_exact

STAMP_NS = 1_796_605_744_552_906_239


def _sample(rng, count: int, n: int) -> SimpleNamespace:
    return SimpleNamespace(t=np.sort(rng.uniform(0.0, 3.0, count)),
                           q=rng.normal(size=(count, n)), qd=rng.normal(size=(count, n)),
                           qdd=rng.normal(size=(count, n)), tau=rng.normal(size=(count, n)))


# Names and frames of several lengths: the first point starts at 0 or 4 modulo 8 (its
# arrays' alignment gaps differ from the other points').
@pytest.mark.parametrize("n", [1, 2, 3, 7])
@pytest.mark.parametrize("count", [1, 2, 5, 60])
@pytest.mark.parametrize("frame", ["", "a", "base_link", "abcdefg"])
def test_bytes_equal_the_message_serialized(n, count, frame):
    rng = np.random.default_rng(n * 1000 + count)
    names = [f"j{i}" * (i + 1) for i in range(n)]
    sample = _sample(rng, count, n)
    data = trajectory_cdr(sample, names, frame, STAMP_NS)
    msg = conv.trajectory_msg(sample, names, frame, conv.time_from_ns(STAMP_NS))
    assert data == serialize_exact(msg)
    back = deserialize_message(data, JointTrajectory)
    assert back == msg


def test_times_round_to_the_nanosecond_as_the_message_does():
    t = np.array([0.0, 1e-9, 0.4999999995, 0.9999999996, 1.0, 1.0000000005, 2.345678901,
                  12.5, 3600.0000000015])
    zeros = np.zeros((t.size, 2))
    sample = SimpleNamespace(t=t, q=zeros, qd=zeros, qdd=zeros, tau=zeros)
    back = deserialize_message(trajectory_cdr(sample, ["a", "b"], "f", 0), JointTrajectory)
    for ti, point in zip(t, back.points, strict=True):
        expect = conv.duration_from_seconds(float(ti))
        assert (point.time_from_start.sec, point.time_from_start.nanosec) == \
            (expect.sec, expect.nanosec), ti


@pytest.mark.parametrize("names, shape", [(["a", "b"], (4, 3)), ([], (4, 0))])
def test_a_sample_that_does_not_match_the_names_is_refused(names, shape):
    zeros = np.zeros(shape)
    sample = SimpleNamespace(t=np.arange(shape[0]), q=zeros, qd=zeros, qdd=zeros, tau=zeros)
    with pytest.raises(ValueError, match="one column per joint name"):
        trajectory_cdr(sample, names, "f", 0)


# ---------------------------------------------------------------- reading the bytes back
def _msg(rng, count: int, n: int, lengths=None, frame: str = "base") -> JointTrajectory:
    """A message whose fields have ``lengths[i][f]`` values (default n for all)."""
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectoryPoint

    msg = JointTrajectory()
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_796_605_744, 552_906_239
    msg.joint_names = [f"joint_{i}" for i in range(n)]
    for i in range(count):
        sizes = lengths[i] if lengths is not None else (n, n, n, n)
        msg.points.append(JointTrajectoryPoint(
            positions=rng.normal(size=sizes[0]).tolist(),
            velocities=rng.normal(size=sizes[1]).tolist(),
            accelerations=rng.normal(size=sizes[2]).tolist(),
            effort=rng.normal(size=sizes[3]).tolist(),
            time_from_start=Duration(sec=i // 3, nanosec=(i * 123_456_789) % 1_000_000_000)))
    return msg


def _assert_read_equals(arrays, msg: JointTrajectory) -> None:
    from tocontrol_ros.nodes.trajectory_cdr import POINT_FIELDS

    assert arrays.stamp_ns == msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert arrays.frame_id == msg.header.frame_id
    assert arrays.joint_names == list(msg.joint_names)
    assert np.array_equal(arrays.t, [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                                     for p in msg.points])
    for field in POINT_FIELDS:
        rows = [np.asarray(getattr(p, field), dtype=float) for p in msg.points]
        assert arrays.counts[field].tolist() == [len(r) for r in rows]
        got = arrays.values[field]
        for i, row in enumerate(rows):
            assert np.array_equal(got[i], row), (field, i)


@pytest.mark.parametrize("n", [1, 3, 7])
@pytest.mark.parametrize("count", [0, 1, 2, 3, 60])
@pytest.mark.parametrize("frame", ["", "a", "base_link", "abcdefg"])
def test_the_reader_gives_back_what_rclpy_serialized(n, count, frame):
    from rclpy.serialization import serialize_message

    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr, trajectory_stamp_ns

    msg = _msg(np.random.default_rng(count * 10 + n), count, n, frame=frame)
    data = serialize_message(msg)
    arrays = read_trajectory_cdr(data)
    _assert_read_equals(arrays, msg)
    assert trajectory_stamp_ns(data) == arrays.stamp_ns
    if count:  # every point's fields of the same length: arrays
        assert arrays.values["positions"].shape == (count, n)


def test_the_reader_takes_fields_of_any_length_and_empty_ones():
    from rclpy.serialization import serialize_message

    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr

    rng = np.random.default_rng(5)
    # positions only (what a JTC client may send), then fields that differ point by point
    # (an odd count after an even one shifts the alignment of what follows).
    for lengths in ([(3, 0, 0, 0)] * 7, [(3, 3, 3, 3), (3, 0, 0, 0), (3, 1, 2, 0), (2, 3, 3, 3),
                                         (3, 3, 3, 3), (3, 3, 3, 3)]):
        msg = _msg(rng, len(lengths), 3, lengths)
        _assert_read_equals(read_trajectory_cdr(serialize_message(msg)), msg)


def test_the_planners_bytes_read_back_as_its_sample():
    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr

    rng = np.random.default_rng(7)
    for frame in ("", "abc", "base_link"):
        sample = _sample(rng, 50, 7)
        arrays = read_trajectory_cdr(trajectory_cdr(sample, list("abcdefg"), frame, STAMP_NS))
        assert arrays.stamp_ns == STAMP_NS and arrays.frame_id == frame
        for field, values in zip(("positions", "velocities", "accelerations", "effort"),
                                 (sample.q, sample.qd, sample.qdd, sample.tau), strict=True):
            assert np.array_equal(arrays.values[field], values)
        assert np.max(np.abs(arrays.t - sample.t)) <= 0.5e-9 + 1e-15


def test_bad_bytes_are_refused_with_the_reason():
    from tocontrol_ros.nodes.trajectory_cdr import PointCountError, read_trajectory_cdr

    data = serialize_exact(_msg(np.random.default_rng(1), 5, 3))  # no padding past the end
    with pytest.raises(PointCountError, match="5 points, more than max_points = 4"):
        read_trajectory_cdr(data, max_points=4)
    for cut in (2, 10, 40, len(data) // 2, len(data) - 9):
        with pytest.raises(ValueError, match="truncated|past the end|CDR"):
            read_trajectory_cdr(data[:cut])
    with pytest.raises(ValueError, match="not a plain CDR message"):
        read_trajectory_cdr(b"\x00\x07\x00\x00" + data[4:])
    # The point count (after the stamp, frame "base" and the three names "joint_i").
    at = 4 + 8 + 4 + 8 + 4 + 3 * (4 + 8)
    assert int(np.frombuffer(data, "<u4", 1, at)[0]) == 5
    big = bytearray(data)
    big[at:at + 4] = np.uint32(1 << 30).tobytes()
    with pytest.raises(ValueError, match="1073741824 points run past the end"):
        read_trajectory_cdr(bytes(big))
    big = bytearray(data)
    big[at - 12:at - 8] = np.uint32(1 << 30).tobytes()  # the last name's length
    with pytest.raises(ValueError, match="truncated"):
        read_trajectory_cdr(bytes(big))


def test_big_endian_bytes_read_as_little_endian_ones():
    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr

    # A big-endian message built by hand: one point, one joint.
    def u32(v):
        return np.array([v], dtype=">u4").tobytes()

    body = bytearray()
    body += np.array([7, 9], dtype=">i4").tobytes()          # stamp
    body += u32(2) + b"f\x00" + b"\x00\x00"                  # frame "f"
    body += u32(1) + u32(2) + b"a\x00" + b"\x00\x00"         # one name, "a"
    body += u32(1)                                            # one point
    for v in (1.5, -2.0, 0.25, 3.0):                          # count, gap, value
        body += bytes(-len(body) % 4) + u32(1)
        body += bytes(-len(body) % 8) + np.array([v], dtype=">f8").tobytes()
    body += np.array([1, 500], dtype=">i4").tobytes()
    arrays = read_trajectory_cdr(b"\x00\x00\x00\x00" + bytes(body))
    assert arrays.stamp_ns == 7_000_000_009 and arrays.frame_id == "f"
    assert arrays.joint_names == ["a"]
    assert [arrays.values[f][0].tolist() for f in ("positions", "velocities",
                                                   "accelerations", "effort")] == \
        [[1.5], [-2.0], [0.25], [3.0]]
    assert arrays.t.tolist() == [1 + 500e-9]
