"""The planner's policy without ROS: from an accepted request to what is published.

:class:`PlanningService` owns the worker thread and every decision between a request and the
planner node's outputs: the one-slot queue (a newer request supersedes a pending one, or
cancels a running solve; goals with ``replan`` queue instead and give way only when the worker
falls behind the stream), replanning from the hand-off of the running motion with its warm
starts, the first motion before the optimum (``publish: first_then_optimum``), the goal a
steady stream predicts solved ahead, the warm-up and the optimised libraries, and the contents
of each ``~/status`` event (with ``replan_on_callback`` a replan goal's quick motion is served
on the goal's own thread when the worker idles: :meth:`PlanningService.goal`). Its inputs are
plain data (numpy arrays, the frozen
:class:`~tocontrol_ros.nodes.planner_config.PlannerConfig`, the requests of
:mod:`tocontrol_ros.nodes.requests`, a :class:`Clock`); its outputs go through
:class:`Outputs`, which :class:`~tocontrol_ros.nodes.planner.PlannerNode` implements with its
publishers (:mod:`tocontrol_ros.nodes.planner_outputs`), and the arm's measured state through
:class:`Arm`. Nothing here imports rclpy or a message package
(``test/nodes/test_nodes_purity.py``), so that a test drives it with fakes, without spinning
(``test/nodes/test_planning_service.py``).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.core.types.problem import MIN_MOVE
from tocontrol_ros.nodes.memory_policy import MemoryPolicy
from tocontrol_ros.nodes.outcomes import result_message, result_values
from tocontrol_ros.nodes.planner_config import (
    FIRST_THEN_OPTIMUM,
    PlannerConfig,
    plan_problem,
    solver_options,
)
from tocontrol_ros.nodes.pose_goals import PoseGoals
from tocontrol_ros.nodes.replan_policy import ReplanPolicy, replanning
from tocontrol_ros.nodes.replanning import CHAIN_KEPT, Replanner
from tocontrol_ros.nodes.requests import LatestSlot, PlanRequest
from tocontrol_ros.nodes.warm_up import load_optimised, warm_up

__all__ = ["Arm", "Clock", "Outputs", "PlanningService", "replanning"]

#: How often a waiting service call looks at the shutdown flag (s).
WAIT_POLL = 0.05
#: How long :meth:`PlanningService.stop` waits for the worker (s); a daemon thread beyond
#: that (e.g. while the C compiler of the first-ever solve runs).
JOIN_TIMEOUT = 3.0
#: While optimised libraries are being built in the background (the first use of a model
#: got quick builds), the idle worker looks this often (s) whether they landed, to load them.
OPTIMISED_POLL = 1.0


class Outputs(Protocol):
    """Where the service's decisions go; the node implements it with its publishers.

    Each ``publish`` may find its publisher gone during shutdown: it then returns None.
    """

    def status(self, level: str, message: str, values: Mapping[str, Any],
               routine: bool = False) -> None:
        """One ``~/status`` event (``level``: OK, WARN or ERROR) and its log line."""

    def log_error(self, message: str) -> None:
        """An error in the log only (an internal error, before its ``failed`` status)."""

    def trajectory(self, sample: Any, stamp_ns: int) -> Any:
        """Publish ``sample`` (a sampled trajectory) on ``~/trajectory``.

        Returns what was sent (handed to :meth:`follow`), or None.
        """

    def path(self, sample: Any, stamp_ns: int) -> Any:
        """Publish its end-effector path on ``~/ee_path``; the path (a ``~/plan`` answer)."""

    def follow(self, request_id: int, trajectory: Any, config: PlannerConfig) -> None:
        """Send the published trajectory to the controller (``controller_action``), if set."""

    def markers(self, result: Any, path: Any, config: PlannerConfig, start_point: np.ndarray,
                target: np.ndarray) -> None:
        """Publish the viewer's markers of a published motion."""

    def rest_path(self, point: np.ndarray) -> Any:
        """The ``~/plan`` answer when there is nothing to plan: a one-pose path at ``point``."""


class Arm(Protocol):
    """The arm's measured state (the node's ``joint_states``), taken on demand."""

    def start(self, config: PlannerConfig, since_ns: int, fresh: bool = True) -> tuple:
        """The current start, ``("state", q, qd)``, or ``("point", default_start)``.

        Raises a :class:`~tocontrol_ros.core.errors.TocontrolError` (naming the field)
        when there is neither. ``fresh``: wait briefly for a state received after
        ``since_ns`` (``time.time_ns()`` scale).
        """

    def latest(self, config: PlannerConfig) -> tuple[int, np.ndarray | None]:
        """The latest joint state's stamp (ns; 0: none) and positions (rad; None: none).

        Positions are None too when the joint state does not name this arm's joints.
        """


@dataclass(frozen=True)
class Clock:
    """The service's clocks (a test passes fakes).

    Attributes
    ----------
    now_ns : callable () -> int
        The node's clock (ns): stamps, hand-offs.
    monotonic : callable () -> float
        Latencies and solve times (s).
    wall_ns : callable () -> int
        ``time.time_ns()`` scale: a replanning goal's stamp (the tracker's control grid).
    """

    now_ns: Callable[[], int]
    monotonic: Callable[[], float] = time.monotonic
    wall_ns: Callable[[], int] = time.time_ns


class PlanningService:
    """Serves plan requests on a worker thread; see the module docstring.

    Parameters
    ----------
    model : RobotModel
    limits : JointLimits
        The planner's limits without the margin
        (:func:`~tocontrol_ros.nodes.planner_config.planner_limits`).
    config : PlannerConfig
        The parameters now; replaced through :attr:`config`.
    frame_id : str
        The frame of the points in the status values.
    outputs : Outputs
    arm : Arm
    clock : Clock
    planner_factory : callable (model) -> Planner, optional
        Default :class:`tocontrol_ros.core.planning.solver.Planner`; also builds the planner on the
        optimised libraries.
    """

    def __init__(self, model, limits, config: PlannerConfig, frame_id: str, outputs: Outputs,
                 arm: Arm, clock: Clock,
                 planner_factory: Callable[[Any], Any] | None = None) -> None:
        if planner_factory is None:
            from tocontrol_ros.core.planning.solver import Planner

            planner_factory = Planner
        self.model = model
        self.limits = limits
        #: The collision model the next problem gets (the planner node sets it: scene_file,
        #: robot_description_semantic, ~/scene); None: no geometry. Replaced, never mutated.
        self.collision = None
        self.frame_id = frame_id
        self.planner = planner_factory(model)
        self.planner_factory = planner_factory
        self.out = outputs
        self.arm = arm
        self.clock = clock
        self.ready = threading.Event()
        self.stopping = threading.Event()
        self.slot = LatestSlot()
        self.replanner = Replanner()
        self._config = config
        self._config_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._last_result = None
        self._published_at = 0.0  # clock.monotonic() of the last ~/trajectory
        # (request id, PlanResult, its stamp ns) last published
        self._sent: tuple[int, Any, int] | None = None
        #: (stamp ns, request id) of the last trajectories published, to name a rejected one.
        self._stamps: deque[tuple[int, int]] = deque(maxlen=4 * CHAIN_KEPT)
        #: The last publication's parts (s): the trajectory sampled, its message sent.
        self._publish_parts = {"sample_time": 0.0, "send_time": 0.0}
        self._replans = ReplanPolicy(self)
        self._poses = PoseGoals(self)
        self.memory = MemoryPolicy(lambda message: self.out.status(
            "WARN", message, {"event": "memory", "frame_id": frame_id}))
        self._worker = threading.Thread(target=self._run, name="planner-worker", daemon=True)
        #: Held by whoever serves: the worker (a request, the idle optimum, a goal solved
        #: ahead) or a goal's callback serving its quick motion (:meth:`goal`).
        self._serving = threading.Lock()
        #: Goals served on their callback's thread (the worker then looks again at its wait).
        self._inline_served = 0

    # ------------------------------------------------------------- state
    @property
    def config(self) -> PlannerConfig:
        """The parameters as they are now (each request keeps the ones at its acceptance)."""
        with self._config_lock:
            return self._config

    @config.setter
    def config(self, config: PlannerConfig) -> None:
        with self._config_lock:
            self._config = config

    @property
    def last_result(self):
        """The last published :class:`~tocontrol_ros.core.types.result.PlanResult` (or None)."""
        return self._last_result

    @property
    def worker(self) -> threading.Thread:
        """The worker thread (started by :meth:`start`)."""
        return self._worker

    def next_id(self) -> int:
        """A new request id (increasing from 1)."""
        return next(self._ids)

    def start(self) -> None:
        """Start the worker: the warm-up, then the requests."""
        self._worker.start()

    # ---------------------------------------------------------- requests in
    def submit(self, req: PlanRequest) -> None:
        """Accept ``req``: it supersedes the pending request, or queues (a replan goal)."""
        self.status(req, "OK", "accepted", f"request {req.id} accepted")
        try:
            replaced, running = self.slot.put(req, req.config.goal_queue)
        except RuntimeError:
            self.finish(req, "WARN", "cancelled", "node shutting down")
            return
        for old in replaced:
            self.finish(old, "WARN", "superseded",
                        f"superseded by request {req.id} before its solve started")
        # Replanning: a goal's solve in progress is not thrown away by the next goal (its
        # result still serves: the next goal is planned from it).
        if running is not None and not (req.queue and running.queue):
            running.cancel("superseded", f"superseded by request {req.id} during its solve")

    def call(self, req: PlanRequest) -> Any:
        """A ``~/plan`` call: submit ``req``, wait for its outcome; its answer path or None.

        Waits at most ``service_timeout`` (then the request is cancelled, "timed out") or
        until the service stops.
        """
        self.submit(req)
        timeout = req.config.service_timeout
        deadline = self.clock.monotonic() + timeout
        while not req.done.wait(WAIT_POLL):
            if self.stopping.is_set():
                break
            if self.clock.monotonic() > deadline:
                req.cancel("timed out", f"no outcome within service_timeout = {timeout:g} s")
                break
        return req.path if req.done.is_set() else None

    def goal(self, rid: int, target: np.ndarray, since_ns: int, received: float) -> None:
        """A ``~/goal`` (``target``, m), received at ``since_ns`` (DDS time) / ``received``.

        With replanning, it queues; its start is taken without waiting for a fresh joint
        state when a published motion may be continued (the replan starts from the
        motion's hand-off; :meth:`ReplanPolicy.serve` takes a fresh one when it does not).
        """
        config = self.config
        replan = replanning(config)
        fresh = not (replan and self.replanner.has_motion())
        try:
            start = self.arm.start(config, since_ns, fresh)
        except TocontrolError as exc:
            self.reject(rid, "goal", str(exc))
            return
        if replan:
            self.replanner.goals.record(target, received)
        req = PlanRequest(rid, "goal", start, target, config, received=received, queue=replan,
                          since_ns=0 if fresh else since_ns)
        self.submit(req)
        if replan and not fresh and config.replan_quick and config.replan_on_callback:
            self._serve_inline(req)

    def _serve_inline(self, req: PlanRequest) -> None:
        """A replan goal's quick motion served on the calling thread when the worker idles.

        With ``replan_on_callback`` (default off: measured without a net gain through the
        nodes on a loaded machine, docs/speed.md, issue 47's fifth pass).

        The goal's callback is running already; handing the goal to the sleeping worker
        costs its wake-up (about a millisecond, more on a loaded machine: issue 47's
        ``wait_time``). When the worker waits for requests (nothing running, ``req`` the
        only one pending, the serving lock free) the quick motion is served here, as the
        worker would (:meth:`ReplanPolicy.serve_first`); when it is not the route (no quick
        motion), the goal goes back to the worker, first in line, which goes on with the
        optimum's route. Afterwards the worker is woken to look at its idle wait (the
        quick motion's optimum) and the goal a stream predicts.
        """
        if not self.ready.is_set() or self.stopping.is_set():
            return
        if not self._serving.acquire(blocking=False):
            return  # the worker serves, improves or solves ahead: it takes the goal next
        try:
            if not self.slot.claim(req):
                return
            try:
                served = self._replans.serve_first(req)
            except Exception as exc:  # noqa: BLE001  (as the worker: a bug must not stop it)
                self.out.log_error(f"request {req.id}: internal error: {exc!r}")
                if not req.done.is_set():
                    self.finish(req, "ERROR", "failed", f"internal error: {exc!r}")
                served = True
            if served:
                self.slot.finished(req)
                self._inline_served += 1
            else:
                req.quick_tried = True
                if not self.slot.give_back(req):
                    self.finish(req, "WARN", "cancelled", "node shutting down")
        finally:
            self._serving.release()
        self.slot.wake()

    # ------------------------------------------------------------ status out
    def values(self, req: PlanRequest, event: str, extra: dict | None = None) -> dict:
        """The values of a request's status event (start, target, frame, k, and ``extra``)."""
        start = req.start[1] if req.start[0] == "point" else None
        values = {"request_id": req.id, "event": event, "source": req.source,
                  "start": start, "start_q": None if start is not None else req.start[1],
                  "start_qd": None if start is not None else req.start[2],
                  "target": req.target, "frame_id": self.frame_id, "k": req.config.k}
        values.update(extra or {})
        return values

    def status(self, req: PlanRequest, level: str, event: str, message: str,
               extra: dict | None = None) -> None:
        """A status event of ``req`` (``accepted`` is routine: logged at DEBUG)."""
        self.out.status(level, message, self.values(req, event, extra),
                        routine=event == "accepted")

    def reject(self, rid: int, source: str, reason: str) -> None:
        """A request refused before it was accepted (its input cannot be converted)."""
        self.out.status("ERROR", f"request {rid} rejected: {reason}",
                        {"request_id": rid, "event": "failed", "source": source,
                         "frame_id": self.frame_id})

    def finish(self, req: PlanRequest, level: str, event: str, message: str,
               extra: dict | None = None, path: Any = None) -> None:
        """The final status of ``req`` (with its latencies); ``path`` is its answer."""
        latency = {"latency": self.clock.monotonic() - req.received}
        if path is not None:  # the replan latency: to the trajectory's publication
            latency["publish_latency"] = self._published_at - req.received
        self.status(req, level, event, f"request {req.id} {event}: {message}",
                    {**latency, **(extra or {})})
        req.path = path
        req.done.set()

    def finish_stopped(self, req: PlanRequest, extra: dict) -> bool:
        """Finish ``req`` when it was cancelled or the service stops (True), else False."""
        if not (req.cancelled.is_set() or self.stopping.is_set()):
            return False
        event, reason = req.cancel_reason if req.cancelled.is_set() else \
            ("cancelled", "node shutting down")
        self.finish(req, "WARN", event, reason, extra)
        return True

    # ----------------------------------------------------------------- worker
    def _run(self) -> None:
        warm_up(self)
        while not self.stopping.is_set():
            waiting = compiled.pending_builds() > 0 or self.planner.stale()
            idle = self._replans.idle_wait()  # a quick motion to improve when idle
            waits = [t for t in (OPTIMISED_POLL if waiting else None, idle) if t is not None]
            inline = self._inline_served
            req, stale = self.slot.take(min(waits) if waits else None,
                                        self.config.goal_max_backlog,
                                        self.replanner.replan_time())
            with self._serving:
                if not self._serve_taken(req, stale, idle, inline):
                    break

    def _serve_taken(self, req: PlanRequest | None, stale: list, idle: float | None,
                     inline: int) -> bool:
        """The worker's turn (the serving lock held): what :meth:`LatestSlot.take` gave.

        ``idle``: the idle wait it waited with; ``inline``: goals served on their callback's
        thread before it waited (more now: its wait is looked at again). False once the
        slot is closed (the worker ends).
        """
        if req is None and inline != self._inline_served:
            self._replans.solve_ahead()  # as after a request the worker served
            return True
        for old, by in stale:  # solves fell behind the stream: newest wins
            by.behind = True
            self.finish(old, "WARN", "superseded", f"superseded by request {by.id}: "
                        "the goals waiting exceed goal_max_backlog")
        if req is None:
            if self.slot.closed:
                return False
            if idle is not None:
                self._replans.improve()
            load_optimised(self)
            return True
        try:
            self.serve(req)
        except Exception as exc:  # noqa: BLE001  (a bug must not stop the planner)
            self.out.log_error(f"request {req.id}: internal error: {exc!r}")
            if not req.done.is_set():
                self.finish(req, "ERROR", "failed", f"internal error: {exc!r}")
        finally:
            self.slot.finished(req)
        self._replans.solve_ahead()
        return True

    def should_stop(self, req: PlanRequest) -> Callable[[], bool]:
        """The solver's ``should_stop`` for ``req``: cancelled, or the service stops."""
        return lambda: req.cancelled.is_set() or self.stopping.is_set()

    def problem(self, config: PlannerConfig, start: tuple, target: np.ndarray,
                target_q: np.ndarray | None = None):
        """The problem from ``start`` to ``target``, or the joint state ``target_q`` (at rest).

        :func:`plan_problem`, with the collision model in use.
        """
        return plan_problem(config, self.model, self.limits, start, target, self.collision,
                            target_q)

    def serve(self, req: PlanRequest) -> None:
        """Solve ``req`` and publish (or not) its outcome; always finishes it."""
        config = req.config
        if req.cancelled.is_set():
            self.finish(req, "WARN", *req.cancel_reason)
            return
        if req.queue and self._replans.serve(req):
            return
        if req.target_pose is not None:  # IK solutions, each a joint goal
            self._poses.serve(req)
            return
        try:
            problem = self.problem(config, req.start, req.target, req.target_q)
        except TocontrolError as exc:
            self.finish(req, "ERROR", "failed", str(exc))
            return
        start_point = problem.start_point
        options = solver_options(config)
        t0 = self.clock.monotonic()
        # A memory hit answers by warm re-solves of stored motions; a miss plans as before.
        # With first_then_optimum, a hit's first motion (its stored motion moved, or a
        # certified IPOPT iterate of its re-solve) is published at once.
        early: list = []
        recalled, memory_values = self.memory.lookup(
            config, self.planner, problem, options, self.should_stop(req),
            first=(lambda r: early.append(self._hit_first(req, r, problem)))
            if config.publish == FIRST_THEN_OPTIMUM else None)
        first = next((f for f in early if f is not None), None)
        warm = None
        if recalled is not None and recalled.result is not None:
            result = recalled.result
        else:
            if config.publish == FIRST_THEN_OPTIMUM and first is None:
                first = self._first(req, problem, options)
            last = self._last_result
            warm = last if config.warm_start and last is not None and \
                last.can_warm_start(problem) else None
            firsts = [first] if first else []
            # A warm solve's first certified iterate, published at once when faster.
            extra_args = {"on_first": self._iterate_first(req, problem, firsts)} \
                if config.publish == FIRST_THEN_OPTIMUM and warm is not None else {}
            result = self.planner.plan(problem, options, warm_start=warm,
                                       should_stop=self.should_stop(req), **extra_args)
            first = firsts[-1] if firsts else None
        extra = {"start": start_point, **result_values(result), **memory_values,
                 "warm_start": warm is not None,
                 "warm_returned": any(r.index == -1 and r.status == "returned"
                                      for r in result.starts),
                 "published": "first" if first else "none"}
        if self.finish_stopped(req, extra):
            return
        # A success is published; so is a TIME_LIMIT that carries the best checked motion
        # found before the deadline (its warning, WARN, says it may not be the optimum).
        # Any other result is not, even with a trajectory (one that failed its certificate).
        time_limited = result.status.name == "TIME_LIMIT" and result.trajectory is not None
        publishable = result.success or time_limited
        if first and not (publishable and result.T < first[0].T):
            why = f"T = {result.T:.6g} s, not faster" if publishable else result.message
            self.finish(req, "WARN", "solved", f"the first motion stands (T = "
                        f"{first[0].T:.6g} s): the optimum was not published ({why})",
                        {**extra, **result_values(first[0]), "optimum_T": result.T,
                         "optimum_status": result.status.name, "samples": first[2]},
                        path=first[1])
            req.result = first[0]
            if first[1] is not None:
                self.out.markers(first[0], first[1], config, start_point, req.target)
            return
        if not publishable:
            self.finish(req, "ERROR", "failed", result.message, extra)
            return
        if result.status.name == "TRIVIAL":
            # The core's rule (Problem.is_trivial): the start is at rest on the target.
            gap = float(np.linalg.norm(start_point - req.target))
            self.finish(req, "OK", "solved",
                        f"nothing to plan: the target {req.target.tolist()} is "
                        f"{gap:.3g} m from the start at rest (within MIN_MOVE = "
                        f"{MIN_MOVE:g} m); T = 0, no trajectory published",
                        {**extra, "samples": 1}, path=self.out.rest_path(start_point))
            return
        self.publish_final(req, result, self._replans.goal_stamp(req), message_prefix="",
                           extra=extra, start_point=start_point)
        if result.success:
            self.memory.learn(config, result, self.clock.monotonic() - t0)

    def publish_final(self, req: PlanRequest, result, stamp_ns: int | None,
                      message_prefix: str, extra: dict, start_point: np.ndarray | None,
                      note: str = "") -> None:
        """Publish ``result`` as the optimum of ``req`` and finish it ``solved``.

        With ``start_point`` (m), the viewer's markers follow (replans publish none).
        """
        self._last_result = result
        req.result = result
        published = self.publish(result, req.config, req.id, stamp_ns, execute=req.execute)
        if published is None:  # publishers gone during shutdown
            req.done.set()
            return
        path, samples = published
        level, message = result_message(result)
        self.finish(req, level, "solved", f"{message_prefix}{message}{note}",
                    {**extra, "published": "optimum" if req.execute else "returned",
                     "samples": samples}, path=path)
        if start_point is not None and path is not None:
            self.out.markers(result, path, req.config, start_point, req.target)

    def _hit_first(self, req: PlanRequest, result, problem) -> tuple | None:
        """A memory hit's first motion (its stored motion moved, or an iterate), published.

        Returns ``(result, path, samples)``, or None when cancelled meanwhile (it is then
        the request's best certified motion at the cancel, as ``_first``'s) or the
        publishers are gone (the optimum follows either way).
        """
        req.first = result
        if req.cancelled.is_set() or self.stopping.is_set():
            return None
        values = {"start": problem.start_point, **result_values(result),
                  "latency": self.clock.monotonic() - req.received, "memory": "hit"}
        published = self.publish_first(req, result, None, values)
        if published is None:
            return None
        return result, published[0], published[1]["samples"]

    def _first(self, req: PlanRequest, problem, options) -> tuple | None:
        """``publish: first_then_optimum``: the first motion, published at once.

        Returns ``(result, path, samples)`` when it was published (with a ``first``
        status), else None: nothing to move, cancelled meanwhile, or it failed (a ``first``
        status says why; the optimum follows either way).
        """
        first = self.planner.first(problem, options)
        if first.status.name == "TRIVIAL":
            return None
        if req.cancelled.is_set() or self.stopping.is_set():
            if first.success:  # the best certified motion at the cancel (~/plan_motion's)
                req.first = first
            return None
        values = {"start": problem.start_point, **result_values(first),
                  "latency": self.clock.monotonic() - req.received}
        if not first.success:
            self.status(req, "WARN", "first", f"request {req.id}: no first motion "
                        f"({first.message}); the optimum follows",
                        {**values, "published": "none"})
            return None
        req.first = first
        published = self.publish_first(req, first, None, values)
        if published is None:
            return None
        return first, published[0], published[1]["samples"]

    def _iterate_first(self, req: PlanRequest, problem, firsts: list) -> Callable[[Any], None]:
        """``publish: first_then_optimum`` with a warm start: the solve's ``on_first``.

        A warm re-solve's first feasible iterate (certified, not converged: the core's
        ``on_first``, issue 47's real-time iterations) is published at once as ``req``'s
        first motion, with a ``first`` status, when no first motion was published or it is
        faster than the last one; ``firsts`` (the published ``(result, path, samples)``)
        gets it, so that the optimum is compared with it.
        """
        def publish(result) -> None:
            if req.cancelled.is_set() or self.stopping.is_set():
                return
            if firsts and result.T >= firsts[-1][0].T:
                return
            req.first = result
            values = {"start": problem.start_point, **result_values(result),
                      "latency": self.clock.monotonic() - req.received, "iterate": True}
            published = self.publish_first(req, result, None, values)
            if published is not None:
                firsts.append((result, published[0], published[1]["samples"]))
        return publish

    def publish_improved(self, req: PlanRequest, result, stamp_ns: int, message_prefix: str,
                         extra: dict) -> None:
        """Publish ``result``, the optimum after ``req``'s quick motion (``improved``)."""
        self._last_result = result
        published = self.publish(result, req.config, req.id, stamp_ns)
        if published is None:  # publishers gone during shutdown
            return
        level, message = result_message(result)
        self.status(req, level, "improved", f"request {req.id} improved: {message_prefix}"
                    f"{message}", {**extra, "published": "optimum",
                                   "samples": published[1],
                                   "latency": self.clock.monotonic() - req.received})

    def publish_first(self, req: PlanRequest, result, stamp_ns: int | None,
                      extra: dict) -> tuple[Any, dict] | None:
        """Publish ``result`` as ``req``'s first motion, with a ``first`` status.

        ``stamp_ns``: when it takes over (a replan's hand-off, ns); default now. Returns
        ``(path, values)`` (the status's values: samples, latencies), or None when the
        publishers are gone (shutdown). A plan-only request (``execute`` false): nothing
        published, the path None, the status says ``published: first`` all the same.
        """
        published = self.publish(result, req.config, req.id, stamp_ns, execute=req.execute)
        if published is None:
            return None
        path, samples = published
        level, message = result_message(result)
        values = {**extra, "published": "first", "samples": samples, **self._publish_parts,
                  "latency": self._published_at - req.received,
                  "publish_latency": self._published_at - req.received}
        self.status(req, level, "first", f"request {req.id} first motion published: "
                    f"{message}; the optimum follows", values)
        return path, values

    def publish(self, result, config: PlannerConfig, rid: int = 0,
                stamp_ns: int | None = None, execute: bool = True) -> tuple[Any, int] | None:
        """``~/trajectory``, ``~/ee_path``, the controller's goal: ``(path, samples)``.

        None when the publishers are gone (shutdown). ``stamp_ns``: when the motion takes
        over (a replan's hand-off, ns); default now. The trajectory first: the path and the
        rest do not hold it up. ``execute`` False (a plan only): nothing is published, and
        the path is None.
        """
        t0 = self.clock.monotonic()
        sample = result.trajectory.sample(config.sample_period)
        if not execute:
            return None, len(sample.t)
        if stamp_ns is None:
            stamp_ns = self.clock.now_ns()
        stamp_ns = int(stamp_ns)
        t1 = self.clock.monotonic()
        msg = self.out.trajectory(sample, stamp_ns)
        if msg is None:
            return None
        self._published_at = self.clock.monotonic()
        self._publish_parts = {"sample_time": t1 - t0, "send_time": self._published_at - t1}
        # Sent after its stamp to a tracker that holds, it starts when it arrives, not at
        # its stamp (a JTC, controller_action, drops the points past instead).
        sent_ns = None if config.controller_action else self.clock.now_ns()
        self.replanner.published(result, stamp_ns, sample, sent_ns=sent_ns)
        self._sent = (rid, result, stamp_ns)
        self._stamps.append((stamp_ns, rid))
        path = self.out.path(sample, stamp_ns)
        if path is None:
            return None
        self.out.follow(rid, msg, config)
        return path, len(sample.t)

    def controller_refused(self, request_id: int, reason: str) -> None:
        """The controller refused (or aborted) the motion published for ``request_id``.

        When it is the last published motion, replans stop continuing it
        (:meth:`Replanner.not_executing`): a ``refused`` status says so, and the next goal is
        planned from the arm's measured state. An older motion (replaced since) changes
        nothing.
        """
        sent = self._sent
        if sent is None or sent[0] != request_id or not self.replanner.not_executing(sent[1]):
            return
        self.out.status("WARN", f"request {request_id}: its motion is not executing "
                        f"({reason}); the planner no longer continues it: the next goal is "
                        "planned from the arm's measured state",
                        {"request_id": request_id, "event": "refused",
                         "frame_id": self.frame_id})

    def tracker_rejected(self, stamp: float, reason: str) -> None:
        """A tracker rejected the trajectory stamped ``stamp`` (s) that it got on the topic.

        When that is the last published motion, or one the last continues (a stream's
        replans are published before the one they continue takes over, where the tracker
        rejects it; matched within 1 us), replans stop continuing it and what was chained on
        it (:meth:`Replanner.rejected`): they continue the motion before it in the chain,
        which the tracker goes on with, or, when none is known, the next goal is planned from
        the arm's measured state. A ``refused`` status says which. Another stamp (a motion
        replaced since and not continued, one never published) changes nothing.
        """
        stamp_ns = round(stamp * 1e9)
        changed, running = self.replanner.rejected(stamp_ns)
        if not changed:
            return
        stamps = tuple(self._stamps)[::-1]  # a copy: the worker appends to it
        rid = next((r for s, r in stamps if abs(s - stamp_ns) <= 1000), None)
        last = self._sent[0] if self._sent is not None else None
        chained = "" if last in (rid, None) else \
            f", nor request {last}'s motion, chained on it"
        if running is None:
            then = "the next goal is planned from the arm's measured state"
        else:
            before = next((r for s, r in stamps if s == running), None)
            then = (f"replans continue the motion before it (request {before}), which the "
                    "tracker goes on with, if the measured arm follows it")
        self.out.status("WARN", f"request {rid}: its motion is not executing (the tracker "
                        f"rejected it: {reason}){chained}; the planner no longer continues "
                        f"it: {then}",
                        {"request_id": rid, "event": "refused", "frame_id": self.frame_id,
                         "last_request_id": last,
                         "continues": "measured" if running is None else "previous"})

    # --------------------------------------------------------------- shutdown
    def stop(self, timeout: float = JOIN_TIMEOUT) -> None:
        """Stop the worker: cancel the running solve, answer the pending requests, join."""
        self.stopping.set()
        for leftover in self.slot.close():
            self.finish(leftover, "WARN", "cancelled", "node shutting down")
        if self._worker.is_alive() and threading.current_thread() is not self._worker:
            self._worker.join(timeout)
        if not self._worker.is_alive():
            self.memory.close()
