"""Replay: ``ros2 run tocontrol_ros replay FILE`` republishes a recording with its timing.

Options follow ``ros2 bag play``'s where they overlap. Each recorded topic gets a publisher
of its recorded type with the QoS its publishers offered when it was recorded (reliability
and durability; keep-last history), and the recorded CDR bytes are published as they are,
spaced by their log times divided by ``--rate``.

- Nothing is sent into the void: before the first message the replay waits (up to
  ``--wait-for-subscribers`` seconds, 10 by default) until every replayed topic has a matched
  subscriber, and warns, naming them, about the topics that have none; ``--delay`` waits
  longer before each pass. After the last message it waits until reliable subscribers have
  acknowledged everything.
- ``--topics`` selects topics, ``--remap FROM:=TO`` publishes a recorded topic under another
  name, ``--start-offset`` skips the first seconds, ``--loop`` repeats until SIGINT or
  SIGTERM.
- ``--clock [HZ]`` publishes ``/clock`` from the recorded time (log time) while playing, up
  to the recording's end: a tracker with ``use_sim_time`` then runs on the recording's time,
  at ``--rate``.
- ``--reexecute`` re-executes a recorded run on a running tracker: it puts the tracker at the
  recorded initial state (``<tracker>/reset``, from the tracker's recorded start event or
  the recording's joint states, see :func:`recorded_initial_state`), waits for the tracker
  to confirm, then replays the planner's trajectories (only ``/planner/trajectory`` unless
  ``--topics`` says otherwise).
- In a terminal, the space bar pauses and resumes, ``s`` publishes the next message while
  paused.

Usage::

    ros2 run tocontrol_ros replay runs/20240101-120000.mcap --topics /planner/trajectory
    ros2 run tocontrol_ros replay runs/demo-X.mcap --reexecute --clock
"""

import argparse
import contextlib
import math
import os
import select
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import rclpy
import rclpy.utilities
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

#: Publisher depth when the recording does not say (offered QoS from the graph report
from tocontrol_ros.nodes import qos
from tocontrol_ros.recording import mcap_io

#: Publisher depth when the recording does not say (offered QoS from the graph report
#: history "unknown", depth 0).
DEFAULT_DEPTH = 10
#: Longest sleep slice (s), so a stop request is seen promptly.
SLEEP_SLICE = 0.05
#: A message this close (s) to its time is due (a shorter sleep may not move the clock).
DUE_TOLERANCE = 1e-9
#: Default of --wait-for-subscribers (s): a tracker started at the same time needs a few
#: seconds (its control law is compiled at start-up).
DEFAULT_WAIT = 10.0
#: After every topic has a matched subscriber, the time (s) left for the subscriber's side of
#: discovery (a best-effort reader drops samples of a writer it has not matched yet).
SETTLE = 0.25
#: How long (s) --reexecute waits for the tracker to confirm the reset.
RESET_TIMEOUT = 5.0
#: Default /clock rate with --clock (Hz): the tracker's update rate.
DEFAULT_CLOCK_RATE = 100.0
TRAJECTORY_TOPIC = "/planner/trajectory"
JOINT_STATES_TOPIC = "/joint_states"


def build_parser():
    """Return the replay's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="replay", description="Republish an MCAP recording with its original timing "
        "(options as ros2 bag play's where they overlap).")
    parser.add_argument("file", type=Path, metavar="FILE", help="recording (.mcap)")
    parser.add_argument("-r", "--rate", type=float, default=1.0,
                        help="time factor: 2 plays twice as fast (default 1)")
    parser.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                        help="only these topics (default: all recorded; with --reexecute "
                        f"{TRAJECTORY_TOPIC})")
    parser.add_argument("-m", "--remap", nargs="+", default=[], metavar="FROM:=TO",
                        help="publish recorded topic FROM as TO")
    parser.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                        help="skip the first S seconds of the recording (default 0)")
    parser.add_argument("-l", "--loop", action="store_true", help="repeat until interrupted")
    parser.add_argument("-d", "--delay", "--start-delay", dest="delay", type=float,
                        default=0.0, metavar="S",
                        help="wait S more seconds before each pass, after the subscribers "
                        "are matched (default 0)")
    parser.add_argument("--wait-for-subscribers", type=float, default=DEFAULT_WAIT,
                        metavar="S",
                        help="wait up to S seconds for every replayed topic to have a "
                        f"matched subscriber, then warn and play (default {DEFAULT_WAIT:g}; "
                        "0: do not wait)")
    parser.add_argument("--clock", type=float, nargs="?", const=DEFAULT_CLOCK_RATE,
                        default=None, metavar="HZ",
                        help="publish /clock from the recorded time at HZ (default "
                        f"{DEFAULT_CLOCK_RATE:g}) up to the recording's end")
    parser.add_argument("--reexecute", action="store_true",
                        help="put the tracker at the recording's initial state first, then "
                        "replay the trajectories")
    parser.add_argument("--tracker", default="/tracker", metavar="NODE",
                        help="the tracker's node name, for --reexecute (default /tracker)")
    parser.add_argument("--no-keys", action="store_true",
                        help="no keyboard control (space: pause/resume, s: step)")
    return parser


def parse_remaps(items):
    """``["FROM:=TO", ...]`` as a dict; a malformed item raises ``ValueError`` naming it."""
    out = {}
    for item in items:
        source, sep, target = item.partition(":=")
        if not sep or not source.startswith("/") or not target.startswith("/"):
            raise ValueError(f"`--remap` takes /FROM:=/TO (absolute topic names), got "
                             f"{item!r}")
        out[source] = target
    return out


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


def _stamp_ns(ns):
    from builtin_interfaces.msg import Time

    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


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
    remap : mapping of str to str, optional
        Recorded topic -> topic to publish on (each key must be replayed).
    clock_rate : float, optional
        Publish ``/clock`` at this rate (Hz, > 0) from the recorded time; None: no clock.
    clock, sleep : callable
        ``time.monotonic`` and ``time.sleep`` (replaceable in tests).
    """

    def __init__(self, node, path, topics=None, rate=1.0, start_offset=0.0, remap=None,
                 clock_rate=None, clock=time.monotonic, sleep=time.sleep):
        if not rate > 0 or not math.isfinite(rate):
            raise ValueError(f"`rate` must be positive, got {rate!r}")
        if not start_offset >= 0:
            raise ValueError(f"`start_offset` must be >= 0 s, got {start_offset!r}")
        if clock_rate is not None and not (clock_rate > 0 and math.isfinite(clock_rate)):
            raise ValueError(f"`clock` rate must be positive (Hz), got {clock_rate!r}")
        self.path = Path(path)
        self.channels = mcap_io.read_channels(self.path)
        if topics is not None:
            missing = sorted(set(topics) - set(self.channels))
            if missing:
                raise ValueError(f"`topics` not in {self.path}: {missing}; recorded: "
                                 f"{sorted(self.channels)}")
            self.channels = {t: c for t, c in self.channels.items() if t in topics}
        self.remap = dict(remap or {})
        unknown = sorted(set(self.remap) - set(self.channels))
        if unknown:
            raise ValueError(f"`remap`: {unknown} not among the replayed topics "
                             f"{sorted(self.channels)}")
        self.rate = rate
        self.start_offset = start_offset
        self._clock = clock
        self._sleep = sleep
        self.publishers = {
            topic: node.create_publisher(mcap_io.message_class(info.type),
                                         self.remap.get(topic, topic),
                                         qos_from_recorded(info.offered_qos_profiles))
            for topic, info in self.channels.items()
        }
        self.clock_period = None if clock_rate is None else 1.0 / clock_rate
        self.clock_publisher = (None if clock_rate is None
                                else node.create_publisher(Clock, "/clock", qos.RELIABLE))
        self.published = 0
        self.paused = False
        self._step = threading.Event()

    # ------------------------------------------------------------------ control
    def toggle_pause(self):
        """Pause or resume playback (the schedule resumes where it stopped)."""
        self.paused = not self.paused

    def step(self):
        """While paused, publish the next message now."""
        self._step.set()

    # ------------------------------------------------------------------ helpers
    def _time_range(self):
        summary = mcap_io.read_summary(self.path)
        stats = summary.statistics
        first = stats.message_start_time if stats else 0
        last = stats.message_end_time if stats else 0
        return first + int(round(self.start_offset * 1e9)), last

    def _publish_clock(self, log_ns):
        self.clock_publisher.publish(Clock(clock=_stamp_ns(log_ns)))

    def wait_for_subscribers(self, timeout, stop=lambda: False):
        """Wait up to `timeout` s until every replayed topic has a matched subscriber.

        Returns
        -------
        list of str
            The published topic names still without one (empty: all matched).
        """
        deadline = self._clock() + timeout

        def missing():
            return [self.remap.get(t, t) for t, p in self.publishers.items()
                    if p.get_subscription_count() == 0]

        while missing() and self._clock() < deadline and not stop():
            self._sleep(min(SLEEP_SLICE, max(deadline - self._clock(), 1e-3)))
        if timeout > 0 and not missing():
            self._sleep(SETTLE)
        return missing()

    def play_once(self, stop=lambda: False):
        """Publish the selected messages once; return how many were published.

        With a clock, ``/clock`` is published every clock period of playback time and just
        before each message (at its log time), and after the last message until the
        recording's end.

        Parameters
        ----------
        stop : callable
            Polled while waiting; returning True ends the pass early.
        """
        start, end = self._time_range()
        records = mcap_io.iter_records(self.path, topics=list(self.publishers),
                                       start_time=start)
        record = next(records, None)
        if record is None:
            return 0
        count = 0
        origin_log, origin_wall = record.log_time, self._clock()
        next_tick = origin_wall
        if self.clock_publisher is not None:
            # The clock one period ahead of the first message, so that subscribers have a
            # time when it arrives.
            self._publish_clock(origin_log)
            origin_wall += self.clock_period
            next_tick = origin_wall
        paused_at = None

        def log_now(wall):
            return origin_log + int((wall - origin_wall) * self.rate * 1e9)

        while record is not None or (self.clock_publisher is not None
                                     and log_now(self._clock()) < end):
            if stop():
                return count
            now = self._clock()
            if self.paused and paused_at is None:
                paused_at = now
            if paused_at is not None and not self.paused:
                origin_wall += now - paused_at
                next_tick += now - paused_at
                paused_at = None
            if paused_at is not None:
                if record is None or not self._step.is_set():
                    self._sleep(SLEEP_SLICE)
                    continue
                self._step.clear()
                # Playback time jumps to the stepped message and stays there.
                origin_wall = now - (record.log_time - origin_log) * 1e-9 / self.rate
                paused_at = now
            else:
                if self.clock_publisher is not None and now >= next_tick - DUE_TOLERANCE:
                    self._publish_clock(min(log_now(now), end))
                    next_tick = max(next_tick + self.clock_period, now)
                    continue
                target = (math.inf if record is None
                          else origin_wall + (record.log_time - origin_log) * 1e-9 / self.rate)
                if now < target - DUE_TOLERANCE:
                    wake = target if self.clock_publisher is None else min(target, next_tick)
                    self._sleep(min(max(wake - now, DUE_TOLERANCE), SLEEP_SLICE))
                    continue
            if self.clock_publisher is not None:
                self._publish_clock(record.log_time)
            self.publishers[record.topic].publish(record.data)
            count += 1
            self.published += 1
            record = next(records, None)
        if self.clock_publisher is not None and not stop():
            self._publish_clock(end)
        return count

    def wait_for_acks(self, timeout=2.0):
        """Wait (up to `timeout` s per publisher) until reliable subscribers acknowledged."""
        for publisher in self.publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=timeout))


# -------------------------------------------------------------- re-execution
@dataclass(frozen=True)
class InitialState:
    """The recorded state a run started from.

    Attributes
    ----------
    msg : sensor_msgs.msg.JointState
        The joint state (names, positions, velocities).
    source : str
        Where it came from, for the log.
    """

    msg: JointState
    source: str


def recorded_initial_state(path, joint_states=JOINT_STATES_TOPIC, tracker="/tracker"):
    """The joint state a recorded run started from.

    In order of preference: the state the tracker reported when it started the first
    trajectory (``start_position.<joint>`` and ``start_velocity.<joint>`` of its first
    "executing trajectory" status, which is latched, so a recorder that subscribed late
    has it); the last ``joint_states`` message stamped at or before that start
    (``start_time``, the same simulated time as the stamps); the first ``joint_states`` in
    the file (the source then says that it may not be the initial state).

    Raises
    ------
    ValueError
        If the recording has neither.
    """
    from rclpy.serialization import deserialize_message

    status_topic = f"{tracker.rstrip('/')}/status"
    channels = mcap_io.read_channels(path)
    start_time = None
    if status_topic in channels:
        for record in mcap_io.iter_records(path, topics=[status_topic]):
            status = deserialize_message(record.data, DiagnosticStatus)
            values = {kv.key: kv.value for kv in status.values}
            if not (status.message.startswith("executing trajectory")
                    and "start_time" in values):
                continue
            start_time = float(values["start_time"])
            names = [k.split(".", 1)[1] for k in values if k.startswith("start_position.")]
            if names and all(f"start_velocity.{n}" in values for n in names):
                msg = JointState(
                    name=names, position=[float(values[f"start_position.{n}"]) for n in names],
                    velocity=[float(values[f"start_velocity.{n}"]) for n in names])
                return InitialState(msg, f"the tracker's state at the first trajectory's "
                                    f"start ({start_time:.3f} s, {status_topic})")
            break
    if joint_states not in channels:
        raise ValueError(f"{path} has no {joint_states} and no tracker start state: no "
                         f"initial state to re-execute from (recorded: {sorted(channels)})")
    first = before = None
    for record in mcap_io.iter_records(path, topics=[joint_states]):
        msg = deserialize_message(record.data, JointState)
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if first is None:
            first = msg
        if start_time is None or stamp > start_time + 1e-9:
            break
        before = msg
    if before is not None:
        return InitialState(before, f"{joint_states} at the first trajectory's start "
                            f"({start_time:.3f} s, tracker status)")
    if first is None:
        raise ValueError(f"{path}: {joint_states} has no messages")
    if start_time is None:
        return InitialState(first, f"the first {joint_states} (no tracker start recorded)")
    return InitialState(first, f"the first {joint_states}, recorded after the first "
                        "trajectory had started: the run's true initial state is not in the "
                        "file")


class TrackerReset:
    """Puts a tracker at a state over its ``~/reset`` topic and waits for its confirmation.

    Parameters
    ----------
    node : rclpy.node.Node
    executor : rclpy.executors.Executor
        Spins `node` while waiting.
    tracker : str
        The tracker's node name (``/tracker``).
    """

    def __init__(self, node, executor, tracker):
        self.name = tracker.rstrip("/")
        self._node, self._executor = node, executor
        self._statuses = []
        node.create_subscription(DiagnosticStatus, f"{self.name}/status",
                                 self._statuses.append, qos.status_profile(20, latched=True))
        self._pub = node.create_publisher(JointState, f"{self.name}/reset", qos.RELIABLE)

    def _spin_until(self, condition, timeout, stop):
        deadline = time.monotonic() + timeout
        while not condition() and time.monotonic() < deadline and not stop():
            self._executor.spin_once(timeout_sec=SLEEP_SLICE)
        return condition()

    def send(self, state, timeout, stop=lambda: False):
        """Send `state` (a ``JointState``); wait up to `timeout` s for a subscriber.

        Returns
        -------
        str or None
            None once the tracker confirmed, else why it did not.
        """
        msg = JointState(name=list(state.name), position=list(state.position),
                         velocity=list(state.velocity))
        msg.header.stamp = self._node.get_clock().now().to_msg()
        want = f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"
        if not self._spin_until(lambda: self._pub.get_subscription_count() > 0, timeout,
                                stop):
            return f"no tracker subscribes to {self.name}/reset (waited {timeout:g} s)"
        time.sleep(SETTLE)
        self._pub.publish(msg)

        def answer():
            return next((s for s in self._statuses if any(
                kv.key == "request_stamp" and kv.value == want for kv in s.values)), None)

        if not self._spin_until(lambda: answer() is not None, RESET_TIMEOUT, stop):
            return (f"the tracker did not confirm the reset on {self.name}/status in "
                    f"{RESET_TIMEOUT:g} s")
        if answer().level != DiagnosticStatus.OK:
            return f"the tracker refused the reset: {answer().message}"
        return None


# ------------------------------------------------------------------ keyboard
@contextlib.contextmanager
def keyboard(player, enabled):
    """Space toggles pause, ``s`` steps, read from a terminal in a daemon thread."""
    if not enabled or not sys.stdin.isatty():
        yield
        return
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    done = threading.Event()

    def read():
        while not done.is_set():
            ready, _, _ = select.select([fd], [], [], 0.1)
            if not ready:
                continue
            key = os.read(fd, 1)
            if key == b" ":
                player.toggle_pause()
                print("paused" if player.paused else "playing", file=sys.stderr)
            elif key in (b"s", b"S") and player.paused:
                player.step()

    tty.setcbreak(fd)
    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(1.0)
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


# ---------------------------------------------------------------------- main
def main(argv=None):
    """Replay a recording; returns the exit status (0, 1: re-execution failed, 2: bad input)."""
    argv = sys.argv[1:] if argv is None else argv
    ros_args = rclpy.utilities.remove_ros_args(["replay", *argv])[1:]
    args = build_parser().parse_args(ros_args)
    if not args.file.is_file():
        print(f"replay: no such file: {args.file}", file=sys.stderr)
        return 2
    for name in ("delay", "wait_for_subscribers"):
        if not getattr(args, name) >= 0:
            print(f"replay: --{name.replace('_', '-')} must be >= 0 s, got "
                  f"{getattr(args, name)}", file=sys.stderr)
            return 2
    rclpy.init(args=["replay", *argv], signal_handler_options=SignalHandlerOptions.NO)
    stopping = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = rclpy.create_node("replay")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    log = node.get_logger()
    status = 0

    def stop():
        return bool(stopping)

    try:
        topics = args.topics
        if args.reexecute and topics is None:
            topics = [TRAJECTORY_TOPIC]
        player = Player(node, args.file, topics=topics, rate=args.rate,
                        start_offset=args.start_offset, remap=parse_remaps(args.remap),
                        clock_rate=args.clock)
        reset = None
        if args.reexecute:
            state = recorded_initial_state(args.file, tracker=args.tracker)
            log.info(f"re-executing: the tracker {args.tracker} goes to "
                     f"{[round(v, 6) for v in state.msg.position]} ({state.source})")
            if "not in the file" in state.source:
                log.warning(f"initial state: {state.source}")
            reset = TrackerReset(node, executor, args.tracker)
        if args.wait_for_subscribers > 0:
            missing = player.wait_for_subscribers(args.wait_for_subscribers, stop)
            if missing:
                log.warning(f"no subscriber matched after {args.wait_for_subscribers:g} s "
                            f"on {missing}: their messages go nowhere (start the "
                            "subscribers first, or raise --wait-for-subscribers)")
        with keyboard(player, not args.no_keys):
            while not stopping:
                end = time.monotonic() + args.delay
                while time.monotonic() < end and not stopping:
                    time.sleep(SLEEP_SLICE)
                if reset is not None:  # each pass from the recorded initial state
                    why = reset.send(state.msg, max(args.wait_for_subscribers, 1.0), stop)
                    if why is not None:
                        log.error(f"cannot re-execute: {why}")
                        return 1
                n = player.play_once(stop=stop)
                counts = {player.remap.get(t, t): p.get_subscription_count()
                          for t, p in player.publishers.items()}
                log.info(f"published {n} messages from {args.file} (subscribers: {counts})")
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
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
