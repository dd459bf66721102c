"""The nodes as deployed: planner and tracker as real processes, joint states flowing.

The planner (``python -P -m tocontrol_ros.planner``, the installed package) runs in a
namespace of its own, with ``warm_start:=false`` so that every call is the same cold solve.
Measured, side by side in one run:

- the planner's idle CPU (``/proc/<pid>/stat`` user + system time over a window, as a share
  of one core) with no tracker, and with the tracker publishing ``joint_states`` at 100 Hz
  and at 500 Hz (its ``publish_rate``);
- the round trip of ``~/plan`` on the paper's example (points, k = 4, the node's default
  solver options) from a client in this process, without and with the tracker running,
  against the same request served in this process (``Problem(...)`` from the two points,
  whose reachability check runs inverse kinematics, then ``Planner.plan`` with the same
  options): the ratio is what the node and DDS add.

Usage: ``scripts/dev run python -P bench/deployed.py`` (one section), or through
``bench/run_all.py`` (part ``deployed``).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import START, TARGET, Section, fmt_ms, log, table  # noqa: E402

#: Joint-state rates (Hz) of the idle measurement; 0 = no tracker.
RATES = (0, 100, 500)
#: Idle CPU window (s) and the settling time before it (s).
WINDOW = 8.0
SETTLE = 3.0
#: Targets (issue 14).
TARGET_IDLE = 2.0   # % of a core at 500 Hz
TARGET_RATIO = 1.2  # service round trip / in-process solve


def _cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _idle_cpu(pid: int, window: float) -> float:
    """Share of one core (%) that process ``pid`` used over ``window`` seconds."""
    c0, t0 = _cpu_seconds(pid), time.monotonic()
    time.sleep(window)
    return 100.0 * (_cpu_seconds(pid) - c0) / (time.monotonic() - t0)


class _Process:
    def __init__(self, module: str, args: list[str], log_path: Path,
                 env: dict | None = None) -> None:
        self._log = open(log_path, "w")  # noqa: SIM115  (closed in stop())
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", **(env or {}))
        self.proc = subprocess.Popen([sys.executable, "-P", "-m", module, *args], env=env,
                                     stdout=self._log, stderr=subprocess.STDOUT)
        self.pid = self.proc.pid

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(2)
            try:
                self.proc.wait(15.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


def prewarm_nodes(nodes: list[tuple[str, list[str], str]], workdir: Path, tag: str,
                  timeout: float = 1800.0) -> float:
    """Start ``nodes`` once with their optimised libraries built in the foreground, then stop them.

    A node's first start on a machine compiles its model's C code: quick builds at once and
    the optimised ones in the background, which a node living for minutes loads when they
    land (``~/status`` "optimised code loaded"). A benchmark's nodes live about a minute and
    their background builds die with them, so a fresh compile cache (``run_all.py``'s) would
    have them measured on the quick ``-O0`` builds with gcc running beside them: not the
    nodes as deployed. This launch (``TOCONTROL_COMPILE_TIERS=0``: every build optimised, in
    the foreground) fills the cache first.

    Parameters
    ----------
    nodes : list of (str, list of str, str)
        Per node its module (``tocontrol_ros.planner``), its arguments and a line of its log
        that says it is ready (``"ready after"``, ``"tracking on"``).
    workdir : Path
        Where the logs go (``{tag}_prewarm_{i}.log``).
    tag : str
        The logs' prefix.
    timeout : float
        Seconds to wait for every node's line (wall clock: the one bound of this loop).

    Returns
    -------
    float
        Seconds it took.

    Raises
    ------
    RuntimeError
        When a node exits or is not ready within ``timeout`` (naming it and its log).
    """
    t0 = time.monotonic()
    logs = [workdir / f"{tag}_prewarm_{i}.log" for i in range(len(nodes))]
    procs = [(_Process(module, args, log_path, env={"TOCONTROL_COMPILE_TIERS": "0"}), line,
              module) for (module, args, line), log_path in zip(nodes, logs, strict=True)]
    try:
        for (proc, line, module), log_path in zip(procs, logs, strict=True):
            while line not in log_path.read_text(errors="replace"):
                if proc.proc.poll() is not None:
                    raise RuntimeError(f"prewarm: {module} exited ({proc.proc.returncode}); "
                                       f"see {log_path}")
                if time.monotonic() - t0 > timeout:
                    raise RuntimeError(f"prewarm: {module} not ready in {timeout:.0f} s; "
                                       f"see {log_path}")
                time.sleep(0.5)
    finally:
        for proc, _, _ in procs:
            proc.stop()
    return time.monotonic() - t0


class RosClient:
    """A node of its own context in this process, spun by a thread of its own."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f"{name}_{os.getpid()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001  (context shut down at close)
            pass

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class _Client(RosClient):
    """A client node in this process: ~/plan calls."""

    def __init__(self, planner: str) -> None:
        from nav_msgs.srv import GetPlan

        super().__init__("bench_deployed")
        self.plan = self.node.create_client(GetPlan, f"{planner}/plan")
        self._request = GetPlan.Request()
        self._request.start.header.frame_id = self._request.goal.header.frame_id = "base_link"
        self._request.start.pose.position.x, self._request.start.pose.position.y = START
        self._request.goal.pose.position.x, self._request.goal.pose.position.y = TARGET

    def wait_ready(self, timeout: float = 180.0) -> None:
        """Service up and one call answered (after the warm-up's builds)."""
        if not self.plan.wait_for_service(timeout_sec=timeout):
            raise RuntimeError("the planner's ~/plan did not come up")
        self.call(timeout)

    def call(self, timeout: float = 60.0) -> tuple[float, int]:
        """One ~/plan call: (round trip in s, poses in the answer)."""
        t0 = time.perf_counter()
        future = self.plan.call_async(self._request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise RuntimeError("~/plan did not answer")
        return time.perf_counter() - t0, len(future.result().plan.poses)


def _in_process():
    """A function that serves the paper's example in this process; returns T (s)."""
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
    from tocontrol_ros.core.types.problem import Problem, point
    from tocontrol_ros.nodes.planner_config import (
        config_from_values,
        default_values,
        solver_options,
    )

    config = config_from_values(default_values(), task_dim=2)
    model = load_robot(default_urdf_path())
    planner = Planner(model)
    options = solver_options(config)

    def request() -> float:
        # What the node does for a call, without ROS: the problem (its reachability check
        # runs inverse kinematics for both points), then the solve.
        problem = Problem(model, point(START), point(TARGET), k=config.k,
                          reserve=config.reserve)
        return planner.plan(problem, options).T

    request()
    return request


def _interleaved(client: _Client, request, runs: int) -> tuple[list[float], list[float], float]:
    """``runs`` pairs (service call, in-process request), alternated so both see one load."""
    client.call()  # the first call after a change of load is not counted
    service, local, T = [], [], float("nan")
    for _ in range(runs):
        elapsed, poses = client.call()
        if poses < 2:
            raise RuntimeError("~/plan returned no plan for the paper's example")
        service.append(elapsed)
        t0 = time.perf_counter()
        T = request()
        local.append(time.perf_counter() - t0)
    return service, local, T


def _cell(values: list[float]) -> str:
    return (f"{fmt_ms(statistics.median(values))} ({fmt_ms(min(values))}-"
            f"{fmt_ms(max(values))})")


def run(runs: int = 10, window: float = WINDOW, workdir: Path | None = None) -> Section:
    """Measure; return the report section."""
    import tempfile

    workdir = Path(workdir or tempfile.mkdtemp(prefix="tocontrol-bench-deployed-"))
    ns = f"/bench_deployed_{os.getpid()}"
    request = _in_process()
    planner = _Process("tocontrol_ros.planner",
                       ["--ros-args", "-r", f"__ns:={ns}", "-p", "warm_start:=false"],
                       workdir / "planner.log")
    client = _Client(f"{ns}/planner")
    idle, tracker_cpu, service, local = {}, {}, {}, {}
    T = float("nan")
    tracker = None
    try:
        client.wait_ready()
        for rate in RATES:
            if tracker is not None:
                tracker.stop()
                tracker = None
            if rate:
                tracker = _Process(
                    "tocontrol_ros.tracker",
                    ["--ros-args", "-r", f"__ns:={ns}", "-p", f"publish_rate:={float(rate)}",
                     "-p", f"trajectory_topic:={ns}/planner/trajectory"],
                    workdir / f"tracker_{rate}.log")
            time.sleep(SETTLE)
            log(f"deployed: idle planner CPU at {rate} Hz joint_states")
            t0 = _cpu_seconds(tracker.pid) if tracker else 0.0
            w0 = time.monotonic()
            idle[rate] = _idle_cpu(planner.pid, window)
            tracker_cpu[rate] = (100.0 * (_cpu_seconds(tracker.pid) - t0)
                                 / (time.monotonic() - w0)) if tracker else 0.0
            log(f"deployed: ~/plan and in-process, alternated, at {rate} Hz ({runs} each)")
            service[rate], local[rate], T = _interleaved(client, request, runs)
    finally:
        if tracker is not None:
            tracker.stop()
        client.close()
        code = planner.stop()
    if code != 0:
        log(f"deployed: the planner exited with {code}; log in {workdir}")
    ratio = {rate: statistics.median(service[rate]) / statistics.median(local[rate])
             for rate in RATES}
    header = ["joint_states (Hz)", "planner CPU when idle (% of a core)",
              "tracker CPU (% of a core)", "~/plan round trip (ms)",
              "same request in-process (ms)", "ratio"]
    rows = [[f"{rate}" + (" (no tracker)" if rate == 0 else " (tracker)"),
             f"{idle[rate]:.1f}", f"{tracker_cpu[rate]:.1f}" if rate else "",
             _cell(service[rate]), _cell(local[rate]), f"{ratio[rate]:.2f}"]
            for rate in RATES]
    lines = [
        "Planner and tracker started as separate processes (`python -P -m "
        "tocontrol_ros.planner` / `tracker`, the installed package), the tracker publishing "
        "`joint_states` at its `publish_rate`. *CPU when idle*: user + system time of the "
        f"planner process over {window:g} s with no request, as a share of one core. "
        f"*Round trip*: median (min-max) of {runs} `~/plan` calls on the paper's example "
        f"(points, k = 4, T = {T:.6f} s, the node's default options, `warm_start:=false` so "
        "every call is the same cold solve) from a client in the benchmark process, "
        "alternated with the *same request in-process* (in the benchmark process, under "
        "the same load: `Problem(...)` from the two points, whose reachability check runs "
        "inverse kinematics, and `Planner.plan`, what a caller of the core does per "
        "request). The ratio of the medians is what the node (conversions, the published "
        "plan and markers, status) and DDS add. Timings on a shared machine: see the load "
        "and CPU steal above.",
        "",
    ]
    lines += table(header, rows)
    top = max(RATES)
    targets = [
        (f"idle planner with {top} Hz joint_states <= {TARGET_IDLE:g} % of a core",
         ("**yes**" if idle[top] <= TARGET_IDLE else "**no**") + f": {idle[top]:.1f} %"),
        (f"`~/plan` with the tracker running <= {TARGET_RATIO:g} x the same request "
         "in-process", _ratio_verdict([ratio[r] for r in RATES if r])),
    ]
    return Section("The nodes as deployed", lines, targets)


def _ratio_verdict(ratios: list[float]) -> str:
    worst = max(ratios)
    return ("**yes**" if worst <= TARGET_RATIO else "**no**") + \
        f": {', '.join(f'{r:.2f}' for r in ratios)} (100 Hz, 500 Hz)"


if __name__ == "__main__":
    section = run(runs=int(sys.argv[1]) if len(sys.argv) > 1 else 10)
    print("\n".join([f"## {section.title}", "", *section.lines, ""]))
    for target, verdict in section.targets:
        print(f"- {target}: {verdict}")
