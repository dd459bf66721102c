"""Demo: the whole system on the paper's example, end to end.

``ros2 run tocontrol_ros demo`` (or ``tocontrol-demo``, ``python -m tocontrol_ros.demo``):

1. loads the arm and checks its dynamics;
2. starts the recorder, the planner and the tracker as separate processes (the same
   executables ``ros2 run`` starts; ROS parameters on their command lines, and
   ``--params-file`` for all three), and waits until the planner is ready and the recorder
   writes what the tracker streams (its ``~/status`` reports the first message of each
   topic), so that the recording holds every motion from its first instant;
3. asks the planner, on its ``~/plan`` service, for the paper's motion from (1.0, 1.0) to
   (2.2, 1.5) with k = 4 (configurations free, multistart);
4. the tracker (``start_at_first_trajectory``) puts the simulated arm at the plan's first
   configuration and executes the plan (nominal torques plus PD feedback); the demo then
   sends a goal back to the start on the planner's ``~/goal`` topic, which plans from the
   arm's measured state;
5. stops the recorder (SIGINT: the file is finished), writes the report from the recording
   alone (a figure per leg, a table, ``index.html``) and prints a summary table.

``--core-only`` skips ROS: model check plus one in-process plan, verified by
re-integration. ROS settings come from the environment (``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE``); ``scripts/dev demo`` sets them to stay on this machine.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET

DEFAULT_URDF = "galicki_3r.urdf"
#: Longest waits (s). The first planner start on a fresh machine compiles C (10-20 s).
READY_TIMEOUT = 240.0
PLAN_TIMEOUT = 120.0
RUN_TIMEOUT = 60.0
STOP_TIMEOUT = 20.0
#: --moving-target: goals per second, for how long (s), on a circle of this radius (m),
#: once around.
MOVING_RATE, MOVING_DURATION, MOVING_RADIUS = 10.0, 5.0, 0.15


def default_urdf_path():
    """Path of the bundled example arm (see ``core.robot.model.default_urdf_path``)."""
    from tocontrol_ros.core.robot.model import default_urdf_path as core_default

    return core_default()


def build_parser():
    """Return the demo's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="demo",
        description="Plan the paper's example, execute it on the simulated arm, record the "
        "run and report it (planner, tracker and recorder as separate processes).",
    )
    parser.add_argument("--urdf", type=Path, default=None, metavar="PATH",
                        help=f"URDF of the arm (default: the bundled config/{DEFAULT_URDF}); "
                        "with --core-only")
    parser.add_argument("--start", type=float, nargs="+", default=None, metavar="X",
                        help="start end-effector point (default: the paper's 1.0 1.0)")
    parser.add_argument("--target", type=float, nargs="+", default=None, metavar="X",
                        help="target end-effector point (default: the paper's 2.2 1.5)")
    parser.add_argument("--k", type=float, default=4.0,
                        help="convexification exponent k >= 1 (default 4)")
    parser.add_argument("--starts", type=int, default=16,
                        help="multistart seed pairs (default 16)")
    parser.add_argument("--out", type=Path, default=Path("runs"), metavar="DIR",
                        help="folder of the recording and its report (default runs/)")
    parser.add_argument("--params-file", type=Path, default=None, metavar="YAML",
                        help="ROS parameters file given to the recorder, planner and tracker "
                        "(sections 'recorder:', 'planner:', 'tracker:' or '/**:'), e.g. a "
                        "plant that differs from the model; the demo's own settings (output, "
                        "k, starts, ...) take precedence")
    parser.add_argument("--core-only", action="store_true",
                        help="no ROS: check the model and plan in this process")
    parser.add_argument("--moving-target", action="store_true",
                        help="after the first leg, a target moving along a circle through "
                        "the arm's position (goals at --rate Hz for --duration s); the arm "
                        "follows with replans spliced into the running motion; the report "
                        "draws the target's path against the end effector's")
    parser.add_argument("--rate", type=float, default=MOVING_RATE, metavar="HZ",
                        help=f"goals per second with --moving-target (default {MOVING_RATE:g})")
    parser.add_argument("--duration", type=float, default=MOVING_DURATION, metavar="S",
                        help="how long the target moves with --moving-target (default "
                        f"{MOVING_DURATION:g} s)")
    parser.add_argument("--radius", type=float, default=MOVING_RADIUS, metavar="M",
                        help="radius of the target's circle with --moving-target (default "
                        f"{MOVING_RADIUS:g} m)")
    return parser


def main(argv=None):
    """Run the demo (``tocontrol-demo``); returns the exit status, 0 on success.

    ``argv`` is the command line after the program name (``sys.argv[1:]`` if None).
    """
    args = build_parser().parse_args(argv)
    # Imported after argument parsing so that --help stays fast.
    from tocontrol_ros.core.robot.model import load_robot

    path = args.urdf if args.urdf is not None else default_urdf_path()
    if not os.path.isfile(path):
        raise SystemExit(f"demo: --urdf: no such file: {path}")
    model = load_robot(str(path))
    print(model.summary())
    print(model.check_dynamics())
    start = tuple(args.start) if args.start is not None else PAPER_START
    target = tuple(args.target) if args.target is not None else PAPER_TARGET
    if args.core_only:
        return _core_only(model, start, target, args.k, args.starts)
    if args.urdf is not None:
        raise SystemExit("demo: --urdf works with --core-only (the ROS pipeline runs the "
                         "nodes' own robot parameter)")
    if args.params_file is not None and not args.params_file.is_file():
        raise SystemExit(f"demo: --params-file: no such file: {args.params_file}")
    moving = None
    if args.moving_target:
        if not (args.rate > 0 and args.duration > 0 and args.radius > 0):
            raise SystemExit(f"demo: --rate, --duration and --radius must be > 0, got "
                             f"{args.rate:g}, {args.duration:g}, {args.radius:g}")
        moving = (args.rate, args.duration, args.radius)
    return _pipeline(start, target, args.k, args.starts, args.out, args.params_file, moving)


# --------------------------------------------------------------------- core only
def _core_only(model, start, target, k, starts) -> int:
    from tocontrol_ros.core.errors import ProblemError
    from tocontrol_ros.core.planning.solver import SolverOptions, plan
    from tocontrol_ros.core.types.problem import Problem, point

    try:
        problem = Problem(model, point(start), point(target), k=k)
    except ProblemError as exc:
        raise SystemExit(f"demo: {exc}") from exc
    print(f"\nplanning {list(start)} -> {list(target)} with k = {k:g}, {starts} starts "
          f"(the first run compiles the solver, about 15 s; later runs use the cache)")
    result = plan(problem, SolverOptions(starts=starts, candidates=min(3, starts)))
    print(f"  {result.status.name}: {result.message}")
    if not result.success:
        return 1
    ver = result.verification
    print(f"  T = {result.T:.6f} s   max |u_i| = {result.max_abs_u:.4f}   "
          f"BVP residual = {result.residual:.1e}   Newton iterations = {result.iterations}")
    print(f"  solve time {result.timings['total']:.2f} s (guess {result.timings['guess']:.2f}, "
          f"shooting {result.timings['shooting']:.2f}, refinement "
          f"{result.timings['refine']:.2f}, verification {result.timings['verify']:.2f})")
    print(f"  re-integration of the nominal torques: end point off by "
          f"{ver['point_error']:.1e} m, end speed {ver['velocity_error']:.1e} rad/s; "
          f"max |H| = {ver['max_abs_H']:.1e}")
    for warning in result.warnings:
        print(f"  warning: {warning}")
    return 0


# ---------------------------------------------------------------------- pipeline
class _Child:
    """One node process, its output kept in a log file."""

    def __init__(self, name: str, module: str, params: dict, log_dir: Path,
                 params_file: Path | None = None) -> None:
        self.name = name
        cmd = [sys.executable, "-m", module, "--ros-args", "-r", f"__node:={name}"]
        if params_file is not None:
            cmd += ["--params-file", str(params_file)]
        for key, value in params.items():
            cmd += ["-p", f"{key}:={_param_text(value)}"]
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT,
                                     env=dict(os.environ, PYTHONUNBUFFERED="1"))

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = STOP_TIMEOUT) -> int:
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        self._log.close()
        return self.proc.returncode

    def tail(self, lines: int = 15) -> str:
        self._log.flush()
        text = self.log_path.read_text(errors="replace").splitlines()
        return "\n".join(f"    {name_line}" for name_line in text[-lines:])


def _param_text(value) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_param_text(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


class _Listener:
    """The demo's own ROS node: status topics, the plan service, the goal topic."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticStatus
        from geometry_msgs.msg import PointStamped
        from nav_msgs.srv import GetPlan
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from trajectory_msgs.msg import JointTrajectory

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("tocontrol_demo", context=self.context)
        # Reentrant: wait_for holds it while predicates read the buckets.
        self.lock = threading.RLock()
        self.planner_status: list = []
        self.tracker_status: list = []
        self.recorder_status: list = []
        self.trajectories: list = []
        self.joint_states = 0
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        # The tracker keeps its last status events for late subscribers: discovery of a
        # new process can finish after its first (short) run has completed.
        history = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(DiagnosticStatus, "/planner/status",
                                      lambda m: self._add(self.planner_status, m), reliable)
        self.node.create_subscription(DiagnosticStatus, "/tracker/status",
                                      lambda m: self._add(self.tracker_status, m), history)
        # The recorder keeps its last 100 events for late subscribers.
        self.node.create_subscription(DiagnosticStatus, "/recorder/status",
                                      lambda m: self._add(self.recorder_status, m),
                                      QoSProfile(depth=100,
                                                 reliability=ReliabilityPolicy.RELIABLE,
                                                 durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.node.create_subscription(JointTrajectory, "/planner/trajectory",
                                      lambda m: self._add(self.trajectories, m), latched)
        self.node.create_subscription(JointState, "/joint_states", self._on_js, 50)
        self.goal_pub = self.node.create_publisher(PointStamped, "/planner/goal", 100)
        self.client = self.node.create_client(GetPlan, "/planner/plan")
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def _add(self, bucket: list, msg) -> None:
        with self.lock:
            bucket.append(msg)

    def _on_js(self, _msg) -> None:
        with self.lock:
            self.joint_states += 1

    def wait_for(self, predicate, timeout: float, children=()) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if predicate():
                    return True
            for child in children:
                if not child.alive():
                    raise RuntimeError(f"{child.name} exited early (status "
                                       f"{child.proc.returncode}); its log:\n{child.tail()}")
            time.sleep(0.05)
        return False

    def call_plan(self, start, target, frame: str, timeout: float):
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.srv import GetPlan

        if not self.client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError("the planner's ~/plan service did not appear")
        req = GetPlan.Request()
        req.start = PoseStamped()
        req.goal = PoseStamped()
        req.start.header.frame_id = req.goal.header.frame_id = frame
        req.start.pose.position.x, req.start.pose.position.y = start[:2]
        req.goal.pose.position.x, req.goal.pose.position.y = target[:2]
        future = self.client.call_async(req)
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.05)
        if not future.done():
            raise RuntimeError("the planner did not answer ~/plan in time")
        return future.result()

    def recorder_events(self, event: str) -> set:
        """Topics of the recorder's status events of kind `event`."""
        with self.lock:
            return {_values(s).get("topic") for s in self.recorder_status
                    if _values(s).get("event") == event}

    def recorder_topics(self) -> list | None:
        """The topics the recorder records (from its "started" event), or None before it."""
        with self.lock:
            started = [_values(s) for s in self.recorder_status
                       if _values(s).get("event") == "started"]
        return started[-1].get("topics", "").split(",") if started else None

    def goal_matches(self) -> tuple[int, int]:
        """Subscriptions of the goal topic matched by our publisher, and in the graph."""
        return self.goal_pub.get_subscription_count(), self.node.count_subscribers(
            "/planner/goal")

    def send_goal(self, target, frame: str) -> None:
        from geometry_msgs.msg import PointStamped

        msg = PointStamped()
        msg.header.frame_id = frame
        msg.point.x, msg.point.y = target[:2]
        self.goal_pub.publish(msg)

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self._thread.join(2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _values(status) -> dict:
    return {kv.key: kv.value for kv in status.values}


#: The tracker's streams (volatile): recorded from their first message only. The demo
#: starts no motion before the recorder has written one of each.
TRACKER_STREAMS = ("/joint_states", "/tracker/tracking_error")
#: Topics whose publishers exist before the first request (the planner's outputs, the demo's
#: goal publisher): the recorder must be subscribed to them before it.
PUBLISHED_BEFORE = ("/planner/trajectory", "/planner/status", "/planner/ee_path",
                    "/planner/markers", "/planner/goal")


def _await_recorder(listener: _Listener, recorder: _Child, children) -> None:
    """Wait until the recorder writes the tracker's streams and follows the other topics.

    A subscription alone is not enough: a volatile publisher sends nothing to it until its
    own side has matched it, so the first message written is the proof (the recorder's
    ``first_message`` event). Topics missing from the recorder's ``topics`` are not waited
    for.
    """
    if not listener.wait_for(lambda: listener.recorder_topics() is not None, READY_TIMEOUT,
                             children):
        raise RuntimeError(f"no status from the recorder in {READY_TIMEOUT:g} s:\n"
                           f"{recorder.tail()}")
    recorded = set(listener.recorder_topics())
    streams = recorded.intersection(TRACKER_STREAMS)
    outputs = recorded.intersection(PUBLISHED_BEFORE)

    def ready() -> bool:
        return (streams <= listener.recorder_events("first_message")
                and outputs <= listener.recorder_events("subscribed"))

    if not listener.wait_for(ready, READY_TIMEOUT, children):
        missing = sorted((streams - listener.recorder_events("first_message"))
                         | (outputs - listener.recorder_events("subscribed")))
        raise RuntimeError(f"the recorder did not record {missing} in {READY_TIMEOUT:g} s:\n"
                           f"{recorder.tail()}")


def _pipeline(start, target, k, starts, out_dir: Path, params_file: Path | None = None,
              moving: tuple | None = None) -> int:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    recording = out_dir / f"demo-{stamp}.mcap"
    log_dir = out_dir / f"demo-{stamp}_logs"
    log_dir.mkdir()
    print(f"\nROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '(unset: 0)')}, "
          f"ROS_AUTOMATIC_DISCOVERY_RANGE="
          f"{os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '(unset)')}; node logs in "
          f"{log_dir}")
    listener = _Listener()
    children: list[_Child] = []
    legs = []
    try:
        recorder = _Child("recorder", "tocontrol_ros.recorder", {"output": str(recording)},
                          log_dir, params_file)
        children.append(recorder)
        planner = _Child("planner", "tocontrol_ros.planner",
                         {"k": float(k), "starts": starts, "candidates": min(3, starts),
                          "sample_period": 0.002, "verify": True}, log_dir, params_file)
        children.append(planner)
        # Started now, not after the plan: the recorder must see the arm before it moves.
        # It takes the free-start plan's first configuration as its initial state.
        tracker = _Child("tracker", "tocontrol_ros.tracker",
                         {"start_at_first_trajectory": True}, log_dir, params_file)
        children.append(tracker)
        print("waiting for the planner (the first start on a machine compiles the solver, "
              "10-20 s) ...")
        # "ready" is a volatile status event: if discovery completes after it, the service
        # still answers once the warm-up is over, so wait for either.
        if not listener.wait_for(lambda: any(_values(s).get("event") == "ready"
                                             for s in listener.planner_status)
                                 or listener.client.service_is_ready(),
                                 READY_TIMEOUT, children):
            raise RuntimeError(f"the planner was not ready in {READY_TIMEOUT:g} s:\n"
                               f"{planner.tail()}")
        _await_recorder(listener, recorder, children)
        frame = "base_link"
        print(f"leg 1: ~/plan service, {list(start)} -> {list(target)}, k = {k:g}, "
              f"{starts} starts")
        t0 = time.monotonic()
        response = listener.call_plan(start, target, frame, PLAN_TIMEOUT + READY_TIMEOUT)
        if not response.plan.poses:
            last = listener.planner_status[-1].message if listener.planner_status else "?"
            raise RuntimeError(f"the planner returned an empty path: {last}")
        print(f"  answered in {time.monotonic() - t0:.2f} s with {len(response.plan.poses)} "
              f"path poses")
        if not listener.wait_for(lambda: listener.trajectories, 10.0, children):
            raise RuntimeError("no trajectory on /planner/trajectory")
        legs.append(_await_leg(listener, "leg 1 (service, free start)", 1, children))
        if moving is not None:
            _await_goal_subscribers(listener, children)
            legs.append(_moving_leg(listener, target, frame, moving, children))
        else:
            print(f"leg 2: ~/goal topic back to {list(start)}, from the arm's measured state")
            n_plans = len(listener.trajectories)
            _await_goal_subscribers(listener, children)
            listener.send_goal(start, frame)
            if not listener.wait_for(lambda: len(listener.trajectories) > n_plans, PLAN_TIMEOUT,
                                     children):
                raise RuntimeError("no new trajectory after the goal")
            legs.append(_await_leg(listener, "leg 2 (goal topic, from joint_states)", 2,
                                   children))
    except RuntimeError as exc:
        print(f"demo: {exc}", file=sys.stderr)
        for child in reversed(children):
            child.stop()
        listener.close()
        return 1
    # The recorder first, so that it records until the others stop publishing.
    codes = {child.name: child.stop() for child in children}
    js_count = listener.joint_states
    listener.close()
    print("\nprocesses stopped: " + ", ".join(f"{n} exit {c}" for n, c in codes.items()))
    from tocontrol_ros.recording import report

    print(f"\nreport from the recording {recording}:")
    report_dir = out_dir / f"demo-{stamp}_report"
    status = report.main([str(recording), "--out", str(report_dir)])
    _print_table(legs, recording, js_count)
    print(f"report page: {report_dir / 'index.html'}")
    return 0 if status == 0 and all(c == 0 for c in codes.values()) else 1


def _await_goal_subscribers(listener: _Listener, children) -> None:
    """Every subscription of the goal topic (planner, recorder) matched by our publisher.

    The goal is volatile: a subscription not yet matched never gets it.
    """
    if not listener.wait_for(lambda: 0 < listener.goal_matches()[1]
                             <= listener.goal_matches()[0], STOP_TIMEOUT, children):
        matched, wanted = listener.goal_matches()
        raise RuntimeError(f"the goal publisher matched {matched} of the {wanted} "
                           f"subscriptions of /planner/goal in {STOP_TIMEOUT:g} s")


def moving_goals(centre, radius: float, count: int) -> list[tuple[float, float]]:
    """``count`` goals once around a circle (m), starting at ``centre + (radius, 0)``."""
    import math

    return [(centre[0] + radius * math.cos(2 * math.pi * i / count),
             centre[1] + radius * math.sin(2 * math.pi * i / count)) for i in range(count)]


def _moving_leg(listener: _Listener, at, frame: str, moving: tuple, children) -> dict:
    """Goals along a circle through ``at`` (the arm's end point), sent at a fixed rate."""
    rate, duration, radius = moving
    count = max(int(round(rate * duration)), 1)
    goals = moving_goals((at[0] - radius, at[1]), radius, count)
    print(f"moving target: {count} goals at {rate:g} Hz on a circle of radius {radius:g} m "
          f"through {list(at)}")
    with listener.lock:
        since = len(listener.planner_status)
        runs = sum(s.message.startswith("trajectory ") and "outcome" in _values(s)
                   for s in listener.tracker_status)
        first_status = len(listener.tracker_status)
    t_next = time.monotonic()
    for goal in goals:
        t_next += 1.0 / rate
        listener.send_goal(goal, frame)
        time.sleep(max(0.0, t_next - time.monotonic()))
    final = ("solved", "failed", "superseded", "cancelled")

    def outcomes():
        return [s for s in listener.planner_status[since:] if _values(s).get("event") in final]

    if not listener.wait_for(lambda: len(outcomes()) >= count, PLAN_TIMEOUT, children):
        raise RuntimeError(f"moving target: {len(outcomes())} of {count} goals answered")
    with listener.lock:
        answered = [_values(s) for s in outcomes()]
    published = [v for v in answered if v.get("published") == "optimum"]
    kinds = {kind: sum(v.get("replan") == kind for v in published)
             for kind in ("warm", "rest", "cold")}

    def taken():
        # Published trajectories taken over, or replaced while waiting for their stamp by a
        # newer one stamped earlier (the tracker's event splice_replaced).
        return sum(s.message.startswith("executing trajectory")
                   or _values(s).get("event") == "splice_replaced"
                   for s in listener.tracker_status[first_status:])

    def last_done():
        # Every published trajectory taken over or replaced (a splice waits for its stamp),
        # the last one run to its end.
        started = taken()
        done = [s for s in listener.tracker_status if "outcome" in _values(s)]
        return (started >= len(published) and len(done) > runs
                and _values(done[-1]).get("outcome") == "completed")

    if not listener.wait_for(last_done, RUN_TIMEOUT, children):
        with listener.lock:
            started = taken()
            done = [_values(s).get("outcome") for s in listener.tracker_status
                    if "outcome" in _values(s)]
        raise RuntimeError(f"moving target: the tracker did not complete the last motion "
                           f"({started} of {len(published)} published trajectories taken over "
                           f"or replaced, run outcomes {done[runs:]})")
    with listener.lock:
        splices = [_values(s) for s in listener.tracker_status
                   if _values(s).get("event") == "spliced"]
        run = [s for s in listener.tracker_status if "outcome" in _values(s)][-1]
    jumps = (max((float(v["position_jump"]) for v in splices), default=0.0),
             max((float(v["velocity_jump"]) for v in splices), default=0.0))
    # Goal received -> trajectory published (the status's publish_latency; its latency
    # runs on to the status itself), as bench/replan.py reports it.
    latency = sorted(float(v["publish_latency"]) for v in published if "publish_latency" in v)
    median = latency[len(latency) // 2] if latency else float("nan")
    print(f"  {len(published)} of {count} goals got a trajectory (replans: {kinds}); "
          f"{len(splices)} splices, largest command jump {jumps[0]:.2e} rad, "
          f"{jumps[1]:.2e} rad/s; goal -> trajectory median {1e3 * median:.1f} ms")
    print(f"  last motion: {run.message}")
    plan_values = published[-1] if published else {}
    return {"label": "moving target (goal topic, replans)", "plan": plan_values,
            "run": _values(run)}


def _await_leg(listener: _Listener, label: str, count: int, children) -> dict:
    """Wait for the count-th completed tracker run; collect the planner's and tracker's data."""
    done = lambda: sum(s.message.startswith("trajectory completed")  # noqa: E731
                       for s in listener.tracker_status) >= count
    if not listener.wait_for(done, RUN_TIMEOUT, children):
        with listener.lock:
            seen = [s.message for s in listener.tracker_status]
        raise RuntimeError(f"{label}: the tracker did not complete the trajectory (its "
                           f"status messages: {seen}; {listener.joint_states} joint states)")
    with listener.lock:
        solved = [s for s in listener.planner_status if _values(s).get("event") == "solved"]
        run = [s for s in listener.tracker_status
               if s.message.startswith("trajectory completed")][count - 1]
    plan_values = _values(solved[-1]) if solved else {}
    run_values = _values(run)
    print(f"  {label}: {run.message}")
    return {"label": label, "plan": plan_values, "run": run_values}


def _fmt(value, spec: str) -> str:
    try:
        return format(float(value), spec)
    except (TypeError, ValueError):
        return "-"


def _print_table(legs: list, recording: Path, js_count: int) -> None:
    print("\nsummary")
    print(f"{'leg':<40}{'T (s)':>9}{'max|u|':>8}{'solve s':>9}{'EE err m':>10}"
          f"{'max e rad':>11}{'sat %':>7}")
    for leg in legs:
        p, r = leg["plan"], leg["run"]
        max_err = max((float(v) for key, v in r.items() if key.startswith("max_error")),
                      default=float("nan"))
        print(f"{leg['label']:<40}{_fmt(p.get('T'), '9.4f')}"
              f"{_fmt(p.get('max_abs_u'), '8.4f')}{_fmt(p.get('solve_time'), '9.2f')}"
              f"{_fmt(r.get('final_point_error'), '10.2e')}{_fmt(max_err, '11.2e')}"
              f"{_fmt(100 * float(r.get('saturated_fraction', 'nan')), '7.1f')}")
    print(f"recording: {recording} ({js_count} joint_states seen by the demo)")


if __name__ == "__main__":
    sys.exit(main())
