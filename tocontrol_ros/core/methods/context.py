"""What every stage of one solve shares, whichever method runs it: its context.

:class:`SolveContext` carries the problem, the options, the deadline, the cancel flag and
the motions found so far; a cancelled or timed-out solve unwinds every stage by
:class:`StopError`, which :func:`~tocontrol_ros.core.planning.solver.plan` turns into a
result. The maximum principle's iterate of one start is
:class:`~tocontrol_ros.core.indirect.run.Run`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from tocontrol_ros.core.types.law import LawParams
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, Status

__all__ = ["EarlyMotion", "SolveContext", "StopError"]


class StopError(Exception):
    """Internal: the deadline passed or the caller cancelled."""

    def __init__(self, status: Status) -> None:
        super().__init__(status.value)
        self.status = status
        #: ``PlanResult.failure``'s fields of what the method had when it stopped (its
        #: records, its iterate), set by the method on the way out; None: nothing.
        self.partial: dict | None = None

    def __reduce__(self):
        return (StopError, (self.status,))  # from a worker process (core/planning/pool.py)


@dataclass
class EarlyMotion:
    """A solve's motions before it converges: its certified iterates, offered as they come.

    A method that can (the bounded solve's warm re-solve: IPOPT's iterates) checks its
    iterate every ``every`` iterations, the check decided by the count, never by the clock:
    the NLP's residual first, then the torques between the samples (held inside the set by
    slowing the path down, as a converged solve's), then the certificate. Each certified
    iterate goes to ``offer`` (a ``PlanResult``, ``success`` True, its warnings saying it is
    an iterate, not the optimum); ``offer`` returning True ends the checks (the solve goes
    on to its optimum either way, the same to the bit as without this). ``seen`` gets one
    record per checked iterate: ``iteration``, ``T`` (s), ``residual``, ``inside`` (held
    inside the set; None: not checked), ``certified`` (None: not checked), ``error`` (an
    exception in the checks or in ``offer``, which ends the checks), and for a report only
    ``at`` (``time.perf_counter()`` when the check began) and ``seconds`` (its cost).

    Attributes
    ----------
    offer : callable
        ``offer(result) -> bool``.
    every : int
        Check every this many iterations (>= 1; the start, iteration 0, is never checked).
    full : bool
        Check the set and the certificate even where the residual is above its tolerance
        (a measurement's: such an iterate passes only where slowing it down into the set
        also brings its residual within tolerance).
    seen : list of dict
    done : bool
        Set when ``offer`` returned True.
    max_T : float
        An iterate slower than this (s), or whose motion held inside the set is, is not
        offered (its record says ``slow``); the checks go on with the next iterates. A
        memory hit's bound is its stored motions' (:mod:`~tocontrol_ros.core.memory.recall`):
        an IPOPT iterate 14 times slower than the optimum was published first once.
    """

    offer: Callable[[PlanResult], bool]
    every: int = 1
    full: bool = False
    seen: list = field(default_factory=list)
    done: bool = False
    max_T: float = float("inf")

    def __post_init__(self) -> None:
        if int(self.every) < 1:
            raise ValueError(f"`every` must be at least 1, got {self.every!r}")
        if not float(self.max_T) > 0.0:
            raise ValueError(f"`max_T` must be positive (s), got {self.max_T!r}")

    def give(self, result: PlanResult, seen: dict | None = None) -> None:
        """Offer ``result`` when it is certified (``success``) and not slower than ``max_T``.

        A slower one is not offered (``seen["slow"]`` where a record is given); ``done`` is
        set when ``offer`` returned True. Every source of a first motion offers through here
        (IPOPT's iterates, the parametric steps', a memory hit's moved stored motion).
        """
        if not result.success:
            return
        if result.T > self.max_T:
            if seen is not None:
                seen["slow"] = True
            return
        self.done = bool(self.offer(result))


@dataclass(frozen=True)
class SolveContext:
    """One call of :func:`~tocontrol_ros.core.planning.solver.plan`: what every stage reads.

    Attributes
    ----------
    system : object
        The model's compiled functions shared by the solve (the maximum principle's
        :class:`~tocontrol_ros.core.indirect.pmp.CanonicalSystem`; None in a worker).
    problem : Problem
    options : SolverOptions
    deadline : float
        ``time.perf_counter()`` value at which the solve stops with ``TIME_LIMIT``.
    should_stop : callable or None
        Polled between Newton iterations; returning True cancels the solve.
    memo : dict
        Values computed once per solve: ``"pairs"``, the multistart's seed pairs (inverse
        kinematics costs), reused by the bounded solve where the joint limits bind;
        ``"incumbents"``, the motions found so far (:meth:`offer`).
    early : EarlyMotion or None
        Where a method that can offers its certified iterates before it converges (a
        memory hit's first motion); None: not asked.
    """

    system: Any
    problem: Problem
    options: SolverOptions
    deadline: float
    should_stop: Callable[[], bool] | None = None
    memo: dict = field(default_factory=dict)
    early: EarlyMotion | None = None

    def portable(self) -> SolveContext:
        """A copy for another process (:mod:`~tocontrol_ros.core.planning.pool`).

        Without the compiled system (a worker has its own), the cancel callback (the pool
        passes an event instead, :meth:`attached`), the memo (incumbents stay here) and the
        early motions' receiver.
        """
        return replace(self, system=None, should_stop=None, memo={}, early=None)

    def attached(self, should_stop: Callable[[], bool] | None) -> SolveContext:
        """A copy with ``should_stop`` as its cancel callback."""
        return replace(self, should_stop=should_stop)

    def extend(self, seconds: float) -> None:
        """Move the deadline ``seconds`` later (time spent compiling, not solving)."""
        if seconds > 0.0:
            object.__setattr__(self, "deadline", self.deadline + seconds)

    def law(self, k: float, delta: float) -> LawParams:
        """The control law's parameters at ``k`` and ``delta`` for this problem."""
        return LawParams(k, delta, self.problem.torque_scale)

    def offer(self, T: float, build: Callable[[dict, float], PlanResult]) -> None:
        """Keep a motion found so far: its ``T`` (s) and how to build its checked result.

        ``build(timings, t_start)`` returns the result (its timings and start time as
        :func:`~tocontrol_ros.core.planning.solver.plan` reports them).
        At the caller's deadline :func:`~tocontrol_ros.core.planning.solver.plan` returns the best
        one that passes its checks (:meth:`incumbent`), with the ``TIME_LIMIT`` status.
        ``build`` must not depend on state that later stages change (take a snapshot).
        """
        if np.isfinite(T):
            self.memo.setdefault("incumbents", []).append((float(T), build))

    def incumbent(self, tries: int, timings: dict, t_start: float) -> PlanResult | None:
        """The least-``T`` motion offered whose result passes its checks, or None.

        At most ``tries`` results are built (each one a certificate), least ``T`` first.
        """
        offered = sorted(self.memo.get("incumbents", ()), key=lambda entry: entry[0])
        for _, build in offered[:tries]:
            result = build(timings, t_start)
            if result.status is Status.SUCCESS:
                return result
        return None

    def check(self) -> None:
        """Raise :class:`StopError` when the caller cancelled or the deadline passed."""
        if self.should_stop is not None and self.should_stop():
            raise StopError(Status.CANCELLED)
        if time.perf_counter() > self.deadline:
            raise StopError(Status.TIME_LIMIT)
