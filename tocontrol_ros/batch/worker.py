"""The work of one ``batch`` worker: build the model once, then plan task after task.

Used by the local process pool (:func:`init_worker` is its initializer) and by the Ray
tasks (:func:`run_task` loads the model on a worker's first task and keeps it). No ROS
import: a result is plain data (numbers, strings, numpy arrays) that the main process
turns into messages.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np

from tocontrol_ros.batch.tasks import RobotSpec, Task, build_problem, load_model
from tocontrol_ros.core.errors import TocontrolError

__all__ = ["init_worker", "run_task", "worker_model", "ERROR", "LOST", "TIMEOUT"]

#: Status of a task whose problem or options the core rejected in the worker.
ERROR = "ERROR"
#: Status of a task whose worker died on every attempt.
LOST = "WORKER_LOST"
#: Status of a task that outlived its hard time limit and was cancelled by the runner.
TIMEOUT = "TIMEOUT"

_MODELS: dict[str, object] = {}
#: How often (s) a pool worker checks that the process that started it is still there.
PARENT_CHECK_PERIOD = 1.0
#: Models built by this process (a test and the benchmark read it: once per worker).
builds = 0


def worker_model(robot: RobotSpec):
    """The model of `robot` in this process, built on first use and kept."""
    global builds
    key = robot.urdf + repr(robot.options)
    model = _MODELS.get(key)
    if model is None:
        model = _MODELS[key] = load_model(robot)
        builds += 1
    return model


def _exit_with_parent(parent: int) -> None:
    # A pool worker whose parent was killed outright would wait on its task queue forever
    # (its siblings keep the pipe open), so it leaves by itself.
    while os.getppid() == parent:
        time.sleep(PARENT_CHECK_PERIOD)
    os._exit(1)


def init_worker(robot: RobotSpec, pids=None) -> None:
    """Pool initializer: Ctrl-C goes to the main process, the worker dies with it; model now.

    Parameters
    ----------
    robot : RobotSpec
    pids : multiprocessing.SimpleQueue, optional
        Where the worker puts its process id (so that the runner can stop it).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if pids is not None:
        pids.put(os.getpid())
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True,
                     name="exit-with-parent").start()
    worker_model(robot)


def run_task(robot: RobotSpec, task: Task) -> dict:
    """Plan one task; numerical failures and rejected problems are results, not exceptions.

    Returns
    -------
    dict
        ``index``, ``key``, ``status`` (a :class:`~tocontrol_ros.core.planning.solver.Status` name,
        or :data:`ERROR` for a rejected problem or an unexpected exception), ``success``,
        ``message``, ``T`` (s), ``k``, ``solve_time`` (s), ``iterations``, ``residual``,
        ``max_abs_u``, ``pid``, ``builds`` (models this process built so far) and
        ``sample``: ``None`` or a dict of arrays ``t`` shape (K,) (s), ``q``, ``qd``, ``qdd``
        (rad, rad/s, rad/s^2), ``tau`` (N m), each (K, n).
    """
    from tocontrol_ros.core.planning.solver import SolverOptions, plan

    t0 = time.perf_counter()
    out = {"index": task.index, "key": task.key, "pid": os.getpid(), "sample": None,
           "T": float("nan"), "k": task.k, "iterations": 0, "residual": float("nan"),
           "max_abs_u": float("nan")}
    try:
        model = worker_model(robot)
        result = plan(build_problem(model, task), SolverOptions(**dict(task.solver)))
    except TocontrolError as exc:
        out.update(status=ERROR, success=False, message=str(exc),
                   solve_time=time.perf_counter() - t0, builds=builds)
        return out
    except Exception as exc:  # noqa: BLE001  (a bug hit by one task must not stop the cell)
        out.update(status=ERROR, success=False,
                   message=f"unexpected {type(exc).__name__} in the solver: {exc}",
                   solve_time=time.perf_counter() - t0, builds=builds)
        return out
    out.update(status=result.status.name, success=bool(result.success),
               message=result.message, T=float(result.T), k=float(result.k),
               solve_time=time.perf_counter() - t0, iterations=int(result.iterations),
               residual=float(result.residual), max_abs_u=float(result.max_abs_u),
               builds=builds)
    if result.success and result.trajectory is not None:
        s = result.trajectory.sample(task.sample_period)
        out["sample"] = {name: np.asarray(getattr(s, name), dtype=float)
                         for name in ("t", "q", "qd", "qdd", "tau")}
    return out
