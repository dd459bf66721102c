"""Independent pieces of one solve on several cores: the caller's process and workers.

A :class:`WorkerPool` runs ``fn(prepared, ctx, *item)`` for a list of items and returns the
results in the items' order, whichever process computed each: the answer does not depend
on which finishes first, nor on how many workers there are (each item is a deterministic
function of its inputs, and the compiled libraries give the same bits in every process,
:data:`~tocontrol_ros.core.robot.compiled.SAME_BITS`).

The caller's process takes items too, from the same queue as the workers: while the
workers start (a new process imports CasADi and loads the model's compiled libraries, a
second or two) or when they are busy, it does all the work itself, so a pool never makes
a solve wait. Workers are separate processes (``spawn``), not threads: IPOPT holds a lock
around every MUMPS call, so threads solving NLPs side by side do not run in parallel
(measured: two bounded Panda solves in two threads, 1.1-1.4x the speed of one after the
other).

What crosses to a worker is pickled: ``fn`` (a module-level function), the solve's
context without its compiled system (:meth:`SolveContext.portable`), the item. The model
goes as its data (:meth:`RobotModel.__reduce__`) and is rebuilt once per worker; each
worker keeps one :class:`~tocontrol_ros.core.planning.prepared.PreparedModel` per model. A
cancelled solve sets an event the workers' solves poll; the caller's deadline travels with
the context. A worker that dies is replaced by the caller's process for the items it held
(the pool is then not used again).
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import queue
import signal
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence

__all__ = ["WorkerPool", "available_cores", "shared_pool"]

#: How often (s) the caller's process, waiting for the workers' last items, looks whether
#: a worker died. Only a liveness check: the results do not depend on it.
LIVENESS_POLL = 0.05
#: How often (s) an idle worker looks whether the caller's process is still there (a
#: caller killed without closing its pool leaves no worker behind).
PARENT_POLL = 1.0


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


_POOLS: dict[int, WorkerPool] = {}
_POOLS_LOCK = threading.Lock()


def shared_pool(workers: int, factory: Callable) -> WorkerPool:
    """The process's pool of ``workers`` (started on first use, kept until exit)."""
    with _POOLS_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = WorkerPool(workers, factory)
        return pool


class WorkerPool:
    """``workers - 1`` worker processes that share a solve's items with the caller's.

    Parameters
    ----------
    workers : int
        Processes that solve, the caller's included (2 on a two-core machine).
    factory : callable
        ``factory(model)`` builds a worker's prepared model (a picklable class or
        module-level function), once per model and worker.
    """

    def __init__(self, workers: int, factory: Callable) -> None:
        mp = multiprocessing.get_context("spawn")
        self.workers = int(workers)
        self._tasks = mp.Queue()
        self._results = mp.Queue()
        # Items left in a queue (those of a dead worker's map, the stop markers of workers
        # already gone) must not hold the interpreter's exit: without this, it waits for
        # the queue's feeder thread, blocked on a full pipe that nobody reads.
        self._tasks.cancel_join_thread()
        self._results.cancel_join_thread()
        self._stop = mp.Event()
        self._generation = mp.Value("q", 0)
        self._lock = threading.Lock()  # one map at a time
        self.broken = False
        self._procs = [mp.Process(target=_worker, name=f"tocontrol-worker-{i + 1}",
                                  args=(self._tasks, self._results, self._stop,
                                        self._generation, factory), daemon=True)
                       for i in range(self.workers - 1)]
        # The workers start with SIGINT blocked (a signal mask survives the fork and the
        # exec): Ctrl-C in a terminal, or ros2 launch's SIGINT to the process group, is the
        # caller's to handle, also while a worker is still importing (where a handler set
        # in the worker would come too late and print a KeyboardInterrupt traceback).
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            for proc in self._procs:
                proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)

    def map(self, fn: Callable, prepared, ctx, items: Sequence[tuple]) -> Iterator:
        """``fn(prepared, ctx, *item)`` for each item, the items shared out; in order.

        Yields once every item has ended (so a stop, the deadline or a cancel, leaves no
        item running); an item's exception is raised where the item stands.
        """
        items = list(items)
        if len(items) < 2 or self.broken or not self._procs:
            for item in items:
                yield fn(prepared, ctx, *item)
            return
        with self._lock:
            done = self._map(fn, prepared, ctx, items)
        for i in range(len(items)):
            ok, value = done[i]
            if not ok:
                raise value
            yield value

    def _map(self, fn, prepared, ctx, items) -> dict[int, tuple[bool, object]]:
        with self._generation.get_lock():
            self._generation.value += 1
            generation = self._generation.value
        self._stop.clear()
        portable = ctx.portable()
        for i, item in enumerate(items):
            self._tasks.put((generation, i, pickle.dumps((fn, portable, item))))
        done: dict[int, tuple[bool, object]] = {}
        watcher = _StopWatcher(ctx.should_stop, self._stop)
        try:
            while len(done) < len(items):
                mine = self._take(generation)
                if mine is not None:
                    if mine not in done:
                        done[mine] = _call(fn, prepared, ctx, items[mine])
                    continue
                self._collect(generation, done)
                if not all(proc.is_alive() for proc in self._procs):
                    # A worker died holding items: the caller's process solves what is
                    # missing (an item solved twice gives the same result), and the pool
                    # is not used again.
                    self.broken = True
                    for i, item in enumerate(items):
                        if i not in done:
                            done[i] = _call(fn, prepared, ctx, item)
        finally:
            watcher.close()
        return done

    def _take(self, generation: int) -> int | None:
        """An item of this map still in the queue (the caller's process solves it), or None."""
        while True:
            try:
                gen, i, _ = self._tasks.get_nowait()
            except queue.Empty:
                return None
            if gen == generation:
                return i

    def _collect(self, generation: int, done: dict) -> None:
        """One worker's result of this map into ``done``, if one comes within the poll."""
        try:
            gen, i, ok, payload = self._results.get(timeout=LIVENESS_POLL)
        except queue.Empty:
            return
        if gen == generation and i not in done:
            value = pickle.loads(payload)
            done[i] = (ok, value)

    def close(self) -> None:
        """Stop the workers (they exit after their current item)."""
        self._stop.set()
        for _ in self._procs:
            self._tasks.put(None)
        for proc in self._procs:
            proc.join(timeout=5.0)
            if proc.is_alive():
                proc.kill()
        self._procs = []


def _call(fn, prepared, ctx, item) -> tuple[bool, object]:
    try:
        return True, fn(prepared, ctx, *item)
    except Exception as exc:  # re-raised by map, in the items' order
        return False, exc


class _StopWatcher:
    """Sets the workers' stop event when the caller's ``should_stop`` turns true."""

    def __init__(self, should_stop, event) -> None:
        self._done = threading.Event()
        self._thread = None
        if should_stop is not None:
            def watch():
                while not self._done.wait(LIVENESS_POLL):
                    if should_stop():
                        event.set()
                        return
            self._thread = threading.Thread(target=watch, daemon=True)
            self._thread.start()

    def close(self) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join()


def _worker(tasks, results, stop, generation, factory) -> None:
    """A worker's loop: items until ``None``; one prepared model per model.

    SIGINT stays blocked (see :class:`WorkerPool`): a worker ends with the caller (a
    daemon process) or when :meth:`WorkerPool.close` asks.
    """
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    prepared: dict[int, object] = {}
    parent = os.getppid()
    while True:
        try:
            task = tasks.get(timeout=PARENT_POLL)
        except queue.Empty:
            if os.getppid() != parent:  # the caller died without closing the pool
                return
            continue
        if task is None:
            return
        gen, i, payload = task
        if gen != generation.value:
            continue  # an item of a map that has ended (stopped)
        try:
            fn, ctx, item = pickle.loads(payload)
            model = ctx.problem.model
            if id(model) not in prepared:
                prepared[id(model)] = factory(model)
            out = (True, fn(prepared[id(model)], ctx.attached(stop.is_set), *item))
        except Exception as exc:
            exc.add_note(traceback.format_exc())
            out = (False, exc)
        try:
            data = pickle.dumps(out[1])
        except Exception as exc:  # an unpicklable result or exception
            out, data = (False, None), pickle.dumps(RuntimeError(f"worker: {exc!r}"))
        results.put((gen, i, out[0], data))
