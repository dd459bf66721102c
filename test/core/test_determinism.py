"""Same request, same plan: on an idle and on a loaded machine, whatever the clock reads.

The solver decides by work (iterations, levels, candidates), never by the clock: the one
wall-clock limit is the caller's ``time_limit`` (and cancel). Three checks:

- the same case planned in two new processes, the second beside CPU-bound processes (one
  per core), prints the same fingerprint: every digit of ``T``, the start records, and a
  hash of the trajectory's bits (:mod:`plan_probe`);
- in-process, a clock whose speed comes and goes (up to 100 s per reading in its fast
  spells: any rule like "5 s per level", "ten times the last solve" or "half the time left"
  would fire at random) gives the same fingerprint as the real one;
- the core's readings of the clock, recorded during those solves, are the deadline's and
  the reported timings' only (:data:`CLOCK_SITES`).

The C libraries round alike at every optimisation level
(``test_compiled.py::test_every_build_of_a_source_gives_the_same_bits``), so which of them
had landed does not change the bits either.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tocontrol_ros.core.planning.solver import SolverOptions, plan

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plan_probe import fingerprint, problem_of  # noqa: E402
from skip_policy import missing

PROBE = Path(__file__).resolve().parent / "plan_probe.py"

#: A new process's plan (model loading, compiled functions from the cache) on a loaded
#: machine: generous, the test waits for the answer, it does not time it.
PROBE_TIMEOUT = 900.0

#: Every place in the core that reads the clock, and why. A reading that chooses what the
#: solver does next would make the answer depend on the machine's load; only the caller's
#: deadline may (and when it fires the result says TIME_LIMIT).
CLOCK_SITES = {
    ("context.py", "check"): "the caller's deadline (between Newton iterations and stages)",
    ("flat.py", "eval"): "the caller's deadline (IPOPT's iteration callback)",
    ("newton.py", "_stopped"): "the caller's deadline (between Newton iterations)",
    ("solver.py", "_plan"): "timings; the deadline is set from time_limit",
    ("solver.py", "solve_once"): "timings",
    ("method.py", "_cold"): "timings",
    ("method.py", "_result"): "timings",
    ("method.py", "solve"): "timings",
    ("method.py", "warm_start"): "timings",
    ("method.py", "_finish"): "timings",
    ("prepared.py", "prepare_shooting"): "timings (the deadline moves by the compile time)",
    ("solver.py", "elapsed"): "timings",
    ("limited.py", "plan_limited"): "timings",
    ("limited.py", "plan_limited_warm"): "timings",
    ("checked.py", "verified"): "timings",
    ("checked.py", "__call__"): "timings (the first motion's, FirstIterate)",
    ("limited.py", "_infeasible"): "timings",
    ("limited.py", "_parametric"): "timings",
    ("sensitivity.py", "sensitivity_solve"): "timings (FlatResult.solve_time)",
    ("path_following.py", "follow"): "timings (FlatResult.solve_time)",
    ("flat.py", "solve"): "timings (FlatResult.solve_time)",
    ("early.py", "watch"): "timings of the early motions' checks (EarlyMotion.seen, a report)",
    ("collocation.py", "solve"): "timings (DirectResult.solve_time)",
    ("compiled.py", "_gcc"): "timings of the compiler (progress reports)",
}


def _run_probe(case: str, urdf: str | None, burners: int) -> dict:
    """The probe's fingerprint, planned in a new process beside ``burners`` busy loops."""
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
             for _ in range(burners)]
    try:
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        proc = subprocess.run([sys.executable, "-P", str(PROBE), case]
                              + ([urdf] if urdf else []), capture_output=True, text=True,
                              timeout=PROBE_TIMEOUT, env=env)
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _panda_urdf(robot_specs) -> str:
    if "panda" not in robot_specs:
        missing("the Panda URDF of example-robot-data (pip install '.[test]')")
    return str(robot_specs["panda"]["source"])


def _same_idle_and_loaded(case: str, urdf: str | None) -> None:
    idle = _run_probe(case, urdf, burners=0)
    assert idle["status"] == "SUCCESS", idle
    loaded = _run_probe(case, urdf, burners=os.cpu_count() or 2)
    assert loaded == idle


def test_the_paper_arm_plans_the_same_idle_and_loaded():
    """The default multistart on the paper's example, k = 4."""
    _same_idle_and_loaded("paper", None)


@pytest.mark.slow
def test_the_panda_with_its_limits_plans_the_same_idle_and_loaded(robot_specs):
    """The bounded solve (default options) of a Panda motion whose limits bind."""
    _same_idle_and_loaded("panda", _panda_urdf(robot_specs))


class _JitteryClock:
    """``time.perf_counter`` whose speed comes and goes, as a machine's load does.

    Every reading moves it forward by up to ``jump`` s in its fast spells and by up to
    ``jump * 1e-6`` in its slow ones; a spell ends at any reading with probability
    :attr:`SWITCH` (spells of some 300 readings, about one IPOPT solve). So one solve may
    look a million times slower than the one before it:
    any rule on measured times (a budget per level, "ten times the last solve", "half the
    time left") fires at random. Records which functions of the core read it.
    """

    SWITCH = 0.003

    def __init__(self, real, jump: float) -> None:
        self._real, self._jump = real, jump
        self._rng = np.random.default_rng(3)
        self._offset, self._fast = 0.0, True
        self._lock = threading.Lock()
        self.sites: set[tuple[str, str]] = set()

    def __call__(self) -> float:
        caller = sys._getframe(1).f_code
        if f"tocontrol_ros{os.sep}core{os.sep}" in caller.co_filename:
            self.sites.add((Path(caller.co_filename).name, caller.co_name))
        with self._lock:
            if self._rng.uniform() < self.SWITCH:
                self._fast = not self._fast
            scale = self._jump if self._fast else 1e-6 * self._jump
            self._offset += scale * float(self._rng.uniform())
            return self._real() + self._offset


def _jittered(monkeypatch, problem, options) -> tuple[dict, set]:
    clock = _JitteryClock(time.perf_counter, jump=100.0)
    with monkeypatch.context() as patch:
        patch.setattr(time, "perf_counter", clock)
        patch.setattr(time, "monotonic", clock)
        result = plan(problem, options)
    return fingerprint(result), clock.sites


@pytest.mark.parametrize("case", ["paper", "panda"])
def test_no_decision_reads_the_clock(case, robot_specs, monkeypatch):
    """A clock whose speed comes and goes (the time limit far away) leaves
    every digit of the plan as the real clock does; the core reads it only at the sites of
    CLOCK_SITES."""
    urdf = _panda_urdf(robot_specs) if case == "panda" else None
    problem = problem_of(case, urdf)
    options = SolverOptions(time_limit=1e9)
    if case == "panda":
        options = SolverOptions(time_limit=1e9, starts=2, candidates=2)
    real = fingerprint(plan(problem, options))
    assert real["status"] == "SUCCESS", real
    jittered, sites = _jittered(monkeypatch, problem, options)
    assert jittered == real
    unknown = sites - set(CLOCK_SITES)
    assert not unknown, f"the core reads the clock at sites not in CLOCK_SITES: {unknown}"
    assert ("context.py", "check") in sites  # the recording itself works


def test_the_deadline_is_the_one_clock_limit(galicki, monkeypatch):
    """With the same jittery clock and a time limit that the jumps pass, the solve stops
    with TIME_LIMIT (the deadline is read), and says so."""
    from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
    from tocontrol_ros.core.types.problem import Problem, point

    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    clock = _JitteryClock(time.perf_counter, jump=100.0)
    with monkeypatch.context() as patch:
        patch.setattr(time, "perf_counter", clock)
        result = plan(problem, SolverOptions(time_limit=600.0))
    assert result.status.name == "TIME_LIMIT", result.message
    assert not result.success
    assert result.message.startswith("the time limit ran out")


class _DeadlineAfterOffers:
    """``time.perf_counter`` that reads the real clock until the solver has offered
    ``offers`` motions (:meth:`SolveContext.offer`), then far past any deadline."""

    def __init__(self, real, offers: int) -> None:
        self._real, self._left, self.fired = real, offers, False

    def offered(self) -> None:
        self._left -= 1
        self.fired = self._left <= 0

    def __call__(self) -> float:
        return self._real() + (1e12 if self.fired else 0.0)


@pytest.mark.parametrize("case, offers", [("paper", 3), ("panda", 3)])
def test_a_time_limit_carries_the_best_certified_motion_found(case, offers, robot_specs,
                                                              monkeypatch):
    """The deadline fires after the solver found motions: the result says TIME_LIMIT, is
    not a success, and carries the best of them that passes its certificate."""
    from tocontrol_ros.core.methods.context import SolveContext

    urdf = _panda_urdf(robot_specs) if case == "panda" else None
    problem = problem_of(case, urdf)
    options = SolverOptions(starts=1, candidates=1, time_limit=600.0)
    full = plan(problem, options)
    assert full.success, full.message
    clock = _DeadlineAfterOffers(time.perf_counter, offers)
    offer = SolveContext.offer

    def counted(self, T, build):
        offer(self, T, build)
        clock.offered()

    with monkeypatch.context() as patch:
        patch.setattr(SolveContext, "offer", counted)
        patch.setattr(time, "perf_counter", clock)
        result = plan(problem, options)
    assert clock.fired
    assert result.status.name == "TIME_LIMIT", result.message
    assert not result.success
    assert result.trajectory is not None, result.message
    assert result.certificate is not None and result.certificate.passed
    assert "best certified motion found before it" in result.message
    assert result.method == full.method
    # Not the finished solve's motion, but one of its stages: close to it in T.
    assert abs(result.T - full.T) <= 0.02 * full.T
    end = result.trajectory.evaluate([result.T])
    assert np.linalg.norm(problem.model.point(end.q[0]) - problem.target_point) <= 1e-4
