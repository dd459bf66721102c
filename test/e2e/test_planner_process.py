"""The planner as a separate process (its installed executable), driven by a client node.

Under ``scripts/dev`` the executable is ``<sys.prefix>/lib/tocontrol_ros/planner``, the
wrapper that ``ros2 run tocontrol_ros planner`` runs; elsewhere (a venv without the project
installed) ``python -m tocontrol_ros.planner`` from the source tree stands in.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from planner_harness import (
    FINAL_EVENTS,
    GOAL_BAD,
    PAPER_START,
    PAPER_TARGET,
    PARAM_BAD,
    SERVICE_BAD,
    PlannerClient,
    close,
    goal_storm,
    path_end,
    rss_kib,
    storm_events,
)

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.conversions import seconds

pytestmark = pytest.mark.ros
REPO = Path(__file__).resolve().parents[2]
GATE_SITE = REPO / "test" / "gate_site"
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0
#: test_goals_while_the_arm_moves_are_solved_and_executed: each goal this long (s) after the
#: tracker started the previous motion (T ~ 0.6 s): mid-motion, at speed.
MOVING_DELAY = 0.15
#: Storm bound (KiB): measured growth 1-4 MiB (allocator noise); one solve's result with its
#: messages is about 0.25 MiB (tracemalloc), so retaining that for each of 50 goals fails.
STORM_RSS_BOUND = 12 * 1024


def planner_command() -> tuple[list[str], dict]:
    exe = Path(sys.prefix) / "lib" / "tocontrol_ros" / "planner"
    if exe.is_file():
        return [str(exe)], {}
    if os.environ.get("TOCONTROL_DEV_VENV"):
        pytest.fail(f"{exe} is not installed (scripts/dev should have installed it)")
    return [sys.executable, "-m", "tocontrol_ros.planner"], {"PYTHONPATH": str(REPO)}


class PlannerProcess:
    """``planner --ros-args -r __ns:=<ns> -p ...`` in a subprocess, log in a file."""

    def __init__(self, tmp_path: Path, namespace: str, params: dict | None = None):
        cmd, extra_env = planner_command()
        # A solve gate the test can arm (test/solve_gate.py), through test/gate_site's
        # sitecustomize: the installed executable, with a test hook on its solves.
        self.gate = FileGate(tmp_path / f"gate{namespace.replace('/', '_')}")
        extra_env = dict(extra_env, TOCONTROL_TEST_SOLVE_GATE=str(self.gate.folder),
                         PYTHONPATH=os.pathsep.join(
                             filter(None, [str(GATE_SITE), extra_env.get("PYTHONPATH")])))
        args = ["--ros-args", "-r", f"__ns:={namespace}"]
        for name, value in (params or {}).items():
            args += ["-p", f"{name}:={value}"]
        # PYTHONFAULTHANDLER: a planner that hangs is sent SIGABRT (see stop()), and the
        # tracebacks of all its threads land in the log.
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   OPENBLAS_NUM_THREADS="1", PYTHONFAULTHANDLER="1", **extra_env)
        env.setdefault("ROS_DOMAIN_ID", "0")
        self.log_path = tmp_path / f"planner{namespace.replace('/', '_')}.log"
        self._log = open(self.log_path, "w")  # noqa: SIM115  (closed in stop())
        self.proc = subprocess.Popen(cmd + args, env=env, stdout=self._log,
                                     stderr=subprocess.STDOUT)
        self.name = f"{namespace}/planner"

    def log(self) -> str:
        return self.log_path.read_text()

    def stop(self, sig=signal.SIGINT, timeout: float = 10.0) -> tuple[int, float]:
        """Send ``sig``; return the exit code and the time to exit (s).

        A planner still running after ``timeout`` gets SIGABRT (its thread tracebacks go to
        the log, for the failure message), then SIGKILL.
        """
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                elapsed = time.monotonic() - t0
                self.proc.send_signal(signal.SIGABRT)
                try:
                    self.proc.wait(5.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(5.0)
                self._log.close()
                return self.proc.returncode, elapsed
        elapsed = time.monotonic() - t0
        self._log.close()
        return self.proc.returncode, elapsed


class FileGate:
    """The test's side of a planner process's solve gate (solve_gate.install_from_environment)."""

    def __init__(self, folder: Path):
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)

    def arm(self) -> None:
        for name in ("open", "held", "outcomes"):
            (self.folder / name).unlink(missing_ok=True)
        (self.folder / "armed").touch()

    def held(self) -> bool:
        return (self.folder / "held").exists()

    def open(self) -> None:
        (self.folder / "open").touch()

    def disarm(self) -> None:
        (self.folder / "armed").unlink(missing_ok=True)

    def outcomes(self) -> list[str]:
        path = self.folder / "outcomes"
        return path.read_text().split() if path.exists() else []


def _wait_warm(client: PlannerClient, proc: PlannerProcess, timeout: float = 120.0) -> None:
    try:
        client.wait_ready(timeout)
    except AssertionError:
        raise AssertionError(f"planner did not come up; its log:\n{proc.log()}") from None


@pytest.fixture(scope="module")
def process(tmp_path_factory):
    proc = PlannerProcess(tmp_path_factory.mktemp("e2e"), f"/e2e_{os.getpid()}")
    yield proc
    code, _ = proc.stop()
    assert code == 0, proc.log()


@pytest.fixture(scope="module")
def client(process):
    c = PlannerClient(process.name)
    _wait_warm(c, process)
    yield c
    c.close()


@pytest.fixture(scope="module")
def model():
    return load_robot(default_urdf_path())


def test_service_round_trip_paper_example(client, model):
    n = len(client.trajectories)
    path, status, elapsed = client.call_plan(PAPER_START, PAPER_TARGET)
    print(f"e2e round trip {elapsed:.3f} s; {status.message}")
    assert status.event == "solved", status.message
    assert close(path_end(path), PAPER_TARGET + (0.0,), 1e-6)
    # The trajectory agrees with the answer and the status: same T, ends at the target, at rest.
    msg = client.wait_for(lambda: len(client.trajectories) > n and client.trajectories[-1],
                          10.0, "trajectory")
    T = float(status.values["T"])
    assert seconds(msg.points[-1].time_from_start) == pytest.approx(T, abs=1e-9)
    # Integer nanoseconds: a float of an absolute stamp resolves only about 2e-7 s.
    end, begin = path.poses[-1].header.stamp, path.header.stamp
    assert ((end.sec - begin.sec) * 10**9 + end.nanosec - begin.nanosec) * 1e-9 == \
        pytest.approx(T, abs=1e-8)
    assert len(msg.points) == len(path.poses) == int(status.values["samples"])
    for point, pose in zip(msg.points, path.poses, strict=True):
        p = pose.pose.position
        np.testing.assert_allclose(model.point(np.array(point.positions)), [p.x, p.y],
                                   atol=1e-9)
    np.testing.assert_allclose(model.point(np.array(msg.points[-1].positions)), PAPER_TARGET,
                               atol=1e-7)
    np.testing.assert_allclose(msg.points[-1].velocities, 0.0, atol=1e-6)
    assert np.all(np.abs([p.effort for p in msg.points]) <= model.tau_max * (1 + 1e-9))


def test_goal_topic_from_joint_state(client):
    q, qd = [0.3, 1.0, -0.5], [0.2, 0.0, -0.1]
    client.wait_subscribed(client.joint_pub)
    client.wait_subscribed(client.goal_pub)
    for _ in range(5):
        client.send_joint_state(["joint1", "joint2", "joint3"], q, qd)
        time.sleep(0.02)
    since = len(client.status_list())
    client.send_goal((2.0, 2.0))
    status = client.final_status(since, 60.0)
    assert status.event == "solved", status.message
    np.testing.assert_allclose(status.vector("start_q"), q, atol=1e-12)
    np.testing.assert_allclose(status.vector("start_qd"), qd, atol=1e-12)


@pytest.mark.parametrize("case, start, goal, start_frame, goal_frame, fragment", SERVICE_BAD,
                         ids=[c[0] for c in SERVICE_BAD])
def test_bad_service_input(client, case, start, goal, start_frame, goal_frame, fragment):
    path, status, _ = client.call_plan(start, goal, start_frame, goal_frame, timeout=30.0)
    assert len(path.poses) == 0
    assert status.level == 2 and fragment in status.message, status.message


@pytest.mark.parametrize("case, goal, frame, fragment", GOAL_BAD, ids=[c[0] for c in GOAL_BAD])
def test_bad_goal_input(client, case, goal, frame, fragment):
    client.wait_subscribed(client.goal_pub)
    since = len(client.status_list())
    client.send_goal(goal, frame)
    status = client.final_status(since, 30.0)
    assert status.level == 2 and fragment in status.message, status.message


def test_joint_state_with_other_names_then_still_serving(client):
    client.wait_subscribed(client.joint_pub)
    for _ in range(5):
        client.send_joint_state(["a", "b", "c"], [0.0, 0.0, 0.0])
        time.sleep(0.02)
    path, status, _ = client.call_plan(None, PAPER_TARGET, start_frame="")
    assert len(path.poses) == 0 and status.level == 2
    assert "lacks the planner's joint(s)" in status.message
    path, status, _ = client.call_plan(PAPER_START, (2.1, 1.5))
    assert status.event == "solved" and len(path.poses) > 0


@pytest.mark.parametrize("values, fragment", PARAM_BAD, ids=[str(v) for v, _ in PARAM_BAD])
def test_parameter_rejected(client, values, fragment):
    (result,) = client.set_parameters(**values)
    assert not result.successful and fragment in result.reason, result.reason


def test_goal_storm(client, process):
    """50 goals within a second: alive afterwards, the last served, RSS growth bounded."""
    client.wait_subscribed(client.goal_pub)
    # Newest wins (goal_queue 1), the mode this storm covers; with the default queue every
    # goal is solved in turn (test/e2e/test_replan.py).
    assert all(r.successful for r in client.set_parameters(joint_state_timeout=0.0,
                                                           goal_queue=1))
    try:
        goal_storm(client, 10, 2.0)  # settles allocations first
        rss0 = rss_kib(process.proc.pid)
        # Each solve of the storm is held at its start (the process's solve gate) until a
        # newer goal supersedes it or, once the last goal is accepted, the test opens it.
        process.gate.arm()

        def open_once_the_last_is_accepted(since, last):
            client.wait_for(lambda: any(s.event == "accepted" and s.values.get("target") == last
                                        for s in client.status_list()[since:]),
                            HANG, "the last goal accepted")
            process.gate.open()

        since, sent, status, total = goal_storm(client, 50, 2.1,
                                                then=open_once_the_last_is_accepted)
        rss1 = rss_kib(process.proc.pid)
        events = storm_events(client, since)
        print(f"e2e storm: sent in {sent:.2f} s, last served after {total:.2f} s; {events}; "
              f"planner RSS {rss0} -> {rss1} KiB")
        # The premise, a storm: goals came faster than the node solves them (held), so some
        # were superseded.
        assert events.get("superseded", 0) > 0, events
        assert status.event == "solved", status.message
        accepted = events.get("accepted", 0)
        assert accepted >= 10
        client.wait_for(lambda: sum(v for k, v in storm_events(client, since).items()
                                    if k in FINAL_EVENTS) >= accepted, 10.0,
                        "an outcome per goal")
        assert rss1 - rss0 < STORM_RSS_BOUND
        assert process.proc.poll() is None
        assert client.get_parameters("k") == [4.0]
        path, status, _ = client.call_plan(PAPER_START, PAPER_TARGET)
        assert status.event == "solved"
    finally:
        process.gate.disarm()
        client.set_parameters(joint_state_timeout=1.0, goal_queue=50)


# SIGTERM takes the same path as SIGINT (node_main): slow, to keep the default run short.
@pytest.mark.parametrize("sig", [signal.SIGINT,
                                 pytest.param(signal.SIGTERM, marks=pytest.mark.slow)],
                         ids=["SIGINT", "SIGTERM"])
def test_shutdown_during_solve(tmp_path, sig):
    ns = f"/e2e_{os.getpid()}_{sig.name}"
    proc = PlannerProcess(tmp_path, ns)
    client = PlannerClient(proc.name)
    try:
        _wait_warm(client, proc)
        client.wait_subscribed(client.goal_pub)
        # Wait for the warm-up to finish: a goal then starts a solve at once, held at its
        # start by the process's solve gate until the signal stops it.
        client.wait_for(lambda: "ready after" in proc.log(), HANG, "ready")
        proc.gate.arm()
        client.send_goal(PAPER_TARGET)
        client.wait_for(proc.gate.held, HANG, "the goal's solve, held at the gate")
        # stop()'s own wait catches a hang (past it the process is aborted and its exit code
        # is not 0); a loaded machine stretches any time, so no bound on it is asserted.
        code, elapsed = proc.stop(sig, timeout=HANG)
        print(f"{sig.name} during a solve: exit {code} after {elapsed:.3f} s")
        log = proc.log()
        assert code == 0, f"exit {code} after {elapsed:.1f} s; log:\n{log}"
        assert "Traceback" not in log, log
        # The solve in flight was cancelled, not run to its end.
        assert proc.gate.outcomes() == ["CANCELLED"], log
    finally:
        client.close()
        if proc.proc.poll() is None:
            proc.stop(signal.SIGKILL)


def test_bad_robot_exits_with_reason(tmp_path):
    proc = PlannerProcess(tmp_path, f"/e2e_{os.getpid()}_bad", {"tip_link": "nowhere"})
    try:
        code = proc.proc.wait(60.0)
    finally:
        proc.stop(signal.SIGKILL)
    assert code == 1
    assert "tip link 'nowhere' is not a link" in proc.log()


# Two more processes started (a quarter of a minute under load): with the slow tests. The
# default run keeps SIGINT during a solve (test_shutdown_during_solve[SIGINT]) and the
# nodes' clean exit on SIGINT in the e2e fixtures that stop them (e.g. test_two_arms.py).
@pytest.mark.slow
def test_double_sigint_to_the_process_group_exits_cleanly(tmp_path):
    # Issue 14: Ctrl-C under `ros2 launch` (SIGINT to the whole group, then launch's own
    # SIGINT to each node) left KeyboardInterrupt tracebacks and exit code -2.
    ns = f"/sigint_{os.getpid()}"
    planner_cmd, planner_env = planner_command()
    tracker_cmd = [str(Path(sys.prefix) / "lib" / "tocontrol_ros" / "tracker")]
    if not Path(tracker_cmd[0]).is_file():
        tracker_cmd = [sys.executable, "-m", "tocontrol_ros.tracker"]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", **planner_env)
    logs = [open(tmp_path / f"{name}.log", "w+") for name in ("planner", "tracker")]  # noqa: SIM115
    args = ["--ros-args", "-r", f"__ns:={ns}"]
    first = subprocess.Popen(planner_cmd + args, env=env, stdout=logs[0],
                             stderr=subprocess.STDOUT, process_group=0)
    second = subprocess.Popen(
        tracker_cmd + args + ["-p", f"trajectory_topic:={ns}/planner/trajectory"], env=env,
        stdout=logs[1], stderr=subprocess.STDOUT, process_group=first.pid)
    procs = (first, second)
    client = PlannerClient(f"{ns}/planner")
    try:
        client.wait_ready(120.0)
        client.call_plan(PAPER_START, PAPER_TARGET)  # after the warm-up's builds
        # A request in flight when the signals come.
        client.plan_client.call_async(GetPlanRequest(PAPER_START, PAPER_TARGET))
        time.sleep(0.2)
        os.killpg(first.pid, signal.SIGINT)
        time.sleep(0.05)
        for proc in procs:
            proc.send_signal(signal.SIGINT)
        codes = [proc.wait(30.0) for proc in procs]
    finally:
        client.close()
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    texts = []
    for log in logs:
        log.seek(0)
        texts.append(log.read())
        log.close()
    assert codes == [0, 0], texts
    for text in texts:
        assert "Traceback" not in text and "KeyboardInterrupt" not in text, text


def GetPlanRequest(start, goal):  # noqa: N802  (reads like the message constructor)
    from nav_msgs.srv import GetPlan

    req = GetPlan.Request()
    req.start.header.frame_id = req.goal.header.frame_id = "base_link"
    req.start.pose.position.x, req.start.pose.position.y = start
    req.goal.pose.position.x, req.goal.pose.position.y = goal
    return req


# Slow: test_moving_target covers goals while the arm moves through both processes (replans).
@pytest.mark.slow
def test_goals_while_the_arm_moves_are_solved_and_executed(tmp_path):
    # Issue 14, defect 1 as a user saw it: with the tracker running, goals sent while the arm
    # moved were each superseded mid-solve (1 of 13 solved in 14 s).
    #
    # Each goal is sent while the arm executes the previous one (MOVING_DELAY after the
    # tracker starts it, T ~ 0.6 s) and after the planner answered the previous goal, so a
    # superseded goal means the moving arm interrupted a solve, not that a loaded machine
    # (two cores shared by several test runs) solved slower than goals came: with a goal
    # every 0.4 s regardless, the test failed about half the time under load, solves from
    # the moving arm taking 0.3-3 s there.
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    ns = f"/moving_{os.getpid()}"
    planner_cmd, planner_env = planner_command()
    tracker_cmd = [str(Path(sys.prefix) / "lib" / "tocontrol_ros" / "tracker")]
    if not Path(tracker_cmd[0]).is_file():
        tracker_cmd = [sys.executable, "-m", "tocontrol_ros.tracker"]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", **planner_env)
    args = ["--ros-args", "-r", f"__ns:={ns}"]
    logs = [open(tmp_path / f"{name}.log", "w+") for name in ("planner", "tracker")]  # noqa: SIM115
    # One start (the setting then).
    fast = ["-p", "starts:=1", "-p", "candidates:=1"]
    procs = [subprocess.Popen(planner_cmd + args + fast, env=env, stdout=logs[0],
                              stderr=subprocess.STDOUT),
             subprocess.Popen(tracker_cmd + args + [
                 "-p", f"trajectory_topic:={ns}/planner/trajectory"], env=env, stdout=logs[1],
                 stderr=subprocess.STDOUT)]
    client = PlannerClient(f"{ns}/planner")
    tracker_status = []
    client.node.create_subscription(
        DiagnosticStatus, f"{ns}/tracker/status", lambda m: tracker_status.append(m.message),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    goals = [(2.2, 1.5), (1.0, 1.0)] * 3
    finals = []
    try:
        client.wait_ready(120.0)
        client.call_plan(PAPER_START, PAPER_TARGET)  # after the warm-up's builds
        client.wait_subscribed(client.goal_pub)
        since = len(client.status_list())
        for i in range(len(goals) + 1):
            if i == len(goals):
                if finals[-1].event == "solved":
                    break
                # The tolerated failure fell on the last goal: one more, to show the node
                # still serves after it.
                goals.append(goals[-2])
            goal = goals[i]
            before = len(client.status_list())
            executing = sum("executing" in m for m in tracker_status)
            client.send_goal(goal)
            final = client.final_status(before, 60.0)
            finals.append(final)
            if final.event == "solved":  # the next goal arrives while this motion runs
                client.wait_for(lambda n=executing: sum("executing" in m
                                                        for m in tracker_status) > n,
                                30.0, "the tracker executing the motion")
                time.sleep(MOVING_DELAY)
        time.sleep(1.0)
    finally:
        client.close()
        for proc in procs:
            proc.send_signal(signal.SIGINT)
        codes = [proc.wait(30.0) for proc in procs]
        for log in logs:
            log.close()
    events = storm_events(client, since)
    print(f"planner events {events}; tracker: {tracker_status[-3:]}")
    for status in finals:  # to reproduce a failure in the core
        if status.event != "solved":
            print(status.event, status.message, {key: status.values.get(key) for key in
                                                 ("start_q", "start_qd", "target", "k")})
    # Every goal from the moving arm answered by its own solve; one numerical failure of a
    # single-start solve is tolerated: in core sweeps of 120 moving starts along these
    # motions (with and without 3 mrad of noise) 1 and 2 failed, CONTINUATION_FAILED where
    # the k = 1 optimum's branch ends before k = 4 (the 16-start default solves them). Such
    # a failure then falls back to the B-spline method, which since session 13 also solves
    # the one CI met (test_solver_stages.py, the continuation step from a wider barrier).
    assert [s.event for s in finals].count("solved") >= len(goals) - 1, events
    assert all(s.event in ("solved", "failed") for s in finals), events
    assert finals[-1].event == "solved", finals[-1].message
    # Each from the arm in motion: none is the trivial "nothing to plan" at rest.
    assert not [s.message for s in finals if "nothing to plan" in s.message]
    assert not [m for m in tracker_status if "rejected" in m], tracker_status
    assert sum("executing" in m for m in tracker_status) >= events["solved"]
    assert codes == [0, 0]
