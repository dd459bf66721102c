"""Building a memory: every task of a cell planned by the batch machinery into the file.

The tasks run on the batch backends (:class:`~tocontrol_ros.batch.runner.LocalPool`: this
machine's cores, each worker building the model once; or
:class:`~tocontrol_ros.batch.ray_backend.RayBackend`) with :func:`build_task` as the work of
one task, scheduled by :func:`~tocontrol_ros.batch.runner.run_tasks` (worker deaths retried,
hard timeouts, Ctrl-C) with its progress line and ETA. Each finished task goes straight into
the SQLite file (:class:`MemoryLog`): its certified motion as an entry, its outcome in the
build's log, so that a build run again (after a Ctrl-C, a kill, or with more targets in
the cell) plans only what is not there yet.
"""

from __future__ import annotations

import os
import time

from tocontrol_ros.batch import worker as batch_worker
from tocontrol_ros.batch.tasks import RobotSpec
from tocontrol_ros.batch.worker import ERROR, worker_model
from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.memory.cell import MotionTask, task_problem

__all__ = ["build_task", "MemoryLog", "task_limits"]

_PLANNERS: dict = {}  # this worker's Planner per model (the batch worker keeps one model)


def _planner(model, problem, options):
    """The :class:`~tocontrol_ros.core.planning.solver.Planner` of ``model`` in this worker."""
    from tocontrol_ros.core.planning.solver import Planner

    planner = _PLANNERS.get(id(model))
    if planner is None or planner.model is not model or planner.stale():
        planner = _PLANNERS[id(model)] = Planner(model)
        planner.prepare(problem, options, shooting=False)
    return planner


def task_limits(task: MotionTask):
    """The :class:`~tocontrol_ros.core.robot.limits.JointLimits` a task carries."""
    from tocontrol_ros.core.robot.limits import JointLimits

    names, lower, upper, velocity, margin = task.limits
    return JointLimits(tuple(names), lower, upper, velocity, margin)


def build_task(robot: RobotSpec, task: MotionTask) -> dict:
    """Plan one task with the cell's (wide) search; plain data back to the parent.

    Returns
    -------
    dict
        ``status`` (a Status name or ``ERROR``), ``success``, ``message``, ``T`` (s),
        ``solve_time`` (s), ``pid``, ``builds``, and ``entry``: the fields
        :func:`~tocontrol_ros.core.memory.recall.entry_fields` stores (with ``serve``, the
        serving state, or None when the motion has none), or None; ``serve_message``.
    """
    from tocontrol_ros.core.memory.recall import DEFAULT_SPANS, entry_fields
    from tocontrol_ros.core.memory.serve import serve_result
    from tocontrol_ros.core.planning.solver import SolverOptions

    t0 = time.perf_counter()
    out = {"index": task.index, "key": task.key, "pid": os.getpid(), "entry": None,
           "T": float("nan")}
    try:
        model = worker_model(robot)
        problem = task_problem(model, task_limits(task), task)
        options = SolverOptions(**dict(task.solver))
        planner = _planner(model, problem, options)
        result = planner.plan(problem, options)
    except TocontrolError as exc:
        out.update(status=ERROR, success=False, message=str(exc),
                   solve_time=time.perf_counter() - t0, builds=batch_worker.builds)
        return out
    except Exception as exc:  # noqa: BLE001  (one task's bug must not stop the build)
        out.update(status=ERROR, success=False,
                   message=f"unexpected {type(exc).__name__} in the solver: {exc}",
                   solve_time=time.perf_counter() - t0, builds=batch_worker.builds)
        return out
    solve_time = time.perf_counter() - t0
    entry = entry_fields(result, "build", solve_time, task.sample_period)
    if entry is not None and entry["warm_kind"] == "path":
        try:
            served, entry["serve"] = serve_result(planner, result, options, DEFAULT_SPANS)
            out["serve_message"] = served.message
        except Exception as exc:  # noqa: BLE001  (the motion is stored without it)
            entry["serve"] = None
            out["serve_message"] = f"unexpected {type(exc).__name__}: {exc}"
    out.update(status=result.status.name, success=entry is not None,
               message=result.message, T=float(result.T), solve_time=solve_time,
               builds=batch_worker.builds, entry=entry)
    return out


class MemoryLog:
    """The batch runner's journal, writing into a memory file instead.

    Parameters
    ----------
    store : MotionStore
    """

    def __init__(self, store) -> None:
        self.store = store
        self.entries = store.tasks()  # key -> outcome: the tasks done before
        self.stored = 0

    def record(self, task: MotionTask, result: dict, attempts: int, cdr=None) -> bool:
        """Store a finished task's motion and outcome; False when it was recorded already."""
        if task.key in self.entries:
            return False
        entry = result.get("entry")
        if entry is not None:
            fields = dict(entry)
            self.stored += self.store.add(fields.pop("request"), **fields)
        self.store.log_task(task.key, str(result.get("status")), str(result.get("message", "")),
                            result.get("T"), result.get("solve_time"),
                            str(result.get("pid", "")))
        self.entries[task.key] = {"status": result.get("status"), "attempts": attempts}
        return True
