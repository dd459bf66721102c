"""A plan request and where it waits for the planning service's worker (no ROS here).

:class:`LatestSlot` hands the newest request to the worker (a newer one supersedes it, so
every call gets exactly one response; goals may queue behind each other, see
:meth:`LatestSlot.put`). The arm's newest joint state is
:class:`~tocontrol_ros.nodes.latest_message.LatestMessage`'s.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tocontrol_ros.nodes.planner_config import PlannerConfig

__all__ = ["LatestSlot", "PlanRequest"]


@dataclass(eq=False)
class PlanRequest:
    """One request, from its acceptance to its outcome.

    Attributes
    ----------
    id : int
        Increasing per node, from 1 (``request_id`` in ``~/status``).
    source : {"service", "goal"}
    start : tuple
        ``("point", p)`` with p of shape (m,) (m), or ``("state", q, qd)`` (rad, rad/s).
    target : ndarray, shape (m,)
        Task-space target point (m).
    config : PlannerConfig
        Parameters at acceptance (later changes apply to later requests).
    target_q : ndarray, shape (n,), optional
        A joint-space target (rad, m; at rest); ``target`` is then its end-effector point.
    execute : bool
        Publish the plan (``~/trajectory``, ``~/ee_path``, the controller's goal); False: a
        plan only, returned to the caller (the ``~/plan_motion`` action's ``execute``).
    result : PlanResult or None
        The motion that answered the request (the optimum, or the first motion that stood),
        set before ``done``.
    first : PlanResult or None
        The first motion of ``publish: first_then_optimum``, once known (certified); for a
        pose goal, the best certified first motion of its IK solutions.
    target_pose : PoseTarget or None
        A pose goal (:mod:`tocontrol_ros.nodes.pose_goals`); ``target`` is then its
        position's task coordinates (m).
    """

    id: int
    source: str
    start: tuple
    target: np.ndarray
    config: PlannerConfig
    received: float = field(default_factory=time.monotonic)
    done: threading.Event = field(default_factory=threading.Event)
    cancelled: threading.Event = field(default_factory=threading.Event)
    cancel_reason: tuple[str, str] = ("", "")
    #: The answer of a ``~/plan`` call (a ``nav_msgs/Path`` the node built), set with done.
    path: Any = None
    #: A goal that queues behind pending goals instead of replacing them (replanning).
    queue: bool = False
    #: A goal that superseded waiting goals: the worker fell behind the stream.
    behind: bool = False
    #: A goal whose start was taken without waiting for a fresh joint state: its DDS receive
    #: time (ns), to take a fresh one if it is not a replan after all; else 0.
    since_ns: int = 0
    target_q: np.ndarray | None = None
    execute: bool = True
    result: Any = None
    first: Any = None
    target_pose: Any = None
    #: A replan goal whose quick motion was tried already (on the goal's callback thread,
    #: :meth:`~tocontrol_ros.nodes.planning_service.PlanningService.goal`): the worker goes
    #: on with the optimum's route without trying it again.
    quick_tried: bool = False

    def cancel(self, event: str, reason: str) -> None:
        """Ask the solve to stop; ``event`` names the outcome (e.g. ``"superseded"``)."""
        if not self.cancelled.is_set():
            self.cancel_reason = (event, reason)
            self.cancelled.set()


class LatestSlot:
    """Hand-over between the callbacks and the worker: pending items and one running item.

    ``put`` replaces the pending items (newest wins), or queues behind them (goals while a
    target moves), and reports what it replaced and what is running, atomically, so that no
    request can slip between "taken" and "running".
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._pending: list = []
        self._running = None
        self._closed = False
        self._woken = False

    def put(self, item, queue: int = 1) -> tuple[list, object]:
        """Add ``item``; return ``(replaced pending items, running item or None)``.

        Parameters
        ----------
        item
        queue : int
            With 1, ``item`` replaces every pending item (newest wins). With more, ``item``
            queues behind the pending items when they all queue too (``item.queue`` true),
            and only the oldest beyond ``queue`` pending items are replaced.
        """
        with self._cond:
            if self._closed:
                raise RuntimeError("the slot is closed (node shutting down)")
            queues = getattr(item, "queue", False) and queue > 1 and \
                all(getattr(p, "queue", False) for p in self._pending)
            if queues:
                self._pending.append(item)
                replaced = self._pending[:-queue] if len(self._pending) > queue else []
                self._pending = self._pending[len(replaced):]
            else:
                replaced, self._pending = self._pending, [item]
            self._cond.notify_all()
            return replaced, self._running

    def take(self, timeout: float | None = None, max_backlog: float = math.inf,
             per_item: float = 0.0) -> tuple[object, list]:
        """The oldest pending item that is not stale, now running, and the stale ones.

        Parameters
        ----------
        timeout : float, optional
            Longest wait for an item (s); None: until one comes or the slot closes.
        max_backlog : float
            Goals fall behind when the worker takes longer per queued item (``per_item``)
            than the interval at which the waiting ones arrived (their ``received``); then,
            while more than one waits and their count times ``per_item`` exceeds this (s),
            the oldest is stale: dropped, the next one behind it in its place (newest wins).
            A backlog that the worker drains faster than it grows (after one slow solve) is
            kept whole. The newest item is never stale.
        per_item : float
            The recent time the worker took per queued item (s); 0: not known yet (nothing
            is stale).

        Returns
        -------
        (item or None, list of (stale item, the item behind it))
            None when closed or on timeout.
        """
        with self._cond:
            self._cond.wait_for(lambda: bool(self._pending) or self._closed or self._woken,
                                timeout)
            self._woken = False
            if self._closed or not self._pending:
                return None, []
            stale = []
            while len(self._pending) > 1 and all(getattr(p, "queue", False)
                                                 for p in self._pending[:2]) \
                    and len(self._pending) * per_item > max_backlog \
                    and per_item > self._interval():
                stale.append((self._pending.pop(0), self._pending[0]))
            self._running = self._pending.pop(0)
            return self._running, stale

    def _interval(self) -> float:
        """The mean interval at which the pending items arrived (s; inf for fewer than 2)."""
        times = [getattr(p, "received", None) for p in self._pending]
        if len(times) < 2 or None in times:
            return math.inf
        return (times[-1] - times[0]) / (len(times) - 1)

    def claim(self, item) -> bool:
        """Run ``item`` outside :meth:`take`, if it is the only pending item and none runs.

        True: it is now running (:meth:`finished` or :meth:`give_back` ends that); False:
        the worker takes it as ever.
        """
        with self._cond:
            if self._closed or self._running is not None or len(self._pending) != 1 \
                    or self._pending[0] is not item:
                return False
            self._pending, self._running = [], item
            return True

    def give_back(self, item) -> bool:
        """A claimed ``item`` not served after all: pending again, first, for :meth:`take`.

        False when the slot is closed (the caller answers it).
        """
        with self._cond:
            if self._running is item:
                self._running = None
            if self._closed:
                return False
            self._pending.insert(0, item)
            self._cond.notify_all()
            return True

    def wake(self) -> None:
        """End a :meth:`take` that waits, without an item (it returns None)."""
        with self._cond:
            self._woken = True
            self._cond.notify_all()

    def finished(self, item) -> None:
        """The worker is done with ``item``."""
        with self._cond:
            if self._running is item:
                self._running = None

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        with self._cond:
            return self._closed

    def running(self):
        """The item running (taken or claimed, not finished yet), or None."""
        with self._cond:
            return self._running

    def pending(self) -> list:
        """The items that wait for the worker, oldest first (a copy)."""
        with self._cond:
            return list(self._pending)

    def has_pending(self) -> bool:
        """True while an item waits for the worker."""
        with self._cond:
            return bool(self._pending)

    def close(self) -> list:
        """Refuse further items, wake the worker; return the pending items."""
        with self._cond:
            self._closed = True
            leftover, self._pending = self._pending, []
            self._cond.notify_all()
            return leftover
