"""The planner node's replans: a goal while a published motion runs, solved and stamped.

:class:`ReplanServing` is a part of :class:`~tocontrol_ros.nodes.planner.PlannerNode` (a
mixin: it uses the node's model, planner, limits, joint states and status helpers), kept
apart so that the node's module stays about requests in general. The policy (hand-off,
latencies, which warm start) is :mod:`tocontrol_ros.nodes.replanning`'s and
:mod:`tocontrol_ros.core.planning.replan`'s; see ``msg_docs/parameters.md``, "Replanning".
"""

from __future__ import annotations

import time

import numpy as np
from geometry_msgs.msg import PointStamped

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.indirect.warm import WarmState
from tocontrol_ros.core.planning.replan import replan_options, warm_replan
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.planner_config import PlannerConfig, solver_options
from tocontrol_ros.nodes.replanning import REPLAN_TRIES, REST, align, keeps_ahead
from tocontrol_ros.nodes.requests import PlanRequest

__all__ = ["ReplanServing"]


def replanning(config: PlannerConfig) -> bool:
    """Whether goals are replanned from the hand-off (``replan``, and no ``controller_action``).

    A plan sent to a FollowJointTrajectory controller starts there on receipt (stamp zero,
    msg_docs/controller_execution.md), so a replan stamped at its hand-off would not be
    spliced there: with ``controller_action`` set, goals are planned from the latest joint
    state and start on receipt, as with ``replan: false``.
    """
    return bool(config.replan and not config.controller_action)


class ReplanServing:
    """Goals and replans of :class:`~tocontrol_ros.nodes.planner.PlannerNode`."""

    def _on_goal(self, msg: PointStamped, info) -> None:
        received = time.monotonic()
        since = int(info.get("received_timestamp", 0)) or time.time_ns()
        rid = next(self._ids)
        config = self.config
        # A replan starts from the published motion, not from the measured state: no wait
        # for a fresh one here (_serve_replan waits when the arm does not follow).
        replan = replanning(config)
        fresh = not (replan and self._replanner.has_motion())
        try:
            target = conv.point_from_msg(msg.point, msg.header.frame_id, self.frame, "goal.point")
            start = self._current_start(config, since, fresh)
        except conv.ConversionError as exc:
            self._reject(rid, "goal", str(exc))
            return
        if replan:
            self._replanner.goals.record(target, received)
        self._submit(PlanRequest(rid, "goal", start, target, config, received=received,
                                 queue=replan, since_ns=0 if fresh else since))

    def _goal_stamp(self, req: PlanRequest) -> int | None:
        """The stamp of a goal's plan (ns), or None (now).

        With replanning, a little ahead on the tracker's control grid, so that a replan from
        it knows when it took over.
        """
        if not req.queue:
            return None
        config = req.config
        return self._handoff_stamp(config, time.time_ns() + int(config.replan_min_lead * 1e9))

    def _handoff_stamp(self, config: PlannerConfig, t_ns: int) -> int:
        """``t_ns`` put on the tracker's control grid (after the latest joint state's stamp)."""
        latest = self._joint_states.newest(0, config.joint_state_timeout, 0.0)
        origin = 0 if latest is None else conv.nanoseconds(latest.header.stamp)
        return align(t_ns, origin or t_ns, config.handoff_grid)

    def _serve_replan(self, req: PlanRequest) -> bool:
        """A goal while a published motion runs: planned from the hand-off, stamped with it.

        Returns False when no published motion runs at the hand-off (the goal is then
        served as any other, from the arm's measured state). Solved again from a later
        hand-off when the plan would arrive late (at most :data:`REPLAN_TRIES` solves).
        """
        config = req.config
        replans = self._replanner
        late = []
        min_lead = 0.0
        late_result = None
        for attempt in range(1, REPLAN_TRIES + 1):
            t0 = time.monotonic()
            origin, measured = self._measured(config)
            handoff = replans.handoff(config, req.target, self.get_clock().now().nanoseconds,
                                      origin, min_lead, measured)
            if handoff is None:
                if req.since_ns:  # as any goal: a joint state received after it
                    try:
                        req.start = self._current_start(config, req.since_ns)
                    except conv.ConversionError:
                        pass  # keep the state taken at its arrival
                return False
            near = replans.near(config, req.target)
            if near:  # its problem's reachability check from the nearest motion's end
                replans.note_reachable(self.model, req.target)
            try:
                problem = self._problem(config, ("state", handoff.q, handoff.qd), req.target)
            except TocontrolError as exc:
                self._finish(req, "ERROR", "failed", str(exc))
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
                result = warm_replan(self.planner, problem, warm, options,
                                     self._should_stop(req))
            if result is None or not (result.success or req.cancelled.is_set()):
                result = self.planner.plan(problem, options,
                                           should_stop=self._should_stop(req))
            if not (result.success or req.cancelled.is_set()) and options.starts == 1 \
                    and not self._slot.has_pending():
                # The one start failed: the multistart (its time counts as this solve's),
                # unless goals wait (a stream: seconds of multistart would hold them all up;
                # the next goal is solved instead).
                result = self.planner.plan(problem, solver_options(config),
                                           should_stop=self._should_stop(req))
            # The status says where the replan starts: the hand-off state, not the state
            # measured when the goal came.
            extra = {"start": problem.start_point, "start_q": handoff.q,
                     "start_qd": handoff.qd, **conv.result_values(result),
                     "replan": handoff.kind, "attempts": attempt,
                     "handoff": conv.stamp_text(handoff.stamp_ns),
                     "warm_start": any(w is not None for w in warm),
                     "published": "none"}
            if req.cancelled.is_set() or self._stopping.is_set():
                event, reason = req.cancel_reason if req.cancelled.is_set() else \
                    ("cancelled", "node shutting down")
                self._finish(req, "WARN", event, reason, extra)
                return True
            if not result.success or result.trajectory is None:
                self._finish(req, "ERROR", "failed", result.message, extra)
                return True
            estimate = replans.estimate(config, handoff.kind)
            estimate.record(time.monotonic() - t0)  # late or not: what a solve takes now
            now = self.get_clock().now().nanoseconds
            if handoff.kind == REST:  # the arm rests there from the hand-off on: not late
                handoff = handoff._replace(stamp_ns=replans.rest_stamp(config, handoff, now,
                                                                       origin))
                extra["handoff"] = conv.stamp_text(handoff.stamp_ns)
            if now > handoff.stamp_ns - int(config.replan_min_lead * 1e9):
                late.append(f"{(now - handoff.stamp_ns) * 1e-9:+.3f} s")
                # Again, with at least twice this solve's time plus the delivery lead.
                min_lead = config.replan_min_lead + 2.0 * (time.monotonic() - t0)
                late_result = result
                continue
            self._last_result = result
            path = self._publish(result, config, req.id, handoff.stamp_ns)
            if path is None:
                req.done.set()
                return True
            level, message = conv.result_message(result)
            note = f" (after {len(late)} late solve(s))" if late else ""
            self._finish(req, level, "solved", f"replan ({handoff.kind}) taking over at "
                         f"{handoff.stamp_ns * 1e-9:.3f}: {message}{note}",
                         {**extra, "published": "optimum", "samples": len(path.poses)},
                         path=path)
            return True
        self._finish(req, "ERROR", "failed", f"each of {REPLAN_TRIES} replans would have "
                     f"arrived after its hand-off (published - hand-off: {', '.join(late)})",
                     {"replan": "late", "attempts": REPLAN_TRIES})
        return True

    def _problem(self, config: PlannerConfig, start: tuple, target):
        """The problem from ``start`` to ``target`` (m); raises TocontrolError.

        ``start``: ``("point", p)`` or ``("state", q, qd)`` (a request's start, or a
        hand-off's state). A joint-state velocity a little over a planning limit (a measured
        arm's tracking overshoot, or the published samples' interpolant at a hand-off where
        the motion runs at the limit) is planned from the limit
        (:meth:`~tocontrol_ros.core.robot.limits.JointLimits.admissible_velocity`).
        """
        from tocontrol_ros.core.types.problem import Problem, joint_state, point

        limits = self._limits.with_margin(config.limit_margin)
        begin = point(start[1]) if start[0] == "point" else \
            joint_state(start[1], limits.admissible_velocity(start[2]))
        return Problem(self.model, begin, point(target), k=config.k, reserve=config.reserve,
                       limits=limits)

    def _measured(self, config: PlannerConfig) -> tuple[int, tuple | None]:
        """The latest joint state's stamp (ns, 0: none) and (positions, stamp) or None."""
        latest = self._joint_states.newest(0, config.joint_state_timeout, 0.0)
        if latest is None:
            return 0, None
        origin = conv.nanoseconds(latest.header.stamp)
        try:
            q, _ = conv.joint_state_from_msg(latest, self.model.joint_names)
        except conv.ConversionError:
            return origin, None  # not this arm's joints: no replan
        return origin, (q, origin)

    def _solve_ahead(self) -> None:
        """While the worker waits: the goal a steady stream predicts, solved ahead.

        With ``replan_predict``, when the recent goals form a stream
        (:class:`~tocontrol_ros.nodes.replanning.GoalStream`) whose next goal is near the
        running motion's target, that goal is replanned now, from the hand-off it would get
        when due, and kept: the real goal's first warm start
        (:meth:`~tocontrol_ros.nodes.replanning.Replanner.warm_starts`), a prediction error
        away. Nothing is published; a request that arrives stops it.
        """
        config = self.config
        replans = self._replanner
        if not (replanning(config) and config.replan_predict) or self._slot.has_pending():
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
        due_ns = self.get_clock().now().nanoseconds + int(max(due - time.monotonic(), 0) * 1e9)
        origin, measured = self._measured(config)
        handoff = replans.handoff(config, target, due_ns, origin, 0.0, measured)
        if handoff is None:
            return
        replans.note_reachable(self.model, target)
        try:
            problem = self._problem(config, ("state", handoff.q, handoff.qd), target)
        except TocontrolError:
            return  # e.g. a predicted target out of reach: the real goal will say so
        options = replan_options(solver_options(config), config.replan_smoothing,
                                 config.replan_spans)
        step = float(np.linalg.norm(target - running.problem.target_point))

        def stop() -> bool:  # any request but the goal predicted stops it
            return self._stopping.is_set() or not keeps_ahead(self._slot.pending(), target,
                                                              step)

        result = warm_replan(self.planner, problem, replans.warm_starts(handoff.warm), options,
                             stop)
        if result.success and result.trajectory is not None:
            replans.solved_ahead(result, running)
