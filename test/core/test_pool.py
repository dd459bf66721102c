"""Worker processes (core/planning/pool.py): the same answer with any number of workers.

The pool's own contract (results in the items' order, an item's exception where it
stands, a worker that dies replaced by the caller) with small module-level functions, and
the bounded solve of a plan whose joint limits bind: every digit of ``T``, the start
records and the trajectory's bits the same with two workers as with one.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.methods.context import SolveContext, StopError
from tocontrol_ros.core.planning.pool import WorkerPool
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.types.problem import Problem, point
from tocontrol_ros.core.types.result import Status

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plan_probe import fingerprint  # noqa: E402

#: Velocity limits (rad/s) that bind on the paper's example (as in test_limits.py).
TIGHT = np.array([0.4, 1.0, 1.0])
#: A hang guard only (the first bounded solve compiles its NLP).
SLOW_OK = 600.0


class _Prepared:
    """A stand-in for a prepared model: what the worker's factory builds."""

    def __init__(self, model) -> None:
        self.model = model
        self.pid = os.getpid()


def _square(prepared, ctx, x):
    return x * x, prepared.pid


def _fail_on(prepared, ctx, x, bad):
    if x == bad:
        raise ValueError(f"item {x}")
    return x


def _stop_on(prepared, ctx, x, bad):
    if x == bad:
        raise StopError(Status.CANCELLED)
    return x


def _die_on(prepared, ctx, x, bad):
    if x == bad and prepared.pid != ctx.options.tol:  # not in the caller's process
        os.kill(os.getpid(), signal.SIGKILL)
    return x


def _ctx(model, caller_pid=0):
    problem = Problem(model, point([1.0, 1.0]), point([2.2, 1.5]), k=4.0)
    # options.tol carries the caller's pid into _die_on (any positive number is valid)
    return SolveContext(None, problem, SolverOptions(tol=float(caller_pid or 1)), np.inf)


@pytest.fixture(scope="module")
def pool():
    p = WorkerPool(2, _Prepared)
    yield p
    p.close()


def test_results_come_in_the_items_order(galicki, pool):
    out = list(pool.map(_square, _Prepared(galicki), _ctx(galicki), [(x,) for x in range(12)]))
    assert [value for value, _ in out] == [x * x for x in range(12)]


def test_an_items_exception_is_raised_where_it_stands(galicki, pool):
    it = pool.map(_fail_on, _Prepared(galicki), _ctx(galicki), [(x, 3) for x in range(6)])
    assert [next(it) for _ in range(3)] == [0, 1, 2]
    with pytest.raises(ValueError, match="item 3"):
        next(it)


def test_a_stop_in_a_worker_reaches_the_caller_as_a_stop(galicki, pool):
    assert pickle.loads(pickle.dumps(StopError(Status.TIME_LIMIT))).status is Status.TIME_LIMIT
    with pytest.raises(StopError) as info:
        list(pool.map(_stop_on, _Prepared(galicki), _ctx(galicki), [(x, 4) for x in range(8)]))
    assert info.value.status is Status.CANCELLED


def test_a_worker_that_dies_is_replaced_by_the_caller(galicki):
    p = WorkerPool(2, _Prepared)
    try:
        # Let the worker start, so that it (not only the caller) takes items.
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            pids = {pid for _, pid in p.map(_square, _Prepared(galicki), _ctx(galicki),
                                            [(x,) for x in range(40)])}
            if len(pids) > 1:
                break
        assert len(pids) > 1, "the worker never took an item: only the caller would be tested"
        ctx = _ctx(galicki, caller_pid=os.getpid())
        caller = _Prepared(galicki)
        caller.pid = os.getpid()
        items = [(x, x) for x in range(40)]  # every item kills a worker that takes it
        assert list(p.map(_die_on, caller, ctx, items)) == list(range(40))
    finally:
        p.close()


def test_workers_must_be_a_count():
    with pytest.raises(ProblemError, match="workers"):
        SolverOptions(workers=-1)
    with pytest.raises(ProblemError, match="workers"):
        SolverOptions(workers=1.5)
    assert SolverOptions(workers=0).workers == 0


def test_a_model_pickles_as_its_data_once_per_process(galicki):
    data = pickle.dumps(galicki)
    again, twice = pickle.loads(data), pickle.loads(data)
    assert again is twice and again is not galicki
    q = np.array([0.3, -0.2, 0.5])
    assert np.array_equal(again.point(q), galicki.point(q))
    assert np.array_equal(again.mass_matrix(q), galicki.mass_matrix(q))


def test_two_workers_plan_what_one_plans(galicki):
    base = JointLimits.from_model(galicki)
    limits = JointLimits(base.names, base.lower, base.upper, TIGHT)
    problem = Problem(galicki, point([1.0, 1.0]), point([2.2, 1.5]), k=4.0, limits=limits)
    one = plan(problem, SolverOptions(starts=6, candidates=3, time_limit=SLOW_OK))
    two = plan(problem, SolverOptions(starts=6, candidates=3, time_limit=SLOW_OK, workers=2))
    assert one.success and one.method == "direct", one.message
    assert sum(np.isfinite(r.T) for r in one.starts) >= 2  # more than one candidate solved
    assert fingerprint(two) == fingerprint(one)


SIGINT_SCRIPT = """
import os, signal, sys, threading, time
signal.signal(signal.SIGINT, lambda *_: None)  # a handler of its own, as the nodes have
from tocontrol_ros.core.planning.pool import WorkerPool
import test_pool
served = threading.Event()

def ctrl_c():
    # Ctrl-C to the group again and again, from the workers' start until one has served an
    # item: some land while it imports its modules, whatever the machine's speed.
    while not served.is_set():
        os.killpg(0, signal.SIGINT)
        time.sleep(0.005)

sender = threading.Thread(target=ctrl_c)
pool = WorkerPool(2, test_pool._Prepared)
sender.start()
model = test_pool._model()
deadline = time.monotonic() + 120.0
pids = set()
while not pids - {os.getpid()} and time.monotonic() < deadline:
    pids = {pid for _, pid in pool.map(test_pool._square, test_pool._Prepared(model),
                                       test_pool._ctx(model), [(x,) for x in range(40)])}
served.set()
sender.join()
assert pids - {os.getpid()}, "the worker never took an item"
assert all(p.is_alive() for p in pool._procs), "a worker died of the SIGINT"
out = [v for v, _ in pool.map(test_pool._square, test_pool._Prepared(model),
                              test_pool._ctx(model), [(x,) for x in range(20)])]
assert out == [x * x for x in range(20)], out
pool.close()
print("done")
"""


def _model():
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    return load_robot(default_urdf_path())


def test_ctrl_c_to_the_group_leaves_starting_workers_quiet(tmp_path):
    # A KeyboardInterrupt traceback from a worker importing its modules when ros2 launch
    # sent SIGINT to the group failed a loaded CI run: the workers start with SIGINT blocked.
    import subprocess

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent))
    proc = subprocess.run([sys.executable, "-P", "-c", SIGINT_SCRIPT], env=env,
                          capture_output=True, text=True, timeout=300, process_group=0)
    assert proc.returncode == 0 and "done" in proc.stdout, proc.stderr
    assert "Traceback" not in proc.stderr and "KeyboardInterrupt" not in proc.stderr, \
        proc.stderr
