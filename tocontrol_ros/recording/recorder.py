"""Recorder: ``ros2 run tocontrol_ros recorder`` writes topics to a rosbag2-compatible MCAP.

Subscribes to a set of topics (by default everything the planner and tracker publish, plus
their inputs) with raw (serialized) messages, so nothing is deserialized on the way, and
writes each message's exact CDR bytes with its receive time (log time) and the publisher's
source timestamp (publish time). Each topic's type and the QoS its publishers offer are
taken from the ROS graph when a publisher first appears; the subscription asks for what all
publishers offer (reliable, transient local), so a latched plan is captured too.

Progress goes to ``~/status`` (``diagnostic_msgs/msg/DiagnosticStatus``, reliable, transient
local, the last 100 kept), one event each (key ``event``): ``started`` (keys ``output`` and
``topics``, comma-separated), ``subscribed`` when a topic is subscribed (keys ``topic``,
``type``), ``first_message`` when its first message is written (key ``topic``),
``not_recorded`` for a topic that cannot be (level ERROR). A topic counts as recorded from
its ``first_message``: a subscription exists before the publisher's side has matched it, and
what a volatile publisher sends in between is lost. A program that needs the whole of a
stream in the file (the demo) waits for that event before it makes the stream's publisher
act.

With ``link_frames`` (the default) the file also holds what a viewer needs to draw the arm
moving, as robot_state_publisher would publish it: ``/robot_description`` (the URDF of the
robot parameters, the same as the planner's and tracker's: ``robot_description``,
``robot_description_file``, ``robot_description_topic``, ``locked_joints``), ``/tf_static``
(the fixed joints) once at the start, and one ``/tf`` message per message on
``joint_states_topic``, with its stamp, computed from its positions
(:mod:`tocontrol_ros.recording.link_frames`) and written with the same times right after it.

SIGINT and SIGTERM finish the file (last chunk, summary, indexes) after taking what is
already queued. A process killed outright (``kill -9``) leaves a file without summary and
indexes that holds every message received up to about ``flush_period`` (0.1 s) before the
kill (chunks are handed to the OS at least that often): a streaming reader reads it as is,
and ``ros2 run tocontrol_ros reindex FILE`` rewrites it as a complete file for indexed
readers and rosbags. The output never overwrites an existing file; an output that cannot be
written ends the recorder with a one-line error and exit status 2.

Parameters (all read-only; see ``config/recorder.yaml``): ``topics``, ``output``,
``compression``, ``discovery_period``, ``chunk_size``, ``flush_period``, ``queue_depth``,
``link_frames``, ``joint_states_topic`` and the robot's.
"""

import argparse
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from tocontrol_ros.nodes import qos
from tocontrol_ros.nodes.diagnostics import Diagnostics
from tocontrol_ros.nodes.params import (
    LOCKED_JOINTS,
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_FILE,
    ROBOT_DESCRIPTION_TIMEOUT,
    ROBOT_DESCRIPTION_TOPIC,
    ParameterSpec,
    declare_all,
    parameters_parser,
    parse_locked_joints,
    robot_from_topic,
)
from tocontrol_ros.recording import cdr, link_frames, mcap_io

#: Everything the planner and the tracker publish, and their inputs: relative names,
#: resolved in the recorder's namespace (the arm's, with the launch file's ``namespace``).
DEFAULT_TOPICS = (
    "planner/goal",
    "planner/trajectory",
    "planner/status",
    "planner/ee_path",
    "planner/markers",
    "joint_states",
    "tracker/tracking_error",
    "tracker/status",
)
#: How long (s) a stop request keeps taking messages already queued in the middleware.
DRAIN_TIME = 0.3
#: Status events kept for late subscribers: two per topic and a few more.
QOS_STATUS = qos.status_profile(100, latched=True)


@dataclass(frozen=True)
class RecorderConfig:
    """Validated recorder parameters.

    Attributes
    ----------
    topics : tuple of str
        Absolute topic names to record.
    output : str
        Output file; empty means ``runs/<YYYYmmdd-HHMMSS>.mcap`` in the working directory.
    compression : str
        ``none``, ``zstd`` or ``lz4`` (chunk compression).
    discovery_period : float
        How often (s) to look for publishers of topics not yet subscribed.
    chunk_size : int
        MCAP chunk size (bytes).
    flush_period : float
        Longest time (s) a received message stays only in memory.
    queue_depth : int
        Subscription history depth (messages): generous, so bursts are not dropped.
    link_frames : bool
        Also write ``/robot_description``, ``/tf_static`` and ``/tf``.
    joint_states_topic : str
        The recorded topic whose joint states give ``/tf``.
    robot_description : str
        The URDF XML (read from the robot parameters; empty without `link_frames`).
    locked_joints : dict of str to float
        Positions (rad, m) of moving joints that joint states do not name.
    """

    topics: tuple
    output: str
    compression: str
    discovery_period: float
    chunk_size: int
    flush_period: float
    queue_depth: int
    link_frames: bool = False
    joint_states_topic: str = "/joint_states"
    robot_description: str = ""
    locked_joints: dict = field(default_factory=dict)


PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("topics", list(DEFAULT_TOPICS), "Topics to record; relative names are "
                  "resolved in the recorder's namespace.", read_only=True),
    ParameterSpec("output", "", "Output .mcap file; empty: runs/<YYYYmmdd-HHMMSS>.mcap. "
                  "Never overwritten.", read_only=True),
    ParameterSpec("compression", "none", "Chunk compression: none, zstd or lz4.",
                  read_only=True),
    ParameterSpec("discovery_period", 0.2, "Period (s) of the search for publishers of "
                  "topics not yet subscribed.", 0.01, 10.0, read_only=True),
    ParameterSpec("chunk_size", mcap_io.DEFAULT_CHUNK_SIZE, "MCAP chunk size (bytes, "
                  "uncompressed).", 1024, 64 * 1024 * 1024, read_only=True),
    ParameterSpec("flush_period", mcap_io.DEFAULT_FLUSH_PERIOD, "Longest time (s) a received "
                  "message is held in memory before it is written (what a killed recorder "
                  "loses).", 0.01, 60.0, read_only=True),
    ParameterSpec("queue_depth", 1000, "Subscription history depth (messages).", 1, 100000,
                  read_only=True),
    ParameterSpec("link_frames", True, "Also write /robot_description (the robot "
                  "parameters' URDF), /tf_static (fixed joints) and /tf (moving joints, one "
                  "message per joint state on joint_states_topic), as robot_state_publisher "
                  "publishes them, so that a viewer draws the arm moving.", read_only=True),
    ParameterSpec("joint_states_topic", "joint_states", "The recorded sensor_msgs/JointState "
                  "topic that /tf is computed from (link_frames); relative: in the "
                  "recorder's namespace.", read_only=True),
    ROBOT_DESCRIPTION, ROBOT_DESCRIPTION_FILE, ROBOT_DESCRIPTION_TOPIC,
    ROBOT_DESCRIPTION_TIMEOUT, LOCKED_JOINTS,
)
#: Topics the recorder writes itself with ``link_frames`` (so not also from the graph).
OWN_TOPICS = (link_frames.DESCRIPTION_TOPIC, link_frames.TF_STATIC_TOPIC,
              link_frames.TF_TOPIC)


def read_config(node):
    """Declare the parameters on `node` and return them as a :class:`RecorderConfig`.

    Raises
    ------
    ValueError
        For a compression name outside none/zstd/lz4, a relative topic name, with
        ``link_frames`` a topic it writes itself in ``topics``, or robot parameters that give
        no URDF (:class:`~tocontrol_ros.nodes.params.RobotDescriptionError`).
    """
    values = declare_all(node, PARAMETERS)
    if values["link_frames"]:
        values = robot_from_topic(node, values)
    if values["compression"] not in mcap_io.COMPRESSIONS:
        raise ValueError(f"parameter `compression` must be one of "
                         f"{sorted(mcap_io.COMPRESSIONS)}, got {values['compression']!r}")
    try:  # relative names in the recorder's namespace; the recording names them absolute
        topics = tuple(node.resolve_topic_name(t, only_expand=True) for t in values["topics"])
        values["joint_states_topic"] = node.resolve_topic_name(values["joint_states_topic"],
                                                               only_expand=True)
    except Exception as exc:  # noqa: BLE001  (rclpy's own invalid-name errors)
        raise ValueError(f"parameter `topics` or `joint_states_topic`: an invalid topic name "
                         f"in {list(values['topics'])!r} / "
                         f"{values['joint_states_topic']!r} ({exc})") from exc
    if not topics:
        raise ValueError("parameter `topics` must list at least one topic")
    values["topics"] = tuple(dict.fromkeys(topics))
    robot = {name: values.pop(name) for name in (
        "robot_description", "robot_description_file", "robot_description_topic",
        "robot_description_timeout", "locked_joints")}
    values["locked_joints"] = parse_locked_joints(robot["locked_joints"])
    if values["link_frames"]:
        clash = sorted(set(topics) & set(OWN_TOPICS))
        if clash:
            raise ValueError(f"parameter `topics` names {clash}, which the recorder writes "
                             f"itself with `link_frames`: drop them or set link_frames false")
        values["robot_description"] = robot_urdf(robot["robot_description"],
                                                 robot["robot_description_file"])
    return RecorderConfig(**values)


def robot_urdf(description, description_file):
    """The URDF XML of the robot parameters, as the nodes read it (the bundled arm if empty).

    Raises
    ------
    RobotDescriptionError
        Both given, a description that is not XML, or a file that cannot be read.
    """
    from tocontrol_ros.core.robot.urdf import default_urdf_path
    from tocontrol_ros.nodes.params import RobotDescriptionError

    text, path = description.strip(), description_file.strip()
    if text and path:
        raise RobotDescriptionError("set `robot_description` or `robot_description_file`, "
                                    "not both")
    if not text:
        source = Path(path) if path else default_urdf_path()
        try:
            text = source.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise RobotDescriptionError(f"`robot_description_file` {str(source)!r} cannot be "
                                        f"read: {exc}") from None
    if not text.lstrip().startswith("<"):
        raise RobotDescriptionError("`robot_description` must be URDF XML (starting with '<')")
    return text


def subscription_qos(offered, depth):
    """QoS that matches every offered profile (as rosbag2 adapts its requests).

    Reliable only if every publisher is reliable, transient local only if every publisher
    is; keep-last `depth`.
    """
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


class Recorder(Node):
    """Node that records topics into a :class:`tocontrol_ros.recording.mcap_io.RecordingWriter`.

    Parameters
    ----------
    writer : RecordingWriter, optional
        Where to write; opened from the ``output`` parameter if None.
    **kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``context``, ``parameter_overrides``).
    """

    def __init__(self, writer=None, **kwargs):
        super().__init__("recorder", **kwargs)
        self.config = read_config(self)
        # Built before the file is opened: a URDF the core cannot read leaves no file.
        frames = (link_frames.LinkFrames(self.config.robot_description,
                                         self.config.locked_joints)
                  if self.config.link_frames else None)
        if writer is None:
            path = self.config.output or str(mcap_io.default_output_path())
            writer = mcap_io.RecordingWriter(
                path, compression=self.config.compression, chunk_size=self.config.chunk_size,
                flush_period=self.config.flush_period)
        self.writer = writer
        self._recorded = {}
        self._first_seen = set()  # topics whose first message was written
        self._pub_status = self.create_publisher(DiagnosticStatus, "~/status", QOS_STATUS)
        self.get_logger().info(f"recording {len(self.config.topics)} topics to "
                               f"{self.writer.path}")
        self._status(DiagnosticStatus.OK, f"recording {len(self.config.topics)} topics to "
                     f"{self.writer.path}", event="started", output=str(self.writer.path),
                     topics=",".join(self.config.topics))
        self._frames = None if frames is None else self._start_link_frames(frames)
        self.create_timer(self.config.discovery_period, self.discover)
        # Checked twice per period: a message waits at most about one period.
        self.create_timer(self.config.flush_period / 2, self.writer.flush_if_due)
        self.diagnostics = Diagnostics(self, "recorder", self._diagnostic_state)
        self.discover()

    def _diagnostic_state(self):
        """``/diagnostics``: the file, what it holds, the topics still without a publisher."""
        pending = self.pending_topics
        values = {"output": str(self.writer.path), "messages": self.writer.message_count,
                  "receiving": ",".join(self.receiving_topics),
                  "pending_topics": ",".join(pending)}
        if self.writer.closed:
            return "WARN", "recording closed", values
        return ("OK" if not pending else "WARN",
                f"recording to {self.writer.path}" +
                (f"; {len(pending)} topics without a publisher" if pending else ""), values)

    @property
    def pending_topics(self):
        """Topics still waiting for a publisher."""
        return [t for t in self.config.topics if t not in self._recorded]

    @property
    def receiving_topics(self):
        """Topics whose first message has been written, in the order of ``topics``."""
        return [t for t in self.config.topics if t in self._first_seen]

    def _status(self, level, message, **values):
        self._pub_status.publish(DiagnosticStatus(
            level=level, name=self.get_fully_qualified_name(), message=message,
            values=[KeyValue(key=k, value=v) for k, v in values.items()]))

    def discover(self):
        """Subscribe to each wanted topic that has gained a publisher."""
        for topic in self.pending_topics:
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            types = sorted({info.topic_type for info in infos})
            type_name = types[0]
            if len(types) > 1:
                self.get_logger().warning(
                    f"{topic}: publishers of several types {types}; recording {type_name}")
                infos = [info for info in infos if info.topic_type == type_name]
            offered = [info.qos_profile for info in infos]
            try:
                msg_class = mcap_io.message_class(type_name)
                self.writer.add_topic(topic, type_name, offered, infos[0].topic_type_hash)
            except mcap_io.McapIOError as err:
                self.get_logger().error(f"{topic}: not recorded: {err}")
                self._status(DiagnosticStatus.ERROR, f"{topic}: not recorded: {err}",
                             event="not_recorded", topic=topic)
                self._recorded[topic] = None
                continue
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, self._callback(topic),
                subscription_qos(offered, self.config.queue_depth), raw=True)
            self.get_logger().info(f"recording {topic} ({type_name})")
            self._status(DiagnosticStatus.OK, f"subscribed to {topic} ({type_name})",
                         event="subscribed", topic=topic, type=type_name)

    def _start_link_frames(self, frames):
        """Add the robot's topics; write ``/robot_description`` and ``/tf_static`` now.

        Returns the function that writes ``/tf`` for a joint state's CDR bytes.
        """
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        own = ((link_frames.DESCRIPTION_TOPIC, link_frames.DESCRIPTION_TYPE,
                link_frames.QOS_DESCRIPTION),
               (link_frames.TF_STATIC_TOPIC, link_frames.TF_TYPE, link_frames.QOS_TF_STATIC),
               (link_frames.TF_TOPIC, link_frames.TF_TYPE, link_frames.QOS_TF))
        for topic, type_name, profile in own:
            self.writer.add_topic(topic, type_name, [profile],
                                  mcap_io.installed_type_hash(type_name))
        # Log times from the system clock, as every received message's; the static frames
        # stamped by the node's clock, as robot_state_publisher stamps them.
        now_ns = time.time_ns()
        self.writer.write(link_frames.DESCRIPTION_TOPIC, cdr.serialize_exact(
            String(data=self.config.robot_description)), now_ns)
        self.writer.write(link_frames.TF_STATIC_TOPIC, cdr.serialize_exact(
            frames.tf_static_message(self.get_clock().now().to_msg())), now_ns)
        if self.config.joint_states_topic not in self.config.topics:
            self.get_logger().warning(
                f"joint_states_topic {self.config.joint_states_topic} is not among `topics`: "
                f"no {link_frames.TF_TOPIC} will be written")
        self.get_logger().info(
            f"writing {link_frames.TF_TOPIC} for {len(frames.moving_joints)} moving joints "
            f"from {self.config.joint_states_topic}, {len(frames.fixed_joints)} fixed joints "
            f"on {link_frames.TF_STATIC_TOPIC}")
        write = self.writer.write

        def on_joint_state(data, received, source):
            tf = frames.tf_message(deserialize_message(bytes(data), JointState))
            write(link_frames.TF_TOPIC, cdr.serialize_exact(tf), received, source)

        return on_joint_state

    def _callback(self, topic):
        write = self.writer.write
        frames = self._frames if topic == self.config.joint_states_topic else None

        def on_message(data, info):
            received = info.get("received_timestamp") or time.time_ns()
            source = info.get("source_timestamp") or received
            write(topic, data, received, source, info.get("publication_sequence_number") or 0)
            if frames is not None:
                frames(data, received, source)
            if topic not in self._first_seen:
                self._first_seen.add(topic)
                self._status(DiagnosticStatus.OK, f"first message on {topic} written",
                             event="first_message", topic=topic)

        return on_message

    def close(self):
        """Finish the file (summary and indexes) and log what it holds."""
        if self.writer.closed:
            return
        self.writer.close()
        counts = ", ".join(f"{t} {n}" for t, (_, n) in self.writer.topics.items())
        self.get_logger().info(f"wrote {self.writer.message_count} messages to "
                               f"{self.writer.path} ({counts or 'no topics'})")


def spin_until_stopped(executor, stop, drain_time=DRAIN_TIME):
    """Spin until ``stop()`` is true, then take what is already queued for `drain_time` s."""
    while not stop():
        executor.spin_once(timeout_sec=0.1)
    deadline = time.monotonic() + drain_time
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)


def build_parser() -> argparse.ArgumentParser:
    """Command line of ``ros2 run tocontrol_ros recorder``: only ``--help`` (ROS parameters)."""
    return parameters_parser(
        "recorder",
        "Record topics to a rosbag2-compatible MCAP file until SIGINT or "
        "SIGTERM. Settings are ROS parameters (--ros-args -p name:=value or "
        "--params-file config/recorder.yaml).",
        PARAMETERS)


def main(args=None):
    """Run the recorder until SIGINT or SIGTERM, then finish the file.

    Parameters
    ----------
    args : list of str, optional
        The whole command line, program name first, ROS arguments included; ``sys.argv``
        if None.

    Returns
    -------
    int
        0 after a clean stop, 2 for bad parameters or an existing output file.
    """
    argv = list(sys.argv if args is None else args)
    build_parser().parse_args(remove_ros_args(argv)[1:])
    # Own handlers: a signal stops the loop, queued messages are still taken, and the
    # file is finished before the context shuts down.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stopping = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    status = 0
    try:
        node = Recorder()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_until_stopped(executor, lambda: bool(stopping))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, mcap_io.McapIOError) as err:
        print(f"recorder: {err}", file=sys.stderr)
        status = 2
    except OSError as err:
        # e.g. an unwritable output: one line, not a traceback.
        print(f"recorder: cannot write the recording: {err.strerror or err}: "
              f"{err.filename or ''}".rstrip(": "), file=sys.stderr)
        status = 2
    finally:
        if node is not None:
            try:
                node.close()
            except OSError as err:
                print(f"recorder: cannot finish the recording: {err}", file=sys.stderr)
                status = 2
            node.destroy_node()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
