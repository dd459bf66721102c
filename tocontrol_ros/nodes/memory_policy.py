"""The planner's use of a memory of optimal motions, without ROS.

:class:`MemoryPolicy` opens the file the ``memory`` parameter names (for the model and the
problem class of each request: a change of ``k``, ``reserve`` or the limits makes it another
memory), answers a request by :func:`~tocontrol_ros.core.memory.recall.recall` when stored
motions are near (``hit``), and says why not otherwise (``miss``: nothing within
``memory_radius`` or every warm re-solve failed; ``off``: no memory; ``unavailable``: the
file cannot be used, with the reason, warned once per file and class). With
``memory_learn`` every certified plan the node publishes is stored. A memory error never
stops a plan: the request is planned as without a memory. Used by
:class:`~tocontrol_ros.nodes.planning_service.PlanningService`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.memory.codec import CodecError
from tocontrol_ros.core.memory.keys import options_hash, robot_hash
from tocontrol_ros.core.memory.recall import Recall, open_memory, recall, remember
from tocontrol_ros.core.memory.store import MemoryFileError
from tocontrol_ros.nodes.planner_config import PlannerConfig

__all__ = ["MemoryPolicy", "HIT", "MISS", "OFF", "UNAVAILABLE"]

HIT, MISS, OFF, UNAVAILABLE = "hit", "miss", "off", "unavailable"


class MemoryPolicy:
    """Lookups, warm re-solves and learning for one planner (see the module docstring).

    Parameters
    ----------
    warn : callable (str) -> None
        Called with a message when a memory file cannot be used (once per file and class)
        or a plan cannot be stored.
    """

    def __init__(self, warn: Callable[[str], None]) -> None:
        self._warn = warn
        self._stores: dict[tuple, object] = {}  # (path, robot, options) -> store or reason
        self._robots: dict[int, tuple] = {}  # id(model) -> (model, its hash)
        self._lock = threading.Lock()

    def _robot_hash(self, model) -> str:
        kept = self._robots.get(id(model))
        if kept is None or kept[0] is not model:
            kept = self._robots[id(model)] = (model, robot_hash(model))
        return kept[1]

    def _store(self, config: PlannerConfig, problem, create: bool):
        """The open store for this request's class, or the reason (str) why there is none."""
        key = (config.memory, self._robot_hash(problem.model), options_hash(problem))
        with self._lock:
            found = self._stores.get(key)
            if found is not None and not (isinstance(found, str) and create):
                return found
            try:
                found = open_memory(config.memory, problem, create=create)
            except MemoryFileError as exc:
                found = str(exc)
                if self._stores.get(key) != found:
                    self._warn(f"memory unavailable, planning without it: {found}")
            self._stores[key] = found
            return found

    def lookup(self, config: PlannerConfig, planner, problem, options,
               should_stop, first=None) -> tuple[Recall | None, dict]:
        """Recall ``problem`` from the memory; ``(recall or None, status values)``.

        The values: ``memory`` (hit, miss, off, unavailable), ``memory_distance`` (warm
        units; None without a lookup), and on a hit ``memory_entries``, ``memory_stored_T``
        (s), ``memory_time`` (s, the lookup and re-solves), ``memory_lookup_time``,
        ``memory_decode_time``, ``memory_solve_time`` (the warm re-solves, certificates
        included), ``memory_certificate_time`` (s), ``memory_iterations`` (IPOPT, all
        re-solves), ``memory_starts`` (what each started from, comma-separated); with
        ``first`` (``first(result)``, :func:`recall`'s: the stored motion moved onto the
        request, or a certified IPOPT iterate before the re-solve converged) and one given
        to it, ``memory_first_T`` (s),
        ``memory_first_iteration`` and ``memory_first_time`` (s from the lookup's start).
        """
        if not config.memory:
            return None, {"memory": OFF}
        store = self._store(config, problem, create=False)
        if isinstance(store, str):
            return None, {"memory": UNAVAILABLE, "memory_error": store}
        try:
            found = recall(planner, problem, options, store, config.memory_radius,
                           config.memory_basins, should_stop, config.memory_spans,
                           config.memory_first_success, first=first)
        except (MemoryFileError, CodecError) as exc:
            self._warn(f"memory lookup failed, planning without it: {exc}")
            return None, {"memory": UNAVAILABLE, "memory_error": str(exc)}
        except Exception as exc:  # noqa: BLE001  (a memory must never cost a request its plan)
            reason = f"unexpected {type(exc).__name__}: {exc}"
            self._warn(f"memory lookup failed, planning without it: {reason}")
            return None, {"memory": UNAVAILABLE, "memory_error": reason}
        values = {"memory": HIT if found.result is not None else MISS,
                  "memory_distance": found.distance if math.isfinite(found.distance)
                  else None}
        if found.hit:
            values.update(memory_entries=list(found.entries),
                          memory_stored_T=list(found.stored_T),
                          memory_time=found.timings["total"],
                          memory_lookup_time=found.timings["lookup"],
                          memory_decode_time=found.timings["decode"],
                          memory_solve_time=found.timings["solve"],
                          memory_certificate_time=found.timings["certificate"],
                          memory_iterations=found.iterations,
                          memory_starts=", ".join(found.starts))
            if found.first is not None:
                values.update(memory_first_T=found.first.T,
                              memory_first_iteration=found.first.iterations,
                              memory_first_time=found.first_time)
            if found.result is None:
                values["memory_note"] = "no warm re-solve succeeded: " + \
                    " | ".join(found.messages)
        return found, values

    def learn(self, config: PlannerConfig, result, solve_time: float) -> bool:
        """With ``memory_learn``, store a published certified ``result``; True if stored."""
        if not (config.memory and config.memory_learn) or result.problem is None:
            return False
        store = self._store(config, result.problem, create=True)
        if isinstance(store, str):
            return False
        try:
            return remember(store, result, "planner", solve_time)
        except (MemoryFileError, TocontrolError) as exc:
            self._warn(f"memory: the plan was not stored: {exc}")
            return False
        except Exception as exc:  # noqa: BLE001  (the plan is published already)
            self._warn(f"memory: the plan was not stored: unexpected "
                       f"{type(exc).__name__}: {exc}")
            return False

    def close(self) -> None:
        """Close every open file."""
        with self._lock:
            for store in self._stores.values():
                if not isinstance(store, str):
                    store.close()
            self._stores.clear()
