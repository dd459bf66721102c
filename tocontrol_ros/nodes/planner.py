"""The planner node: time-optimal plans on request, over standard ROS 2 interfaces only.

Run as ``ros2 run tocontrol_ros planner`` (either install route), ``tocontrol-planner``
(pip) or ``python -m tocontrol_ros.planner``; parameters from ``config/planner.yaml`` with
``--ros-args --params-file``. Interfaces (one page each in ``msg_docs/``):

- service ``~/plan`` (``nav_msgs/srv/GetPlan``): start and goal end-effector points; the
  answer is the end-effector path stamped with the planned times, empty on failure;
- topic ``~/goal`` (``geometry_msgs/msg/PointStamped``): plan from the robot's current state
  (the latest ``sensor_msgs/msg/JointState`` on ``joint_states``);
- published: ``~/trajectory`` (``trajectory_msgs/msg/JointTrajectory``, transient local;
  with ``publish: first_then_optimum`` first a certified motion at once, then the optimum),
  ``~/status`` (``diagnostic_msgs/msg/DiagnosticStatus``, one per request event),
  ``~/ee_path`` (``nav_msgs/msg/Path``), ``~/markers`` (``visualization_msgs/msg/MarkerArray``).

Concurrency: callbacks only convert and queue. One worker thread solves; it is fed by a slot
that holds the newest request (newest wins: a request that arrives while another is pending
or being solved supersedes it, and a running solve is stopped through the solver's
``should_stop``; goals with ``replan`` queue instead, :mod:`.replan_serving`). Service callbacks
wait for their outcome in a reentrant group; everything else stays served.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.problem import MIN_MOVE
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import qos
from tocontrol_ros.nodes.controller_client import ControllerClient
from tocontrol_ros.nodes.node_main import run_node
from tocontrol_ros.nodes.params import declare_all, robot_from_topic
from tocontrol_ros.nodes.planner_config import (
    FIRST_THEN_OPTIMUM,
    PARAMETERS,
    ConfigError,
    PlannerConfig,
    config_from_values,
    planner_limits,
    planner_model,
    solver_options,
    warm_up_problems,
)
from tocontrol_ros.nodes.replan_serving import ReplanServing
from tocontrol_ros.nodes.replanning import Replanner
from tocontrol_ros.nodes.latest_message import LatestMessage
from tocontrol_ros.nodes.requests import LatestSlot, PlanRequest

__all__ = ["PlannerNode", "main", "QOS_LATCHED", "QOS_STATUS", "QOS_GOAL", "QOS_JOINT_STATES"]

#: Threads of the executor: service calls each hold one while they wait for their outcome.
EXECUTOR_THREADS = 8
#: A request that starts from the robot's current state waits up to this long (s) for a joint
#: state that arrived after it (a goal: received after the goal; a service request: processed
#: after the request), so that a state still queued when the request came is not used while
#: the arm moves. Else the newest one within ``joint_state_timeout`` is used after the wait.
FRESH_STATE_WAIT = 0.1
#: How often a waiting service callback looks at the shutdown flag (s).
WAIT_POLL = 0.05
#: How long destroy_node waits for the worker (s); a daemon thread beyond that (e.g. while the
#: C compiler of the first-ever solve runs).
JOIN_TIMEOUT = 3.0

#: Outputs for late subscribers (a viewer, a tracker started after the plan): the last one.
QOS_LATCHED = qos.LATCHED
#: One message per request event; deep enough for a burst of requests.
QOS_STATUS = qos.status_profile(100, latched=False)
#: Goals: reliable; newest wins anyway, so a short queue is enough.
QOS_GOAL = qos.RELIABLE
#: Joint states: best effort matches both reliable and best-effort publishers; the newest
#: one is all the planner needs, so the middleware keeps one.
QOS_JOINT_STATES = qos.profile(1, reliable=False)
#: Service requests: a burst of calls must not overflow the request queue before the
#: executor takes them (each call gets exactly one response).
QOS_SERVICE = qos.profile(1000)
#: While optimised libraries are being built in the background (the first use of a model
#: got quick builds), the idle worker looks this often (s) whether they landed, to load them.
OPTIMISED_POLL = 1.0


class PlannerNode(ReplanServing, Node):
    """Serves time-optimal plans (see the module docstring and ``msg_docs/``).

    Parameters
    ----------
    node_name : str
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).

    Raises
    ------
    ConfigError
        A parameter value the planner cannot use.
    ModelError
        The robot description cannot be turned into a model (message from the core).
    """

    def __init__(self, node_name: str = "planner", **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        config = config_from_values(robot_from_topic(self, declare_all(self, PARAMETERS)))
        self.model = planner_model(config)
        self._limits = planner_limits(config, self.model)
        self._config = config_from_values(self._parameter_values(), task_dim=self.model.m)
        self.frame = conv.task_frame(self.model, config.frame_id or self.model.base_link)
        from tocontrol_ros.core.solver import Planner

        self.planner = Planner(self.model)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._status_lock = threading.Lock()
        self._stopping = threading.Event()
        self._slot = LatestSlot()
        self._joint_states = LatestMessage(self, JointState, "joint_states", QOS_JOINT_STATES)
        self._last_result = None
        self._published_at = 0.0  # time.monotonic() of the last ~/trajectory
        self._replanner = Replanner()
        self.ready = threading.Event()

        self._pub_trajectory = self.create_publisher(JointTrajectory, "~/trajectory", QOS_LATCHED)
        self._pub_path = self.create_publisher(Path, "~/ee_path", QOS_LATCHED)
        self._pub_markers = self.create_publisher(MarkerArray, "~/markers", QOS_LATCHED)
        self._pub_status = self.create_publisher(DiagnosticStatus, "~/status", QOS_STATUS)
        waiting = ReentrantCallbackGroup()
        inputs = MutuallyExclusiveCallbackGroup()
        self.create_service(GetPlan, "~/plan", self._on_plan, qos_profile=QOS_SERVICE,
                            callback_group=waiting)
        self.create_subscription(PointStamped, "~/goal", self._on_goal, QOS_GOAL,
                                 callback_group=inputs)
        self._controller = ControllerClient(self, config.controller_action, self._publish_status)
        self._worker = threading.Thread(target=self._run, name="planner-worker", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"planning for {self.model.name!r} ({self.model.n} joints, task axes "
            f"{''.join('xyz'[a] for a in self.model.task_axes)}) in frame "
            f"{self.frame.frame_id!r}")

    # ------------------------------------------------------------ parameters
    def _parameter_values(self) -> dict:
        return {spec.name: self.get_parameter(spec.name).value for spec in PARAMETERS}

    def _on_set_parameters(self, params) -> SetParametersResult:
        values = self._parameter_values()
        # Only the planner's own: rclpy's (use_sim_time) are rclpy's to check.
        values.update({p.name: p.value for p in params if p.name in values})
        try:
            config = config_from_values(values, task_dim=self.model.m)
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        with self._lock:
            self._config = config
        return SetParametersResult(successful=True)

    @property
    def last_result(self):
        """The last successful :class:`~tocontrol_ros.core.solver.PlanResult` (or None)."""
        return self._last_result

    @property
    def config(self) -> PlannerConfig:
        """The parameters as they are now (each request keeps the ones at its acceptance)."""
        with self._lock:
            return self._config

    # -------------------------------------------------------------- callbacks
    def _current_start(self, config: PlannerConfig, since_ns: int, fresh: bool = True
                       ) -> tuple:
        """The robot's current state if a recent joint state is there, else default_start.

        Parameters
        ----------
        config : PlannerConfig
        since_ns : int
            When the request came (``time.time_ns()``, or a goal's DDS receive time): with a
            recent joint state, wait up to :data:`FRESH_STATE_WAIT` for one received after
            this, so that a state still queued when the request came is not used.
        """
        latest = self._joint_states.newest(since_ns, config.joint_state_timeout,
                                           FRESH_STATE_WAIT if fresh else 0.0)
        if latest is not None:
            q, qd = conv.joint_state_from_msg(latest, self.model.joint_names)
            return ("state", q, qd)
        if not config.default_start:
            raise conv.ConversionError(
                f"no recent joint state on joint_states (within "
                f"joint_state_timeout = {config.joint_state_timeout:g} s) and no "
                f"`default_start` for this arm: publish its joint states, set default_start "
                f"({self.model.m} values) or give the start in the request")
        return ("point", np.array(config.default_start))

    def _on_plan(self, request: GetPlan.Request, response: GetPlan.Response):
        since = time.time_ns()
        rid = next(self._ids)
        config = self.config
        try:
            if request.start.header.frame_id == "":
                start = self._current_start(config, since)
            else:
                start = ("point", conv.point_from_msg(
                    request.start.pose.position, request.start.header.frame_id, self.frame,
                    "start.pose.position"))
            target = conv.point_from_msg(request.goal.pose.position,
                                         request.goal.header.frame_id, self.frame,
                                         "goal.pose.position")
        except conv.ConversionError as exc:
            self._reject(rid, "service", str(exc))
            response.plan = conv.empty_path(self.frame.frame_id, self._now())
            return response
        req = PlanRequest(rid, "service", start, target, config)
        self._submit(req)
        deadline = time.monotonic() + config.service_timeout
        while not req.done.wait(WAIT_POLL):
            if self._stopping.is_set():
                break
            if time.monotonic() > deadline:
                req.cancel("timed out", f"no outcome within service_timeout = "
                           f"{config.service_timeout:g} s")
                break
        path = req.path if req.done.is_set() else None
        response.plan = path if path is not None else conv.empty_path(self.frame.frame_id,
                                                                      self._now())
        return response

    def _submit(self, req: PlanRequest) -> None:
        self._status(req, "OK", "accepted", f"request {req.id} accepted")
        try:
            replaced, running = self._slot.put(req, req.config.goal_queue)
        except RuntimeError:
            self._finish(req, "WARN", "cancelled", "node shutting down")
            return
        for old in replaced:
            self._finish(old, "WARN", "superseded",
                         f"superseded by request {req.id} before its solve started")
        # Replanning: a goal's solve in progress is not thrown away by the next goal (its
        # result still serves: the next goal is planned from it).
        if running is not None and not (req.queue and running.queue):
            running.cancel("superseded", f"superseded by request {req.id} during its solve")

    # ------------------------------------------------------------ status out
    def _now(self):
        return self.get_clock().now().to_msg()

    def _values(self, req: PlanRequest, event: str, extra: dict | None = None) -> dict:
        start = req.start[1] if req.start[0] == "point" else None
        values = {"request_id": req.id, "event": event, "source": req.source,
                  "start": start, "start_q": None if start is not None else req.start[1],
                  "start_qd": None if start is not None else req.start[2],
                  "target": req.target, "frame_id": self.frame.frame_id,
                  "k": req.config.k}
        values.update(extra or {})
        return values

    def _publish_status(self, level: str, message: str, values: dict,
                        routine: bool = False) -> None:
        """``~/status`` and the log (a ``routine`` event, e.g. ``accepted``, at DEBUG)."""
        # rclpy's logger reads its caller's source file, about 1 ms a message: a goal waited.
        msg = conv.status_msg(level, self.get_fully_qualified_name(), message,
                              self.model.name, values)
        with self._status_lock:
            try:
                self._pub_status.publish(msg)
            except Exception:  # noqa: BLE001  (publisher gone during shutdown)
                return
        if level == "ERROR":
            self.get_logger().error(message)
        elif level == "WARN":
            self.get_logger().warning(message)
        elif routine:
            self.get_logger().debug(message)
        else:
            self.get_logger().info(message)

    def _status(self, req: PlanRequest, level: str, event: str, message: str,
                extra: dict | None = None) -> None:
        self._publish_status(level, message, self._values(req, event, extra),
                             routine=event == "accepted")

    def _reject(self, rid: int, source: str, reason: str) -> None:
        self._publish_status("ERROR", f"request {rid} rejected: {reason}",
                             {"request_id": rid, "event": "failed", "source": source,
                              "frame_id": self.frame.frame_id})

    def _finish(self, req: PlanRequest, level: str, event: str, message: str,
                extra: dict | None = None, path: Path | None = None) -> None:
        latency = {"latency": time.monotonic() - req.received}
        if path is not None:  # the replan latency: to the trajectory's publication
            latency["publish_latency"] = self._published_at - req.received
        self._status(req, level, event, f"request {req.id} {event}: {message}",
                     {**latency, **(extra or {})})
        req.path = path
        req.done.set()

    # ----------------------------------------------------------------- worker
    def _run(self) -> None:
        self._warm_up()
        while not self._stopping.is_set():
            waiting = compiled.pending_builds() > 0 or self.planner.stale()
            req, stale = self._slot.take(OPTIMISED_POLL if waiting else None,
                                         self.config.goal_max_backlog,
                                         self._replanner.replan_time())
            for old, by in stale:  # solves fell behind the stream: newest wins
                by.behind = True
                self._finish(old, "WARN", "superseded", f"superseded by request {by.id}: "
                             "the goals waiting exceed goal_max_backlog")
            if req is None:
                if self._slot.closed:
                    break
                self._load_optimised()
                continue
            try:
                self._serve(req)
            except Exception as exc:  # noqa: BLE001  (a bug must not stop the planner)
                self.get_logger().error(f"request {req.id}: internal error: {exc!r}")
                if not req.done.is_set():
                    self._finish(req, "ERROR", "failed", f"internal error: {exc!r}")
            finally:
                self._slot.finished(req)
            self._solve_ahead()

    def _compile_progress(self, event: str, name: str, info: dict) -> None:
        """Compile listener of the warm-up: one ``~/status`` per build started and ended."""
        if event not in ("compiling", "compiled"):
            return
        quick = " (quick build; optimised in the background)" \
            if info.get("flags", "").startswith("-O0") else ""
        if event == "compiling":
            message = (f"warming up: compiling {name} ({info['bytes'] / 1e3:.0f} kB of C)"
                       f"{quick}")
        else:
            message = (f"warming up: compiled {name} in {info['seconds']:.1f} s"
                       + ("" if info.get("ok") else " (failed: the virtual machine is used)"))
        self._publish_status("OK", message, {"event": "warming up", "compile": event,
                                             "library": name, "c_bytes": info["bytes"],
                                             "seconds": info.get("seconds")})

    def _load_optimised(self) -> None:
        """Between requests: a new planner on the optimised libraries once they all landed."""
        from tocontrol_ros.core.solver import Planner
        if not self.planner.stale() or self._stopping.is_set():
            return
        t0 = time.monotonic()
        planner = Planner(self.model)
        options = solver_options(self.config)
        try:
            for problem in warm_up_problems(self.config, self.model, self._limits):
                planner.prepare(problem, options)
        except TocontrolError:
            return
        self.planner = planner
        self._publish_status("OK", f"optimised code loaded in {time.monotonic() - t0:.1f} s",
                             {"event": "optimised"})

    def _warm_up(self) -> None:
        """Build what requests need, so that no request pays for a build.

        First the direct transcription and the compiled functions of every problem kind the
        node serves (point to point for ``~/plan``, joint state to point for ``~/goal`` and
        ``~/plan`` without a start frame), always, with one ``~/status`` per compiled
        library; then one throw-away solve of each kind (builds the rest, e.g. the
        certificate's functions), stopped early when a request arrives or the node shuts
        down.
        """
        self._publish_status("OK", "warming up (the first start on a machine compiles the "
                             "model's C code)", {"event": "warming up"})
        t0 = time.monotonic()
        compiled.add_listener(self._compile_progress)
        try:
            note = self._warm_up_solves()
        finally:
            compiled.remove_listener(self._compile_progress)
        if self._stopping.is_set():
            return
        self.ready.set()
        self._publish_status("OK", f"ready after {time.monotonic() - t0:.1f} s{note}",
                             {"event": "ready", "warmup_time": time.monotonic() - t0})

    def _warm_up_solves(self) -> str:
        """The warm-up's builds and throw-away solves; returns a note for the status."""
        config = self.config
        note = ""
        try:
            options = solver_options(config)  # verify as configured: compiles the certificate
            problems = warm_up_problems(config, self.model, self._limits)
            for problem in problems:
                if self._stopping.is_set():
                    return note
                self.planner.prepare(problem, options)
            for problem in problems:
                self.planner.first(problem, options)  # loads TOPP-RA, builds its integrator
                result = self.planner.plan(problem, options, should_stop=lambda:
                                           self._stopping.is_set() or self._slot.has_pending())
                if not result.success and not note:
                    note = f" (warm-up solve: {result.message})"
        except TocontrolError as exc:
            note = f" (warm-up skipped: {exc})"
        return note

    def _should_stop(self, req: PlanRequest):
        return lambda: req.cancelled.is_set() or self._stopping.is_set()

    def _serve(self, req: PlanRequest) -> None:
        config = req.config
        if req.cancelled.is_set():
            self._finish(req, "WARN", *req.cancel_reason)
            return
        if req.queue and self._serve_replan(req):
            return
        try:
            problem = self._problem(config, req.start, req.target)
        except TocontrolError as exc:
            self._finish(req, "ERROR", "failed", str(exc))
            return
        start_point = problem.start_point
        options = solver_options(config)
        first = self._first(req, problem, options) \
            if config.publish == FIRST_THEN_OPTIMUM else None
        last = self._last_result
        warm = last if config.warm_start and last is not None and \
            last.can_warm_start(problem) else None
        result = self.planner.plan(problem, options, warm_start=warm,
                                   should_stop=self._should_stop(req))
        extra = {"start": start_point, **conv.result_values(result),
                 "warm_start": warm is not None,
                 "warm_returned": any(r.index == -1 and r.status == "returned"
                                      for r in result.starts),
                 "published": "first" if first else "none"}
        if req.cancelled.is_set() or self._stopping.is_set():
            event, reason = req.cancel_reason if req.cancelled.is_set() else \
                ("cancelled", "node shutting down")
            self._finish(req, "WARN", event, reason, extra)
            return
        # A success is published; so is a TIME_LIMIT that carries the best checked motion
        # found before the deadline (its warning, WARN, says it may not be the optimum).
        # Any other result is not, even with a trajectory (one that failed its certificate).
        time_limited = result.status.name == "TIME_LIMIT" and result.trajectory is not None
        publishable = result.success or time_limited
        if first and not (publishable and result.T < first[0].T):
            why = f"T = {result.T:.6g} s, not faster" if publishable else result.message
            self._finish(req, "WARN", "solved", f"the first motion stands (T = "
                         f"{first[0].T:.6g} s): the optimum was not published ({why})",
                         {**extra, **conv.result_values(first[0]), "optimum_T": result.T,
                          "optimum_status": result.status.name,
                          "samples": len(first[1].poses)}, path=first[1])
            self._markers(first[0], first[1], config, start_point, req.target)
            return
        if not publishable:
            self._finish(req, "ERROR", "failed", result.message, extra)
            return
        if result.status.name == "TRIVIAL":
            # The core's rule (Problem.is_trivial): the start is at rest on the target.
            gap = float(np.linalg.norm(start_point - req.target))
            path = conv.point_path(self.frame, start_point, self.frame.frame_id, self._now())
            self._finish(req, "OK", "solved",
                         f"nothing to plan: the target {req.target.tolist()} is "
                         f"{gap:.3g} m from the start at rest (within MIN_MOVE = "
                         f"{MIN_MOVE:g} m); T = 0, no trajectory published",
                         {**extra, "samples": 1}, path=path)
            return
        self._last_result = result
        path = self._publish(result, config, req.id, self._goal_stamp(req))
        if path is None:  # publishers gone during shutdown
            req.done.set()
            return
        level, message = conv.result_message(result)
        self._finish(req, level, "solved", message, {**extra, "published": "optimum",
                                                     "samples": len(path.poses)}, path=path)
        self._markers(result, path, config, start_point, req.target)

    def _first(self, req: PlanRequest, problem, options) -> tuple | None:
        """``publish: first_then_optimum``: the first motion, published at once.

        Returns ``(result, path)`` when it was published (with a ``first`` status), else
        None: nothing to move, cancelled meanwhile, or it failed (a ``first`` status says
        why; the optimum follows either way).
        """
        first = self.planner.first(problem, options)
        if first.status.name == "TRIVIAL" or req.cancelled.is_set() or self._stopping.is_set():
            return None
        values = {"start": problem.start_point, **conv.result_values(first),
                  "latency": time.monotonic() - req.received}
        if not first.success:
            self._status(req, "WARN", "first", f"request {req.id}: no first motion "
                         f"({first.message}); the optimum follows",
                         {**values, "published": "none"})
            return None
        path = self._publish(first, req.config, req.id)
        if path is None:
            return None
        level, message = conv.result_message(first)
        self._status(req, level, "first", f"request {req.id} first motion published: "
                     f"{message}; the optimum follows",
                     {**values, "published": "first", "samples": len(path.poses),
                      "latency": self._published_at - req.received,
                      "publish_latency": self._published_at - req.received})
        return first, path

    def _publish(self, result, config: PlannerConfig, rid: int = 0,
                 stamp_ns: int | None = None) -> Path | None:
        """``~/trajectory``, ``~/ee_path``, the controller's goal; the path, None in shutdown.

        ``stamp_ns``: when the motion takes over (a replan's hand-off, ns); default now.
        """
        sample = result.trajectory.sample(config.sample_period)
        if stamp_ns is None:
            stamp_ns = self.get_clock().now().nanoseconds
        stamp = conv.time_from_ns(int(stamp_ns))
        msg = conv.trajectory_msg(sample, self.model.joint_names, self.frame.frame_id, stamp)
        try:  # the trajectory first: the path and the rest do not hold it up
            self._pub_trajectory.publish(msg)
            self._published_at = time.monotonic()
        except Exception:  # noqa: BLE001  (publishers gone during shutdown)
            return None
        self._replanner.published(result, stamp_ns, sample)
        path = conv.path_msg(self.model, sample, self.frame.frame_id, stamp)
        try:
            self._pub_path.publish(path)
        except Exception:  # noqa: BLE001  (publisher gone during shutdown)
            return None
        self._controller.send(rid, msg, config)
        return path

    def _markers(self, result, path: Path, config: PlannerConfig, start_point, target) -> None:
        """The viewer's markers, after the answer: the caller does not wait for them."""
        snaps = result.trajectory.evaluate(np.linspace(0.0, result.T, config.marker_snapshots)).q
        ee = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                       for p in path.poses])
        markers = conv.markers_msg(self.model, snaps, ee, conv.embed_point(self.frame,
                                   start_point), conv.embed_point(self.frame, target),
                                   self.frame.frame_id, path.header.stamp)
        try:
            self._pub_markers.publish(markers)
        except Exception:  # noqa: BLE001  (publisher gone during shutdown)
            return

    # --------------------------------------------------------------- shutdown
    def stop_worker(self, timeout: float = JOIN_TIMEOUT) -> None:
        """Stop the worker: cancel the running solve, answer the pending request, join."""
        self._stopping.set()
        for leftover in self._slot.close():
            self._finish(leftover, "WARN", "cancelled", "node shutting down")
        if self._worker.is_alive() and threading.current_thread() is not self._worker:
            self._worker.join(timeout)

    def destroy_node(self) -> None:
        """Stop the worker, then destroy the node."""
        self.stop_worker()
        self._controller.destroy()
        self._joint_states.destroy()
        super().destroy_node()


def build_parser() -> argparse.ArgumentParser:
    """The command line: no options of its own besides ``--help``; ROS arguments pass through."""
    return argparse.ArgumentParser(
        prog="planner",
        description="Serve time-optimal plans: service ~/plan (nav_msgs/srv/GetPlan), topic "
        "~/goal (geometry_msgs/msg/PointStamped); publishes ~/trajectory, ~/status, "
        "~/ee_path, ~/markers. Interfaces and parameters: msg_docs/ in the source tree.",
        epilog="ROS arguments: --ros-args --params-file config/planner.yaml -p k:=8.0 "
        "-r __ns:=/arm",
    )


def main(args=None) -> int:
    """``ros2 run tocontrol_ros planner``: the node on a multi-threaded executor.

    ``args``: the command line (list of str), as for
    :func:`~tocontrol_ros.nodes.node_main.run_node`, which gives the exit status.
    """
    return run_node("planner", args, PlannerNode,
                    lambda: MultiThreadedExecutor(num_threads=EXECUTOR_THREADS), build_parser())


if __name__ == "__main__":
    sys.exit(main())
