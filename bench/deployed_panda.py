"""The Panda through the planner node as deployed: ``~/plan`` round trips, one core or all.

Two planner processes (``python -P -m tocontrol_ros.planner``, the installed package) load
the Panda of example-robot-data (``robot_description_file``, tip ``panda_hand``, its URDF
limits, which bind), ``warm_start:=false`` so that every call is a cold solve, the node's
default solver options otherwise; one with ``workers:=1`` (everything in the planner's
process), one with the default ``workers`` (0: one per core). A client in this process calls
``~/plan`` (nav_msgs/GetPlan) with the start and goal points of the best-motion section's
Panda cases (:func:`bench.limits.draw_cases`, seed of :mod:`bench.optimum_panda`: the
end-effector point of each drawn start configuration to the drawn target), alternating the
two planners case by case (who goes first alternates too), so both see the same load. One
call per planner first, not counted (compile cache, worker start).

Printed: per case the round trip (request sent to response received) of each planner and
whether both returned the same path (every pose equal); the medians, the worst, and the
paired ratio. Run alone: ``scripts/dev run python -P bench/deployed_panda.py [CASES]``.
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

#: Targets of issue 32 for the default Panda plan through the node (two cores).
TARGET_MEDIAN = 1.0
TARGET_WORST = 2.0


class _Client(RosClient):
    """``~/plan`` calls to several planners from one node in this process."""

    def __init__(self, planners: list[str]) -> None:
        from nav_msgs.srv import GetPlan

        super().__init__("bench_deployed_panda")
        self._GetPlan = GetPlan
        self.clients = {name: self.node.create_client(GetPlan, f"{name}/plan")
                        for name in planners}

    def call(self, name: str, start, goal, timeout: float = 300.0) -> tuple[float, tuple]:
        """One call: (round trip in s, the returned poses as tuples)."""
        request = self._GetPlan.Request()
        request.start.header.frame_id = request.goal.header.frame_id = "panda_link0"
        for pose, p in ((request.start.pose, start), (request.goal.pose, goal)):
            pose.position.x, pose.position.y, pose.position.z = (float(v) for v in p)
        done = threading.Event()
        t0 = time.perf_counter()
        future = self.clients[name].call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise RuntimeError(f"{name}/plan did not answer")
        elapsed = time.perf_counter() - t0
        poses = tuple((p.pose.position.x, p.pose.position.y, p.pose.position.z)
                      for p in future.result().plan.poses)
        return elapsed, poses


def _prewarm(ns: str, common: list[str], case: tuple, workdir: Path) -> float:
    """One plan on a planner whose every build is optimised in the foreground, then stop it.

    The measured nodes then find the optimised libraries of a plan in the compile cache, as
    a deployed node does after its first plans: without it, ``run_all.py``'s fresh cache had
    them plan on the quick ``-O0`` builds with gcc optimising beside them on the two cores
    (bench/deployed.py's ``prewarm_nodes`` does this for the nodes' start; a plan's own
    libraries are built at its first plan). Returns the seconds it took.
    """
    t0 = time.monotonic()
    name = f"{ns}/warm/planner"
    proc = _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/warm", *common],
                    workdir / "prewarm.log", env={"TOCONTROL_COMPILE_TIERS": "0"})
    client = _Client([name])
    try:
        if not client.clients[name].wait_for_service(timeout_sec=1800.0):
            raise RuntimeError(f"{name}/plan did not come up (log {workdir / 'prewarm.log'})")
        client.call(name, *case, timeout=1800.0)
    finally:
        client.close()
        proc.stop()
    return time.monotonic() - t0


def run(count: int = 20) -> Section:
    title = "The Panda through the planner node (issue 32)"
    found, urdf = robots().get("Panda"), panda_urdf()
    if found is None or urdf is None:
        return Section(title, ["example-robot-data is not installed: section skipped."], [])
    model, limits = found
    cases = [(model.point(q0), target)
             for q0, _qd0, target in draw_cases(model, limits, count, seed=SEED)]
    workdir = Path(tempfile.mkdtemp(prefix="tocontrol-bench-deployed-panda-"))
    ns = f"/bench_panda_{os.getpid()}"
    common = ["-p", f"robot_description_file:={urdf}", "-p", "tip_link:=panda_hand",
              "-p", "warm_start:=false"]
    names = {1: f"{ns}/one/planner", 0: f"{ns}/all/planner"}
    prewarm = _prewarm(ns, common, cases[0], workdir)
    procs = [
        _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/one", *common,
                                           "-p", "workers:=1"], workdir / "one.log"),
        _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/all", *common],
                 workdir / "all.log"),
    ]
    client = _Client(list(names.values()))
    times = {1: [], 0: []}
    same = 0
    rows = []
    try:
        for name in names.values():
            if not client.clients[name].wait_for_service(timeout_sec=300.0):
                raise RuntimeError(f"{name}/plan did not come up")
            client.call(name, *cases[0])  # compile cache, workers started: not counted
        for i, (start, goal) in enumerate(cases):
            order = (1, 0) if i % 2 == 0 else (0, 1)
            out = {w: client.call(names[w], start, goal) for w in order}
            equal = out[1][1] == out[0][1] and len(out[1][1]) > 1
            same += equal
            for w in (1, 0):
                times[w].append(out[w][0])
            rows.append([str(i + 1), f"{out[1][0]:.2f}", f"{out[0][0]:.2f}",
                         f"{out[1][0] / out[0][0]:.2f}", "yes" if equal else "NO"])
            log(f"deployed Panda {i + 1}/{count}: workers=1 {out[1][0]:.2f} s, "
                f"default {out[0][0]:.2f} s, same path {equal}")
    finally:
        client.close()
        for proc in procs:
            proc.stop()
    ratios = [a / b for a, b in zip(times[1], times[0], strict=True)]
    med, worst = statistics.median(times[0]), max(times[0])
    lines = [
        f"Two planner nodes as processes, the Panda of example-robot-data "
        f"(`robot_description_file`, `tip_link:=panda_hand`, its URDF limits), "
        f"`warm_start:=false`, default options otherwise: one with `workers:=1`, one with the "
        f"default `workers` (one per core). {count} `~/plan` calls each (the best-motion "
        f"section's Panda cases as start and goal points), alternated case by case from a "
        f"client in the benchmark process, after one uncounted call each; before them one "
        f"plan of the first case on a third planner whose every build is optimised in the "
        f"foreground ({prewarm:.0f} s), so that the measured nodes find a plan's optimised "
        f"libraries in the compile cache as a deployed node does after its first plans (a "
        f"fresh cache had them plan on the quick builds with gcc beside them). Round trip: "
        f"request sent to response received (s). Default node: median {med:.2f} s, worst "
        f"{worst:.2f} s; `workers:=1`: median {statistics.median(times[1]):.2f} s, worst "
        f"{max(times[1]):.2f} s; paired ratio median {statistics.median(ratios):.2f}; the "
        f"same path from both in {same}/{count}. "
        f"Command: `scripts/dev run python -P bench/deployed_panda.py {count}`.",
        "",
        *table(["case", "workers=1 (s)", "default (s)", "ratio", "same path"], rows),
    ]
    targets = [
        (f"default Panda plan through the node: median <= {TARGET_MEDIAN:g} s, worst <= "
         f"{TARGET_WORST:g} s",
         ("**yes**" if med <= TARGET_MEDIAN and worst <= TARGET_WORST else "**no**")
         + f": {med:.2f} s, {worst:.2f} s"),
    ]
    return Section(title, lines, targets)


if __name__ == "__main__":
    section = run(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
    print("\n".join([f"## {section.title}", "", *section.lines, ""]))
    for target, verdict in section.targets:
        print(f"- {target}: {verdict}")
