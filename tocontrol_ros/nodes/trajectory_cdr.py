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

The tracker takes trajectories the same way back: its subscription is raw (the bytes as they
arrive, no message objects) and :func:`read_trajectory_cdr` reads them into arrays in its
parser thread. rclpy's own deserialization builds a ``JointTrajectoryPoint`` per point on
the executor's thread before any callback runs (0.4-1.6 ms for 60-250 points of 3-7
joints on an idle machine, several ms on a loaded one), which held up the tracker's
control loop on every replan. The reader takes any ``JointTrajectory`` in plain CDR, little
or big endian (a publisher's fields may have any length: the tracker's checks name a point
whose field is short), with every point after the first viewed as one numpy record where
they share their layout, as the planner's do.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["trajectory_cdr", "ENCAPSULATION", "POINT_FIELDS", "TrajectoryArrays",
           "PointCountError", "read_trajectory_cdr", "trajectory_stamp_ns"]

#: A point's ``float64[]`` fields, in their order in the message.
POINT_FIELDS = ("positions", "velocities", "accelerations", "effort")

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


class PointCountError(ValueError):
    """A trajectory with more points than the reader was asked to take."""


@dataclass(frozen=True)
class TrajectoryArrays:
    """A ``trajectory_msgs/JointTrajectory`` as arrays.

    Attributes
    ----------
    stamp_ns : int
        ``header.stamp`` (ns since the epoch).
    frame_id : str
    joint_names : list of str
    t : ndarray, shape (P,)
        Every point's ``time_from_start`` (s).
    counts : dict of str to ndarray
        For each of :data:`POINT_FIELDS`, how many values each point has (P,).
    values : dict of str to ndarray or list
        For each of :data:`POINT_FIELDS`, the values: one (P, c) array when every point has
        ``c`` of them, else a list of P arrays.
    """

    stamp_ns: int
    frame_id: str
    joint_names: list[str]
    t: np.ndarray
    counts: dict
    values: dict


class _Reader:
    """Reads CDR primitives from ``buf`` (the payload after the encapsulation header)."""

    def __init__(self, buf: memoryview, order: str) -> None:
        self.buf, self.order, self.pos = buf, order, 0

    def align(self, size: int) -> None:
        self.pos += -self.pos % size

    def take(self, size: int) -> int:
        start = self.pos
        if start + size > len(self.buf):
            raise ValueError(f"truncated at byte {start + 4}: {size} more bytes expected, "
                             f"{len(self.buf) - start} left")
        self.pos += size
        return start

    def unpack(self, fmt: str, alignment: int):
        self.align(alignment)
        fmt = self.order + fmt
        return struct.unpack_from(fmt, self.buf, self.take(struct.calcsize(fmt)))

    def string(self) -> str:
        (length,) = self.unpack("I", 4)
        if length == 0:
            raise ValueError(f"a string of length 0 at byte {self.pos + 4} (CDR strings "
                             f"carry their NUL)")
        start = self.take(length)
        return bytes(self.buf[start:start + length - 1]).decode("utf-8")

    def doubles(self) -> tuple[int, int, int]:
        """A ``float64[]``: its count's offset, its values' offset, its count."""
        self.align(4)
        at = self.pos
        (count,) = self.unpack("I", 4)
        if count:
            self.align(8)
        if count * 8 > len(self.buf) - self.pos:
            raise ValueError(f"a float64 sequence of {count} values at byte {at + 4} runs "
                             f"past the end")
        values_at = self.take(8 * count)
        return at, values_at, count

    def point(self) -> list:
        """One point's layout.

        Its fields' ``(count offset, values offset, count)``, then ``time_from_start``'s
        offset.
        """
        layout = [self.doubles() for _ in POINT_FIELDS]
        self.align(4)
        layout.append(self.take(8))
        return layout


def read_trajectory_cdr(data: bytes, max_points: int | None = None) -> TrajectoryArrays:
    """A ``JointTrajectory`` from its serialized bytes (a raw subscription's message).

    Parameters
    ----------
    data : bytes
        The 4-byte encapsulation header (plain CDR, little or big endian) and the message.
    max_points : int, optional
        Refuse a trajectory with more points than this before reading them.

    Returns
    -------
    TrajectoryArrays

    Raises
    ------
    PointCountError
        More than ``max_points`` points (the message says how many).
    ValueError
        Another encapsulation, or bytes that end before the message does.
    """
    buf = memoryview(data).cast("B")
    if len(buf) < 4 or buf[0] != 0 or buf[1] not in (0, 1):
        raise ValueError(f"not a plain CDR message (encapsulation {bytes(buf[:4])!r})")
    order = "<" if buf[1] == 1 else ">"
    r = _Reader(buf[4:], order)
    sec, nanosec = r.unpack("iI", 4)
    frame_id = r.string()
    (n_names,) = r.unpack("I", 4)
    if n_names * 5 > len(r.buf) - r.pos:
        raise ValueError(f"{n_names} joint names run past the end")
    names = [r.string() for _ in range(n_names)]
    (count,) = r.unpack("I", 4)
    if max_points is not None and count > max_points:
        raise PointCountError(f"{count} points, more than max_points = {max_points}")
    if count * 24 > len(r.buf) - r.pos:  # a point has at least 4 counts and a duration
        raise ValueError(f"{count} points run past the end")
    layouts = [r.point() for _ in range(min(count, 2))]
    rest = None
    if count > 2:
        rest = _same_layout(r, layouts[1], count - 2)
        if rest is None:
            layouts += [r.point() for _ in range(count - 2)]
    return _arrays(r, sec * 1_000_000_000 + nanosec, frame_id, names, layouts, rest)


def _same_layout(r: _Reader, second: list, more: int) -> np.ndarray | None:
    """The points after the second as numpy records of its layout, if all share it.

    A point starts at a multiple of 4; one whose size is a multiple of 8 leaves the next one
    at the same offset modulo 8, so every point with the same counts has the same layout. None
    where they do not (a count differs, or the size is not a multiple of 8): read one by one.
    """
    start = second[0][0]
    size = second[-1] + 8 - start
    if size % 8 or more * size > len(r.buf) - r.pos:
        return None
    names, formats, offsets = [], [], []
    for name, (c_at, v_at, c) in zip(POINT_FIELDS, second[:-1], strict=True):
        names.append(f"c_{name}")
        formats.append(r.order + "u4")
        offsets.append(c_at - start)
        if c:
            names.append(name)
            formats.append((r.order + "f8", (c,)))
            offsets.append(v_at - start)
    names += ["sec", "nanosec"]
    formats += [r.order + "i4", r.order + "u4"]
    offsets += [second[-1] - start, second[-1] + 4 - start]
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                      "itemsize": size})
    # The next point starts at the first multiple of 4 after the second (where r stands).
    records = np.frombuffer(r.buf, dtype=dtype, count=more, offset=r.pos)
    for name, (_, _, c) in zip(POINT_FIELDS, second[:-1], strict=True):
        if np.any(records[f"c_{name}"] != c):
            return None
    r.take(more * size)
    return records


def _arrays(r: _Reader, stamp_ns: int, frame_id: str, names: list, layouts: list,
            rest: np.ndarray | None) -> TrajectoryArrays:
    """The points of ``layouts`` (then ``rest``'s records) as arrays."""
    order, buf = r.order, r.buf
    secs = [struct.unpack_from(order + "iI", buf, lay[-1]) for lay in layouts]
    t = np.array([s + 1e-9 * ns for s, ns in secs], dtype=float)
    if rest is not None:
        t = np.concatenate([t, rest["sec"] + 1e-9 * rest["nanosec"].astype(float)])
    counts, values = {}, {}
    for i, name in enumerate(POINT_FIELDS):
        rows = [np.frombuffer(buf, dtype=order + "f8", count=lay[i][2], offset=lay[i][1])
                for lay in layouts]
        c = np.array([lay[i][2] for lay in layouts], dtype=int)
        if rest is not None:
            c = np.concatenate([c, rest[f"c_{name}"].astype(int)])
        counts[name] = c
        if c.size and np.all(c == c[0]):
            parts = [np.array(rows, dtype=float).reshape(len(rows), int(c[0]))]
            if rest is not None:
                parts.append(rest[name].reshape(len(rest), -1) if c[0] else
                             np.zeros((len(rest), 0)))
            values[name] = np.concatenate(parts).astype(float)
        else:  # the fields of various lengths: rest is None here
            values[name] = [row.astype(float) for row in rows]
    return TrajectoryArrays(stamp_ns, frame_id, names, t, counts, values)


def trajectory_stamp_ns(data: bytes) -> int:
    """``header.stamp`` (ns since the epoch) of a serialized ``JointTrajectory``.

    Its first eight bytes after the encapsulation header, read without the rest.
    """
    buf = memoryview(data).cast("B")
    if len(buf) < 12 or buf[0] != 0 or buf[1] not in (0, 1):
        raise ValueError(f"not a plain CDR message (encapsulation {bytes(buf[:4])!r})")
    sec, nanosec = struct.unpack_from("<iI" if buf[1] == 1 else ">iI", buf, 4)
    return sec * 1_000_000_000 + nanosec
