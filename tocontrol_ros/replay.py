"""Replay: ``ros2 run tocontrol_ros replay FILE`` republishes a recording with its timing.

Each recorded topic gets a publisher of its recorded type with the QoS its publishers
offered when it was recorded (reliability and durability; keep-last history), and the
recorded CDR bytes are published as they are, spaced by their log times divided by
``--rate``. ``--topics`` selects topics, ``--start-offset`` skips the first seconds,
``--loop`` repeats until SIGINT or SIGTERM. Replaying a run's ``/planner/trajectory``
to a running tracker re-executes it.

Usage::

    ros2 run tocontrol_ros replay runs/20240101-120000.mcap --rate 2 --topics /planner/trajectory
"""

import argparse
import signal
import sys
import time
from pathlib import Path

import rclpy
import rclpy.utilities
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from tocontrol_ros import mcap_io

#: Publisher depth when the recording does not say (offered QoS from the graph report
#: history "unknown", depth 0).
DEFAULT_DEPTH = 10
#: Longest sleep slice (s), so a stop request is seen promptly.
SLEEP_SLICE = 0.05


def build_parser():
    """Return the replay's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="replay", description="Republish an MCAP recording with its original timing.")
    parser.add_argument("file", type=Path, metavar="FILE", help="recording (.mcap)")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="time factor: 2 plays twice as fast (default 1)")
    parser.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                        help="only these topics (default: all recorded)")
    parser.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                        help="skip the first S seconds of the recording (default 0)")
    parser.add_argument("--loop", action="store_true", help="repeat until interrupted")
    parser.add_argument("--delay", type=float, default=0.5, metavar="S",
                        help="wait S seconds after creating the publishers, for discovery "
                        "(default 0.5)")
    return parser


def qos_from_recorded(profiles):
    """Publisher QoS from the recorded ``offered_qos_profiles`` (first publisher's).

    Policies the recording leaves open (none recorded, ``system_default``, ``unknown``)
    fall back to reliable, volatile, keep-last ``DEFAULT_DEPTH``.
    """
    profile = profiles[0] if profiles else {}
    reliability = {"best_effort": ReliabilityPolicy.BEST_EFFORT}.get(
        profile.get("reliability"), ReliabilityPolicy.RELIABLE)
    durability = {"transient_local": DurabilityPolicy.TRANSIENT_LOCAL}.get(
        profile.get("durability"), DurabilityPolicy.VOLATILE)
    depth = profile.get("depth") or DEFAULT_DEPTH
    if profile.get("history") != "keep_last":
        depth = DEFAULT_DEPTH
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=reliability, durability=durability)


class Player:
    """Publishes a recording's messages on `node` with their recorded spacing.

    Parameters
    ----------
    node : rclpy.node.Node
    path : str or os.PathLike
        A finished recording.
    topics : collection of str, optional
        Only these topics (each must be in the recording).
    rate : float
        Time factor (> 0).
    start_offset : float
        Seconds of the recording to skip (>= 0).
    clock, sleep : callable
        ``time.monotonic`` and ``time.sleep`` (replaceable in tests).
    """

    def __init__(self, node, path, topics=None, rate=1.0, start_offset=0.0,
                 clock=time.monotonic, sleep=time.sleep):
        if not rate > 0:
            raise ValueError(f"`rate` must be positive, got {rate!r}")
        if not start_offset >= 0:
            raise ValueError(f"`start_offset` must be >= 0 s, got {start_offset!r}")
        self.path = Path(path)
        self.channels = mcap_io.read_channels(self.path)
        if topics is not None:
            missing = sorted(set(topics) - set(self.channels))
            if missing:
                raise ValueError(f"`topics` not in {self.path}: {missing}; recorded: "
                                 f"{sorted(self.channels)}")
            self.channels = {t: c for t, c in self.channels.items() if t in topics}
        self.rate = rate
        self.start_offset = start_offset
        self._clock = clock
        self._sleep = sleep
        self.publishers = {
            topic: node.create_publisher(mcap_io.message_class(info.type), topic,
                                         qos_from_recorded(info.offered_qos_profiles))
            for topic, info in self.channels.items()
        }
        self.published = 0

    def _start_time(self):
        summary = mcap_io.read_summary(self.path)
        first = summary.statistics.message_start_time if summary.statistics else 0
        return first + int(round(self.start_offset * 1e9))

    def play_once(self, stop=lambda: False):
        """Publish the selected messages once; return how many were published.

        Parameters
        ----------
        stop : callable
            Polled while waiting; returning True ends the pass early.
        """
        start = self._start_time()
        count = 0
        origin_log = None
        origin_wall = None
        for record in mcap_io.iter_records(self.path, topics=list(self.publishers),
                                           start_time=start):
            if origin_log is None:
                origin_log, origin_wall = record.log_time, self._clock()
            target = origin_wall + (record.log_time - origin_log) * 1e-9 / self.rate
            while (remaining := target - self._clock()) > 0:
                if stop():
                    return count
                self._sleep(min(remaining, SLEEP_SLICE))
            if stop():
                return count
            self.publishers[record.topic].publish(record.data)
            count += 1
            self.published += 1
        return count

    def wait_for_acks(self, timeout=2.0):
        """Wait (up to `timeout` s per publisher) until reliable subscribers acknowledged."""
        for publisher in self.publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=timeout))


def main(argv=None):
    """Replay a recording; returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    ros_args = rclpy.utilities.remove_ros_args(["replay", *argv])[1:]
    args = build_parser().parse_args(ros_args)
    if not args.file.is_file():
        print(f"replay: no such file: {args.file}", file=sys.stderr)
        return 2
    rclpy.init(args=["replay", *argv], signal_handler_options=SignalHandlerOptions.NO)
    stopping = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = rclpy.create_node("replay")
    status = 0
    try:
        player = Player(node, args.file, topics=args.topics, rate=args.rate,
                        start_offset=args.start_offset)
        end = time.monotonic() + args.delay
        while time.monotonic() < end and not stopping:
            time.sleep(SLEEP_SLICE)
        while not stopping:
            n = player.play_once(stop=lambda: bool(stopping))
            node.get_logger().info(f"published {n} messages from {args.file}")
            if not args.loop or n == 0:
                break
        if not stopping:
            player.wait_for_acks()
    except (ValueError, mcap_io.McapIOError) as err:
        print(f"replay: {err}", file=sys.stderr)
        status = 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
