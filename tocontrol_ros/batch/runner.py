"""Running a task set: the local process pool, the scheduling loop and the progress line.

A *backend* runs tasks somewhere: :class:`LocalPool` (this machine's cores, a
``ProcessPoolExecutor`` whose initializer builds the model once per worker) or
:class:`tocontrol_ros.batch.ray_backend.RayBackend`. Both offer ``capacity``, ``submit(task)``,
``poll(timeout)`` (finished tasks as ``(task, result, None)``, tasks whose worker died as
``(task, None, reason)``), ``stop(tasks)`` (stop the workers running these tasks) and
``close(abandon)``.

:func:`run_tasks` keeps ``capacity`` tasks in flight, journals each result as it arrives
(no task is journaled twice), submits a task again when its worker died (up to
:data:`MAX_ATTEMPTS`, then records it as lost), records a task still out after its
``hard_timeout`` as ``TIMEOUT`` (its worker stopped) and stops submitting when ``stop()`` turns
true, letting the tasks in flight finish unless ``abandon()`` turns true too.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
import sys
import time
from collections import deque

from tocontrol_ros.batch.library import Journal, trajectory_cdr
from tocontrol_ros.batch.tasks import RobotSpec, Task
from tocontrol_ros.batch.worker import LOST, TIMEOUT, init_worker, run_task

__all__ = ["LocalPool", "Progress", "run_tasks", "MAX_ATTEMPTS"]

#: Attempts of a task whose worker dies under it before it is recorded as lost.
MAX_ATTEMPTS = 3
#: Longest wait (s) in one poll, so Ctrl-C and the progress line are handled promptly.
POLL_PERIOD = 0.5


class LocalPool:
    """Worker processes on this machine (``spawn``ed: no fork of a threaded parent).

    Parameters
    ----------
    robot : RobotSpec
    workers : int
        Processes; each builds the model once, in its initializer.
    fn : callable (robot, task) -> dict, optional
        The work of one task (default :func:`~tocontrol_ros.batch.worker.run_task`; the
        memory's build passes its own); a module-level function (pickled by name).
    """

    def __init__(self, robot: RobotSpec, workers: int, fn=run_task) -> None:
        if workers < 1:
            raise ValueError(f"`workers` must be >= 1, got {workers!r}")
        self.robot = robot
        self.capacity = workers
        self.fn = fn
        self._pool = None
        self._futures: dict[cf.Future, tuple[Task, cf.ProcessPoolExecutor]] = {}
        self._context = multiprocessing.get_context("spawn")
        self._pids = None  # the workers report their pid here (to be stopped on a timeout)

    def _executor(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._pids = self._context.SimpleQueue()
            self._pool = cf.ProcessPoolExecutor(
                self.capacity, mp_context=self._context, initializer=init_worker,
                initargs=(self.robot, self._pids))
        return self._pool

    def stop(self, tasks) -> None:
        """Kill the pool's workers, since one cannot be stopped alone.

        `tasks` and the others in flight come back from :meth:`poll` as lost; the next
        submit starts a fresh pool.
        """
        if self._pool is None:
            return
        while not self._pids.empty():
            pid = self._pids.get()
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        # Returns once the pool has seen its workers die and failed their futures.
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None

    def submit(self, task: Task) -> None:
        """Start `task` on a free worker."""
        pool = self._executor()
        self._futures[pool.submit(self.fn, self.robot, task)] = (task, pool)

    def poll(self, timeout: float) -> list:
        """Finished tasks (waits up to `timeout` s for the first)."""
        if not self._futures:
            time.sleep(timeout)
            return []
        done, _ = cf.wait(list(self._futures), timeout, return_when=cf.FIRST_COMPLETED)
        out = []
        for future in done:
            task, pool = self._futures.pop(future)
            try:
                out.append((task, future.result(), None))
            except cf.process.BrokenProcessPool as exc:
                out.append((task, None, f"worker process died ({exc})"))
                if pool is self._pool:  # every task of a broken pool fails; start a new one
                    self._pool.shutdown(wait=False, cancel_futures=True)
                    self._pool = None
        return out

    def close(self, abandon: bool = False) -> None:
        """Shut the pool down; `abandon` kills workers still planning."""
        if self._pool is None:
            return
        if abandon:
            self._pool.shutdown(wait=False, cancel_futures=True)
            for child in multiprocessing.active_children():
                child.kill()
        self._pool.shutdown(wait=True)
        self._pool = None


class Progress:
    """A progress line on stderr: done / total, rate (motions/s) and the ETA.

    On a terminal the line is redrawn in place; otherwise one line every `period` s.
    """

    def __init__(self, total: int, done: int, stream=None, period: float = 2.0) -> None:
        self.total = total
        self.done0 = done
        self.done = done
        self.failed = 0
        self.stream = stream if stream is not None else sys.stderr
        self.period = period
        self.t0 = time.monotonic()
        self._last = -float("inf")
        self._tty = getattr(self.stream, "isatty", lambda: False)()

    def line(self) -> str:
        """The current text."""
        elapsed = time.monotonic() - self.t0
        new = self.done - self.done0
        rate = new / elapsed if elapsed > 0 else 0.0
        left = self.total - self.done
        eta = _clock(left / rate) if rate > 0 else "?"
        width = 24
        filled = int(width * self.done / self.total) if self.total else width
        return (f"batch [{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} "
                f"({self.failed} failed), {rate:.2f} motions/s, elapsed {_clock(elapsed)}, "
                f"ETA {eta}")

    def update(self, success: bool | None = None, force: bool = False) -> None:
        """Count a finished task (None: just redraw if due)."""
        if success is not None:
            self.done += 1
            self.failed += not success
        now = time.monotonic()
        if force or now - self._last >= (0.2 if self._tty else self.period):
            self._last = now
            end = "" if self._tty else "\n"
            self.stream.write(("\r" if self._tty else "") + self.line() + end)
            self.stream.flush()

    def finish(self) -> None:
        """Final line."""
        self.update(force=True)
        if self._tty:
            self.stream.write("\n")


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def run_tasks(tasks, backend, journal: Journal, joint_names, frame_id: str,
              progress: Progress | None = None, stop=lambda: False,
              abandon=lambda: False, on_result=None) -> dict:
    """Run `tasks` on `backend`, journaling each outcome (see the module docstring).

    Parameters
    ----------
    tasks : sequence of Task
        The tasks still to do (not in the journal).
    backend : LocalPool or RayBackend
    journal : Journal
    joint_names : sequence of str
    frame_id : str
        Frame of the stored trajectories.
    progress : Progress, optional
    stop, abandon : callable
        Polled: ``stop()`` ends submitting, ``abandon()`` also drops the tasks in flight.
    on_result : callable, optional
        Called with each ``(task, result)`` after it is journaled (tests, benchmarks).

    Returns
    -------
    dict
        ``recorded`` (tasks journaled in this run), ``lost_attempts`` (worker deaths),
        ``unfinished`` (tasks not journaled, to do on resume).
    """
    queue = deque(tasks)
    attempts: dict[str, int] = {}
    in_flight: dict[str, Task] = {}
    started: dict[str, float] = {}
    recorded = lost = 0

    def record(task, result):
        nonlocal recorded
        cdr = trajectory_cdr(result["sample"], joint_names, frame_id) \
            if result.get("sample") is not None else None
        if journal.record(task, result, attempts[task.key], cdr):
            recorded += 1
            if progress is not None:
                progress.update(bool(result.get("success")))
            if on_result is not None:
                on_result(task, result)

    try:
        while queue or in_flight:
            if abandon():
                break
            while queue and len(in_flight) < backend.capacity and not stop():
                task = queue.popleft()
                attempts[task.key] = attempts.get(task.key, 0) + 1
                in_flight[task.key] = task
                started[task.key] = time.monotonic()
                backend.submit(task)
            if stop() and not in_flight:
                break
            for task, result, error in backend.poll(POLL_PERIOD):
                if in_flight.pop(task.key, None) is None:
                    continue  # recorded already (timed out)
                if result is None:
                    lost += 1
                    if attempts[task.key] < MAX_ATTEMPTS and not stop():
                        queue.appendleft(task)
                        continue
                    if attempts[task.key] < MAX_ATTEMPTS:
                        continue  # stopping: left for the resumed run
                    result = {"status": LOST, "success": False, "message": error,
                              "pid": ""}
                record(task, result)
            now = time.monotonic()
            late = [t for t in in_flight.values() if now - started[t.key] > t.hard_timeout]
            if late:
                backend.stop(late)
                for task in late:
                    del in_flight[task.key]
                    record(task, {"status": TIMEOUT, "success": False, "pid": "",
                                  "message": f"no result after {now - started[task.key]:.1f} "
                                  f"s (hard_timeout {task.hard_timeout:g} s): worker stopped"})
            if progress is not None:
                progress.update()
    finally:
        backend.close(abandon=abandon() or bool(in_flight))
    return {"recorded": recorded, "lost_attempts": lost,
            "unfinished": len(queue) + len(in_flight)}
