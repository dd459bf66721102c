"""A sampled trajectory as the CDR bytes of its ``trajectory_msgs/JointTrajectory``, in numpy.

The planner publishes a replan's trajectory as serialized bytes (``Publisher.publish``
takes ``bytes`` and sends them as they are): the same message a subscriber receives and
deserializes, built without a ``JointTrajectoryPoint`` object per sample. Building the
message objects and rclpy's conversion of them for publication took 1-3 ms of a replan's
latency through the nodes (50-200 points, most of it the per-point constructors and the
per-point conversion to C); here every point is one row of a numpy structured array.

The layout is XCDR1 little endian with its 4-byte encapsulation header (what Fast DDS and
``rclpy.serialization.serialize_message`` write), alignment counted from after the header,
alignment gaps zeroed: equal, byte for byte, to
:func:`tocontrol_ros.recording.cdr.serialize_exact` of
:func:`tocontrol_ros.nodes.conversions.trajectory_msg`'s message
(``test/nodes/test_trajectory_cdr.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["trajectory_cdr", "ENCAPSULATION"]

#: XCDR1, little endian (CDR_LE), options 0.
ENCAPSULATION = b"\x00\x01\x00\x00"


def _string(out: bytearray, text: str) -> None:
    """A CDR string at the end of ``out``: aligned to 4, its length with the NUL, bytes, NUL."""
    out += bytes(-len(out) % 4)
    data = text.encode("utf-8") + b"\x00"
    out += np.uint32(len(data)).tobytes() + data


def _point_dtype(n: int, aligned: bool) -> np.dtype:
    """One ``JointTrajectoryPoint`` of ``n`` joints as a packed numpy record.

    Four ``float64[]`` (positions, velocities, accelerations, effort: a ``uint32`` count, a
    gap to the next multiple of 8, the values) and ``time_from_start`` (``int32`` sec,
    ``uint32`` nanosec). ``aligned``: the point starts at a multiple of 8 (each count then
    has a 4-byte gap after it); else at 4 more than one (the first count has none).
    """
    fields = []
    for i in range(4):
        fields.append((f"c{i}", "<u4"))
        if aligned or i > 0:
            fields.append((f"g{i}", "<u4"))
        fields.append((f"v{i}", "<f8", (n,)))
    fields += [("sec", "<i4"), ("nanosec", "<u4")]
    return np.dtype(fields)


def trajectory_cdr(sample, joint_names: Sequence[str], frame_id: str,
                   stamp_ns: int) -> bytes:
    """The serialized ``JointTrajectory`` of ``sample``, stamped ``stamp_ns``.

    The message of :func:`~tocontrol_ros.nodes.conversions.trajectory_msg` (one point per
    sample, ``time_from_start`` rounded to whole nanoseconds), as CDR bytes.

    Parameters
    ----------
    sample : TrajectorySample
        ``t`` (K,) in s, ``q``, ``qd``, ``qdd`` (K, n) in rad, rad/s, rad/s^2 (m for a
        prismatic joint), ``tau`` (K, n) in N m (N).
    joint_names : sequence of str
        ``n`` names.
    frame_id : str
    stamp_ns : int
        ``header.stamp`` (ns since the epoch, >= 0).

    Returns
    -------
    bytes
        The encapsulation header and the message, as a subscriber receives them.
    """
    fields = [np.ascontiguousarray(a, dtype=float) for a in
              (sample.q, sample.qd, sample.qdd, sample.tau)]
    count, n = fields[0].shape
    if n == 0 or len(joint_names) != n or any(f.shape != (count, n) for f in fields):
        raise ValueError(f"`sample` must have q, qd, qdd and tau of shape (K, {len(joint_names)})"
                         f" (one column per joint name), got {[f.shape for f in fields]}")
    stamp_ns = int(stamp_ns)
    out = bytearray()
    out += np.array([stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000],
                    dtype="<i4").tobytes()
    _string(out, frame_id)
    out += bytes(-len(out) % 4)
    out += np.uint32(len(joint_names)).tobytes()
    for name in joint_names:
        _string(out, name)
    out += bytes(-len(out) % 4)
    out += np.uint32(count).tobytes()
    ns = np.round(np.asarray(sample.t, dtype=float) * 1e9).astype(np.int64)
    if count:
        # The points after the first start at a multiple of 8 whatever the first's start:
        # a point's size from an aligned start is a multiple of 8.
        first_aligned = len(out) % 8 == 0
        first = np.zeros(1, dtype=_point_dtype(n, first_aligned))
        rest = np.zeros(count - 1, dtype=_point_dtype(n, True))
        for rec, rows in ((first, slice(0, 1)), (rest, slice(1, count))):
            for i, values in enumerate(fields):
                rec[f"c{i}"] = n
                rec[f"v{i}"] = values[rows]
            rec["sec"] = ns[rows] // 1_000_000_000
            rec["nanosec"] = ns[rows] % 1_000_000_000
        out += first.tobytes()
        out += rest.tobytes()
    return ENCAPSULATION + bytes(out)
