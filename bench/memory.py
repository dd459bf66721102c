"""A memory of optimal motions for the Panda cell (issue 50): build, then serve as deployed.

The cell (``bench/memory_cell/panda_cell.yaml``): the Panda of example-robot-data with its
URDF limits (which bind), tip ``panda_hand``, three stations (start points) and a 40 x 40 x
30 cm target box at a 10 cm grid: 300 motions, each planned with a search wider than the
node's default (``starts`` 24, ``candidates`` 8). The requests
(``bench/memory_cell/requests.yaml``, made once by :func:`write_requests` from a seed): 50
inside the cell (a station, a target drawn uniformly in the box: none on the grid) and 20
outside (targets 15-30 cm beside the box).

Measured:

- *The build* (``ros2 run tocontrol_ros memory build``, two worker processes; resumed when a
  file is there already, so the figures come from the file's build log): motions per minute
  (stored motions over the span of the log's finish times, plus one median solve), the
  file's size per 1000 motions, and the coverage: the share of 2000 targets drawn uniformly
  in the box (from a random station) with a stored motion within the hit radius.
- *The conversion* (``ros2 run tocontrol_ros memory upgrade``: every stored motion's request
  re-solved warm on the serving mesh with its multipliers, the state a hit continues; run on
  an existing file before the build resumes it; a no-op on a file converted already): its
  wall time, motions converted, median iterations, the serving mesh's ``T`` against the
  stored one.
- *Serving, through the node as deployed*: three planner processes (``python -P -m
  tocontrol_ros.planner``) with the Panda as above, ``warm_start:=false``, the default
  options otherwise: one with ``memory`` set (``memory_basins`` basins re-solved, the least
  ``T``), one with ``memory``, ``memory_first_success`` (the next basin only when the
  nearest failed; the inside requests only) and ``publish: first_then_optimum`` (a hit's
  first motion published at once: the nearest stored motion moved onto the request, or
  where that fails the first certified IPOPT iterate; the time from the request to it and
  its ``T``, from its ``first`` status), one without (the full default multistart: the
  reference). A client in this process calls ``~/plan`` on each in turn (the order
  alternating), after one uncounted call each; the round trip is request sent to response
  received, ``T``, the certificate and ``memory: hit|miss`` come from the request's final
  ``~/status``. Inside: median and p95 latency with the memory, certified count, ``T``
  within 1e-3 (relative) of the reference's; outside: both nodes' latencies (a miss plans
  cold: the memory's cost is the lookup) and ``T`` (the same cold plan). Where a hit's time
  goes, from the status values: the lookup, decoding, the warm re-solves' IPOPT part, their
  certificates, their iterations and what they started from, and the node's overhead (the
  round trip less the memory's time: the request, sampling, publishing, the reply).
- *The compiled peer, side by side*: :class:`bench.peer_compiled.Peer` (Hermite-Simpson,
  compiled, IPOPT) on 25 intervals started from the same nearest stored motion (its samples
  at the peer's collocation points, torques normalised), against our warm re-solve of that
  one entry in this process (:func:`~tocontrol_ros.core.memory.recall.recall` with one
  basin): time, iterations and ``T`` on the first :data:`PEER_CASES` inside requests.

Run alone: ``scripts/dev run python -P bench/memory.py [--memory FILE] [--inside N]
[--outside N]`` (builds into FILE, default ``panda_cell.sqlite`` in the system's temporary
folder, resuming a partial build). ``--write-requests`` rewrites the request file.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, load_text, log, panda_urdf, table  # noqa: E402
from bench.deployed import RosClient, _Process  # noqa: E402

HERE = Path(__file__).resolve().parent
CELL = HERE / "memory_cell" / "panda_cell.yaml"
REQUESTS = HERE / "memory_cell" / "requests.yaml"
SEED = 50
#: Inside requests whose nearest stored motion the compiled peer also re-solves.
PEER_CASES = 10
#: The peer's mesh (intervals): its fastest of bench/peer_compiled.py's meshes.
PEER_INTERVALS = 25
#: The memory node's first, uncounted request (the box's centre from the home station).
WARM_UP_TARGET = (0.5, 0.0, 0.35)
#: The issue's bars.
TARGET_MEDIAN, TARGET_P95, TARGET_T_COUNT, T_TOL = 0.100, 0.250, 48, 1e-3
FINAL = ("solved", "failed", "superseded", "cancelled", "timed out")


def write_requests(path: Path = REQUESTS, inside: int = 50, outside: int = 20) -> None:
    """Draw the request sets from :data:`SEED` and write them (YAML)."""
    cell = yaml.safe_load(CELL.read_text())
    stations = cell["starts"]["stations"]
    box = cell["targets"]["boxes"][0]
    lo, hi = np.array(box["lower"]), np.array(box["upper"])
    rng = np.random.default_rng(SEED)
    names = sorted(stations)
    ins = [{"start": names[rng.integers(len(names))],
            "target": np.round(lo + rng.uniform(0, 1, 3) * (hi - lo), 4).tolist()}
           for _ in range(inside)]
    outs = []
    while len(outs) < outside:
        side = 1.0 if len(outs) % 2 else -1.0
        y = side * rng.uniform(0.35, 0.5)
        target = [rng.uniform(0.25, 0.5), y, rng.uniform(0.25, 0.5)]
        outs.append({"start": names[rng.integers(len(names))],
                     "target": np.round(target, 4).tolist()})
    header = ("# The memory benchmark's requests (bench/memory.py, issue 50), drawn with "
              f"seed {SEED}:\n# {inside} targets uniform in the cell's box (none on its "
              f"grid), {outside} beside it\n# (|y| 0.35-0.5 m, 15-30 cm from the box). "
              "Rewritten by `bench/memory.py --write-requests`.\n")
    path.write_text(header + yaml.safe_dump({"stations": stations, "inside": ins,
                                             "outside": outs}, sort_keys=False))


class _Client(RosClient):
    """``~/plan`` calls to several planners, and their ``~/status``."""

    def __init__(self, planners: list[str]) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus
        from nav_msgs.srv import GetPlan
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        super().__init__("bench_memory")
        self._GetPlan = GetPlan
        self.clients = {name: self.node.create_client(GetPlan, f"{name}/plan")
                        for name in planners}
        self.statuses = {name: [] for name in planners}
        self._lock = threading.Lock()
        for name in planners:
            self.node.create_subscription(
                DiagnosticStatus, f"{name}/status",
                lambda msg, name=name: self._status(name, msg),
                QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))

    def _status(self, name, msg) -> None:
        with self._lock:
            self.statuses[name].append({kv.key: kv.value for kv in msg.values})

    def call(self, name: str, start, goal, timeout: float = 300.0,
             status: bool = True) -> tuple[float, dict]:
        """One call: (round trip in s, the final status's values; {} without ``status``).

        ``status`` False (the uncounted first calls): the status subscriptions may still be
        matching the planners' publishers, so the final status is not waited for.
        """
        request = self._GetPlan.Request()
        request.start.header.frame_id = request.goal.header.frame_id = "panda_link0"
        for pose, p in ((request.start.pose, start), (request.goal.pose, goal)):
            pose.position.x, pose.position.y, pose.position.z = (float(v) for v in p)
        with self._lock:
            since = len(self.statuses[name])
        done = threading.Event()
        t0 = time.perf_counter()
        future = self.clients[name].call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise RuntimeError(f"{name}/plan did not answer")
        elapsed = time.perf_counter() - t0
        if not status:
            return elapsed, {}
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            with self._lock:
                final = [s for s in self.statuses[name][since:] if s.get("event") in FINAL]
                first = [s for s in self.statuses[name][since:] if s.get("event") == "first"
                         and s.get("published") == "first"]
            if final:  # with the first motion's latency and T, when one was published
                return elapsed, {**final[0], **({"first_latency": first[0].get("latency"),
                                                 "first_T": first[0].get("T")} if first else {})}
            time.sleep(0.01)
        raise RuntimeError(f"{name}: no final status")


def _upgrade(memory: Path, cell: Path = CELL) -> dict:
    """``memory upgrade`` on the file (a no-op when converted): wall time and its summary."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-P", "-m", "tocontrol_ros.memory", "upgrade",
                           str(memory), str(cell), "--quiet"], check=True, text=True,
                          stderr=subprocess.PIPE)
    lines = [line for line in done.stderr.splitlines() if line.startswith("memory:")]
    log(f"memory upgrade: {' | '.join(lines)}")
    return {"wall": time.perf_counter() - t0, "summary": lines[-1] if lines else ""}


def _build(memory: Path, cell: Path = CELL) -> float:
    """Run the build (resumes); its wall time (s)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-P", "-m", "tocontrol_ros.memory", "build", str(cell),
                    str(memory), "-j", "2", "--quiet"], check=True)
    return time.perf_counter() - t0


def build_span(tasks: dict) -> tuple[float, float]:
    """A build's span from its log (``MotionStore.tasks()``): the first to the last finish
    plus one median solve, and that median solve (s); nan without finished tasks."""
    finished = sorted(t["finished"] for t in tasks.values())
    solves = [t["solve_time"] for t in tasks.values() if t["solve_time"] is not None]
    solve = statistics.median(solves) if solves else float("nan")
    return (finished[-1] - finished[0] + solve if finished else float("nan")), solve


def _build_figures(memory: Path, model, radius: float = 1.0, cell_file: Path = CELL) -> dict:
    from tocontrol_ros.core.memory.recall import distances
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.types.problem import Problem, point

    cell = yaml.safe_load(cell_file.read_text())
    with MotionStore(memory) as store:
        tasks = store.tasks()
        keys = store.keys()
        count = store.count()
    span, solve = build_span(tasks)
    box = cell["targets"]["boxes"][0]
    lo, hi = np.array(box["lower"]), np.array(box["upper"])
    stations = [np.array(s["point"]) for s in cell["starts"]["stations"].values()]
    rng = np.random.default_rng(SEED + 1)
    covered, draws = 0, 2000
    for _ in range(draws):
        target = lo + rng.uniform(0, 1, 3) * (hi - lo)
        start = stations[rng.integers(len(stations))]
        problem = Problem(model, point(start), point(target), k=4.0, reserve=0.1)
        covered += bool(np.min(distances(keys, problem, 0.05)) <= radius)
    return {"tasks": len(tasks), "ok": sum(t["status"] == "SUCCESS" for t in tasks.values()),
            "motions": count, "per_minute": 60.0 * count / span, "span": span,
            "solve_median": solve, "size": memory.stat().st_size,
            "coverage": covered / draws, "total": len(cell_tasks(cell_file))}


def cell_tasks(cell: Path = CELL):
    """The tasks (start, target) of a cell file (default the benchmark's)."""
    from tocontrol_ros.memory.cell import load_cell

    return load_cell(cell).tasks


def _peer_rows(memory: Path, model, limits, cases: list) -> list:
    """The compiled peer and our in-process warm re-solve from the same nearest entry."""
    from scipy.interpolate import CubicHermiteSpline, make_interp_spline

    from bench.peer_compiled import Peer
    from tocontrol_ros.core import Planner, SolverOptions
    from tocontrol_ros.core.direct.limited import PAD, state_bounds
    from tocontrol_ros.core.memory.codec import decode_sample
    from tocontrol_ros.core.memory.recall import distances, recall
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.types.problem import Problem, point

    cache = Path(tempfile.gettempdir()) / "tocontrol-bench-memory-peer"
    planner = Planner(model)
    rows = []
    with MotionStore(memory) as store:
        keys = store.keys()
        peer = Peer(model, PEER_INTERVALS, "point", 4, 0.9, cache)
        log(f"memory: peer built in {peer.build_seconds:.1f} s")
        warmup = True
        for start, target in cases:
            problem = Problem(model, point(start), point(target), k=4.0, reserve=0.1,
                              limits=limits)
            d = distances(keys, problem, 0.05)
            entry = store.get(int(keys["id"][int(np.argmin(d))]))
            s = decode_sample(entry.trajectory)
            t = np.linspace(0.0, entry.T, 2 * PEER_INTERVALS + 1)
            z = np.hstack([CubicHermiteSpline(s["t"], s["q"], s["qd"])(t),
                           CubicHermiteSpline(s["t"], s["qd"], s["qdd"])(t),
                           make_interp_spline(s["t"], s["qdd"], k=1)(t),
                           np.clip(make_interp_spline(s["t"], s["tau"], k=1)(t)
                                   / (model.tau_max * problem.torque_scale), -1, 1)])
            bounds = state_bounds(problem, PAD)
            if warmup:  # the first solve of each loads its libraries: not counted
                recall(planner, problem, SolverOptions(), store, radius=math.inf, basins=1)
                peer.solve(problem.start.value, problem.target.value, *bounds, entry.T, z)
                warmup = False
            sol = peer.solve(problem.start.value, problem.target.value, *bounds, entry.T, z)
            t0 = time.perf_counter()
            ours = recall(planner, problem, SolverOptions(), store, radius=math.inf, basins=1)
            ours_time = time.perf_counter() - t0
            res = ours.result
            rows.append({"d": float(d.min()), "peer_ok": sol.success, "peer_T": sol.T,
                         "peer_s": sol.seconds, "peer_it": sol.iterations,
                         "ours_ok": res is not None, "ours_T": res.T if res else np.nan,
                         "ours_s": ours_time,
                         "ours_it": res.iterations if res else 0})
            log(f"memory peer: d {d.min():.2f}: peer {sol.status} T {sol.T:.5f} "
                f"{sol.seconds:.3f} s {sol.iterations} it; ours "
                f"{res.T if res else float('nan'):.5f} {ours_time:.3f} s")
    return rows


def _within(memory: Path, model, limits, cases: list) -> list[bool]:
    """Which requests have a stored motion within the hit radius (the node's lookup)."""
    from tocontrol_ros.core.memory.recall import DEFAULT_RADIUS, distances
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.types.problem import Problem, point

    with MotionStore(memory) as store:
        keys = store.keys()
    return [bool(np.min(distances(keys, Problem(model, point(start), point(target), k=4.0,
                                                reserve=0.1, limits=limits), 0.05))
                 <= DEFAULT_RADIUS) for start, target in cases]


def _quantile(values, q) -> float:
    return float(np.quantile(values, q)) if values else float("nan")


def run(memory: Path | None = None, inside: int = 50, outside: int = 20,
        peer_cases: int = PEER_CASES, build: bool = True, cell: Path = CELL,
        requests: Path = REQUESTS) -> Section:
    """The section (see the module docstring); ``cell`` and ``requests``: another cell's
    files (e.g. the small cell of ``bench/memory_blend.py``), the benchmark's by default."""
    from bench.limits import robots

    title = "A memory of optimal motions: the Panda cell (issue 50)"
    found, urdf = robots().get("Panda"), panda_urdf()
    if found is None or urdf is None:
        return Section(title, ["example-robot-data is not installed: section skipped."], [])
    model, limits = found
    memory = Path(memory or Path(tempfile.gettempdir()) / "panda_cell.sqlite")
    load_start = load_text()
    # An existing file first brought to this format with its serving states (a build of
    # this code stores them with every new motion).
    upgrade = _upgrade(memory, cell) if memory.exists() else {
        "wall": 0.0, "summary": "no file before the build: the build stores them"}
    build_wall = _build(memory, cell) if build else 0.0
    build = _build_figures(memory, model, cell_file=cell)
    log(f"memory: build {build}")
    req = yaml.safe_load(requests.read_text())
    stations = {k: v["point"] for k, v in req["stations"].items()}
    sets = {name: [(stations[r["start"]], r["target"]) for r in req.get(name, [])[:count]]
            for name, count in (("inside", inside), ("outside", outside))}
    near = {name: _within(memory, model, limits, cases) for name, cases in sets.items()}
    workdir = Path(tempfile.mkdtemp(prefix="tocontrol-bench-memory-"))
    ns = f"/bench_memory_{os.getpid()}"
    common = ["-p", f"robot_description_file:={urdf}", "-p", "tip_link:=panda_hand",
              "-p", "warm_start:=false"]
    names = {"memory": f"{ns}/mem/planner", "first": f"{ns}/first/planner",
             "cold": f"{ns}/cold/planner"}
    procs = [
        _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/mem", *common,
                                           "-p", f"memory:={memory}"], workdir / "mem.log"),
        _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/first", *common,
                                           "-p", f"memory:={memory}",
                                           "-p", "memory_first_success:=true",
                                           "-p", "publish:=first_then_optimum"],
                 workdir / "first.log"),
        _Process("tocontrol_ros.planner", ["--ros-args", "-r", f"__ns:={ns}/cold", *common],
                 workdir / "cold.log"),
    ]
    client = _Client(list(names.values()))
    out = {"inside": [], "outside": []}
    try:
        for name in names.values():
            if not client.clients[name].wait_for_service(timeout_sec=300.0):
                raise RuntimeError(f"{name}/plan did not come up")
            until = time.monotonic() + 60.0  # the status topic discovered (bounded)
            while client.node.count_publishers(f"{name}/status") < 1 and \
                    time.monotonic() < until:
                time.sleep(0.05)
        # Not counted: the cold node's first plan (compiled functions, worker processes), and
        # the memory node's first hit (the uniform transcription of memory_spans is built
        # then), a request of neither set.
        client.call(names["cold"], *(sets["outside"] or sets["inside"])[0], status=False)
        first_hit = client.call(names["memory"], stations["home"], WARM_UP_TARGET,
                                status=False)
        client.call(names["first"], stations["home"], WARM_UP_TARGET, status=False)
        log(f"memory: first hit {first_hit[0]:.2f} s")
        for which, cases in sets.items():
            for i, (start, goal) in enumerate(cases):
                order = ("memory", "first", "cold") if i % 2 == 0 else \
                    ("cold", "first", "memory")
                if which == "outside" or not near[which][i]:  # a miss for both: cold
                    order = tuple(w for w in order if w != "first")
                got = {w: client.call(names[w], start, goal) for w in order}
                out[which].append(got)
                m, c = got["memory"][1], got["cold"][1]
                log(f"memory {which} {i + 1}/{len(cases)}: {m.get('memory')} "
                    f"d {m.get('memory_distance')} {got['memory'][0]:.3f} s T {m.get('T')} | "
                    f"cold {got['cold'][0]:.2f} s T {c.get('T')}")
    finally:
        client.close()
        for proc in procs:
            proc.stop()
    # The peer side by side where the memory serves: the first inside requests that were hits.
    served = [case for case, got in zip(sets["inside"], out["inside"], strict=True)
              if got["memory"][1].get("memory") == "hit"]
    peer = _peer_rows(memory, model, limits, served[:peer_cases]) if peer_cases else []
    return _section(title, build, build_wall, upgrade, out, peer, first_hit,
                    (load_start, load_text()), (cell, requests))


def _f(values: dict, key: str) -> float:
    try:
        return float(values.get(key))
    except (TypeError, ValueError):
        return float("nan")


def _breakdown(hits: list, name: str) -> dict:
    """Medians over ``hits`` (of node ``name``) of where a hit's time goes (s), iterations."""
    def values(key):
        return [_f(g[name][1], key) for g in hits]

    solve, cert = values("memory_solve_time"), values("memory_certificate_time")
    total = values("memory_time")
    starts = [t.strip() for g in hits for t in str(g[name][1].get("memory_starts", "")).split(",")]
    return {"lookup": _med(values("memory_lookup_time")),
            "decode": _med(values("memory_decode_time")),
            "ipopt": _med([a - b for a, b in zip(solve, cert, strict=True)]),
            "certificate": _med(cert), "memory": _med(total),
            "overhead": _med([g[name][0] - t for g, t in zip(hits, total, strict=True)]),
            "iterations": _med(values("memory_iterations")),
            "iterations_p95": _quantile([v for v in values("memory_iterations")
                                         if np.isfinite(v)], 0.95),
            "fallbacks": starts.count("serve"), "fits": starts.count("path fit")}


def _served(ins: list, name: str) -> dict:
    """Latency, certified and T figures of node ``name`` over the inside requests it got."""
    ins = [g for g in ins if name in g]
    lat = [g[name][0] for g in ins]
    rel = [(_f(g[name][1], "T") - _f(g["cold"][1], "T")) / _f(g["cold"][1], "T") for g in ins]
    hits = [g for g in ins if g[name][1].get("memory") == "hit"]
    return {"lat": lat, "median": statistics.median(lat), "p95": _quantile(lat, 0.95),
            "hits": hits, "hit_median": _med([g[name][0] for g in hits]),
            "hit_p95": _quantile([g[name][0] for g in hits], 0.95),
            "certified": sum(g[name][1].get("event") == "solved"
                             and g[name][1].get("certified") == "true" for g in ins),
            "within": sum(r <= T_TOL for r in rel), "better": sum(r < -T_TOL for r in rel),
            "worst": max(rel), "requests": len(ins), "hit_within": sum(
                (_f(g[name][1], "T") - _f(g["cold"][1], "T")) / _f(g["cold"][1], "T") <= T_TOL
                for g in hits)}


def _first_figures(f: dict) -> tuple[list, list, list, int]:
    """Node ``f``'s hits with a first motion: their values, its latency (s), its ``T`` above
    the final motion's (relative), and how many were the moved stored motion."""
    got = [g["first"][1] for g in f["hits"] if "first_latency" in g["first"][1]]
    lat = [_f(v, "first_latency") for v in got]
    gap = [_f(v, "first_T") / _f(v, "T") - 1 for v in got]
    return got, lat, gap, sum(str(v.get("memory_first_iteration")) == "0" for v in got)


def first_motions(f: dict) -> str:
    """The first motions published on the hits of node ``f`` (``publish: first_then_optimum``:
    the stored motion moved, ``memory_first_iteration`` 0, else a certified IPOPT iterate):
    the time from the request to it, its ``T``."""
    got, lat, gap, moved = _first_figures(f)
    return (f"its first motions (published at once: the nearest stored motion moved onto the "
            f"request on {moved}, a certified IPOPT iterate on {len(got) - moved}): "
            f"on {len(got)}/{len(f['hits'])} hits, published a median {_med(lat) * 1e3:.0f} ms "
            f"after the request (p95 {_quantile(lat, 0.95) * 1e3:.0f} ms), `T` above the "
            f"final motion's by a median {100 * _med(gap):.2f} % (worst "
            f"{100 * max(gap, default=float('nan')):.2f} %).")


def _section(title, build, build_wall, upgrade, out, peer, first_hit, load,
             files: tuple = (CELL, REQUESTS)) -> Section:
    from tocontrol_ros.core.memory.recall import DEFAULT_BASINS

    ins, outs = out["inside"], out["outside"]
    mem, first = _served(ins, "memory"), _served(ins, "first")
    cold_lat = [g["cold"][0] for g in ins]
    hit_cold = [g["cold"][0] for g in mem["hits"]]
    where, where_first = _breakdown(mem["hits"], "memory"), _breakdown(first["hits"], "first")
    o_mem = [g["memory"][0] for g in outs]
    o_cold = [g["cold"][0] for g in outs]
    o_same = sum(_f(g["memory"][1], "T") == _f(g["cold"][1], "T") for g in outs)
    o_worse = sum(_f(g["memory"][1], "T") > _f(g["cold"][1], "T") * (1 + 1e-9) for g in outs)
    o_miss = sum(g["memory"][1].get("memory") == "miss" for g in outs)
    med, p95 = mem["median"], mem["p95"]

    def served(f, label):
        return (f"{label} ({f['requests']} requests): memory hits "
                f"{len(f['hits'])}/{f['requests']}; latency median "
                f"{f['median'] * 1e3:.0f} ms, p95 {f['p95'] * 1e3:.0f} ms; over the hits "
                f"alone median {f['hit_median'] * 1e3:.0f} ms, p95 {f['hit_p95'] * 1e3:.0f} ms; "
                f"certified {f['certified']}/{f['requests']}; `T` within {T_TOL:g} (relative) "
                f"of the default multistart's on {f['within']}/{f['requests']} (hits: "
                f"{f['hit_within']}/{len(f['hits'])}; better by more than that on "
                f"{f['better']}; worst {100 * f['worst']:+.3f} %).")

    def went(w, label):
        return (f"{label}: lookup {w['lookup'] * 1e3:.2f} ms; decoding the stored states "
                f"{w['decode'] * 1e3:.1f} ms; the warm re-solves' IPOPT part "
                f"{w['ipopt'] * 1e3:.0f} ms ({w['iterations']:.0f} iterations, all re-solves of "
                f"a hit together; p95 {w['iterations_p95']:.0f}); their certificates "
                f"{w['certificate'] * 1e3:.0f} ms; the node's overhead (the round trip less "
                f"the memory's time: request, sampling, publishing, reply) "
                f"{w['overhead'] * 1e3:.0f} ms. Re-solves that fell back from the "
                f"multipliers to the solution alone: {w['fallbacks']}; hits of motions "
                f"without a serving state (path fitted): {w['fits']}.")

    lines = [
        (f"The cell `bench/memory_cell/panda_cell.yaml` (the Panda of example-robot-data, its "
         f"URDF limits, tip `panda_hand`; 3 stations, a 40 x 40 x 30 cm target box at a 10 cm "
         f"grid: {build['total']} motions; the build's search `starts` 24, `candidates` 8), "
         f"the requests `bench/memory_cell/requests.yaml` (50 inside, 20 outside; "
         if files == (CELL, REQUESTS) else
         f"**Not the benchmark's cell**: the cell `{files[0].name}` ({build['total']} "
         f"motions), the requests `{files[1].name}` (") +
        f"this run: the first {len(ins)} and {len(outs)}). Two cores shared with "
        f"other work (load average {load[0]} at the start, {load[1]} at the end): the "
        f"figures are as measured. Command: "
        f"`scripts/dev bench run_all.py --update --only memory --memory-file FILE` "
        f"(`--memory-requests {len(ins)},{len(outs)},{len(peer)}` for this run's counts, "
        f"`--memory-no-build` to serve FILE as it is; without it the build resumes in FILE), "
        f"or `scripts/dev run python -P bench/memory.py --memory FILE`.",
        "",
        f"**Build** (`ros2 run tocontrol_ros memory build`, 2 worker processes): "
        f"{build['ok']}/{build['tasks']} tasks solved and certified, {build['motions']} "
        f"motions stored, {build['per_minute']:.1f} motions per minute (the build log's span, "
        f"{build['span'] / 60:.1f} min; median solve {build['solve_median']:.1f} s per "
        f"motion per worker; this run's build call {build_wall:.0f} s, resumed); "
        f"{build['size'] / 1e6:.1f} MB, "
        f"{build['size'] / max(build['motions'], 1) * 1000 / 1e6:.1f} MB per 1000 "
        f"motions; coverage {100 * build['coverage']:.1f} % of 2000 uniform "
        f"targets in the box (a stored motion within the hit radius, 1 warm unit = 0.1 m)."
        + (f" **The build was stopped at {build['tasks']}/{build['total']} tasks** (the "
           f"cell's tasks go station by station: home, left, right); a request whose "
           f"station's motions near its target are not built is a miss."
           if build["tasks"] < build["total"] else ""),
        "",
        f"**Conversion to the serving mesh** (`ros2 run tocontrol_ros memory upgrade FILE "
        f"CELL`, one process, this run: {upgrade['wall']:.0f} s): {upgrade['summary']}",
        "",
        f"**Inside the cell, through the node** ({len(ins)} requests, both memory nodes "
        f"against the default node, all as processes; default node: median "
        f"{statistics.median(cold_lat):.2f} s, p95 {_quantile(cold_lat, 0.95):.2f} s, on the "
        f"memory node's hits median {_med(hit_cold):.2f} s).",
        "",
        "- " + served(mem, f"memory, {DEFAULT_BASINS} basins re-solved side by side (the "
                      f"default)"),
        "- " + served(first, "memory, `memory_first_success` and `publish: "
                      "first_then_optimum` (the second basin only when the nearest failed; "
                      "asked only the requests with a stored motion within the radius: the "
                      "others are the same cold plan)"),
        "- " + first_motions(first),
        "",
        "Where a hit's time goes (medians over the hits):",
        "",
        "- " + went(where, f"{DEFAULT_BASINS} basins"),
        "- " + went(where_first, "`memory_first_success`"),
        "",
        f"The memory node's first hit after start (not counted: it builds the transcriptions "
        f"of `memory_spans` = 64 uniform spans) took {first_hit[0]:.2f} s.",
        "",
        f"**Outside the cell** ({len(outs)} requests): misses {o_miss}/{len(outs)}; memory "
        f"node median {_med(o_mem):.2f} s, default node "
        f"{_med(o_cold):.2f} s (paired ratio median "
        f"{_med([a / b for a, b in zip(o_mem, o_cold, strict=True)]):.2f}); the "
        f"same `T` on {o_same}/{len(outs)}, worse on {o_worse}.",
    ]
    if peer:
        ok = [r for r in peer if r["peer_ok"] and r["ours_ok"]]
        lines += [
            "",
            f"**The compiled peer from the same nearest stored motion** (the first {len(peer)} "
            f"inside requests that were hits, in this process): the peer (Hermite-Simpson, "
            f"{PEER_INTERVALS} intervals, compiled, IPOPT) converged on "
            f"{sum(r['peer_ok'] for r in peer)}/"
            f"{len(peer)}, median {_med([r['peer_s'] for r in peer]) * 1e3:.0f} ms, "
            f"{_med([r['peer_it'] for r in peer]):.0f} iterations; ours (warm re-solve of that "
            f"entry alone) {sum(r['ours_ok'] for r in peer)}/{len(peer)}, median "
            f"{_med([r['ours_s'] for r in peer]) * 1e3:.0f} ms. `T` peer / ours (the peer's "
            f"coarse mesh is not certified and errs by about 1/N^2): median "
            f"{_med([r['peer_T'] / r['ours_T'] for r in ok]):.4f}.",
            "",
            *table(["distance", "peer (ms)", "peer it", "peer T (s)", "ours (ms)", "ours it",
                    "ours T (s)"],
                   [[f"{r['d']:.2f}", f"{r['peer_s'] * 1e3:.0f}", str(r["peer_it"]),
                     f"{r['peer_T']:.5f}" if r["peer_ok"] else "failed",
                     f"{r['ours_s'] * 1e3:.0f}", str(r["ours_it"]),
                     f"{r['ours_T']:.5f}" if r["ours_ok"] else "failed"] for r in peer]),
        ]
    def first_cells(g):
        if "first" not in g:
            return ["", "", "", ""]
        v = g["first"][1]
        return [f"{g['first'][0]:.3f}", f"{(_f(v, 'T') / _f(g['cold'][1], 'T') - 1):+.1e}",
                f"{_f(v, 'first_latency'):.3f}" if "first_latency" in v else "-",
                f"{(_f(v, 'first_T') / _f(g['cold'][1], 'T') - 1):+.1e}"
                if "first_T" in v else "-"]

    lines += ["", *table(
        ["set", "case", "memory", "distance", "iterations", "memory node (s)", "T",
         "default node (s)", "T default", "rel. diff", "first-success (s)", "its rel. diff",
         "its first motion (s)", "first's rel. diff"],
        [[which, str(i + 1), g["memory"][1].get("memory", "?"),
          f"{_f(g['memory'][1], 'memory_distance'):.2f}",
          str(g["memory"][1].get("memory_iterations", "")), f"{g['memory'][0]:.3f}",
          f"{_f(g['memory'][1], 'T'):.5f}", f"{g['cold'][0]:.2f}", f"{_f(g['cold'][1], 'T'):.5f}",
          f"{(_f(g['memory'][1], 'T') / _f(g['cold'][1], 'T') - 1):+.1e}", *first_cells(g)]
         for which, gs in (("inside", ins), ("outside", outs)) for i, g in enumerate(gs)])]
    _, first_lat, first_gap, _ = _first_figures(first)
    targets = [
        (f"inside: median <= {TARGET_MEDIAN * 1e3:.0f} ms, p95 <= {TARGET_P95 * 1e3:.0f} ms",
         ("**yes**" if med <= TARGET_MEDIAN and p95 <= TARGET_P95 else "**no**")
         + f": {med * 1e3:.0f} ms, {p95 * 1e3:.0f} ms"),
        (f"inside: every one certified, T within {T_TOL:g} on >= {TARGET_T_COUNT}/50",
         ("**yes**" if mem["certified"] == len(ins)
          and mem["within"] >= TARGET_T_COUNT * len(ins) / 50 else "**no**")
         + f": {mem['certified']}/{len(ins)} certified, {mem['within']}/{len(ins)} within"),
        ("inside, `first_then_optimum` (reported; not the bar: its `T` is above the "
         "answer's): a certified motion published, median and p95",
         f"{_med(first_lat) * 1e3:.0f} ms, {_quantile(first_lat, 0.95) * 1e3:.0f} ms, `T` a "
         f"median {100 * _med(first_gap):.1f} % above the answer's"),
        ("outside: no worse T than without the memory",
         ("**yes**" if o_worse == 0 else "**no**") + f": worse on {o_worse}/{len(outs)}"),
    ]
    return Section(title, lines, targets)


def _med(values) -> float:
    values = [v for v in values if np.isfinite(v)]
    return statistics.median(values) if values else float("nan")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--memory", type=Path, default=None)
    parser.add_argument("--inside", type=int, default=50)
    parser.add_argument("--outside", type=int, default=20)
    parser.add_argument("--peer", type=int, default=PEER_CASES)
    parser.add_argument("--no-build", action="store_true",
                        help="serve the memory as it is (no build call)")
    parser.add_argument("--write-requests", action="store_true")
    parser.add_argument("--cell", type=Path, default=CELL,
                        help="the cell file (default the benchmark's)")
    parser.add_argument("--requests", type=Path, default=REQUESTS,
                        help="the requests file (default the benchmark's)")
    args = parser.parse_args(argv)
    if args.write_requests:
        write_requests()
        return 0
    section = run(args.memory, args.inside, args.outside, args.peer, not args.no_build,
                  args.cell, args.requests)
    print("\n".join([f"## {section.title}", "", *section.lines, ""]))
    for target, verdict in section.targets:
        print(f"- {target}: {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
