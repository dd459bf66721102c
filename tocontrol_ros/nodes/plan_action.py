"""The planner's ``~/plan_motion`` action (``tocontrol_msgs/action/PlanMotion``).

A goal gives a start (the arm's current state, or a joint state), a target (an end-effector
point, an end-effector pose: position and orientation, :mod:`tocontrol_ros.nodes.pose_goals`;
or a joint state) and options (``k``, ``time_limit``, ``limit_margin``: negative takes
the parameter; ``execute``: also publish the plan on ``~/trajectory`` and send it to
``controller_action``). The goal becomes a request of the planning service like a ``~/plan``
call (newest wins: a newer request supersedes it); feedback every :data:`FEEDBACK_PERIOD`
(stage, the best certified duration known so far, elapsed time); a cancel asks the solve to
stop (the solver's ``should_stop``) and the result carries the best certified motion known
then (the first motion of ``publish: first_then_optimum``, a pose goal's best first motion)
or none, as its message says: the solve's own outcome when it stops within
:data:`CANCEL_GRACE`, else at once, the solve stopping after it in the background. The
result: the joint trajectory with efforts (nominal torques), its duration, status and the
certificate's items. msg_docs/plan_motion_action.md.

``tocontrol_msgs`` is imported when the server is made (:func:`plan_motion_type`): a
planner without it still serves ``~/plan`` and the topics.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.controller_client import MissingInterfaceError
from tocontrol_ros.nodes.outcomes import certificate_values
from tocontrol_ros.nodes.planner_config import PlannerConfig, config_from_values
from tocontrol_ros.nodes.pose_goals import PoseTarget, pose_target
from tocontrol_ros.nodes.requests import PlanRequest

__all__ = ["FEEDBACK_PERIOD", "GoalRequest", "PlanMotionServer", "goal_request",
           "plan_motion_type"]

#: Feedback while a goal is planned (s).
FEEDBACK_PERIOD = 0.1
#: How often the goal's execution looks at its request's outcome, its cancel and the node's
#: shutdown (s): a cancel is answered this much after it at the latest, plus the grace.
WAKE_PERIOD = 0.02
#: After a cancel, the result waits this long for the solve to stop (s; it then returns the
#: solve's own outcome); beyond it, the result goes with the best certified motion known at
#: the cancel, and the solve stops in the background at its next check. Some units of a
#: Panda plan check the cancel seconds apart on a loaded machine (the bounded solve's
#: certificate, a first motion: BENCHMARKS.md "Cancel during a Panda plan"), and issue
#: 52's bar for cancel to result is 0.5 s.
CANCEL_GRACE = 0.2
#: The goal's options that override a parameter of the same name when not negative.
OPTIONS = ("k", "time_limit", "limit_margin")
#: Result codes (``PlanMotion.Result``).
SUCCESS, PARTIAL, FAILED = 0, 1, 2


def plan_motion_type():
    """``tocontrol_msgs.action.PlanMotion``, imported now.

    Raises
    ------
    MissingInterfaceError
        ``tocontrol_msgs`` is not installed (the message says how to get it).
    """
    try:
        from tocontrol_msgs.action import PlanMotion
    except ImportError as exc:
        raise MissingInterfaceError(
            f"~/plan_motion needs the tocontrol_msgs interfaces ({exc}): build "
            "interfaces/tocontrol_msgs (scripts/dev setup on the pip route; colcon builds it "
            "in a workspace)") from exc
    return PlanMotion


@dataclass(frozen=True)
class GoalRequest:
    """A ``PlanMotion`` goal in the planner's terms.

    Attributes
    ----------
    start : tuple
        ``("state", q, qd)`` (rad, rad/s) or ``("point", p)`` (the ``default_start``).
    target : ndarray, shape (m,)
        The target's end-effector point (m).
    target_q : ndarray, shape (n,) or None
        A joint-space target (rad, m).
    target_pose : PoseTarget or None
        A pose target (in the base frame).
    config : PlannerConfig
        The parameters with the goal's options.
    execute : bool
    """

    start: tuple
    target: np.ndarray
    target_q: np.ndarray | None
    config: PlannerConfig
    execute: bool
    target_pose: PoseTarget | None = None


def _config(goal, values: dict, task_dim: int) -> PlannerConfig:
    values = dict(values)
    for name in OPTIONS:
        value = float(getattr(goal, name))
        if not np.isfinite(value):
            raise conv.ConversionError(f"`{name}` must be finite (negative: the parameter), "
                                       f"got {value!r}")
        if value >= 0.0:
            values[name] = value
    try:
        return config_from_values(values, task_dim=task_dim)
    except TocontrolError as exc:
        raise conv.ConversionError(f"goal options: {exc}") from exc


def goal_request(goal, model, frame: conv.TaskFrame, values: dict,
                 current: Callable[[PlannerConfig], tuple]) -> GoalRequest:
    """Convert a ``PlanMotion.Goal``; raises ``TocontrolError`` naming the field.

    Parameters
    ----------
    goal : tocontrol_msgs.action.PlanMotion.Goal
    model : RobotModel
    frame : TaskFrame
        The planner's frame (points and poses must be stamped with it).
    values : dict
        The planner's parameter values now.
    current : callable (config) -> tuple
        The arm's current start (``MeasuredArm.start``), for ``START_CURRENT``.
    """
    config = _config(goal, values, model.m)
    names = model.joint_names
    if goal.start_type == goal.START_CURRENT:
        start = current(config)
    elif goal.start_type == goal.START_JOINTS:
        q, qd = conv.joint_state_from_msg(goal.start_state, names, "start_state")
        start = ("state", q, qd)
    else:
        raise conv.ConversionError(f"`start_type` must be START_CURRENT (0) or START_JOINTS "
                                   f"(1), got {goal.start_type}")
    target_q = target_pose = None
    if goal.target_type == goal.TARGET_POINT:
        target = conv.point_from_msg(goal.target_point.point,
                                     goal.target_point.header.frame_id, frame,
                                     "target_point.point")
    elif goal.target_type == goal.TARGET_JOINTS:
        target_q, qd = conv.joint_state_from_msg(goal.target_joints, names, "target_joints")
        if np.any(qd != 0.0):
            raise conv.ConversionError("`target_joints.velocity` must be empty or zero (a "
                                       f"target is at rest), got {qd.tolist()}")
        target = model.point(target_q)
    elif goal.target_type == goal.TARGET_POSE:
        pose = goal.target_pose.pose
        target_pose = pose_target(
            (pose.position.x, pose.position.y, pose.position.z),
            (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w),
            goal.target_pose.header.frame_id, model, frame.frame_id, start, "target_pose")
        target = target_pose.position[list(model.task_axes)]
    else:
        raise conv.ConversionError(f"`target_type` must be TARGET_POINT (0), TARGET_POSE (1) "
                                   f"or TARGET_JOINTS (2), got {goal.target_type}")
    return GoalRequest(start, target, target_q, config, bool(goal.execute), target_pose)


class _Progress:
    """What the status events of one request said so far (from the outputs' listener)."""

    def __init__(self) -> None:
        self.stage = "accepted"
        self.best = 0.0
        self.message = ""
        #: A pose goal's achieved errors (the final status's values), for the result.
        self.pose_errors: dict = {}
        self._lock = threading.Lock()

    def __call__(self, event: str, message: str, values: dict) -> None:
        with self._lock:
            if event == "first" and values.get("published") == "first" and \
                    values.get("certified"):
                self.best = float(values["T"])
            if event == "candidates":  # a pose goal's best certified first motion
                self.best = float(values["best_T"])
            self.stage = event
            self.message = message
            self.pose_errors = {f"pose_{name}": values[name] for name in
                                ("position_error", "orientation_error") if name in values}

    def snapshot(self) -> tuple[str, float, str]:
        with self._lock:
            return self.stage, self.best, self.message


class PlanMotionServer:
    """Serves ``~/plan_motion`` on ``node`` through its planning service.

    Parameters
    ----------
    node : PlannerNode
        Its ``service``, ``model``, ``frame``, ``config`` and parameter values.
    outputs : PlannerOutputs
        Its ``listeners`` tell the progress of each request.
    current : callable (config) -> tuple
        The arm's current start.
    values : callable () -> dict
        The planner's parameter values now.

    Raises
    ------
    MissingInterfaceError
        ``tocontrol_msgs`` is not installed.
    """

    def __init__(self, node, outputs, current: Callable[[PlannerConfig], tuple],
                 values: Callable[[], dict]) -> None:
        self._type = plan_motion_type()
        self._node = node
        self._outputs = outputs
        self._current = current
        self._values = values
        self._requests: dict[bytes, PlanRequest] = {}
        self._lock = threading.Lock()
        self._server = ActionServer(
            node, self._type, "~/plan_motion", execute_callback=self._execute,
            goal_callback=lambda goal: GoalResponse.ACCEPT,
            cancel_callback=self._on_cancel, callback_group=ReentrantCallbackGroup())

    def _on_cancel(self, handle) -> CancelResponse:
        with self._lock:
            req = self._requests.get(bytes(handle.goal_id.uuid))
        if req is not None:  # the solve stops at its next check
            req.cancel("cancelled", "cancelled by the action client")
        return CancelResponse.ACCEPT

    def _execute(self, handle):
        received = time.monotonic()
        service = self._node.service
        rid = service.next_id()
        result_type = self._type.Result
        try:
            goal = goal_request(handle.request, service.model, self._node.frame,
                                self._values(),
                                lambda config: self._current(config, time.time_ns()))
        except TocontrolError as exc:
            service.reject(rid, "action", str(exc))
            handle.abort()
            return result_type(code=FAILED, status="REJECTED", message=str(exc))
        progress = _Progress()
        key = bytes(handle.goal_id.uuid)
        req = PlanRequest(rid, "action", goal.start, goal.target, goal.config,
                          received=received, target_q=goal.target_q, execute=goal.execute,
                          target_pose=goal.target_pose)
        self._outputs.listeners[rid] = progress
        with self._lock:
            self._requests[key] = req
        try:
            if handle.is_cancel_requested:
                req.cancel("cancelled", "cancelled by the action client")
            service.submit(req)
            self._wait(handle, req, progress, received)
        finally:
            with self._lock:
                self._requests.pop(key, None)
            self._outputs.listeners.pop(rid, None)
        return self._finish(handle, req, progress)

    def _wait(self, handle, req: PlanRequest, progress: _Progress, received: float) -> None:
        """Feedback until ``req`` has its outcome, or :data:`CANCEL_GRACE` after a cancel."""
        feedback = self._type.Feedback()
        timeout = req.config.service_timeout
        next_feedback = received + FEEDBACK_PERIOD
        cancelled_at = None
        while not req.done.wait(WAKE_PERIOD):
            if self._node.service.stopping.is_set():
                return
            now = time.monotonic()
            if req.cancelled.is_set():
                cancelled_at = now if cancelled_at is None else cancelled_at
                if now - cancelled_at >= CANCEL_GRACE:
                    return  # the result does not wait for the solve to stop
            elapsed = now - received
            if elapsed > timeout:
                req.cancel("timed out", f"no outcome within service_timeout = {timeout:g} s")
            if now < next_feedback:
                continue
            next_feedback = now + FEEDBACK_PERIOD
            feedback.stage, feedback.best_duration, _ = progress.snapshot()
            if feedback.stage == "accepted":
                feedback.stage = "planning"
            feedback.elapsed = elapsed
            handle.publish_feedback(feedback)

    def _finish(self, handle, req: PlanRequest, progress: _Progress):
        stage, _, message = progress.snapshot()
        if not req.done.is_set() and req.cancelled.is_set():
            event, reason = req.cancel_reason
            stage, message = event, (f"request {req.id} {event}: {reason}; the solve stops "
                                     "at its next check, after this result")
        elif not req.done.is_set():
            stage, message = "cancelled", "node shutting down"
        out = self._type.Result(code=FAILED, status=stage.upper().replace(" ", "_"))
        motion = None
        if stage == "solved":
            motion = req.result  # None: nothing to plan (TRIVIAL), T = 0
            out.code, out.status = SUCCESS, "TRIVIAL"
        elif req.first is not None and req.cancelled.is_set():
            motion = req.first
            message += (f"; returned: the first motion (certified, T = {motion.T:.6g} s), the "
                        "best known when the solve stopped, not shown to be the optimum")
        elif req.cancelled.is_set():
            message += "; no certified motion was known when the solve stopped"
        out.message = message
        if motion is not None:
            out.code = SUCCESS if stage == "solved" and motion.status.name == "SUCCESS" \
                else PARTIAL
            out.status = motion.status.name
            sample = motion.trajectory.sample(req.config.sample_period)
            out.trajectory = conv.trajectory_msg(sample, self._node.model.joint_names,
                                                 self._node.frame.frame_id,
                                                 conv.time_from_ns(0))
            out.duration = float(motion.T)
            values = certificate_values(motion.certificate)
            out.certified = bool(values.pop("certified"))
            out.certificate = conv.status_values({**values, **progress.pose_errors})
        if handle.is_cancel_requested and req.cancelled.is_set():
            handle.canceled()
        elif out.code == FAILED:
            handle.abort()
        else:
            handle.succeed()
        return out

    def destroy(self) -> None:
        """Destroy the action server."""
        self._server.destroy()

