"""The tracker node's time keeping and recent positions, without ROS.

:class:`SimClock` says how far the simulation should be now (the wall clock times
``time_scale``, or the ROS time of ``/clock`` with ``use_sim_time``) and on which epoch its
stamps are; :class:`PublishSchedule` picks the control instants published at
``publish_rate``; :class:`PositionHistory` keeps the positions published in the last
:data:`START_HISTORY` seconds, from which a trajectory may start.
:class:`~tocontrol_ros.nodes.tracker.TrackerNode` reads the ROS clock and publishes.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable

import numpy as np

__all__ = ["MAX_TICK_PERIODS", "START_HISTORY", "PositionHistory", "PublishSchedule",
           "SimClock"]

#: Control periods one timer tick may simulate (a few tens of ms of work); beyond, the
#: simulation drops time (it cannot keep up with ``time_scale``) rather than starve the
#: executor.
MAX_TICK_PERIODS = 10_000
#: A trajectory may start from any position the arm had (as published on joint_states) in
#: this many wall-clock seconds: a plan made from a state of a moving arm arrives after the
#: arm has moved on (the planner uses joint states up to joint_state_timeout = 1 s old).
START_HISTORY = 2.0


class SimClock:
    """Where the simulation should be now, and the epoch of its stamps.

    A stamp is ``epoch + t`` for the simulation's time ``t`` (s).

    Parameters
    ----------
    time_scale : float
        Simulated seconds per wall-clock second (without ``/clock``).
    epoch : float
        The stamps' time at ``t = 0`` (s); with ``/clock``, set from the first one.
    monotonic : callable () -> float
        The wall clock (s).
    """

    def __init__(self, time_scale: float, epoch: float,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.time_scale = time_scale
        self.epoch = epoch
        #: Simulated time dropped when the simulation fell behind (s).
        self.offset = 0.0
        #: With ``/clock``: whether one has arrived.
        self.clock_seen = False
        self._monotonic = monotonic
        self._wall_start = monotonic()

    def wall_target(self) -> float:
        """The simulated time to advance to, from the wall clock (s)."""
        return (self._monotonic() - self._wall_start) * self.time_scale - self.offset

    def follow(self, now: float, t: float, h: float) -> tuple[float | None, bool]:
        """With ``/clock``: ``now`` (ROS time, s) or None before the first; whether first.

        The first clock, or a clock gone back (a looped replay), sets the epoch so that the
        simulation's time ``t`` (control period ``h``) is now.
        """
        if now <= 0.0:
            return None, False
        first = not self.clock_seen
        if first or now < self.epoch + t - h:
            self.epoch, self.offset = now - t, 0.0
            self.clock_seen = True
        return now, first

    def ros_target(self, now: float | None) -> float | None:
        """The simulated time to advance to with ``/clock`` (None before the first)."""
        return None if now is None else now - self.epoch - self.offset

    def limit(self, target: float, t: float, h: float) -> tuple[float, float]:
        """``target`` at most :data:`MAX_TICK_PERIODS` periods ahead; the time dropped (s)."""
        behind = int(math.ceil((target - t) / h - 1e-9))
        if behind <= MAX_TICK_PERIODS:
            return target, 0.0
        dropped = (behind - MAX_TICK_PERIODS) * h
        self.offset += dropped
        return target - dropped, dropped


class PublishSchedule:
    """The control instants published at ``rate`` (Hz) of simulated time."""

    def __init__(self, rate: float) -> None:
        self.period = 1.0 / rate
        self._next = self.period

    def rows(self, t: np.ndarray) -> np.ndarray:
        """Of the instants ``t`` (s, increasing), the first at or after each publishing time.

        Returns indices into ``t`` (int); the schedule moves past them.
        """
        if not len(t):
            return np.zeros(0, dtype=int)
        due = np.arange(self._next, t[-1] + 1e-9, self.period)
        self._next += due.size * self.period
        return np.unique(np.searchsorted(t, due - 1e-9))


class PositionHistory:
    """The positions published in the last ``span`` wall-clock seconds."""

    def __init__(self, span: float = START_HISTORY,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.span = span
        self._monotonic = monotonic
        self._items: collections.deque = collections.deque()  # (wall time, q)

    def add(self, q: np.ndarray) -> None:
        """``q`` (rad) was published now."""
        now = self._monotonic()
        self._items.append((now, np.array(q, dtype=float)))
        while self._items and self._items[0][0] < now - self.span:
            self._items.popleft()

    def clear(self) -> None:
        """The arm was put elsewhere: the positions it had are no start for a plan."""
        self._items.clear()

    def nearest(self, q0: np.ndarray, current: np.ndarray) -> float:
        """The smallest max-norm distance (rad) from ``q0`` to a recent position.

        ``current`` (the arm's position now) stands in when none was published.
        """
        recent = np.array([q for _, q in self._items]) if self._items else current[None, :]
        return float(np.min(np.max(np.abs(recent - q0), axis=1)))

    def start_gap(self, q0: np.ndarray, q: np.ndarray, tolerance: float,
                  joint_names: list[str]) -> tuple[float, str | None]:
        """How far a trajectory's first point ``q0`` is from the arm now, and any refusal.

        A plan made from a state the arm had (published in the last ``span`` s) is
        accepted although the arm has moved on since.

        Returns
        -------
        offset : float
            The max-norm distance (rad) from the position ``q`` now.
        reason : str or None
            Why it cannot start (farther than ``tolerance`` from ``q`` and from every recent
            position), None when it can.
        """
        gaps = np.abs(q0 - q)
        offset = float(np.max(gaps))
        nearest = self.nearest(q0, q)
        if min(offset, nearest) <= tolerance:
            return offset, None
        j = int(np.argmax(gaps))
        return offset, (f"its first point is {offset:.3g} rad from the current position "
                        f"({joint_names[j]}) and {nearest:.3g} rad from every position of "
                        f"the last {self.span:g} s, more than start_tolerance = "
                        f"{tolerance:g}")
