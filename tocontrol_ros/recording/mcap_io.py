"""MCAP files in rosbag2's layout: message definitions, QoS metadata, exact CDR, a writer.

Pure helpers (no node) shared by the recorder, replay and report:

- :func:`message_definition` builds the ``ros2msg`` schema text of a type from the
  ``.msg`` files installed under ``share/<pkg>/msg/``, as rosbag2's
  ``LocalMessageDefinitionSource`` does (the root text, then each dependency after a line
  of 80 ``=`` and ``MSG: pkg/Type``);
- :func:`qos_profiles_to_yaml` and :func:`qos_profiles_from_yaml` write and read the channel
  metadata ``offered_qos_profiles`` in the format of rosbag2 Jazzy (metadata version 9);
- :class:`RecordingWriter` wraps :class:`mcap.writer.Writer` with rosbag2's profile,
  schemas and channel metadata, a never-overwrite open, and a flush policy under which a
  killed process loses at most the chunk in progress;
- :func:`read_channels` and :func:`iter_records` read a recording back.

Nothing here deserializes message payloads. (Exact CDR bytes of a message, by walking a
buffer, are in ``tocontrol_ros/cdr.py``.)
"""

import importlib
import json
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

#: MCAP header profile of rosbag2 files.
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: rosbag2 metadata version written into the ``rosbag2`` metadata record (Jazzy).
ROSBAG2_METADATA_VERSION = 9
#: A chunk this size (bytes, uncompressed) is written as soon as it fills: at the
#: pipeline's rates (a few hundred small messages per second) that is a few seconds of data.
DEFAULT_CHUNK_SIZE = 256 * 1024
#: ... and at least this often (s), so a killed recorder loses at most about this much.
DEFAULT_FLUSH_PERIOD = 0.1
COMPRESSIONS = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD,
                "lz4": CompressionType.LZ4}

_DELIMITER = "=" * 80 + "\n"
_PACKAGE_TYPENAME = re.compile(r"^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$")
# rosbag2's dependency scan: the first word of each line (comments start with '#', so
# never match), with an optional array suffix, followed by whitespace.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVE_TYPES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
#: Nanoseconds of RMW_DURATION_INFINITE (``{sec: 9223372036, nsec: 854775807}``).
_INFINITE_NS = 2**63 - 1


class McapIOError(ValueError):
    """Invalid input to an MCAP helper (bad type name, missing definition, bad file)."""


# ---------------------------------------------------------------- message definitions
def _share_dirs(package):
    """Candidate ``share/<package>`` directories: ament index first, then sys.prefix."""
    dirs = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        dirs.append(Path(get_package_share_directory(package)))
    except (ImportError, PackageNotFoundError, OSError):
        pass  # not in an ament index (OSError: AMENT_PREFIX_PATH unset)
    dirs.append(Path(sys.prefix) / "share" / package)
    return dirs


def _split_type(type_name):
    match = _PACKAGE_TYPENAME.match(type_name)
    if match is None:
        raise McapIOError(
            f"`type_name` must look like 'pkg/msg/Type' or 'pkg/Type', got {type_name!r}")
    return match.group(1), match.group(2)


def _msg_text(type_name, cache):
    if type_name in cache:
        return cache[type_name]
    package, name = _split_type(type_name)
    candidates = [d / "msg" / f"{name}.msg" for d in _share_dirs(package)]
    for path in candidates:
        if path.is_file():
            # newline="" keeps the file's bytes as they are, as rosbag2's ifstream does.
            with open(path, encoding="utf-8", newline="") as f:
                text = f.read()
            break
    else:
        raise McapIOError(f"no .msg definition for {type_name!r}; looked in: "
                          + ", ".join(str(p) for p in candidates))
    deps = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        deps.add(field_type if "/" in field_type else f"{package}/{field_type}")
    cache[type_name] = (text, sorted(deps))
    return cache[type_name]


_DEFINITION_CACHE = {}


def message_definition(type_name):
    """Full ``ros2msg`` definition of a message type, as rosbag2 writes it into schemas.

    The root type's ``.msg`` text, then, depth first and in sorted order, each dependency
    not seen before: a newline, a line of 80 ``=``, ``MSG: <name as written in the
    field>`` and its ``.msg`` text.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Type`` (or ``pkg/Type``).

    Returns
    -------
    str

    Raises
    ------
    McapIOError
        For a malformed name or a type (or dependency) without an installed ``.msg`` file.
    """
    seen = set()

    def append(name, depth):
        if depth <= 0:
            raise McapIOError(f"dependencies of {type_name!r} nest too deeply")
        text, deps = _msg_text(name, _DEFINITION_CACHE)
        parts = [text]
        for dep in deps:
            if dep not in seen:
                seen.add(dep)
                parts.append("\n" + _DELIMITER + f"MSG: {dep}\n" + append(dep, depth - 1))
        return "".join(parts)

    return append(type_name, 50)


def installed_type_hash(type_name):
    """The RIHS01 type hash of an installed message type, as rosidl wrote it at build time.

    Read from ``share/<pkg>/msg/<Type>.json`` (``type_hashes``), for a channel whose
    messages the recorder makes itself (no publisher announces a hash).

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Type``.

    Returns
    -------
    str
        ``RIHS01_...``, or empty when no installed description names the type.
    """
    package, name = _split_type(type_name)
    full = f"{package}/msg/{name}"
    for directory in _share_dirs(package):
        path = directory / "msg" / f"{name}.json"
        if not path.is_file():
            continue
        try:
            entries = json.loads(path.read_text(encoding="utf-8")).get("type_hashes", [])
        except (OSError, ValueError):
            continue
        for entry in entries:
            if entry.get("type_name") == full:
                return str(entry.get("hash_string", ""))
    return ""


# ---------------------------------------------------------------- QoS metadata
def _policy_name(value):
    """Rmw's string for a policy (``keep_last``, ``transient_local``, ...)."""
    name = getattr(value, "name", None)
    if name is None:
        raise McapIOError(f"QoS policy must be an rclpy enum member, got {value!r}")
    return name.lower()


def _duration_ns(value):
    ns = getattr(value, "nanoseconds", value)
    if not isinstance(ns, int):
        raise McapIOError(f"QoS duration must be an rclpy Duration or int ns, got {value!r}")
    return ns


def _duration_node(value):
    ns = _duration_ns(value)
    if ns >= _INFINITE_NS:
        return {"sec": 9223372036, "nsec": 854775807}
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_profile_to_dict(profile):
    """One QoS profile (``rclpy.qos.QoSProfile`` or alike) as rosbag2's YAML mapping."""
    return {
        "history": _policy_name(profile.history),
        "depth": int(profile.depth),
        "reliability": _policy_name(profile.reliability),
        "durability": _policy_name(profile.durability),
        "deadline": _duration_node(profile.deadline),
        "lifespan": _duration_node(profile.lifespan),
        "liveliness": _policy_name(profile.liveliness),
        "liveliness_lease_duration": _duration_node(profile.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    }


def qos_profiles_to_yaml(profiles):
    """Channel metadata ``offered_qos_profiles``: a YAML sequence, one entry per publisher.

    The format of rosbag2 Jazzy (``rosbag2_storage::serialize_rclcpp_qos_vector``, metadata
    version 9): policies as rmw strings, durations as ``{sec, nsec}``, infinity as
    ``{sec: 9223372036, nsec: 854775807}``.

    Parameters
    ----------
    profiles : sequence of rclpy.qos.QoSProfile
        As ``Node.get_publishers_info_by_topic(...)[i].qos_profile`` reports them.

    Returns
    -------
    str
        Empty string for no profiles.
    """
    nodes = [qos_profile_to_dict(p) for p in profiles]
    if not nodes:
        return ""
    return yaml.safe_dump(nodes, sort_keys=False, default_flow_style=False).rstrip("\n")


_LEGACY_POLICY_NAMES = {  # metadata version <= 8 wrote the rmw enum values
    "history": ["system_default", "keep_last", "keep_all", "unknown"],
    "reliability": ["system_default", "reliable", "best_effort", "unknown", "best_available"],
    "durability": ["system_default", "transient_local", "volatile", "unknown",
                   "best_available"],
    "liveliness": ["system_default", "automatic", "manual_by_node", "manual_by_topic",
                   "unknown", "best_available"],
}


def qos_profiles_from_yaml(text):
    """Parse ``offered_qos_profiles`` (versions 8 and 9) into plain dictionaries.

    Returns
    -------
    list of dict
        Keys as in :func:`qos_profile_to_dict`; policies as lower-case strings, durations
        in ns (int).
    """
    if not text.strip():
        return []
    nodes = yaml.safe_load(text)
    if not isinstance(nodes, list):
        raise McapIOError(f"offered_qos_profiles must be a YAML sequence, got {text!r}")
    out = []
    for node in nodes:
        entry = dict(node)
        for key, names in _LEGACY_POLICY_NAMES.items():
            if isinstance(entry.get(key), int):
                entry[key] = names[entry[key]]
        for key in ("deadline", "lifespan", "liveliness_lease_duration"):
            value = entry.get(key) or {"sec": 0, "nsec": 0}
            ns = int(value["sec"]) * 1_000_000_000 + int(value["nsec"])
            entry[key] = min(ns, _INFINITE_NS)
        out.append(entry)
    return out


# ---------------------------------------------------------------- writer
def default_output_path(directory="runs", now=None):
    """``<directory>/<YYYYmmdd-HHMMSS>.mcap`` for the local time `now` (default: now)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    return Path(directory) / f"{stamp}.mcap"


@dataclass
class _Topic:
    name: str
    type: str
    channel_id: int
    offered_qos_profiles: str
    type_hash: str
    count: int = 0


class RecordingWriter:
    """An MCAP file in rosbag2's layout, written message by message.

    Opening never overwrites: the file is created exclusively (``McapIOError`` naming the
    path if it exists). Chunks are written when they reach `chunk_size` bytes and at least
    every `flush_period` seconds (checked on each write and in :meth:`flush_if_due`), and
    the file is flushed to the OS after each chunk, so a process killed outright leaves a
    file that a streaming reader can read up to the last complete chunk. :meth:`close`
    writes the summary and indexes (and rosbag2's ``rosbag2`` metadata record).

    Parameters
    ----------
    path : str or os.PathLike
        Output file; its parent directories are created.
    compression : {"none", "zstd", "lz4"}
        Chunk compression.
    chunk_size : int
        Chunk size in bytes (uncompressed).
    flush_period : float
        Longest time (s) a received message stays in memory only.
    clock : callable, optional
        Returns the current time in s (for the flush period); ``time.monotonic``.
    """

    def __init__(self, path, compression="none", chunk_size=DEFAULT_CHUNK_SIZE,
                 flush_period=DEFAULT_FLUSH_PERIOD, clock=time.monotonic):
        if compression not in COMPRESSIONS:
            raise McapIOError(f"`compression` must be one of {sorted(COMPRESSIONS)}, "
                              f"got {compression!r}")
        if not chunk_size > 0:
            raise McapIOError(f"`chunk_size` must be positive, got {chunk_size!r}")
        if not flush_period > 0:
            raise McapIOError(f"`flush_period` must be positive, got {flush_period!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file = open(self.path, "xb")  # noqa: SIM115 (closed in close())
        except FileExistsError:
            raise McapIOError(f"output file exists, not overwriting: {self.path}") from None
        self.compression = compression
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=COMPRESSIONS[compression])
        from tocontrol_ros import __version__

        self._writer.start(profile=PROFILE, library=f"tocontrol_ros {__version__}")
        self._file.flush()
        self._schemas = {}
        self._topics = {}
        self._clock = clock
        self._flush_period = flush_period
        self._last_flush = clock()
        self._pending = 0
        self._written_end = self._file.tell()
        self.start_ns = None
        self.end_ns = None
        self.closed = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def topics(self):
        """Topics added so far: name -> (type, messages written)."""
        return {name: (t.type, t.count) for name, t in self._topics.items()}

    @property
    def message_count(self):
        """Messages written so far."""
        return sum(t.count for t in self._topics.values())

    def add_topic(self, name, type_name, offered_qos_profiles="", type_hash="",
                  definition=None):
        """Register a topic (channel) and its type (schema, once per type).

        Parameters
        ----------
        name : str
            Topic name, e.g. ``/joint_states``.
        type_name : str
            ``pkg/msg/Type``.
        offered_qos_profiles : str or sequence of QoSProfile
            The publishers' QoS, as YAML (see :func:`qos_profiles_to_yaml`) or profiles.
        type_hash : str
            ``RIHS01_...`` type hash (channel metadata ``topic_type_hash``), if known; an
            ``rclpy`` ``TypeHash`` is converted with ``str``.
        definition : str, optional
            The ``ros2msg`` schema text; default: built from the installed ``.msg`` files
            (:func:`message_definition`).
        """
        if name in self._topics:
            raise McapIOError(f"topic {name!r} was added already")
        if not isinstance(offered_qos_profiles, str):
            offered_qos_profiles = qos_profiles_to_yaml(offered_qos_profiles)
        type_hash = str(type_hash) if type_hash else ""  # rclpy gives a TypeHash object
        if type_name not in self._schemas:
            text = message_definition(type_name) if definition is None else definition
            self._schemas[type_name] = self._writer.register_schema(
                type_name, SCHEMA_ENCODING, text.encode("utf-8"))
        metadata = {"offered_qos_profiles": offered_qos_profiles,
                    "topic_type_hash": type_hash or ""}
        channel_id = self._writer.register_channel(
            name, MESSAGE_ENCODING, self._schemas[type_name], metadata)
        self._topics[name] = _Topic(name, type_name, channel_id, offered_qos_profiles,
                                    type_hash or "")

    def write(self, topic, data, log_time, publish_time=None, sequence=0):
        """Write one serialized message.

        Parameters
        ----------
        topic : str
            A topic added with :meth:`add_topic`.
        data : bytes
            Exact CDR bytes (header included).
        log_time, publish_time : int
            Receive and publish times (ns since the epoch); `publish_time` defaults to
            `log_time`.
        sequence : int
            Publisher's sequence number (kept modulo 2**32), 0 if unknown.
        """
        entry = self._topics.get(topic)
        if entry is None:
            raise McapIOError(f"topic {topic!r} was not added (add_topic first)")
        publish_time = log_time if publish_time is None else publish_time
        self._writer.add_message(entry.channel_id, int(log_time), bytes(data),
                                 int(publish_time), int(sequence) & 0xFFFFFFFF)
        entry.count += 1
        self._pending += 1
        self.start_ns = log_time if self.start_ns is None else min(self.start_ns, log_time)
        self.end_ns = log_time if self.end_ns is None else max(self.end_ns, log_time)
        if self._file.tell() != self._written_end:
            # The writer closed a chunk (it reached chunk_size): hand it to the OS now.
            self._file.flush()
            self._written_end = self._file.tell()
            self._pending = 0
            self._last_flush = self._clock()
        else:
            self.flush_if_due()

    def flush_if_due(self):
        """Write the chunk in progress if it is older than the flush period."""
        if self._pending and self._clock() - self._last_flush >= self._flush_period:
            self.flush()

    def flush(self):
        """Write the chunk in progress (if any) and flush the file to the OS."""
        if self.closed:
            return
        self._writer.flush()
        self._written_end = self._file.tell()
        self._pending = 0
        self._last_flush = self._clock()

    def _rosbag2_metadata(self):
        start = self.start_ns or 0
        duration = (self.end_ns or 0) - start
        topics = [
            {"topic_metadata": {
                "name": t.name, "type": t.type, "serialization_format": MESSAGE_ENCODING,
                "offered_qos_profiles": yaml.safe_load(t.offered_qos_profiles) or [],
                "type_description_hash": t.type_hash},
             "message_count": t.count}
            for t in self._topics.values()
        ]
        node = {
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.message_count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration},
                       "message_count": self.message_count}],
            "custom_data": {},
            "ros_distro": os.environ.get("ROS_DISTRO", "jazzy"),
        }
        return yaml.safe_dump(node, sort_keys=False, default_flow_style=False)

    def close(self):
        """Write the last chunk, the ``rosbag2`` metadata, summary and indexes; close."""
        if self.closed:
            return
        try:
            self._writer.add_metadata("rosbag2",
                                      {"serialized_metadata": self._rosbag2_metadata()})
            self._writer.finish()
        finally:
            self.closed = True
            self._file.close()


# ---------------------------------------------------------------- reading
@dataclass(frozen=True)
class ChannelInfo:
    """A recorded topic.

    Attributes
    ----------
    topic : str
    type : str
        ``pkg/msg/Type`` (the schema name).
    schema_encoding, message_encoding : str
    definition : str
        The schema text.
    offered_qos_profiles : list of dict
        Parsed with :func:`qos_profiles_from_yaml`.
    type_hash : str
    message_count : int or None
        From the summary's statistics (None without a summary).
    """

    topic: str
    type: str
    schema_encoding: str
    message_encoding: str
    definition: str
    offered_qos_profiles: list
    type_hash: str
    message_count: int | None


def read_summary(path):
    """The summary section of a finished recording (``mcap.records.Summary``).

    Raises
    ------
    McapIOError
        If the file has none (an unfinished recording: read it with a stream reader).
    """
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None:
        raise McapIOError(f"{path}: no summary (an unfinished recording?)")
    return summary


def read_channels(path):
    """Topics of a finished recording (needs its summary), keyed by topic name."""
    summary = read_summary(path)
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    out = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        out[channel.topic] = ChannelInfo(
            topic=channel.topic,
            type=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
            definition=schema.data.decode("utf-8") if schema else "",
            offered_qos_profiles=qos_profiles_from_yaml(
                channel.metadata.get("offered_qos_profiles", "")),
            type_hash=channel.metadata.get("topic_type_hash", ""),
            message_count=counts.get(channel.id) if counts else None,
        )
    return out


@dataclass(frozen=True)
class Record:
    """One recorded message: topic, type, times (ns) and its CDR bytes."""

    topic: str
    type: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


def iter_records(path, topics=None, start_time=None, log_time_order=True):
    """Messages of a recording in log-time order (the file needs its summary).

    Parameters
    ----------
    path : str or os.PathLike
    topics : collection of str, optional
        Only these topics.
    start_time : int, optional
        Only messages with ``log_time >= start_time`` (ns).
    log_time_order : bool
        Sort by log time (else file order).

    Yields
    ------
    Record
    """
    with open(path, "rb") as f:
        reader = make_reader(f)
        selection = {"topics": list(topics) if topics is not None else None,
                     "log_time_order": log_time_order}
        if start_time is not None:
            # mcap >= 1.3 names it starting_at (inclusive); older versions start_time.
            selection["starting_at"] = start_time
        try:
            messages = reader.iter_messages(**selection)
        except TypeError:
            selection["start_time"] = selection.pop("starting_at")
            messages = reader.iter_messages(**selection)
        for schema, channel, message in messages:
            yield Record(channel.topic, schema.name if schema else "", message.log_time,
                         message.publish_time, message.sequence, message.data)


def message_class(type_name):
    """The Python class of ``pkg/msg/Type`` (imported from ``pkg.msg``)."""
    package, name = _split_type(type_name)
    try:
        module = importlib.import_module(f"{package}.msg")
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise McapIOError(f"message type {type_name!r} is not installed") from None
