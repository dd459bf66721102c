"""The planning service's replans: a goal while a published motion runs, solved and stamped.

:class:`ReplanPolicy` is a part of :class:`~tocontrol_ros.nodes.planning_service.PlanningService`
(composition: it uses the service's public state and helpers), kept apart so that the
service's module stays about requests in general. The hand-off, latencies and warm starts
are :mod:`tocontrol_ros.nodes.replanning`'s and :mod:`tocontrol_ros.core.planning.replan`'s; see
``msg_docs/parameters.md``, "Replanning". No ROS here.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.indirect.warm import WarmState
from tocontrol_ros.core.planning.replan import (
    path_tail_warm_start,
    replan_options,
    warm_replan,
)
from tocontrol_ros.nodes.outcomes import result_values, stamp_text
from tocontrol_ros.nodes.planner_config import PlannerConfig, solver_options
from tocontrol_ros.nodes.replanning import (
    IMPROVE,
    QUICK,
    REPLAN_TRIES,
    REST,
    STREAM_PERIOD,
    STREAM_RATIO,
    align,
    keeps_ahead,
)
from tocontrol_ros.nodes.requests import PlanRequest

__all__ = ["ReplanPolicy", "replanning", "served_by", "HELD", "HELD_SPEED"]

#: The kind (``replan`` status value) of a quick motion from the arm's measured state, held
#: still off the last published motion (:meth:`ReplanPolicy.serve_quick_held`).
HELD = "held"
#: The arm holds still when every joint's measured speed is within this (rad/s, m/s): a
#: holding tracker's PD leaves speeds of order 1e-9 with the planning model, and a motion's
#: command moves faster than this except within a few milliseconds of its ends.
HELD_SPEED = 1e-3


def replanning(config: PlannerConfig) -> bool:
    """Whether goals are replanned from the hand-off (``replan``).

    With ``controller_action`` too (issue 52): a replan goes to the FollowJointTrajectory
    controller with its hand-off as a future ``header.stamp``, where a Jazzy JTC (and the
    tracker's action) joins it to the running trajectory
    (:func:`~tocontrol_ros.nodes.controller_client.controller_goal`).
    """
    return bool(config.replan)


def served_by(service: Any) -> str:
    """Which thread serves a quick replan: ``"worker"`` or ``"goal callback"`` (issue 47)."""
    return "worker" if threading.current_thread() is service.worker else "goal callback"


class ReplanPolicy:
    """Goals and replans of a :class:`~tocontrol_ros.nodes.planning_service.PlanningService`.

    Parameters
    ----------
    service : PlanningService
        Its planner, replanner (the published motions), arm, clock, slot and its
        ``finish``/``publish_final`` helpers. (Typed ``Any`` here: the service's module
        imports this one, and the import graph has no cycles, not even for type hints.)
    """

    def __init__(self, service: Any) -> None:
        self.service = service
        #: The last quick motion published, until its optimum was tried:
        #: (request, quick result, its stamp ns, the motion before it, its status values).
        self._improvable: tuple | None = None

    def idle_wait(self) -> float | None:
        """How long the worker waits for a goal before it improves a quick motion (s).

        None: nothing to improve (wait for requests). Else, while goals stream in (the last
        two at most :data:`~tocontrol_ros.nodes.replanning.STREAM_PERIOD` apart), 1.5 times
        their interval (:data:`~tocontrol_ros.nodes.replanning.STREAM_RATIO`: a stream's
        next goal is served first); at least ``replan_min_lead``.
        """
        if self._improvable is None:
            return None
        interval = self.service.replanner.goals.interval()
        stream = 0.0 < interval <= STREAM_PERIOD  # goals a second apart or more: none
        return max(STREAM_RATIO * interval if stream else 0.0,
                   self.service.config.replan_min_lead)

    def goal_stamp(self, req: PlanRequest) -> int | None:
        """The stamp of a goal's plan (ns), or None (now).

        With replanning, a little ahead on the tracker's control grid (the lead of motions
        from rest, :meth:`~tocontrol_ros.nodes.replanning.Replanner.rest_lead`), so that a
        replan from it knows when it took over.
        """
        if not req.queue:
            return None
        config = req.config
        lead = self.service.replanner.rest_lead(config)
        t_ns = self.service.clock.wall_ns() + int(lead * 1e9)
        origin = self.service.arm.latest(config)[0]
        return align(t_ns, origin or t_ns, config.handoff_grid)

    def _measured(self, config: PlannerConfig) -> tuple[int, tuple | None]:
        """The latest joint state's stamp (ns, 0: none) and (positions, stamp) or None."""
        origin, q = self.service.arm.latest(config)
        return origin, (None if q is None else (q, origin))

    def serve(self, req: PlanRequest) -> bool:
        """A goal while a published motion runs: planned from the hand-off, stamped with it.

        Returns False when no published motion runs at the hand-off (the goal is then
        served as any other, from the arm's measured state). With ``replan_quick``, a quick
        motion first (:meth:`serve_quick`); else, or when it fails, the optimum
        (:meth:`serve_optimum`).
        """
        if not req.quick_tried and self._quick_route(req):
            served = self.serve_quick(req)
            if served is not None:
                return served
        return self.serve_optimum(req)

    def _quick_route(self, req: PlanRequest) -> bool:
        """Whether ``req`` gets the quick motion first: ``replan_quick`` and a near goal.

        A far goal is a new motion: the cold multistart's, as ever.
        """
        return bool(req.config.replan_quick) and \
            self.service.replanner.near(req.config, req.target)

    def serve_first(self, req: PlanRequest) -> bool:
        """:meth:`serve`'s quick motion alone, for a goal served on its callback's thread.

        True when it answered ``req`` (published, or finished stopped); False when the
        quick motion is not the route (cancelled, not near, none in time): the worker then
        serves ``req`` (:meth:`serve` without the quick motion again).
        """
        if req.cancelled.is_set() or not self._quick_route(req):
            return False
        return bool(self.serve_quick(req))

    def serve_quick(self, req: PlanRequest) -> bool | None:
        """The quick motion from the hand-off, published at once; then the optimum after it.

        The target's configuration is found near the running motion's end and the path
        from the hand-off state to it timed by TOPP-RA
        (:func:`~tocontrol_ros.core.direct.first_motion.quick_motion`), certified, stamped
        with the hand-off (its lead from the quick motions' latencies) and published with a
        ``first`` status, and the request finishes ``solved`` with it. Its optimum is
        solved when the worker is idle (:meth:`improve`). Returns None when no quick
        motion could be published (it failed, or was late :data:`REPLAN_TRIES` times;
        nothing was published, or no published motion runs at the hand-off): the caller
        goes on as without ``replan_quick``.
        """
        service = self.service
        clock = service.clock
        config = req.config
        replans = service.replanner
        min_lead = 0.0
        wait_time = clock.monotonic() - req.received  # acceptance -> the worker took it
        for attempt in range(1, REPLAN_TRIES + 1):
            t0 = clock.monotonic()
            origin, measured = self._measured(config)
            running = replans.running()
            handoff = replans.handoff(config, req.target, clock.now_ns(), origin, min_lead,
                                      measured, quick=True)
            if handoff is None and attempt == 1:
                # The arm does not follow the last motion (late beyond FOLLOW_LAG, refused,
                # reset): from its measured state if it holds still, never the cold
                # multistart while a stream's near goals come.
                return self.serve_quick_held(req, wait_time)
            if handoff is None or running is None or running.trajectory is None:
                return None  # the optimum's route decides (a goal from the measured state)
            t_problem = clock.monotonic()
            if replans.near(config, req.target):
                replans.note_reachable(service.model, req.target, service.collision)
            try:
                problem = service.problem(config, ("state", handoff.q, handoff.qd),
                                          req.target)
            except TocontrolError:
                return None  # the optimum's route says why
            n = problem.model.n
            q_end = running.trajectory.state(running.T)[0][:n]
            # The parabola's time scale from the straight path's rest-to-rest time, not from
            # the time the running motion has left: along a stream of quick motions that
            # grew (each a little slower than the last: 0.5 s to 2.2 s on the paper's arm).
            t_solve = clock.monotonic()
            quick = service.planner.quick(problem, q_end, solver_options(config))
            extra = {"start": problem.start_point, "start_q": handoff.q,
                     "start_qd": handoff.qd, **result_values(quick),
                     "wait_time": wait_time, "handoff_time": t_problem - t0,
                     "problem_time": t_solve - t_problem,
                     "replan": handoff.kind, "attempts": attempt,
                     "served_by": served_by(service),
                     "follow_lag": handoff.lag_ns * 1e-9,
                     "handoff": stamp_text(handoff.stamp_ns), "warm_start": False,
                     "published": "none"}
            if service.finish_stopped(req, extra):
                return True
            if not quick.success or quick.trajectory is None:
                service.status(req, "WARN", "first", f"request {req.id}: no quick motion "
                               f"({quick.message}); the optimum follows", extra)
                return None
            now = clock.now_ns()
            if handoff.kind == REST:
                handoff = handoff._replace(stamp_ns=replans.rest_stamp(config, handoff, now,
                                                                       origin))
                extra["handoff"] = stamp_text(handoff.stamp_ns)
            replans.estimate(config, QUICK).record(clock.monotonic() - t0)
            if now > handoff.stamp_ns - int(config.replan_min_lead * 1e9):
                min_lead = config.replan_min_lead + 2.0 * (clock.monotonic() - t0)
                continue
            return self._publish_quick(req, quick, handoff.stamp_ns, running, extra)
        service.status(req, "WARN", "first", f"request {req.id}: no quick motion in time for "
                       f"its hand-off in {REPLAN_TRIES} tries; the optimum follows", extra)
        return None

    def serve_quick_held(self, req: PlanRequest, wait_time: float) -> bool | None:
        """A near goal while the arm holds still off the last published motion: a quick motion.

        The arm does not follow the last motion (no hand-off on it: late by more than
        :data:`~tocontrol_ros.nodes.replanning.FOLLOW_LAG`, refused by the tracker, a reset)
        but holds still (its latest joint state's speeds within :data:`HELD_SPEED`): the
        quick motion from there at rest, the target's configuration found near the last
        motion's end, certified, stamped as a goal's first motion from rest
        (:meth:`goal_stamp`: nothing runs that it must join) and published with a ``first``
        status (``replan: held``); its optimum follows when the worker is idle
        (:meth:`improve`). A moving arm that follows no known motion cannot be predicted to
        a stamp: None, and so for no joint state or a failed quick motion; the caller then
        plans the goal as a new motion from the measured state, as before.
        """
        service = self.service
        clock = service.clock
        config = req.config
        running = service.replanner.running()
        if running is None or running.trajectory is None or running.problem is None:
            return None
        t0 = clock.monotonic()
        try:
            measured = service.arm.start(config, 0, fresh=False)
        except TocontrolError:
            return None
        if measured[0] != "state" or np.max(np.abs(measured[2])) > HELD_SPEED:
            return None
        q = np.asarray(measured[1], dtype=float)
        t_problem = clock.monotonic()
        try:
            problem = service.problem(config, ("state", q, np.zeros_like(q)), req.target)
        except TocontrolError:
            return None  # the new motion's route says why
        n = problem.model.n
        q_end = running.trajectory.state(running.T)[0][:n]
        t_solve = clock.monotonic()
        quick = service.planner.quick(problem, q_end, solver_options(config))
        extra = {"start": problem.start_point, "start_q": q, "start_qd": np.zeros_like(q),
                 **result_values(quick), "wait_time": wait_time,
                 "handoff_time": t_problem - t0, "problem_time": t_solve - t_problem,
                 "replan": HELD, "attempts": 1, "warm_start": False, "published": "none",
                 "served_by": served_by(service)}
        if service.finish_stopped(req, extra):
            return True
        if not quick.success or quick.trajectory is None:
            service.status(req, "WARN", "first", f"request {req.id}: no quick motion from "
                           f"the held arm ({quick.message}); a new motion follows", extra)
            return None
        stamp_ns = self.goal_stamp(req)
        extra["handoff"] = stamp_text(stamp_ns)
        return self._publish_quick(req, quick, stamp_ns, running, extra, " from the held arm",
                                   "; the arm did not follow the last motion")

    def _publish_quick(self, req: PlanRequest, quick, stamp_ns: int, running, extra: dict,
                       where: str = "", why: str = "") -> bool:
        """Publish ``quick`` stamped ``stamp_ns``, finish ``req`` with it, keep it improvable.

        ``running``: the motion it follows; ``where``, ``why``: said in the ``solved`` status.
        Returns True (the request is answered, or the node shuts down).
        """
        service = self.service
        published = service.publish_first(req, quick, stamp_ns, extra)
        if published is None:  # shutdown
            req.done.set()
            return True
        path, values = published
        service.finish(req, "OK", "solved", f"the quick motion published{where} (T = "
                       f"{quick.T:.6g} s{why}); its optimum follows when the worker is idle",
                       values, path=path)
        self._improvable = (req, quick, stamp_ns, running, values)
        return True

    def improve(self) -> None:
        """The optimum after the last quick motion, when the worker is idle; or it stands.

        From a later hand-off on the quick motion, while no request waits (one that arrives
        stops it), warm alone (the
        motion that ran before the quick one, and the replanner's warm starts), no cold
        solve; the quick motion's own rest from the hand-off is the first warm start (of the
        bounded solve: :func:`~tocontrol_ros.core.planning.replan.path_tail_warm_start`),
        with ``replan_spans``; published as the
        request's optimum when certified, in time for its hand-off
        and ending before the quick motion does, with an ``improved`` status (the request
        was answered by the quick motion); otherwise a ``kept`` status says why. Nothing
        when the quick motion no longer runs (a later motion was published).
        """
        service = self.service
        improvable, self._improvable = self._improvable, None
        if improvable is None:
            return
        req, quick, quick_stamp_ns, before, extra = improvable
        clock = service.clock
        config = req.config
        replans = service.replanner
        if replans.running() is not quick:
            return
        quick_end = quick_stamp_ns * 1e-9 + quick.T
        stands = {**extra, "published": "first"}

        def keep(why: str) -> None:
            service.status(req, "OK", "kept", f"request {req.id}: the quick motion stands "
                           f"(T = {quick.T:.6g} s): {why}", stands)

        t0 = clock.monotonic()
        origin, measured = self._measured(config)
        # Any moving hand-off on the quick motion (quick=True: no REST_TAIL rule, which is
        # the tail continuation's), with the lead of the optima solved after quick motions.
        handoff = replans.handoff(config, req.target, clock.now_ns(), origin, 0.0, measured,
                                  quick=True, lead_kind=IMPROVE)
        if handoff is None or handoff.kind == REST:
            return keep("it ends before an optimum could take over")
        try:
            problem = service.problem(config, ("state", handoff.q, handoff.qd), req.target)
        except TocontrolError as exc:
            return keep(str(exc))
        options = replan_options(solver_options(config), config.replan_smoothing,
                                 config.replan_spans)

        def stop() -> bool:
            return service.stopping.is_set() or service.slot.has_pending()

        # The quick motion's own rest from the hand-off (the bounded solve from its path
        # fitted on replan_spans uniform spans) where the bounded solve is the method (the
        # last optimum published was one: the limits bind here; on the paper's arm it
        # crawled to its iteration limit from a long quick motion), then the others.
        bounded = getattr(service.last_result, "method", None) == "direct"
        tail = path_tail_warm_start(quick, (handoff.stamp_ns - quick_stamp_ns) * 1e-9) \
            if options.replan_spans and bounded else None
        warm = [w for w in (tail, before, *replans.warm_starts(handoff.warm))
                if w is not None and w.warm_state is not None
                and w.can_warm_start(problem, options.warm_joint_radius)]
        if not warm:  # a cold solve takes longer than a quick motion runs
            return keep("no warm start applies to its optimum")
        result = warm_replan(service.planner, problem, warm, options, stop)
        if stop():
            return keep("stopped by a request")
        if not result.success or result.trajectory is None:
            return keep(f"its optimum was not found ({result.message})")
        replans.estimate(config, IMPROVE).record(clock.monotonic() - t0)
        now = clock.now_ns()
        if now > handoff.stamp_ns - int(config.replan_min_lead * 1e9):
            return keep(f"the optimum came {(now - handoff.stamp_ns) * 1e-9:+.3f} s after "
                        "its hand-off")
        if handoff.stamp_ns * 1e-9 + result.T >= quick_end:
            return keep(f"the optimum from its hand-off would not end sooner "
                        f"(T = {result.T:.6g} s)")
        values = {**extra, "start": problem.start_point, "start_q": handoff.q,
                  "start_qd": handoff.qd, **result_values(result), "replan": handoff.kind,
                  "handoff": stamp_text(handoff.stamp_ns), "warm_start": True,
                  "quick_T": quick.T}
        service.publish_improved(req, result, handoff.stamp_ns,
                                 f"replan ({handoff.kind}) improving the quick motion, taking "
                                 f"over at {handoff.stamp_ns * 1e-9:.3f}: ", values)

    def serve_optimum(self, req: PlanRequest) -> bool:
        """A goal while a published motion runs, its optimum from the hand-off.

        Solved again from a later hand-off when the plan would arrive late (at most
        :data:`REPLAN_TRIES` solves). Returns False when no published motion runs at the
        hand-off.
        """
        service = self.service
        clock = service.clock
        config = req.config
        replans = service.replanner
        late = []
        min_lead = 0.0
        late_result = None
        for attempt in range(1, REPLAN_TRIES + 1):
            t0 = clock.monotonic()
            origin, measured = self._measured(config)
            handoff = replans.handoff(config, req.target, clock.now_ns(), origin, min_lead,
                                      measured)
            if handoff is None:
                if req.since_ns:  # as any goal: a joint state received after it
                    try:
                        req.start = service.arm.start(config, req.since_ns)
                    except TocontrolError:
                        pass  # keep the state taken at its arrival
                return False
            near = replans.near(config, req.target)
            if near:  # its problem's reachability check from the nearest motion's end
                replans.note_reachable(service.model, req.target, service.collision)
            try:
                problem = service.problem(config, ("state", handoff.q, handoff.qd), req.target)
            except TocontrolError as exc:
                service.finish(req, "ERROR", "failed", str(exc))
                return True
            options = solver_options(config)
            warm = [handoff.warm]
            if near or (req.behind and problem.limits.active):
                # Near: the running motion's tail continued, or the last motions published
                # (replanning.Replanner.warm_starts); should they fail, one start, no
                # multistart. So too a far goal after the worker fell behind the stream on an
                # arm whose limits bind (its multistart takes seconds: the stream moves on).
                options = replan_options(options, config.replan_smoothing,
                                         config.replan_spans)
                # A late solve's result first: the same goal from a little earlier.
                warm = [late_result, *replans.warm_starts(handoff.warm)]
            result = None
            if any(w is not None for w in warm):
                result = warm_replan(service.planner, problem, warm, options,
                                     service.should_stop(req))
            if result is None or not (result.success or req.cancelled.is_set()):
                result = service.planner.plan(problem, options,
                                              should_stop=service.should_stop(req))
            if not (result.success or req.cancelled.is_set()) and options.starts == 1 \
                    and not service.slot.has_pending():
                # The one start failed: the multistart (its time counts as this solve's),
                # unless goals wait (a stream: seconds of multistart would hold them all up;
                # the next goal is solved instead).
                result = service.planner.plan(problem, solver_options(config),
                                              should_stop=service.should_stop(req))
            # The status says where the replan starts: the hand-off state, not the state
            # measured when the goal came.
            extra = {"start": problem.start_point, "start_q": handoff.q,
                     "start_qd": handoff.qd, **result_values(result),
                     "replan": handoff.kind, "attempts": attempt,
                     "served_by": served_by(service),
                     "follow_lag": handoff.lag_ns * 1e-9,
                     "handoff": stamp_text(handoff.stamp_ns),
                     "warm_start": any(w is not None for w in warm),
                     "published": "none"}
            if service.finish_stopped(req, extra):
                return True
            if not result.success or result.trajectory is None:
                service.finish(req, "ERROR", "failed", result.message, extra)
                return True
            estimate = replans.estimate(config, handoff.kind)
            estimate.record(clock.monotonic() - t0)  # late or not: what a solve takes now
            now = clock.now_ns()
            if handoff.kind == REST:  # the arm rests there from the hand-off on: not late
                handoff = handoff._replace(stamp_ns=replans.rest_stamp(config, handoff, now,
                                                                       origin))
                extra["handoff"] = stamp_text(handoff.stamp_ns)
            if now > handoff.stamp_ns - int(config.replan_min_lead * 1e9):
                late.append(f"{(now - handoff.stamp_ns) * 1e-9:+.3f} s")
                # Again, with at least twice this solve's time plus the delivery lead.
                min_lead = config.replan_min_lead + 2.0 * (clock.monotonic() - t0)
                late_result = result
                continue
            note = f" (after {len(late)} late solve(s))" if late else ""
            service.publish_final(req, result, handoff.stamp_ns,
                                  f"replan ({handoff.kind}) taking over at "
                                  f"{handoff.stamp_ns * 1e-9:.3f}: ", extra, None, note)
            return True
        service.finish(req, "ERROR", "failed", f"each of {REPLAN_TRIES} replans would have "
                       f"arrived after its hand-off (published - hand-off: {', '.join(late)})",
                       {"replan": "late", "attempts": REPLAN_TRIES})
        return True

    def solve_ahead(self) -> None:
        """While the worker waits: the goal a steady stream predicts, solved ahead.

        With ``replan_predict``, when the recent goals form a stream
        (:class:`~tocontrol_ros.nodes.replanning.GoalStream`) whose next goal is near the
        running motion's target, that goal is replanned now, from the hand-off it would get
        when due, and kept: the real goal's first warm start
        (:meth:`~tocontrol_ros.nodes.replanning.Replanner.warm_starts`), a prediction error
        away. Nothing is published; a request that arrives stops it.
        """
        service = self.service
        config = service.config
        replans = service.replanner
        if not (replanning(config) and config.replan_predict) or service.slot.has_pending():
            return
        predicted = replans.goals.predict(config.replan_radius)
        running = replans.running()
        # Shooting solutions only: a bounded B-spline solve (seconds, IPOPT) would hold up
        # the real goal, whose arrival stops a solve only between Newton iterations.
        if predicted is None or not isinstance(getattr(running, "warm_state", None),
                                               WarmState) \
                or not replans.near(config, predicted[0]):
            return
        target, due = predicted
        due_ns = service.clock.now_ns() + int(max(due - service.clock.monotonic(), 0) * 1e9)
        origin, measured = self._measured(config)
        handoff = replans.handoff(config, target, due_ns, origin, 0.0, measured)
        if handoff is None:
            return
        replans.note_reachable(service.model, target, service.collision)
        try:
            problem = service.problem(config, ("state", handoff.q, handoff.qd), target)
        except TocontrolError:
            return  # e.g. a predicted target out of reach: the real goal will say so
        options = replan_options(solver_options(config), config.replan_smoothing,
                                 config.replan_spans)
        step = float(np.linalg.norm(target - running.problem.target_point))

        def stop() -> bool:  # any request but the goal predicted stops it
            return service.stopping.is_set() or not keeps_ahead(service.slot.pending(),
                                                                target, step)

        result = warm_replan(service.planner, problem, replans.warm_starts(handoff.warm),
                             options, stop)
        if result.success and result.trajectory is not None:
            replans.solved_ahead(result, running)
