"""A client of the planner node for tests: in-process (test/ros) and across processes (test/e2e).

Importable as ``planner_harness`` because pytest (prepend import mode) puts ``test/`` on
``sys.path`` for ``test/conftest.py``. Everything here is bounded in time: every wait takes
a timeout and fails the test when it runs out.
"""

from __future__ import annotations

import itertools
import math
import os
import threading
import time
from dataclasses import dataclass

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET

#: Bad ~/plan calls: id, start, goal, start frame, goal frame, fragment of the message.
SERVICE_BAD = [
    ("nan", PAPER_START, (float("nan"), 1.5), "base_link", "base_link",
     "`goal.pose.position.x` must be finite"),
    ("inf", (1.0, float("inf")), PAPER_TARGET, "base_link", "base_link",
     "`start.pose.position.y` must be finite"),
    ("unreachable", PAPER_START, (9.0, 0.0), "base_link", "base_link", "not reachable"),
    ("frame", PAPER_START, PAPER_TARGET, "base_link", "map", "frame_id 'map'"),
    ("boundary", PAPER_START, (5.5, 0.0), "base_link", "base_link",
     "is on the boundary of the workspace"),
    ("off-plane", PAPER_START, (2.2, 1.5, 0.3), "base_link", "base_link",
     "`goal.pose.position.z` = 0.3 m is off"),
]
#: Bad ~/goal messages: id, goal, frame, fragment of the message.
GOAL_BAD = [
    ("nan", (float("nan"), 1.0), "base_link", "`goal.point.x` must be finite"),
    ("frame", PAPER_TARGET, "world", "frame_id 'world'"),
    ("unreachable", (0.0, 6.0), "base_link", "not reachable"),
]
#: Rejected parameter changes: values, fragment of the reason.
PARAM_BAD = [
    ({"k": 100.0}, "out of range"),
    ({"reserve": -0.1}, "out of range"),
    ({"starts": 0}, "out of range"),
    ({"candidates": 20}, "must not exceed `starts`"),
    ({"default_start": [1.0, 1.0, 0.0]}, "`default_start` must have 2 entries"),
    ({"robot_description": "<robot/>"}, "read-only"),
    ({"frame_id": "map"}, "read-only"),
    ({"k": "four"}, "type"),
    ({"publish": "sometimes"}, "`publish` must be one of optimum, first_then_optimum"),
]
FINAL_EVENTS = ("solved", "failed", "superseded", "cancelled", "timed out")
_counter = itertools.count()


@dataclass(frozen=True)
class Status:
    """A received ``DiagnosticStatus``, decoded."""

    level: int
    message: str
    values: dict
    received: float

    @property
    def event(self) -> str:
        return self.values.get("event", "")

    @property
    def request_id(self) -> int | None:
        rid = self.values.get("request_id")
        return int(rid) if rid is not None else None

    def vector(self, key: str) -> list[float]:
        return [float(v) for v in self.values[key].strip("[]").split(",")]


def rss_kib(pid: int | str = "self") -> int:
    """Resident set size of a process (KiB), from /proc."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc status")


#: The jump bar of a splice that came in time (rad, rad/s): the moving-target tests'.
SPLICE_JUMP_BAR = (1e-3, 1e-2)


def hold_splices_to_the_bar(splices: list[dict]) -> None:
    """Hold every splice that came in time to :data:`SPLICE_JUMP_BAR`; report the late ones.

    ``splices``: the tracker's ``spliced`` status values. A trajectory delivered after its
    hand-off joins as far along as its stamp says (``late``, as a JTC drops the points past):
    its own jump grows with its lateness (a loaded machine), but the motion then is the one
    its planner assumed, so every splice in time, those after it included, is held.
    """
    on_time = [s for s in splices if s.get("late") == "false"]
    late = [s for s in splices if s.get("late") == "true"]
    assert len(on_time) + len(late) == len(splices)
    for s in late:
        print("late splice", s["message"], s["stamp"])
    assert on_time, [s["message"] for s in splices]
    jumps_q = [float(s["position_jump"]) for s in on_time]
    jumps_qd = [float(s["velocity_jump"]) for s in on_time]
    print(f"largest jumps {max(jumps_q):.2e} rad, {max(jumps_qd):.2e} rad/s "
          f"({len(on_time)} splices in time, {len(late)} late)")
    for s in on_time:
        if float(s["velocity_jump"]) > 1e-3 or float(s["position_jump"]) > 1e-4:
            print("large splice", s["message"], s["stamp"])
    assert max(jumps_q) < SPLICE_JUMP_BAR[0] and max(jumps_qd) < SPLICE_JUMP_BAR[1]


#: A controller's outcome of a plan sent to it (msg_docs/controller_execution.md).
OUTCOME_EVENTS = ("executed", "rejected")


def plans_without_outcome(events: list[Status], published: set[int]) -> str:
    """The requests whose plans lack a controller's outcome, with their status events.

    A request lacks one when it has more ``sent`` events than outcomes (``executed`` or
    ``rejected``), or when it is in ``published`` and has no outcome at all.

    Parameters
    ----------
    events : list of Status
        The planner's status events to look at (those of the test's goals).
    published : set of int
        Request ids whose plan was published (each must get an outcome).

    Returns
    -------
    str
        One line per such request: its id, counts, and every event of it
        (``event@received: message``); "none" when every plan has its outcome.
    """
    by_id: dict[int | None, list[Status]] = {}
    for s in events:
        by_id.setdefault(s.request_id, []).append(s)
    lines = []
    for rid in sorted(r for r in by_id if r is not None):
        mine = by_id[rid]
        sent = sum(s.event == "sent" for s in mine)
        done = sum(s.event in OUTCOME_EVENTS for s in mine)
        if done < sent or (rid in published and done == 0):
            trail = "; ".join(f"{s.event}@{s.received:.3f}: {s.message}" for s in mine)
            lines.append(f"request {rid}: {sent} sent, {done} outcomes: {trail}")
    for rid in sorted(published - set(by_id)):
        lines.append(f"request {rid}: published but no event of it seen")
    total = sum(s.event == "sent" for s in events)
    outcomes = sum(s.event in OUTCOME_EVENTS for s in events)
    return (f"{total} sent, {outcomes} outcomes in all; plans without an outcome: "
            + ("\n".join(lines) if lines else "none"))


class PlannerClient:
    """A node that talks to one planner: calls, goals, joint states, parameters, status.

    Parameters
    ----------
    planner : str
        Fully qualified name of the planner node, e.g. ``"/ns/planner"``.
    context : rclpy.Context, optional
        Default: a private context of its own (shut down by :meth:`close`).
    """

    def __init__(self, planner: str, context=None) -> None:
        self.planner = planner
        self._own_context = context is None
        self.context = context or rclpy.Context()
        if self._own_context:
            rclpy.init(context=self.context)
        ns = planner.rsplit("/", 1)[0]
        self.node = rclpy.create_node(f"planner_test_client_{os.getpid()}_{next(_counter)}",
                                      context=self.context)
        self._lock = threading.Lock()
        self.statuses: list[Status] = []
        self.trajectories: list[JointTrajectory] = []
        self.paths: list[Path] = []
        self.markers: list[MarkerArray] = []
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node = self.node
        node.create_subscription(DiagnosticStatus, f"{planner}/status", self._on_status,
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(JointTrajectory, f"{planner}/trajectory",
                                 lambda m: self._append(self.trajectories, m), latched)
        node.create_subscription(Path, f"{planner}/ee_path",
                                 lambda m: self._append(self.paths, m), latched)
        node.create_subscription(MarkerArray, f"{planner}/markers",
                                 lambda m: self._append(self.markers, m), latched)
        self.goal_pub = node.create_publisher(PointStamped, f"{planner}/goal", 100)
        self.joint_pub = node.create_publisher(JointState, f"{ns}/joint_states", 10)
        self.plan_client = node.create_client(GetPlan, f"{planner}/plan")
        self.set_client = node.create_client(SetParameters, f"{planner}/set_parameters")
        self.get_client = node.create_client(GetParameters, f"{planner}/get_parameters")
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001  (context shut down under us at close)
            pass

    def _append(self, bucket: list, msg) -> None:
        with self._lock:
            bucket.append(msg)

    def _on_status(self, msg: DiagnosticStatus) -> None:
        level = msg.level[0] if isinstance(msg.level, bytes) else int(msg.level)
        status = Status(level, msg.message, {kv.key: kv.value for kv in msg.values},
                        time.monotonic())
        self._append(self.statuses, status)

    # ---------------------------------------------------------------- waiting
    def wait_for(self, predicate, timeout: float, what: str, detail=None):
        """Poll ``predicate()`` until it returns a truthy value; fail after ``timeout`` s.

        ``detail``: a callable whose string goes into the failure's message (what is missing).
        """
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                more = f"; {detail()}" if detail is not None else ""
                raise AssertionError(f"timed out after {timeout} s waiting for {what}; "
                                     f"statuses: {[s.message for s in self.status_list()[-8:]]}"
                                     + more)
            time.sleep(0.01)

    def wait_motion_over(self, timeout: float = 30.0) -> None:
        """Wait until the last motion on ``~/trajectory`` has ended (its stamp plus its
        duration, on the node's clock): a goal then is not a replan of it."""
        def over():
            with self._lock:
                if not self.trajectories:
                    return True
                last = self.trajectories[-1]
            if not last.points:
                return True
            d = last.points[-1].time_from_start
            end = (last.header.stamp.sec + d.sec) * 10**9 + last.header.stamp.nanosec \
                + d.nanosec
            return self.node.get_clock().now().nanoseconds > end
        self.wait_for(over, timeout, "the last published motion to end")

    def wait_joint_states(self, timeout: float) -> None:
        """Wait until the planner's ``/diagnostics`` says it is receiving ``joint_states``: a
        goal sent before then may start from ``default_start`` (msg_docs/joint_states_input.md)."""
        from diagnostic_msgs.msg import DiagnosticArray

        seen = []

        def on_array(msg) -> None:
            for st in msg.status:
                if st.name == self.planner:
                    seen.append({kv.key: kv.value for kv in st.values}.get("joint_states", ""))
        sub = self.node.create_subscription(DiagnosticArray, "/diagnostics", on_array, 10)
        try:
            self.wait_for(lambda: any(v.startswith("receiving") for v in list(seen)), timeout,
                          f"the planner receiving joint states (its diagnostics: {seen[-1:]})")
        finally:
            self.node.destroy_subscription(sub)

    def status_list(self) -> list[Status]:
        with self._lock:
            return list(self.statuses)

    def wait_ready(self, timeout: float = 120.0) -> None:
        """Wait until the planner's services are up."""
        for client in (self.plan_client, self.set_client, self.get_client):
            assert client.wait_for_service(timeout_sec=timeout), f"{client.srv_name} not up"

    def final_status(self, since: int, timeout: float, match=None) -> Status:
        """The first final status (solved, failed, ...) after index ``since`` that matches."""
        def find():
            for s in self.status_list()[since:]:
                if s.event in FINAL_EVENTS and (match is None or match(s)):
                    return s
            return None
        return self.wait_for(find, timeout, "a final status")

    # ---------------------------------------------------------------- requests
    def call_plan(self, start, goal, start_frame="base_link", goal_frame="base_link",
                  timeout: float = 120.0) -> tuple[Path, Status, float]:
        """Call ``~/plan``; return the path, the request's final status, the call's time (s)."""
        req = GetPlan.Request()
        req.start.header.frame_id = start_frame
        req.goal.header.frame_id = goal_frame
        for pose, xyz in ((req.start.pose, start), (req.goal.pose, goal)):
            if xyz is not None:
                pose.position.x, pose.position.y = float(xyz[0]), float(xyz[1])
                pose.position.z = float(xyz[2]) if len(xyz) > 2 else 0.0
        since = len(self.status_list())
        t0 = time.monotonic()
        future = self.plan_client.call_async(req)
        self.wait_for(future.done, timeout, "the ~/plan response")
        elapsed = time.monotonic() - t0
        target = target_key(goal) if goal is not None else None
        status = self.final_status(
            since, 10.0, match=lambda s: s.values.get("target") in (None, target))
        return future.result().plan, status, elapsed

    def send_goal(self, xyz, frame="base_link") -> None:
        msg = PointStamped()
        msg.header.frame_id = frame
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.point.x, msg.point.y = float(xyz[0]), float(xyz[1])
        msg.point.z = float(xyz[2]) if len(xyz) > 2 else 0.0
        self.goal_pub.publish(msg)

    def send_joint_state(self, names, q, qd=()) -> None:
        msg = JointState(name=list(names), position=[float(v) for v in q],
                         velocity=[float(v) for v in qd])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.joint_pub.publish(msg)

    def wait_subscribed(self, publisher, timeout: float = 10.0) -> None:
        self.wait_for(lambda: publisher.get_subscription_count() > 0, timeout,
                      f"a subscriber on {publisher.topic_name}")

    # -------------------------------------------------------------- parameters
    def set_parameters(self, **values) -> list:
        """Set parameters through the service; return the SetParametersResult list."""
        req = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        future = self.set_client.call_async(req)
        self.wait_for(future.done, 10.0, "set_parameters")
        return future.result().results

    def get_parameters(self, *names) -> list:
        future = self.get_client.call_async(GetParameters.Request(names=list(names)))
        self.wait_for(future.done, 10.0, "get_parameters")
        return [parameter_value_to_python(v) for v in future.result().values]

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        if self._own_context:
            rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=2.0)


def path_end(path: Path) -> tuple[float, float, float]:
    p = path.poses[-1].pose.position
    return (p.x, p.y, p.z)


def goal_storm(client: PlannerClient, count: int, x0: float, period: float = 0.018,
               then=None):
    """Send ``count`` goals, one every ``period`` s, along x from ``x0``; wait for the last.

    ``then(since, last)``, if given, runs once all are sent, before the wait (``last``: the
    last goal's ``target`` value), e.g. to open a gate that holds the solves.

    Returns
    -------
    since : int
        Index of the first status of the storm in ``client.statuses``.
    sent : float
        Time taken to send them (s).
    status : Status
        The last goal's final status.
    total : float
        From the first goal to the last one's final status (s).
    """
    since = len(client.status_list())
    t0 = time.monotonic()
    for i in range(count):
        client.send_goal((x0 + 0.002 * i, 1.5))
        time.sleep(max(0.0, t0 + (i + 1) * period - time.monotonic()))
    sent = time.monotonic() - t0
    last = target_key((x0 + 0.002 * (count - 1), 1.5))
    if then is not None:
        then(since, last)
    status = client.final_status(since, 90.0, match=lambda s: s.values.get("target") == last)
    return since, sent, status, time.monotonic() - t0


def storm_events(client: PlannerClient, since: int) -> dict:
    """Count of each status event since index ``since``."""
    events = [s.event for s in client.status_list()[since:]]
    return {e: events.count(e) for e in sorted(set(events))}


def target_key(xy) -> str:
    """The ``target`` value of ``~/status`` for a planar target (as the node formats it)."""
    return "[" + ", ".join(f"{float(v):.9g}" for v in xy[:2]) + "]"


def close(a, b, tol: float) -> bool:
    return all(math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True))
