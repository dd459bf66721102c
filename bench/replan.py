"""On-line replanning as deployed (issue 33): a target moving at 10 Hz, planner and tracker as
processes, joint states flowing.

For each robot (the paper's arm; the Panda of example-robot-data with its URDF limits, tip
``panda_hand``), a planner and a tracker (``python -P -m tocontrol_ros.<node>``, default
parameters but the robot's) run in a namespace of their own. A client in this process sends
one goal at the circle's first point (the first motion from rest: a cold multistart, not
counted) and waits until the arm is there, then sends goals along a circle through it at
``RATE`` Hz for ``DURATION`` s (once around, about the arm's initial end-effector point),
without waiting for answers.

Measured, per robot: the share of goals that got a trajectory (their own ``solved`` status
with ``published: optimum``); the replan latency, goal received -> trajectory published (the
``publish_latency`` of each solved status: from the goal's callback to the trajectory's
publication; its ``latency``, to the status after it, is shown beside it), median and p95,
over all answered goals and per kind (``warm`` from the running motion's tail, ``rest`` from
the end of a motion that was over, ``cold``); the share published within one 100 ms
period; the tracker's splices and their largest command jumps; the end-effector error after
the target stopped (the last joint state against the last goal). Goals superseded by a newer
one while they waited (``goal_queue``) are counted apart. In this process, for the paper's
arm: what the replans' smoothing (``replan_smoothing``) costs in ``T`` on a circle's chain of
rest replans (:func:`smoothing_cost`).

With ``--moving`` (issue 47's hard case) the targets keep the arm moving: the paper's arm on
a circle of 0.3 m (goals 3.8 cm apart, 0.1 s apart: the arm is still on its way to one goal
when the next comes), the Panda from the README's own set-up ("Your own arm": its start
configuration, joints 1 and 3 aligned, the limit margin and sample period it gives the
planner, the tracker's own gains) on its 0.1 m circle. Beside the node's
own ``publish_latency``, the latency as a client sees it: the goal's publication in this
process -> its trajectory received here, matched by request (the solved status's ``target``
is the goal's, its ``handoff`` the trajectory's ``header.stamp``), not by arrival order; and
the share of the replans of each kind (``warm`` from a moving state, ``rest``, ``cold``).

Usage: ``scripts/dev run python -P bench/replan.py [paper|panda|both] [--moving]
[--on-callback]`` (default both, the easy circles; ``--on-callback``: the planner with
``replan_on_callback``, a goal's quick motion served on its callback's thread).
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, log, panda_urdf, table  # noqa: E402
from bench.deployed import RosClient, _Process, prewarm_nodes  # noqa: E402
from tocontrol_ros.nodes.trajectory_cdr import trajectory_stamp_ns  # noqa: E402

#: The issue's moving target: goals per second, for how long (s).
RATE, DURATION = 10.0, 5.0
#: One control period of the goal stream (s): a replan published within it kept up.
PERIOD = 0.1
#: Targets (issue 33): median replan latency (s).
TARGET_PAPER, TARGET_PANDA = 0.010, 0.020
#: At rest: the last 10 joint states within 1e-9 rad of each other, or when that does not
#: come within STILL_TIMEOUT s, within SETTLED (rad): the tracked Panda holds its last point
#: with a small limit cycle of its PD feedback (5e-5 rad measured). The final error is the
#: mean of those states' against the last goal.
SETTLED, STILL_TIMEOUT = 1e-4, 30.0
#: Waits (s).
READY_TIMEOUT, ANSWER_TIMEOUT, SETTLE_TIMEOUT = 400.0, 300.0, 120.0


class _Client(RosClient):
    """Goals out; planner and tracker status, joint states in."""

    def __init__(self, ns: str) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus
        from geometry_msgs.msg import PointStamped
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState

        super().__init__("bench_replan")
        self.lock = threading.Lock()
        self.planner, self.tracker, self.states = [], [], []
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(DiagnosticStatus, f"{ns}/planner/status",
                                      lambda m: self._add(self.planner, m), reliable)
        self.node.create_subscription(DiagnosticStatus, f"{ns}/tracker/status",
                                      lambda m: self._add(self.tracker, m), latched)
        self.node.create_subscription(JointState, f"{ns}/joint_states",
                                      lambda m: self._add(self.states, m), 10)
        from diagnostic_msgs.msg import DiagnosticArray

        #: The planner's ``joint_states`` diagnostic ("receiving ..." once it has a state: a
        #: goal sent before then starts from ``default_start``, msg_docs/joint_states_input.md).
        self.planner_states: list[str] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                      lambda m: self._on_diagnostics(f"{ns}/planner", m), 10)
        from trajectory_msgs.msg import JointTrajectory

        #: (header stamp ns, time received: time.monotonic()) of every trajectory, taken raw
        #: (the bytes as they arrive: rclpy's deserialization into message objects, which a
        #: client may do or not, is timed apart, :func:`deserialize_ms`).
        self.trajectories: list[tuple[int, float]] = []
        #: The bytes of every trajectory.
        self.trajectory_bytes: list[bytes] = []
        self.node.create_subscription(JointTrajectory, f"{ns}/planner/trajectory",
                                      self._on_trajectory, latched, raw=True)
        #: (task point, time sent: time.monotonic()) of every goal.
        self.sent: list[tuple[np.ndarray, float]] = []
        self.goals = self.node.create_publisher(PointStamped, f"{ns}/planner/goal", 100)
        self._Point = PointStamped

    def _on_diagnostics(self, planner: str, msg) -> None:
        for st in msg.status:
            if st.name == planner:
                value = {kv.key: kv.value for kv in st.values}.get("joint_states", "")
                with self.lock:
                    self.planner_states.append(value)

    def _on_trajectory(self, data: bytes) -> None:
        received = time.monotonic()
        stamp = trajectory_stamp_ns(data)
        with self.lock:
            self.trajectories.append((stamp, received))
            self.trajectory_bytes.append(data)

    def _add(self, bucket: list, msg) -> None:
        if hasattr(msg, "values"):
            msg = {"message": msg.message, **{kv.key: kv.value for kv in msg.values}}
        else:
            msg = list(msg.position)
        with self.lock:
            bucket.append(msg)

    def snapshot(self, name: str) -> list:
        with self.lock:
            return list(getattr(self, name))

    def wait(self, predicate, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = predicate()
            if value:
                return value
            time.sleep(0.02)
        raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")

    def send(self, point, frame: str, task=None) -> None:
        msg = self._Point()
        msg.header.frame_id = frame
        msg.point.x, msg.point.y, msg.point.z = (float(v) for v in (list(point) + [0.0])[:3])
        with self.lock:
            self.sent.append((np.asarray(point if task is None else task, dtype=float),
                              time.monotonic()))
        self.goals.publish(msg)


def _numbers(text: str) -> np.ndarray:
    """The numbers of a status value such as ``[1.2, 0.5]``."""
    return np.array([float(v) for v in re.findall(r"[-+]?[0-9.]+(?:e[-+]?[0-9]+)?", text)])


def deserialize_ms(data: list[bytes]) -> tuple[float, float]:
    """What rclpy's deserialization of these trajectories into message objects costs, and
    what the package's reader does (:func:`~tocontrol_ros.nodes.trajectory_cdr.
    read_trajectory_cdr`): medians over them (ms), each the least of 3 in this process."""
    from rclpy.serialization import deserialize_message
    from trajectory_msgs.msg import JointTrajectory

    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr

    def least(fn, item) -> float:
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            fn(item)
            times.append(time.perf_counter() - t0)
        return min(times)

    if not data:
        return float("nan"), float("nan")
    rclpy_ms = [1e3 * least(lambda b: deserialize_message(b, JointTrajectory), b) for b in data]
    reader_ms = [1e3 * least(read_trajectory_cdr, b) for b in data]
    return float(np.median(rclpy_ms)), float(np.median(reader_ms))


def client_latencies(sent: list, trajectories: list, published: list) -> list[float]:
    """Goal sent -> its trajectory received (s), per answered goal, matched by request.

    ``sent``: (task point, send time); ``trajectories``: (header stamp ns, receive time);
    ``published``: the solved statuses (``target``: the goal's point, ``handoff``: the
    trajectory's stamp, s with nine decimals). A goal sent twice at one point counts its
    last sending before the trajectory.
    """
    received = {}
    for stamp, t in trajectories:
        received.setdefault(stamp, t)
    out = []
    for status in published:
        if "handoff" not in status or "target" not in status:
            continue
        target = _numbers(status["target"])
        sec, _, frac = str(status["handoff"]).strip().partition(".")
        stamp = int(sec) * 1_000_000_000 + int((frac + "000000000")[:9])
        t_recv = received.get(stamp)
        times = [t for p, t in sent if len(p) == len(target)
                 and np.max(np.abs(p - target)) < 1e-6 and (t_recv is None or t <= t_recv)]
        if t_recv is not None and times:
            out.append(t_recv - times[-1])
    return out


#: The README's Panda set-up ("Your own arm"): its start configuration (joints 1 and 3
#: aligned) and gains; the moving-target run's circle of the paper's arm (m).
README_PANDA_Q0 = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
MOVING_PAPER_RADIUS = 0.3
#: The Panda's moving target: twice around a 0.25 m circle in 5 s (goals 6.3 cm apart, 0.75
#: m/s). On the 0.1 m circle once around (1.3 cm apart) the Panda reaches each goal in
#: 30-40 ms, long before the next: every replan started at rest.
MOVING_PANDA_RADIUS, MOVING_PANDA_LAPS = 0.25, 2


def _robot(name: str, moving: bool = False):
    """(model, planner/tracker arguments, frame, circle centre, radius, initial q) or None."""
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    if name == "paper":
        model = load_robot(default_urdf_path())
        q0 = np.array([0.3, 0.9, 0.6])
        return model, [], [], "base_link", model.point(q0), \
            MOVING_PAPER_RADIUS if moving else 0.15, q0
    urdf = panda_urdf()
    if urdf is None:
        return None
    model = load_robot(str(urdf), tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    # Inside the limits, away from the singular mid-range (joints 1 and 3 coaxial at
    # q2 = 0, where the held arm oscillates in the self-motion).
    q0 = np.array(README_PANDA_Q0 if moving else [0.3, -0.4, 0.2, -2.0, 0.1, 1.6, 0.5])
    robot = ["-p", f"robot_description_file:={urdf}", "-p", "tip_link:=panda_hand"]
    q_text = "[" + ",".join(f"{v:.6f}" for v in q0) + "]"
    tracker = ["-p", f"initial_positions:={q_text}"]
    if moving:  # the README's "Your own arm" as it reads (no joint_limits.yaml: the URDF's)
        robot += ["-p", "limit_margin:=0.05", "-p", "sample_period:=0.002", "-p",
                  "time_limit:=120.0"]
    else:  # the gains of the README's Panda before the tracker derived its own (issue 49)
        tracker += ["-p", "kp:=[10.0,20.0,13.0,10.0,2.4,4.0,0.5]",
                    "-p", "kd:=[0.47,0.91,0.6,0.49,0.11,0.19,0.023]"]
    return model, robot, tracker, "panda_link0", model.point(q0), \
        MOVING_PANDA_RADIUS if moving else 0.1, q0


def _circle(centre, radius: float, count: int, laps: int = 1) -> list:
    """``count`` points ``laps`` times around a circle about ``centre`` in the first two
    task axes, from ``centre + (radius, 0, ...)`` on."""
    out = []
    for a in np.linspace(0.0, 2.0 * math.pi * laps, count + 1)[:-1]:
        p = np.array(centre, dtype=float)
        p[0] += radius * math.cos(a)
        p[1] += radius * math.sin(a)
        out.append(p)
    return out


def _embed(model, p) -> list:
    """A task point as x, y, z (the task axes' coordinates; the others 0)."""
    out = [0.0, 0.0, 0.0]
    for axis, v in zip(model.task_axes, p, strict=True):
        out[axis] = float(v)
    return out


def _pct(values: list[float], q: float) -> float:
    return float(np.quantile(values, q)) if values else float("nan")


def measure(name: str, workdir: Path, planner_args: tuple = (), label: str = "",
            moving: bool = False) -> dict | None:
    """One robot's moving-target run; the figures, or None when the robot is missing.

    ``planner_args``: more ``-p name:=value`` arguments of the planner; ``label`` names
    them in the report and the run's files; ``moving``: the hard case (module docstring).
    """
    found = _robot(name, moving)
    if found is None:
        return None
    model, robot_args, tracker_args, frame, p0, radius, q0 = found
    laps = MOVING_PANDA_LAPS if moving and name == "panda" else 1
    ns = f"/bench_replan_{name}_{os.getpid()}"
    base = ["--ros-args", "-r", f"__ns:={ns}", *robot_args]
    tag = name + (f"_{label.replace(' ', '_')}" if label else "")
    planner_argv = [*base, *planner_args]
    tracker_argv = [*base, *tracker_args, "-p", f"trajectory_topic:={ns}/planner/trajectory"]
    # The nodes as deployed: their optimised libraries in the cache (bench/deployed.py's
    # prewarm_nodes), not a first start's quick builds with gcc beside them.
    prewarm = prewarm_nodes([("tocontrol_ros.planner", planner_argv, "ready after"),
                             ("tocontrol_ros.tracker", tracker_argv, "tracking on")],
                            workdir, tag)
    procs = [_Process("tocontrol_ros.planner", planner_argv, workdir / f"{tag}_planner.log"),
             _Process("tocontrol_ros.tracker", tracker_argv, workdir / f"{tag}_tracker.log")]
    client = _Client(ns)
    count = int(RATE * DURATION)
    goals = _circle(p0, radius, count, laps)
    try:
        # "ready" is a volatile status event, lost when discovery completes after it: its
        # log line says it too.
        log = workdir / f"{tag}_planner.log"
        client.wait(lambda: any(s.get("event") == "ready" for s in client.snapshot("planner"))
                    or "ready after" in log.read_text(), READY_TIMEOUT,
                    f"the {name} planner's warm-up")
        client.wait(lambda: client.goals.get_subscription_count() > 0 and
                    client.snapshot("states"), 30.0, "the goal subscription, joint states")
        # The planner's own joint states (its diagnostics), not only the client's: a first
        # goal before them was planned from default_start and rejected by the tracker.
        client.wait(lambda: any(v.startswith("receiving")
                                for v in client.snapshot("planner_states")), 30.0,
                    "the planner receiving joint states (its diagnostics)")
        # The first motion from rest to the circle (cold multistart): not counted.
        first = len(client.snapshot("planner"))
        client.send(_embed(model, goals[0]), frame, goals[0])
        client.wait(lambda: [s for s in client.snapshot("planner")[first:]
                             if s.get("event") in ("solved", "failed")], ANSWER_TIMEOUT,
                    "the first motion's plan")
        client.wait(lambda: any(s.get("outcome") == "completed"
                                for s in client.snapshot("tracker")), SETTLE_TIMEOUT,
                    "the first motion's end")
        since = len(client.snapshot("planner"))
        tracker0 = len(client.snapshot("tracker"))
        splices0 = len([s for s in client.snapshot("tracker") if s.get("event") == "spliced"])
        t_next = time.monotonic()
        for goal in goals[1:] + goals[:1]:  # once around, ending where it started
            t_next += 1.0 / RATE
            client.send(_embed(model, goal), frame, goal)
            time.sleep(max(0.0, t_next - time.monotonic()))
        final = ("solved", "failed", "superseded", "cancelled")
        outcomes = client.wait(
            lambda: (lambda f: f if len(f) >= count else None)(
                [s for s in client.snapshot("planner")[since:] if s.get("event") in final]),
            ANSWER_TIMEOUT, "an outcome for every goal")

        # Trajectories published: a quick motion's ("first" status) and an optimum's.
        published = sum(s.get("published") == "optimum" for s in outcomes) + sum(
            s.get("event") in ("first", "improved") and s.get("published") != "none"
            for s in client.snapshot("planner")[since:])

        def settled(spread: float):
            # Every published trajectory taken over (a splice waits for its stamp) or
            # dropped for a later one, the last run to its end, the arm at rest.
            states = client.snapshot("states")
            status = client.snapshot("tracker")[tracker0:]
            taken = [i for i, s in enumerate(status)
                     if s["message"].startswith("executing") or "rejected" in s["message"]
                     or s.get("event") == "splice_replaced"]
            done = [i for i, s in enumerate(status) if s.get("outcome") == "completed"]
            return (len(taken) >= published and done and done[-1] > taken[-1]
                    and len(states) > 10
                    and np.ptp(np.asarray(states[-10:]), axis=0).max() < spread)
        # At rest to rounding, or else (a limit cycle of the tracker's feedback) within
        # SETTLED; an arm that is neither is reported, not fatal.
        at_rest = True
        try:
            client.wait(lambda: settled(1e-9), STILL_TIMEOUT, "the arm still")
        except RuntimeError:
            try:
                client.wait(lambda: settled(SETTLED), SETTLE_TIMEOUT,
                            "the arm at rest after the last goal")
            except RuntimeError:
                at_rest = False
        states = client.snapshot("states")
        splices = [s for s in client.snapshot("tracker")
                   if s.get("event") == "spliced"][splices0:]
    finally:
        client.close()
        for proc in procs:
            proc.stop()
    answered = {s["request_id"] for s in outcomes if s.get("event") == "solved"
                and s.get("published") in ("optimum", "first")}
    improved = sum(s.get("event") == "improved" for s in client.snapshot("planner")[since:])
    # A goal's answer is its first trajectory: the quick motion's ("first" status, with
    # replan_quick) or else the optimum's ("solved").
    first_of = {}
    for s in client.snapshot("planner")[since:]:
        if s.get("request_id") in answered and s.get("publish_latency") is not None and \
                s.get("event") in ("first", "solved"):
            first_of.setdefault(s["request_id"], s)
    published = list(first_of.values())
    # Goal received -> trajectory published (the measure); the status follows it.
    latency = [float(s["publish_latency"]) for s in published]
    to_status = [float(s["latency"]) for s in published]
    # The solve itself (the published result's, last attempt) and the rest of the latency:
    # waiting for the worker (goals before it, a solve ahead), earlier attempts, publication.
    solve = [float(s["solve_time"]) for s in published if s.get("solve_time") is not None]
    seen = client_latencies(client.snapshot("sent"), client.snapshot("trajectories"),
                            published)
    (workdir / f"{tag}_outcomes.json").write_text(json.dumps(outcomes, default=str))
    (workdir / f"{tag}_statuses.json").write_text(
        json.dumps(client.snapshot("planner")[since:], default=str))
    (workdir / f"{tag}_tracker_statuses.json").write_text(
        json.dumps(client.snapshot("tracker"), default=str))
    kinds = {}
    for s in published:
        kinds.setdefault(s.get("replan", "none"), []).append(float(s["publish_latency"]))
    ee = np.asarray(model.point(np.mean(np.asarray(states[-10:]), axis=0)), dtype=float)
    return {
        "robot": name + (f" ({label})" if label else ""), "goals": count,
        "answered": len(published), "improved": improved,
        "failed": sum(s.get("event") == "failed" for s in outcomes),
        "superseded": sum(s.get("event") == "superseded" for s in outcomes),
        "median": _pct(latency, 0.5), "p95": _pct(latency, 0.95),
        "client_median": _pct(seen, 0.5), "client_p95": _pct(seen, 0.95),
        "client_matched": len(seen),
        "deserialize": deserialize_ms(client.snapshot("trajectory_bytes")[-count:]),
        "status_median": _pct(to_status, 0.5),
        "solve_median": _pct(solve, 0.5),
        "iterations_median": _pct([float(s["iterations"]) for s in published], 0.5),
        "within": sum(v <= PERIOD for v in latency) / count,
        "kinds": {k: (len(v), _pct(v, 0.5), _pct(v, 0.95)) for k, v in kinds.items()},
        "splices": len(splices),
        "jump_q": max((float(s["position_jump"]) for s in splices), default=float("nan")),
        "jump_qd": max((float(s["velocity_jump"]) for s in splices), default=float("nan")),
        "final_error": float(np.linalg.norm(ee - goals[0])), "at_rest": at_rest,
        "parts": latency_parts(published),
        # Hand-offs on a motion the arm ran late (or early): its start from the joint states.
        "lagged": [float(s["follow_lag"]) for s in published
                   if s.get("follow_lag") is not None and float(s["follow_lag"]) != 0.0],
        "late_splices": sum(s.get("late") == "true" for s in splices),
        "prewarm": prewarm,
    }


#: A quick motion's latency in parts, its status's values (s): acceptance -> the worker took
#: it, the hand-off, the problem, the solve's Newton steps, TOPP-RA and certificate (and the
#: rest of the solve: sampling and checks), the trajectory sampled, its message sent.
PARTS = ("wait_time", "handoff_time", "problem_time", "guess_time", "scaling_time",
         "verify_time", "solve_rest", "sample_time", "send_time")


def latency_parts(published: list) -> dict:
    """Median of each of :data:`PARTS` (s) over the quick motions' statuses, and their count.

    Also ``on_callback``: how many were served on the goal callback's thread (the worker
    idle, ``served_by``), ``unaccounted``: the median of each ``publish_latency`` minus the
    sum of its parts (what no part holds: the lines between them), ``sum_of_medians`` and
    ``median`` (of the ``publish_latency`` of the same statuses): a median of sums is not
    the sum of the medians when the parts' tails come on different goals.
    """
    quick = [s for s in published if s.get("event") == "first"
             and all(s.get(k) is not None for k in PARTS if k != "solve_rest")]
    out = {"count": len(quick),
           "on_callback": sum(s.get("served_by") == "goal callback" for s in quick)}

    def part(s: dict, key: str) -> float:
        if key == "solve_rest":
            return float(s["solve_time"]) - sum(float(s[k]) for k in
                                                ("guess_time", "scaling_time", "verify_time"))
        return float(s[key])

    for key in PARTS:
        out[key] = _pct([part(s, key) for s in quick], 0.5)
    out["unaccounted"] = _pct([float(s["publish_latency"]) - sum(part(s, k) for k in PARTS)
                               for s in quick], 0.5)
    out["sum_of_medians"] = sum(out[k] for k in PARTS)
    out["median"] = _pct([float(s["publish_latency"]) for s in quick], 0.5)
    return out


def _rest_chain(name: str, count: int, variants: dict) -> tuple[float, list] | None:
    """The moving-target circle's rest chain, replanned in this process.

    ``name``'s circle (:func:`_robot`, :func:`_circle`), its first ``count`` + 1 goals:
    each problem from rest at the last goal's end (as the node's rest replans) is planned
    with the default options (the reference, and the next problem's warm start), and
    replanned warm from the last reference with each of ``variants`` (key -> options),
    timed one after the other.

    Returns
    -------
    (float, list) or None
        The circle's radius (m) and, per replan, ``(reference T or nan, {key: (certified,
        T or nan, iterations, seconds)})``; None when the robot is missing.
    """
    import time

    from tocontrol_ros.core.planning.replan import warm_replan
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.types.options import SolverOptions
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    found = _robot(name)
    if found is None:
        return None
    model, _, _, _, p0, radius, q = found
    planner = Planner(model)
    goals = _circle(p0, radius, int(RATE * DURATION))[:count + 1]
    last = planner.plan(Problem(model, joint_state(q, np.zeros(model.n)), point(goals[0]),
                                k=4), SolverOptions())
    rows = []
    for goal in goals[1:]:
        q = last.trajectory.state(last.T)[0][:model.n]
        problem = Problem(model, joint_state(q, np.zeros(model.n)), point(goal), k=4)
        ref = planner.plan(problem, SolverOptions())
        out = {}
        for key, opts in variants.items():
            t0 = time.perf_counter()
            r = warm_replan(planner, problem, [last], opts)
            elapsed = time.perf_counter() - t0
            certified = r.success and r.certificate is not None and r.certificate.passed
            out[key] = (certified, r.T if certified else float("nan"), r.iterations, elapsed)
        rows.append((ref.T if ref.success else float("nan"), out))
        last = ref  # the chain goes on from the reference
    return radius, rows


#: Final smoothings of replans compared in :func:`smoothing_cost` (0: the full schedule).
SMOOTHINGS = (1e-2, 3e-3, 1e-3, 0.0)


def smoothing_cost(count: int = 49) -> list[str]:
    """What ``replan_smoothing`` costs in ``T``, in this process: the paper's arm at k = 4.

    :func:`_rest_chain` of ``count`` replans at every smoothing of :data:`SMOOTHINGS`;
    ``T`` against the full schedule's (0). Markdown lines.
    """
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.types.options import SolverOptions

    radius, rows = _rest_chain("paper", count, {d: replan_options(SolverOptions(), d)
                                                for d in SMOOTHINGS})
    rows = [out for _, out in rows]
    table_rows = []
    for d in SMOOTHINGS:
        both = [r for r in rows if r[d][0] and r[0.0][0]]
        excess = [(r[d][1] - r[0.0][1]) / r[0.0][1] for r in both]
        table_rows.append([f"{d:g}", f"{sum(r[d][0] for r in rows)}/{len(rows)}",
                           f"{np.median(excess):.1e}" if excess else "-",
                           f"{np.max(excess):.1e}" if excess else "-",
                           f"{np.median([r[d][2] for r in rows if r[d][0]]):.0f}"])
    return ["", f"What the replans' smoothing costs (`replan_smoothing`, in one process): "
            f"the paper's arm at k = 4, the rest chain of a circle of {count + 1} goals "
            f"({radius:g} m radius), each problem replanned warm from the last default plan "
            f"at each smoothing; `T` above the full schedule's (0), relative.", "",
            *table(["replan_smoothing", "certified", "T excess median", "T excess max",
                    "Newton iterations median"], table_rows)]


#: ``replan_spans`` compared by :func:`spans_cost` (0: the warm start's own refined mesh).
SPAN_COUNTS = (0, 16, 24, 32)


def spans_cost(count: int = 12) -> list[str] | None:
    """What ``replan_spans`` costs and saves, in this process: the Panda with its limits.

    :func:`_rest_chain` of ``count`` replans at each of :data:`SPAN_COUNTS`; ``T`` against
    the default plan's, and the time of the warm replan. Markdown lines, or None without
    example-robot-data.
    """
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.types.options import SolverOptions

    # (The smoothing is the maximum principle's: bounded solves have none.)
    chain = _rest_chain("panda", count, {s: replan_options(SolverOptions(), 0.0, s)
                                         for s in SPAN_COUNTS})
    if chain is None:
        return None
    rows = chain[1]
    table_rows = []
    for spans in SPAN_COUNTS:
        ok = [(t_ref, o[spans]) for t_ref, o in rows if o[spans][0] and np.isfinite(t_ref)]
        excess = [(r[1] - t_ref) / t_ref for t_ref, r in ok]
        times = [o[spans][3] for _, o in rows]
        table_rows.append([f"{spans}" + (" (the warm start's mesh)" if spans == 0 else ""),
                           f"{sum(o[spans][0] for _, o in rows)}/{len(rows)}",
                           f"{np.median(excess):+.1e}" if excess else "-",
                           f"{np.max(excess):+.1e}" if excess else "-",
                           f"{1e3 * np.median(times):.0f} / {1e3 * np.max(times):.0f}"])
    return ["", f"What `replan_spans` costs and saves (in one process): the Panda with its "
            f"limits, the rest chain of the circle's first {count + 1} goals (1.3 cm apart), "
            f"each problem planned with the default options (the reference) and replanned "
            f"warm from the last reference (its refined mesh) at each `replan_spans`; `T` "
            f"against the reference's, relative; time of the warm replan, median / max.", "",
            *table(["replan_spans", "certified", "T excess median", "T excess max",
                    "ms median / max"], table_rows)]


def run(which: str = "both", moving: bool = False, planner_args: tuple = ()) -> Section:
    title = ("Replanning: targets that keep the arm moving, 10 Hz, nodes as deployed "
             "(issue 47)" if moving else
             "Replanning: a target moving at 10 Hz, nodes as deployed (issue 33)")
    workdir = Path(tempfile.mkdtemp(prefix="tocontrol-bench-replan-"))
    names = ("paper", "panda") if which == "both" else (which,)
    results = []
    # The paper's arm also with newest wins (goal_queue 1; the default queues every goal).
    runs = [(name, planner_args, "") for name in names]
    if "paper" in names and not moving:
        runs.insert(1, ("paper", ("-p", "goal_queue:=1"), "goal_queue 1"))
    for name, planner_args, label in runs:
        log(f"replan: {name} {label} ...")
        out = measure(name, workdir, planner_args, label, moving)
        if out is None:
            log(f"replan: {name} skipped (example-robot-data is not installed)")
            continue
        results.append(out)
        log(f"replan {name} {label}: {out}")
    rows = []
    for r in results:
        kinds = "; ".join(f"{k} {n}: {1e3 * m:.1f} / {1e3 * p:.1f} ms"
                          for k, (n, m, p) in sorted(r["kinds"].items()))
        lagged = r.get("lagged", [])
        kinds += f"; followed late {len(lagged)}" + (
            f" (lag up to {1e3 * max(lagged, key=abs):.0f} ms)" if lagged else "")
        kinds += f"; late splices {r.get('late_splices', 0)}"
        rows.append([r["robot"], f"{r['answered']}/{r['goals']} ({r['superseded']} "
                     f"superseded; {r['improved']} improved)",
                     f"{1e3 * r['median']:.1f} ({1e3 * r['status_median']:.1f})",
                     f"{1e3 * r['p95']:.1f}",
                     f"{1e3 * r['client_median']:.1f} / {1e3 * r['client_p95']:.1f} "
                     f"({r['client_matched']}; deserialization {r['deserialize'][0]:.2f}, "
                     f"reader {r['deserialize'][1]:.2f})", f"{100 * r['within']:.0f} %",
                     f"{1e3 * r['solve_median']:.1f}", f"{r['iterations_median']:.0f}", kinds,
                     f"{r['splices']}", f"{r['jump_q']:.1e} / {r['jump_qd']:.1e}",
                     f"{r['final_error']:.1e}" + ("" if r["at_rest"] else
                                                    f" (not at rest after {SETTLE_TIMEOUT:g} s)")])
    lines = [
        f"Planner and tracker as processes (default parameters but the robot's; the Panda "
        f"with its URDF limits), started once before with every build optimised in the "
        f"foreground and stopped, so that the measured nodes find their optimised libraries "
        f"in the compile cache as a deployed node does after its first start (without it "
        f"`run_all.py`'s fresh cache had them run on the quick `-O0` builds with gcc beside "
        f"them; bench/deployed.py's `prewarm_nodes`), a client sending goals along a "
        f"circle at {RATE:g} Hz for "
        f"{DURATION:g} s after a first, uncounted motion onto it. Latency: goal received by "
        f"the planner -> trajectory published (its status's `publish_latency`; in parentheses "
        f"its `latency`, to the status that follows), over the goals answered; "
        f"within one period: published within {1e3 * PERIOD:.0f} ms, share of all goals. "
        f"A goal's answer is its first trajectory: with `replan_quick` (the default) the "
        f"quick motion published at once; *improved*: the goals whose optimum followed it "
        f"(msg_docs/parameters.md, 'Replanning'). "
        f"Solve ms, iterations: the first published result's own solve time and iterations "
        f"(TOPP-RA passes for a quick motion), median (the rest of a latency is waiting for "
        f"the worker, the hand-off and the problem, and publication). Per kind: count, "
        f"median / p95 (kind of the first publication's hand-off: `rest` from the end of a "
        f"motion over by then, `warm` or `cold` from a moving state, `held` from the arm's "
        f"measured state held still off the last motion, `none` a new motion from the "
        f"measured state: the cold multistart); *followed late*: hand-offs on a motion the "
        f"arm started later (or earlier) than its stamp, as its joint states showed, and the "
        f"largest such lag; *late splices*: trajectories the tracker joined after their "
        f"stamp. "
        f"Jumps: the tracker's largest command jump at a splice (rad / rad/s). Final "
        f"error: end effector at rest (the mean of the last 10 joint states, within 1e-9 "
        f"rad of each other, or within {SETTLED:g} rad when that did not come in "
        f"{STILL_TIMEOUT:g} s) against the last goal (m)."
        f" Client: goal published in the client -> its trajectory received there (a raw "
        f"subscription: the message's bytes as they arrive, its stamp read from them), "
        f"matched by request (status target and hand-off stamp), median / p95 over the "
        f"matched; a client that turns them into rclpy's message objects adds their "
        f"deserialization, in parentheses (median over the same trajectories, timed in the "
        f"benchmark's process after the run), then what the package's reader "
        f"(`tocontrol_ros.nodes.trajectory_cdr.read_trajectory_cdr`, which the tracker uses) "
        f"takes instead."
        + (f" Hard case: the paper's arm on a {MOVING_PAPER_RADIUS:g} m circle, the Panda "
           f"as the README's \"Your own arm\" sets it up (start configuration with joints 1 and 3 "
           f"aligned, limit margin 0.05, sample period 2 ms, the tracker's derived gains), "
           f"its target {MOVING_PANDA_LAPS} times around a {MOVING_PANDA_RADIUS:g} m circle "
           f"(goals {100 * 2 * math.pi * MOVING_PANDA_RADIUS * MOVING_PANDA_LAPS / 50:.1f} cm "
           f"apart: on a 0.1 m circle once around every replan started at rest)."
           if moving else "")
        + f" Command: `scripts/dev run python -P bench/replan.py {which}"
        + (" --moving`." if moving else "`."),
        "",
        *table(["robot", "answered", "median ms", "p95 ms", "client median / p95 ms (matched)",
                "within 100 ms", "solve ms",
                "iterations", "per kind",
                "splices", "jumps", "final error m"], rows),
    ]
    if moving:
        lines += ["", "Where a quick motion's latency goes (its status's values, median over "
                  "the goals answered by one, ms; *unaccounted*: the median of each latency "
                  "minus its parts; then the parts' medians summed against the latencies' "
                  "median: docs/speed.md, \"A paper replan's latency through the nodes\"): "
                  + "; ".join(
                      f"{r['robot']} ({r['parts']['count']}, "
                      f"{r['parts']['on_callback']} on the goal's callback): " + ", ".join(
                          f"{k.removesuffix('_time')} {1e3 * r['parts'][k]:.1f}"
                          for k in (*PARTS, "unaccounted"))
                      + f" (sum {1e3 * r['parts']['sum_of_medians']:.1f} against median "
                      f"{1e3 * r['parts']['median']:.1f})" for r in results) + "."]
    if "paper" in names and not moving:
        log("replan: the smoothing's cost in T ...")
        lines += smoothing_cost()
    if "panda" in names and not moving:
        log("replan: the Panda's replan_spans ...")
        lines += spans_cost() or []
    targets = []
    for r in results:
        goal = TARGET_PAPER if r["robot"].startswith("paper") else TARGET_PANDA
        targets.append((f"{r['robot']}: median replan latency <= {1e3 * goal:.0f} ms",
                        ("**yes**" if r["median"] <= goal else "**no**")
                        + f": {1e3 * r['median']:.1f} ms (client {1e3 * r['client_median']:.1f}"
                        f" ms)"))
        if moving:
            share = r["answered"] / r["goals"]
            targets.append((f"{r['robot']}: >= 95 % of goals answered",
                            ("**yes**" if share >= 0.95 else "**no**")
                            + f": {r['answered']}/{r['goals']}"))
            if not r["robot"].startswith("paper"):
                targets.append((f"{r['robot']}: p95 <= 60 ms",
                                ("**yes**" if r["p95"] <= 0.060 else "**no**")
                                + f": {1e3 * r['p95']:.1f} ms"))
    return Section(title, lines, targets)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a not in ("--moving", "--on-callback")]
    which = args[0] if args else "both"
    if which not in ("paper", "panda", "both") or len(args) > 1:
        raise SystemExit(f"usage: bench/replan.py [paper|panda|both] [--moving] "
                         f"[--on-callback], got {sys.argv[1:]!r}")
    # --on-callback: the planner with replan_on_callback (docs/speed.md, fifth pass)
    section = run(which, "--moving" in sys.argv[1:],
                  ("-p", "replan_on_callback:=true") if "--on-callback" in sys.argv[1:] else ())
    print("\n".join(section.lines))
    for target, verdict in section.targets:
        print(f"- {target}: {verdict}")
