r"""The ``memory`` tool: build a memory of optimal motions, list, inspect, prune, export it.

Usage::

    ros2 run tocontrol_ros memory build cell.yaml cell.sqlite [-j 2 | --ray local]
    ros2 run tocontrol_ros memory upgrade cell.sqlite cell.yaml [--spans 64] [--limit N]
    ros2 run tocontrol_ros memory list cell.sqlite
    ros2 run tocontrol_ros memory inspect cell.sqlite [ID]
    ros2 run tocontrol_ros memory prune cell.sqlite --ids 3 7 | --source planner | --failed
    ros2 run tocontrol_ros memory export cell.sqlite motions.mcap [--ids ...]
    ros2 run tocontrol_ros memory figure cell.sqlite coverage.png

``build`` plans every task of a cell file (:mod:`tocontrol_ros.memory.cell`) with the batch
machinery, on this machine's cores or a Ray cluster, with a progress line and an ETA, into
one SQLite file (:mod:`tocontrol_ros.core.memory.store`); interrupted (Ctrl-C, a kill) and run
again, it plans only the tasks not done. A planner node serves from the file with its
``memory`` parameter (``docs/memory.md``). ``upgrade`` brings a file of an older format to
this one and gives each stored motion without one its serving state (its request re-solved
warm on the serving mesh, with the multipliers: :mod:`tocontrol_ros.core.memory.serve`),
resumable as a build is. ``export`` writes the batch library's layout: one
``trajectory_msgs/JointTrajectory`` per motion on ``/library/memory_<id>``, which ``replay``
plays. ``figure`` draws the coverage of the target region and ``T`` over it.

Exit status: 0 done, 130 interrupted (run again to resume), 2 bad input (cell file, memory
file, options), each with a message naming what was wrong.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from tocontrol_ros.batch.ray_backend import RayBackend, RayUnavailableError
from tocontrol_ros.batch.runner import LocalPool, Progress, run_tasks
from tocontrol_ros.batch.tasks import TaskFileError
from tocontrol_ros.core.memory.codec import CodecError, decode_sample
from tocontrol_ros.core.memory.keys import options_hash, robot_hash
from tocontrol_ros.core.memory.recall import DEFAULT_SPANS, open_memory
from tocontrol_ros.core.memory.serve import serve_spans
from tocontrol_ros.core.memory.store import MemoryFileError, MotionStore, upgrade_format
from tocontrol_ros.memory.build import MemoryLog, build_task
from tocontrol_ros.memory.cell import cell_problem, load_cell

__all__ = ["main", "build_parser", "run"]

EXIT_INTERRUPTED = 130
TOPIC_PREFIX = "/library/memory_"


def build_parser() -> argparse.ArgumentParser:
    """The command line (one subcommand per job)."""
    parser = argparse.ArgumentParser(prog="memory", description="A memory of optimal "
                                     "motions: build it from a cell file, list, inspect, "
                                     "prune, export, draw it.")
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="plan every task of a cell file into a memory")
    b.add_argument("cell", type=Path, metavar="CELL.yaml")
    b.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    b.add_argument("-j", "--workers", type=int, default=None, metavar="N",
                   help="worker processes (default: this machine's cores)")
    b.add_argument("--ray", default=None, metavar="auto|local|ADDRESS",
                   help="plan on a Ray cluster (as the batch tool's --ray)")
    b.add_argument("--limit", type=int, default=None, metavar="N",
                   help="plan at most N of the tasks not done yet (a partial build)")
    b.add_argument("--quiet", action="store_true", help="no progress line")
    up = sub.add_parser("upgrade", help="a file of an older format to this one, and every "
                        "motion re-solved on the serving mesh with its multipliers")
    up.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    up.add_argument("cell", type=Path, metavar="CELL.yaml",
                    help="the cell file it was built from (its robot and limits)")
    up.add_argument("--spans", type=int, default=DEFAULT_SPANS, metavar="N",
                    help=f"the serving mesh: the planner's memory_spans (default "
                    f"{DEFAULT_SPANS})")
    up.add_argument("--limit", type=int, default=None, metavar="N",
                    help="convert at most N motions (run again to go on)")
    up.add_argument("--quiet", action="store_true", help="no line per motion")
    ls = sub.add_parser("list", help="one line per stored motion")
    ls.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    ins = sub.add_parser("inspect", help="the memory's key and figures, or one entry")
    ins.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    ins.add_argument("id", type=int, nargs="?", default=None)
    pr = sub.add_parser("prune", help="remove entries")
    pr.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    pr.add_argument("--ids", type=int, nargs="+", default=None, help="these entries")
    pr.add_argument("--source", default=None, help="every entry from this source "
                    "(build, planner)")
    pr.add_argument("--failed", action="store_true",
                    help="forget the build's failed tasks (a build run again retries them)")
    ex = sub.add_parser("export", help="motions as JointTrajectory messages in an MCAP")
    ex.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    ex.add_argument("output", type=Path, metavar="OUT.mcap")
    ex.add_argument("--ids", type=int, nargs="+", default=None, help="only these entries")
    fig = sub.add_parser("figure", help="coverage of the target region and T over it")
    fig.add_argument("memory", type=Path, metavar="MEMORY.sqlite")
    fig.add_argument("output", type=Path, metavar="OUT.png")
    return parser


def _backend(args, robot):
    if args.ray is None:
        return LocalPool(robot, args.workers or os.cpu_count() or 1, fn=build_task)
    return RayBackend(robot, args.ray, args.workers, fn=build_task)


def _build(args, stream) -> int:
    if args.workers is not None and args.workers < 1:
        print(f"memory: --workers must be >= 1, got {args.workers}", file=stream)
        return 2
    try:
        cell = load_cell(args.cell)
        problem = cell_problem(cell, cell.tasks[0])
        store = open_memory(args.memory, problem, cell.method, create=True,
                            cell=json.loads(json.dumps(cell.description, default=str)))
    except (TaskFileError, MemoryFileError) as exc:
        print(f"memory: {exc}", file=stream)
        return 2
    log = MemoryLog(store)
    todo = [t for t in cell.tasks if t.key not in log.entries]
    total, done = len(cell.tasks), len(cell.tasks) - len(todo)
    if args.limit is not None:
        todo = todo[:max(args.limit, 0)]
    print(f"memory: {total} tasks, {done} done already ({args.memory}), {len(todo)} to plan",
          file=stream)
    signals = []
    previous = {sig: signal.signal(sig, lambda *_: signals.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        outcome = {"unfinished": 0}
        if todo:
            backend = _backend(args, cell.robot)
            progress = None if args.quiet else Progress(total, done, stream)
            outcome = run_tasks(todo, backend, log, cell.model.joint_names,
                                cell.model.base_link, progress, stop=lambda: bool(signals),
                                abandon=lambda: len(signals) > 1)
            if progress is not None:
                progress.finish()
    except RayUnavailableError as exc:
        print(f"memory: {exc}", file=stream)
        return 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        counts = Counter(e["status"] for e in store.tasks().values())
        stored = store.count()
        store.close()
    statuses = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    size = args.memory.stat().st_size
    print(f"memory: {stored} motions in {args.memory} ({size / 1e6:.2f} MB; tasks: "
          f"{statuses or 'none done'})", file=stream)
    if outcome["unfinished"] or sum(counts.values()) < total:
        print(f"memory: {total - sum(counts.values())} tasks left; run the same command "
              "again to go on", file=stream)
        return EXIT_INTERRUPTED if signals or outcome["unfinished"] else 0
    return 0


def _upgrade(args, stream) -> int:
    from tocontrol_ros.core.memory.serve import convert
    from tocontrol_ros.core.planning.solver import Planner, SolverOptions

    if args.spans < 1:
        print(f"memory: --spans must be >= 1, got {args.spans}", file=stream)
        return 2
    try:
        cell = load_cell(args.cell)
        problem = cell_problem(cell, cell.tasks[0])
        was = upgrade_format(args.memory, robot_hash(problem.model),
                             options_hash(problem, cell.method))
        store = open_memory(args.memory, problem, cell.method)
    except (TaskFileError, MemoryFileError) as exc:
        print(f"memory: {exc}", file=stream)
        return 2
    if was is not None:
        print(f"memory: {args.memory}: format {was!r} upgraded", file=stream)
    options = SolverOptions(**{**dict(cell.tasks[0].solver), "method": cell.method})
    planner = Planner(cell.model)
    signals = []
    previous = {sig: signal.signal(sig, lambda *_: signals.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}

    def progress(done, total, line):
        if not args.quiet:
            print(f"memory upgrade {done}/{total}: {line}", file=stream, flush=True)
        if signals:
            raise KeyboardInterrupt

    try:
        out = convert(store, planner, problem, options, args.spans, args.limit, progress)
    except KeyboardInterrupt:
        print("memory: interrupted; run the same command again to go on", file=stream)
        return EXIT_INTERRUPTED
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        left = int(np.sum(~store.keys()["serve"]))
        store.close()
    its = f", median {np.median(out.iterations):.0f} iterations" if out.iterations else ""
    change = f", T on the mesh {100 * np.median(out.T_change):+.3f} % (median)" \
        if out.T_change else ""
    print(f"memory: {out.converted} motions given a serving state on {args.spans} spans in "
          f"{out.seconds:.0f} s{its}{change}; {out.failed} failed (served from their path), "
          f"{out.skipped} needed none (on this mesh already, or maximum-principle motions); "
          f"{left} without one", file=stream)
    return 0


def _open(path: Path) -> MotionStore:
    return MotionStore(path)  # the tools serve nothing: any robot's memory is read


def _list(args, out) -> int:
    with _open(args.memory) as store:
        rows = store.summary()
    print(f"{'id':>6} {'source':>7} {'method':>8} {'T (s)':>10} {'start point (m)':>26} "
          f"{'target point (m)':>26}", file=out)
    for r in rows:
        sp = " ".join(f"{v:7.3f}" for v in r["start_point"])
        tp = " ".join(f"{v:7.3f}" for v in r["target_point"])
        print(f"{r['id']:>6} {r['source']:>7} {r['method']:>8} {r['T']:10.6f} {sp:>26} "
              f"{tp:>26}", file=out)
    print(f"{len(rows)} motions", file=out)
    return 0


def _inspect(args, out) -> int:
    with _open(args.memory) as store:
        if args.id is None:
            rows, tasks = store.summary(), store.tasks()
            meta = dict(store.meta)
            print(f"memory {args.memory}: {len(rows)} motions, "
                  f"{args.memory.stat().st_size / 1e6:.2f} MB", file=out)
            for key in ("format", "robot_hash", "options_hash", "robot", "options"):
                print(f"  {key}: {meta.get(key)}", file=out)
            if rows:
                T = np.array([r["T"] for r in rows])
                size = np.mean([r["bytes"] for r in rows])
                print(f"  T: min {T.min():.4f} s, median {np.median(T):.4f} s, max "
                      f"{T.max():.4f} s; {size / 1e3:.1f} kB of blobs per motion", file=out)
            counts = Counter(t["status"] for t in tasks.values())
            print(f"  build log: {dict(counts) or 'empty'}", file=out)
            served = int(np.sum(store.keys()["serve"]))
            print(f"  serving states: {served} of {len(rows)} motions"
                  + ("" if served == len(rows) else " (`memory upgrade` converts the rest)"),
                  file=out)
            return 0
        entry = store.get(args.id)
    sample = decode_sample(entry.trajectory, f"entry {entry.id}")
    print(f"entry {entry.id} ({entry.source}, {entry.method}, {entry.status}): T = "
          f"{entry.T:.6f} s, solved in {entry.solve_time:.2f} s", file=out)
    print(f"  start {entry.request.start_kind} {np.round(entry.request.start, 4).tolist()}",
          file=out)
    print(f"  target {entry.request.target_kind} "
          f"{np.round(entry.request.target, 4).tolist()}", file=out)
    print(f"  end configuration {np.round(entry.end_q, 4).tolist()} rad", file=out)
    print(f"  certificate: {entry.certificate.get('summary')}", file=out)
    print(f"  trajectory: {len(sample['t'])} samples; warm state {entry.warm_kind} "
          f"({len(entry.warm)} bytes)", file=out)
    spans = serve_spans(entry.serve)
    print("  serving state: " + (f"{spans} uniform spans with multipliers "
                                 f"({len(entry.serve)} bytes)" if spans else "none"), file=out)
    return 0


def _prune(args, out) -> int:
    if args.ids is None and args.source is None and not args.failed:
        print("memory: prune needs --ids, --source or --failed", file=out)
        return 2
    with _open(args.memory) as store:
        ids = set(args.ids or [])
        if args.source is not None:
            ids |= {r["id"] for r in store.summary() if r["source"] == args.source}
        removed = store.delete(sorted(ids))
        forgotten = store.forget_failed() if args.failed else 0
        store.vacuum()
    print(f"memory: {removed} motions removed, {forgotten} failed tasks forgotten", file=out)
    return 0


def _export(args, out) -> int:
    from tocontrol_ros.batch.library import TRAJECTORY_TYPE, trajectory_cdr
    from tocontrol_ros.nodes import qos
    from tocontrol_ros.recording import mcap_io

    with _open(args.memory) as store:
        ids = args.ids or [r["id"] for r in store.summary()]
        joints = json.loads(store.meta.get("robot", "{}")).get("joints", [])
        base = json.loads(store.meta.get("robot", "{}")).get("base_link", "")
        tmp = args.output.with_name(args.output.name + ".tmp")
        tmp.unlink(missing_ok=True)
        with mcap_io.RecordingWriter(tmp, compression="zstd") as writer:
            for i in ids:
                entry = store.get(i)
                sample = decode_sample(entry.trajectory, f"entry {i}")
                topic = f"{TOPIC_PREFIX}{i:05d}"
                writer.add_topic(topic, TRAJECTORY_TYPE, [qos.LATCHED])
                writer.write(topic, trajectory_cdr(sample, joints, base),
                             int(entry.created * 1e9), sequence=i)
        os.replace(tmp, args.output)
    print(f"memory: {len(ids)} motions in {args.output}", file=out)
    return 0


def _figure(args, out) -> int:
    from tocontrol_ros.memory.figure import coverage_figure

    with _open(args.memory) as store:
        rows = store.summary()
    if not rows:
        print(f"memory: {args.memory} holds no motion to draw", file=out)
        return 2
    coverage_figure(rows, args.output)
    print(f"memory: figure {args.output}", file=out)
    return 0


def run(args, stream=None) -> int:
    """Run a parsed command line; the exit status."""
    stream = stream if stream is not None else sys.stderr
    jobs = {"build": _build, "upgrade": _upgrade, "list": _list, "inspect": _inspect,
            "prune": _prune, "export": _export, "figure": _figure}
    try:
        return jobs[args.command](args, stream if args.command in ("build", "upgrade")
                                  else sys.stdout)
    except (MemoryFileError, CodecError) as exc:
        print(f"memory: {exc}", file=stream)
        return 2


def main(argv=None) -> int:
    """The ``memory`` executable; returns the exit status."""
    from rclpy.utilities import remove_ros_args

    argv = sys.argv[1:] if argv is None else argv
    return run(build_parser().parse_args(remove_ros_args(["memory", *argv])[1:]))


if __name__ == "__main__":
    sys.exit(main())
