r"""Batch planning: ``ros2 run tocontrol_ros batch TASKS.yaml`` plans a whole work cell.

Every motion of a task file (see :mod:`tocontrol_ros.batch.tasks`) is one task, planned on
this machine's cores by default (a process pool; each worker builds the model once) or on
a Ray cluster with ``--ray auto|local|ADDRESS`` (see :mod:`tocontrol_ros.batch.ray_backend`). A
progress line with the rate and the ETA goes to stderr.

The results land next to ``--output`` (default: the task file with ``.mcap``): the library
``cell.mcap`` (one ``trajectory_msgs/JointTrajectory`` per solved motion, topic
``/library/motion_<index>``, in the recorder's rosbag2 layout), the summary ``cell.csv``
(one row per task: status, T, solve time, ...) and the journal ``cell.journal.jsonl``
(see :mod:`tocontrol_ros.batch.library`). A run that is interrupted (Ctrl-C: the tasks in
flight finish; a second Ctrl-C drops them) or killed resumes where it stopped when the same
command is run again: journaled tasks are not planned again, and none is lost. A task that
fails or runs out of time is recorded with its status; the others go on.

Usage::

    ros2 run tocontrol_ros batch cell.yaml --workers 2
    ros2 run tocontrol_ros batch cell.yaml --ray auto -o runs/cell.mcap
    ros2 run tocontrol_ros replay cell.mcap --topics /library/motion_00003 \
        --ros-args -r /library/motion_00003:=/planner/trajectory

Exit status: 0 when every task is recorded (whatever its outcome), 130 when interrupted
(run again to resume), 2 for a bad task file or options.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections import Counter
from pathlib import Path

from tocontrol_ros.batch.library import Journal, library_paths, write_library, write_summary
from tocontrol_ros.batch.ray_backend import RayBackend, RayUnavailableError
from tocontrol_ros.batch.runner import LocalPool, Progress, run_tasks
from tocontrol_ros.batch.tasks import TaskFileError, load_task_file

__all__ = ["main", "build_parser", "run"]

EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog="batch", description="Plan every motion of a task file into an MCAP library.")
    parser.add_argument("tasks", type=Path, metavar="TASKS.yaml", help="task file")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="LIB.mcap",
                        help="library (default: the task file with .mcap); the summary "
                        "(.csv) and the journal (.journal.jsonl) go next to it")
    parser.add_argument("-j", "--workers", type=int, default=None, metavar="N",
                        help="worker processes (default: this machine's cores); with "
                        "--ray local the cluster's CPUs, else at most N tasks at once")
    parser.add_argument("--ray", default=None, metavar="auto|local|ADDRESS",
                        help="plan on a Ray cluster: `auto` joins the one `ray start` "
                        "started here, `local` starts a private one on 127.0.0.1, else its "
                        "address")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    return parser


def _backend(args, robot):
    if args.ray is None:
        return LocalPool(robot, args.workers or os.cpu_count() or 1)
    return RayBackend(robot, args.ray, args.workers)


def run(args, stream=None) -> int:
    """Run a parsed command line; returns the exit status."""
    stream = stream if stream is not None else sys.stderr
    if args.workers is not None and args.workers < 1:
        print(f"batch: --workers must be >= 1, got {args.workers}", file=stream)
        return 2
    try:
        task_set, model = load_task_file(args.tasks)
        paths = library_paths(args.output or args.tasks.with_suffix(".mcap"))
        if paths["mcap"].exists() and not paths["journal"].exists():
            raise TaskFileError(f"{paths['mcap']} exists without its journal "
                                f"{paths['journal'].name}: not overwriting it")
        journal = Journal(paths["journal"], task_set.fingerprint)
    except (TaskFileError, OSError) as exc:
        print(f"batch: {exc}", file=stream)
        return 2
    todo = [t for t in task_set.tasks if t.key not in journal.entries]
    total = len(task_set.tasks)
    print(f"batch: {total} tasks, {total - len(todo)} done already ({journal.path}), "
          f"{len(todo)} to plan", file=stream)
    signals = []
    previous = {sig: signal.signal(sig, lambda *_: signals.append(True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        backend = _backend(args, task_set.robot) if todo else None
        progress = None if args.quiet else Progress(total, total - len(todo), stream)
        outcome = {"unfinished": 0}
        if todo:
            outcome = run_tasks(todo, backend, journal, model.joint_names, model.base_link,
                                progress, stop=lambda: bool(signals),
                                abandon=lambda: len(signals) > 1)
            if progress is not None:
                progress.finish()
    except RayUnavailableError as exc:
        print(f"batch: {exc}", file=stream)
        return 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        journal.close()
    motions = write_library(paths["mcap"], task_set.tasks, journal.entries)
    write_summary(paths["csv"], task_set.tasks, journal.entries)
    counts = Counter(e["status"] for e in journal.entries.values())
    statuses = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    print(f"batch: {motions} motions in {paths['mcap']}, summary {paths['csv']} "
          f"({statuses or 'nothing done'})", file=stream)
    if outcome["unfinished"] or len(journal.entries) < total:
        print(f"batch: interrupted with {total - len(journal.entries)} tasks left; run the "
              "same command again to resume", file=stream)
        return EXIT_INTERRUPTED
    return 0


def main(argv=None) -> int:
    """Plan a task file; returns the exit status."""
    from rclpy.utilities import remove_ros_args

    argv = sys.argv[1:] if argv is None else argv
    # Not a node, but `ros2 launch` appends --ros-args to every executable it starts.
    return run(build_parser().parse_args(remove_ros_args(["batch", *argv])[1:]))


if __name__ == "__main__":
    sys.exit(main())
