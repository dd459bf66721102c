"""Cancel during a Panda plan through ``~/plan_motion``: the time to the result (issue 52).

One planner process (``python -P -m tocontrol_ros.planner``, the installed package) loads the
Panda of example-robot-data (``robot_description_file``, tip ``panda_hand``, its URDF limits,
which bind), ``warm_start:=false`` (every goal a cold solve); a client in this process sends
``tocontrol_msgs/action/PlanMotion`` goals (a joint-state start at rest to a point: the cases
of the best-motion section, :func:`bench.limits.draw_cases` with :mod:`bench.optimum_panda`'s
seed) and cancels each one ``DELAYS`` s after its acceptance (in turn). Measured per goal:
cancel request sent to result received (s), what the result returned, and when the planner's
worker had stopped the solve (the request's ``cancelled`` status on ``~/status``; the next
goal waits for it). A goal whose result
came before its cancel (the plan was faster) is counted apart. Two settings, alternated goal
by goal: the default ``publish: optimum`` (a cancel returns no motion: the optimum's solve
keeps none) and ``publish: first_then_optimum`` (the first motion, certified, returned).
The bar (issue 52): every cancel answered within 0.5 s.

Run alone: ``scripts/dev run python -P bench/cancel.py [CASES]`` (prints the section).
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, log, panda_urdf, table  # noqa: E402
from bench.deployed import RosClient, _Process  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED  # noqa: E402
from tocontrol_ros.nodes.plan_action import CANCEL_GRACE  # noqa: E402

#: Issue 52's bar: cancel to result (s).
BAR = 0.5
#: When the cancel is sent after the goal's acceptance (s), in turn.
DELAYS = (0.05, 0.15, 0.3)
#: Longest wait for one result (s): a hang, not a measurement.
HANG = 300.0
MODES = ("optimum", "first_then_optimum")


class _Client(RosClient):
    """``~/plan_motion`` goals to two planners (one per ``publish`` mode), and cancels."""

    def __init__(self, planners: dict[str, str]) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from tocontrol_msgs.action import PlanMotion

        from tocontrol_ros.nodes.action_calls import SerialActionClient

        super().__init__("bench_cancel")
        self.PlanMotion = PlanMotion
        self.clients = {mode: SerialActionClient(self.node, PlanMotion, f"{name}/plan_motion")
                        for mode, name in planners.items()}
        # The planners' final status of each cancelled request: when the solve stopped.
        self._stopped = {mode: [] for mode in planners}
        self._cond = threading.Condition()
        for mode, name in planners.items():
            self.node.create_subscription(
                DiagnosticStatus, f"{name}/status",
                lambda msg, mode=mode: self._on_status(mode, msg),
                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def _on_status(self, mode: str, msg) -> None:
        values = {kv.key: kv.value for kv in msg.values}
        if values.get("source") == "action" and values.get("event") == "cancelled":
            with self._cond:
                self._stopped[mode].append(time.perf_counter())
                self._cond.notify_all()

    def stopped_after(self, mode: str, since: float) -> float | None:
        """When the planner's worker reported the cancelled request stopped (after ``since``)."""
        with self._cond:
            self._cond.wait_for(lambda: any(t > since for t in self._stopped[mode]), HANG)
            later = [t for t in self._stopped[mode] if t > since]
        return min(later) if later else None

    def goal(self, q0, names, target):
        goal = self.PlanMotion.Goal(start_type=self.PlanMotion.Goal.START_JOINTS,
                                    target_type=self.PlanMotion.Goal.TARGET_POINT)
        goal.start_state.name = list(names)
        goal.start_state.position = [float(v) for v in q0]
        goal.target_point.header.frame_id = "panda_link0"
        p = goal.target_point.point
        p.x, p.y, p.z = (float(v) for v in target)
        return goal

    def run(self, mode: str, goal, delay: float | None) -> dict:
        """Send, cancel after ``delay`` s (None: never); the outcome and its times."""
        client = self.clients[mode]
        accepted, done = threading.Event(), threading.Event()
        box: dict = {}

        def on_result(future):
            box["result_at"] = time.perf_counter()
            box["response"] = future.result()
            done.set()

        def on_goal(future):
            box["handle"] = handle = future.result()
            box["accepted_at"] = time.perf_counter()
            accepted.set()
            client.get_result(handle).add_done_callback(on_result)

        client.send_goal(goal).add_done_callback(on_goal)
        if not accepted.wait(HANG):
            raise RuntimeError("the goal was not answered")
        if delay is not None and not done.wait(delay):
            box["cancel_at"] = time.perf_counter()
            client.cancel(box["handle"])
        if not done.wait(HANG):
            raise RuntimeError("no result")
        return box


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def run(count: int = 12) -> Section:
    title = "Cancel during a Panda plan through ~/plan_motion (issue 52)"
    found, urdf = robots().get("Panda"), panda_urdf()
    if found is None or urdf is None:
        return Section(title, ["example-robot-data is not installed: section skipped."], [])
    model, limits = found
    cases = draw_cases(model, limits, count, seed=SEED)
    workdir = Path(tempfile.mkdtemp(prefix="tocontrol-bench-cancel-"))
    ns = f"/bench_cancel_{os.getpid()}"
    common = ["-p", f"robot_description_file:={urdf}", "-p", "tip_link:=panda_hand",
              "-p", "warm_start:=false"]
    names = {mode: f"{ns}/{mode}/planner" for mode in MODES}
    procs = [_Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/{mode}",
                                                *common, "-p", f"publish:={mode}"],
                      workdir / f"{mode}.log") for mode in MODES]
    client = _Client(names)
    latencies = {mode: [] for mode in MODES}
    stops = {mode: [] for mode in MODES}
    plan_times = {mode: [] for mode in MODES}
    returned = {mode: 0 for mode in MODES}
    before = {mode: 0 for mode in MODES}
    rows = []
    try:
        for mode, action in client.clients.items():
            if not action.wait_for_server(HANG):
                raise RuntimeError(f"{names[mode]}/plan_motion did not come up")
            q0, _qd0, target = cases[0]
            client.run(mode, client.goal(q0, model.joint_names, target), None)  # warm-up
        for i, (q0, _qd0, target) in enumerate(cases):
            delay = DELAYS[i % len(DELAYS)]
            goal = client.goal(q0, model.joint_names, target)
            order = MODES if i % 2 == 0 else MODES[::-1]
            row = [str(i + 1), f"{delay:g}"]
            cells = {}
            for mode in order:
                full = client.run(mode, goal, None)  # the plan's own time, not cancelled
                plan_times[mode].append(full["result_at"] - full["accepted_at"])
                box = client.run(mode, goal, delay)
                result = box["response"].result
                if "cancel_at" not in box:
                    before[mode] += 1
                    cells[mode] = f"done before ({plan_times[mode][-1]:.2f} s)"
                    continue
                latency = box["result_at"] - box["cancel_at"]
                latencies[mode].append(latency)
                # The worker's own stop (the request's cancelled status), waited for so that
                # the next goal does not queue behind a solve still stopping.
                stopped = client.stopped_after(mode, box["cancel_at"])
                stop = stopped - box["cancel_at"] if stopped is not None else float("nan")
                stops[mode].append(stop)
                got = len(result.trajectory.points) > 0
                returned[mode] += got
                cells[mode] = (f"{latency * 1e3:.0f} ms, "
                               f"{'first motion' if got else 'none'} ({result.status}); "
                               f"solve stopped {stop * 1e3:.0f} ms")
            row += [f"{plan_times['optimum'][-1]:.2f}", cells["optimum"],
                    cells["first_then_optimum"]]
            rows.append(row)
            log(f"cancel {i + 1}/{count}: {cells}")
    finally:
        client.close()
        for proc in procs:
            proc.stop()
    every = latencies["optimum"] + latencies["first_then_optimum"]
    summary = []
    for mode in MODES:
        values = latencies[mode]
        if values:
            summary.append(f"`publish: {mode}`: {len(values)} cancelled during the plan, "
                           f"cancel to result median {statistics.median(values) * 1e3:.0f} ms, "
                           f"p95 {_pct(values, 0.95) * 1e3:.0f} ms, worst "
                           f"{max(values) * 1e3:.0f} ms; a motion returned in "
                           f"{returned[mode]}; {before[mode]} finished before the cancel; the "
                           f"solve itself stopped (its `cancelled` status) a median "
                           f"{statistics.median(stops[mode]) * 1e3:.0f} ms, worst "
                           f"{max(stops[mode]) * 1e3:.0f} ms after the cancel")
        else:
            summary.append(f"`publish: {mode}`: every plan finished before its cancel")
    lines = [
        f"Two planner processes on the Panda of example-robot-data (`tip_link:=panda_hand`, "
        f"its URDF limits, `warm_start:=false`), one with `publish: optimum` (the default), "
        f"one with `publish: first_then_optimum`. {count} goals each on `~/plan_motion` (a "
        f"joint-state start at rest to a point: the best-motion section's Panda cases), each "
        f"first planned to the end (its plan time below), then sent again and cancelled "
        f"{', '.join(f'{d:g}' for d in DELAYS)} s after its acceptance (in turn). Cancel to "
        f"result: the cancel request sent to the result received by the client (s); the "
        f"result waits at most `CANCEL_GRACE` = {CANCEL_GRACE:g} s for the solve to stop, then "
        f"goes with the best certified motion known at the cancel "
        f"(tocontrol_ros/nodes/plan_action.py). \"Solve stopped\": the cancel to the "
        f"planner's `cancelled` status of the request, when its worker is free again (the "
        f"solver's units that check the cancel seconds apart: docs/speed.md, \"Cancel\"). "
        f"The machine shared with other work. " + "; ".join(summary) + ". "
        f"Command: `scripts/dev run python -P bench/cancel.py {count}`.",
        "",
        *table(["case", "cancel after (s)", "plan (s, optimum)", "optimum: cancel to result",
                "first_then_optimum: cancel to result"], rows),
    ]
    worst = max(every) if every else float("nan")
    targets = [(f"issue 52: a cancel during a Panda plan answered within {BAR:g} s",
                ("**yes**" if every and worst <= BAR else "**no**")
                + f": worst {worst * 1e3:.0f} ms over {len(every)} cancels")]
    return Section(title, lines, targets)


if __name__ == "__main__":
    run(int(sys.argv[1]) if len(sys.argv) > 1 else 12).print()
