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
