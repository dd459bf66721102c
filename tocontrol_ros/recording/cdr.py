"""Exact CDR bytes of a message, for files that other readers decode.

``rclpy.serialization.serialize_message`` returns a buffer padded past the end with the
alignment gaps inside uninitialised; :func:`serialize_exact` trims the one and zeroes the
other (what a raw subscription receives from Fast DDS), walking the buffer along the message
class's ``SLOT_TYPES`` (:func:`cdr_size`). The batch library writes its trajectories with it
(the recorder writes the bytes it receives); the tests compare recorded bytes with it.
"""

import importlib
import struct

from tocontrol_ros.recording.mcap_io import McapIOError

__all__ = ["cdr_size", "serialize_exact"]

_PRIMITIVE_SIZES = {
    "boolean": 1, "octet": 1, "char": 1, "uint8": 1, "int8": 1,
    "int16": 2, "uint16": 2, "int32": 4, "uint32": 4, "float": 4,
    "int64": 8, "uint64": 8, "double": 8,
}


def _message_class(namespaced_type):
    module = importlib.import_module(".".join(namespaced_type.namespaces))
    return getattr(module, namespaced_type.name)


class _CdrWalker:
    """Walks an XCDR1 little/big-endian buffer along a message class's ``SLOT_TYPES``."""

    def __init__(self, buffer):
        self.buf = memoryview(buffer)
        self.pos = 4  # after the encapsulation header; alignment is relative to here
        self.endian = ">" if self.buf[1] == 0 else "<"
        self.padding = []  # (start, stop) of alignment gaps

    def align(self, size):
        gap = (-(self.pos - 4)) % size
        if gap:
            self.padding.append((self.pos, self.pos + gap))
            self.pos += gap

    def skip_primitive(self, typename, count=1):
        size = _PRIMITIVE_SIZES.get(typename)
        if size is None:
            raise McapIOError(f"CDR size: unsupported primitive type {typename!r}")
        if count:
            self.align(size)
            self.pos += size * count

    def read_u32(self):
        self.align(4)
        if self.pos + 4 > len(self.buf):
            raise McapIOError("CDR size: buffer ends inside a length field")
        (value,) = struct.unpack_from(self.endian + "I", self.buf, self.pos)
        self.pos += 4
        return value

    def walk_type(self, slot_type, count=1):
        kind = type(slot_type).__name__
        if kind == "BasicType":
            self.skip_primitive(slot_type.typename, count)
        elif kind in ("UnboundedString", "BoundedString"):
            for _ in range(count):
                length = self.read_u32()  # (not `pos += read_u32()`: that loads pos first)
                self.pos += length
        elif kind == "NamespacedType":
            cls = _message_class(slot_type)
            for _ in range(count):
                self.walk_message(cls)
        elif kind == "Array":
            self.walk_type(slot_type.value_type, count * slot_type.size)
        elif kind in ("UnboundedSequence", "BoundedSequence"):
            for _ in range(count):
                self.walk_type(slot_type.value_type, self.read_u32())
        else:
            raise McapIOError(f"CDR size: unsupported field type {slot_type!r}")

    def walk_message(self, cls):
        slot_types = getattr(cls, "SLOT_TYPES", None)
        if slot_types is None:
            raise McapIOError(f"CDR size: {cls!r} is not a ROS message class")
        if not slot_types:
            self.pos += 1  # empty structures carry one uint8 placeholder
        for slot_type in slot_types:
            self.walk_type(slot_type)


def _walk(buffer, msg_class):
    if len(buffer) < 4:
        raise McapIOError(f"`buffer` must hold a 4-byte CDR header, got {len(buffer)} bytes")
    walker = _CdrWalker(buffer)
    walker.walk_message(msg_class)
    if walker.pos > len(buffer):
        raise McapIOError(f"`buffer` ({len(buffer)} bytes) is shorter than its contents "
                          f"({walker.pos} bytes) for {msg_class.__name__}")
    return walker


def cdr_size(buffer, msg_class):
    """Exact size of the CDR serialization at the start of `buffer` (bytes).

    Parameters
    ----------
    buffer : bytes-like
        A CDR (XCDR1) buffer with its 4-byte encapsulation header, possibly padded past the
        end, as ``rclpy.serialization.serialize_message`` returns it.
    msg_class : type
        The ROS message class it holds.

    Returns
    -------
    int

    Raises
    ------
    McapIOError
        If the buffer is shorter than its own contents say, or holds an unsupported type.
    """
    return _walk(buffer, msg_class).pos


def serialize_exact(msg):
    """CDR bytes of a message object as DDS sends them: exact size, zeroed alignment gaps.

    ``rclpy.serialization.serialize_message`` pads the buffer past the end and leaves the
    alignment gaps inside uninitialised; this trims the one and zeroes the other, so the
    result is deterministic (and equals what a raw subscription receives from Fast DDS).

    Parameters
    ----------
    msg : ROS message object

    Returns
    -------
    bytes
    """
    from rclpy.serialization import serialize_message

    buffer = serialize_message(msg)
    walker = _walk(buffer, type(msg))
    out = bytearray(buffer[:walker.pos])
    for start, stop in walker.padding:
        out[start:stop] = bytes(stop - start)
    return bytes(out)
