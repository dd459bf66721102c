"""The planner node: time-optimal plans on request, over standard ROS 2 interfaces only.

Run as ``ros2 run tocontrol_ros planner`` (either install route), ``tocontrol-planner``
(pip) or ``python -m tocontrol_ros.planner``; parameters from ``config/planner.yaml`` with
``--ros-args --params-file``. Interfaces (one page each in ``msg_docs/``):

- service ``~/plan`` (``nav_msgs/srv/GetPlan``): start and goal end-effector points; the
  answer is the end-effector path stamped with the planned times, empty on failure;
- topic ``~/goal`` (``geometry_msgs/msg/PointStamped``): plan from the robot's current state
  (the latest ``sensor_msgs/msg/JointState`` on ``joint_states``);
- topic ``~/goal_joints`` (``sensor_msgs/msg/JointState``): a joint-space target, from the
  current state;
- topic ``~/goal_pose`` (``geometry_msgs/msg/PoseStamped``): a pose of the tip (position
  and orientation), from the current state (:mod:`tocontrol_ros.nodes.pose_goals`);
- action ``~/plan_motion`` (``tocontrol_msgs/action/PlanMotion``, when that package is
  installed): start, target (point, pose or joints) and options; feedback, cancel, the trajectory
  as the result (:mod:`tocontrol_ros.nodes.plan_action`);
- published: ``~/trajectory`` (``trajectory_msgs/msg/JointTrajectory``, transient local;
  with ``publish: first_then_optimum`` first a certified motion at once, then the optimum),
  ``~/status`` (``diagnostic_msgs/msg/DiagnosticStatus``, one per request event),
  ``~/ee_path`` (``nav_msgs/msg/Path``), ``~/markers`` (``visualization_msgs/msg/MarkerArray``).

The node only wires: its callbacks convert the message, hand the request to the ROS-free
:class:`~tocontrol_ros.nodes.planning_service.PlanningService` (the policy: the queue, the
replans, the first motion, what is published) and build the reply; the service's outputs are
the node's publishers (:mod:`tocontrol_ros.nodes.planner_outputs`).

Concurrency: callbacks only convert and queue. The service's worker thread solves (but with
``replan_on_callback`` a replan goal's quick motion, served on the goal's callback when the
worker idles: no wake-up of the worker, issue 47); it is fed by a slot that holds the newest
request (newest wins: a request that arrives while another is pending or being solved
supersedes it, and a running solve is stopped through the solver's ``should_stop``; goals with
``replan`` queue instead, :mod:`tocontrol_ros.nodes.replan_policy`). Service callbacks wait for
their outcome in a reentrant group; everything else stays served.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped, PoseStamped
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
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import qos
from tocontrol_ros.nodes.controller_client import ControllerClient, MissingInterfaceError
from tocontrol_ros.nodes.diagnostics import Diagnostics
from tocontrol_ros.nodes.latest_message import LatestMessage
from tocontrol_ros.nodes.node_main import run_node
from tocontrol_ros.nodes.params import declare_all, robot_from_topic
from tocontrol_ros.nodes.plan_action import PlanMotionServer
from tocontrol_ros.nodes.planner_config import (
    PARAMETERS,
    ConfigError,
    PlannerConfig,
    config_from_values,
    planner_collision,
    planner_limits,
    planner_model,
)
from tocontrol_ros.nodes.planner_outputs import FRESH_STATE_WAIT, MeasuredArm, PlannerOutputs
from tocontrol_ros.nodes.planning_service import JOIN_TIMEOUT, Clock, PlanningService
from tocontrol_ros.nodes.pose_goals import pose_target
from tocontrol_ros.nodes.requests import PlanRequest
from tocontrol_ros.nodes.scene_markers import scene_from_markers

__all__ = ["PlannerNode", "main", "QOS_LATCHED", "QOS_STATUS", "QOS_GOAL", "QOS_JOINT_STATES",
           "FRESH_STATE_WAIT"]

#: Threads of the executor: service calls each hold one while they wait for their outcome.
EXECUTOR_THREADS = 8

#: Outputs for late subscribers (a viewer, a tracker started after the plan): the last one.
QOS_LATCHED = qos.LATCHED
#: One message per request event; deep enough for a burst of requests.
QOS_STATUS = qos.status_profile(100, latched=False)
#: Goals: reliable, and deep enough for ten seconds of a 10 Hz stream: with ``replan`` every
#: goal is queued and answered (``goal_queue``), and an executor starved by a busy machine
#: must not lose goals in the middleware before their callback takes them (a CI run under
#: load lost one of 50 with a queue of 10).
QOS_GOAL = qos.profile(100)
#: Joint states: best effort matches both reliable and best-effort publishers; the newest
#: one is all the planner needs, so the middleware keeps one.
QOS_JOINT_STATES = qos.profile(1, reliable=False)
#: Service requests: a burst of calls must not overflow the request queue before the
#: executor takes them (each call gets exactly one response).
QOS_SERVICE = qos.profile(1000)
#: ~/scene: reliable (every change counts), volatile: matches RViz's and a script's publishers.
QOS_SCENE = qos.profile(10)


class PlannerNode(Node):
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
        limits = planner_limits(config, self.model)
        self.frame = conv.task_frame(self.model, config.frame_id or self.model.base_link)

        self._joint_states = LatestMessage(self, JointState, "joint_states", QOS_JOINT_STATES)
        self._arm = MeasuredArm(self._joint_states, self.model, self.get_logger().warning)
        self._pub_trajectory = self.create_publisher(JointTrajectory, "~/trajectory", QOS_LATCHED)
        publishers = {
            "trajectory": self._pub_trajectory,
            "path": self.create_publisher(Path, "~/ee_path", QOS_LATCHED),
            "markers": self.create_publisher(MarkerArray, "~/markers", QOS_LATCHED),
            "status": self.create_publisher(DiagnosticStatus, "~/status", QOS_STATUS)}
        self._outputs = PlannerOutputs(self, self.model, self.frame, publishers)
        try:  # control_msgs only with a controller: a pip install without it still plans
            self._controller = ControllerClient(self, config.controller_action,
                                                self._outputs.status)
        except MissingInterfaceError as exc:
            raise ConfigError(str(exc)) from exc
        self._outputs.controller = self._controller
        self.service = PlanningService(
            self.model, limits, config_from_values(self._parameter_values(),
                                                   task_dim=self.model.m),
            self.frame.frame_id, self._outputs, self._arm,
            Clock(now_ns=lambda: self.get_clock().now().nanoseconds))
        self.service.collision = planner_collision(config, self.model)
        self._controller.on_refused = self.service.controller_refused
        self.add_on_set_parameters_callback(self._on_set_parameters)
        waiting = ReentrantCallbackGroup()
        inputs = MutuallyExclusiveCallbackGroup()
        self.create_service(GetPlan, "~/plan", self._on_plan, qos_profile=QOS_SERVICE,
                            callback_group=waiting)
        self.create_subscription(PointStamped, "~/goal", self._on_goal, QOS_GOAL,
                                 callback_group=inputs)
        self.create_subscription(MarkerArray, "~/scene", self._on_scene, QOS_SCENE,
                                 callback_group=inputs)
        self.create_subscription(JointState, "~/goal_joints", self._on_goal_joints, QOS_GOAL,
                                 callback_group=inputs)
        self.create_subscription(PoseStamped, "~/goal_pose", self._on_goal_pose, QOS_GOAL,
                                 callback_group=inputs)
        # The tracker's refusals of topic trajectories (relative: the launch file's tracker
        # beside this planner; remap it to another executor's status topic).
        self.create_subscription(DiagnosticStatus, "tracker/status", self._on_tracker_status,
                                 QOS_STATUS, callback_group=inputs)
        try:  # tocontrol_msgs only for the action: without it the rest is served
            self._plan_action = PlanMotionServer(self, self._outputs, self._arm.start,
                                                 self._parameter_values)
        except MissingInterfaceError as exc:
            self._plan_action = None
            self.get_logger().warning(f"~/plan_motion is not served: {exc}")
        self.diagnostics = Diagnostics(self, self.model.name, self._diagnostic_state)
        self.service.start()
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
        self.service.config = config
        return SetParametersResult(successful=True)

    @property
    def config(self) -> PlannerConfig:
        """The parameters as they are now (each request keeps the ones at its acceptance)."""
        return self.service.config

    @property
    def last_result(self):
        """The last published :class:`~tocontrol_ros.core.planning.solver.PlanResult` (or None)."""
        return self.service.last_result

    @property
    def planner(self):
        """The service's :class:`~tocontrol_ros.core.planning.solver.Planner`."""
        return self.service.planner

    @property
    def ready(self):
        """A ``threading.Event`` set once the warm-up is done."""
        return self.service.ready

    # -------------------------------------------------------------- callbacks
    def _on_plan(self, request: GetPlan.Request, response: GetPlan.Response):
        since = time.time_ns()
        rid = self.service.next_id()
        config = self.config
        try:
            if request.start.header.frame_id == "":
                start = self._arm.start(config, since)
            else:
                start = ("point", conv.point_from_msg(
                    request.start.pose.position, request.start.header.frame_id, self.frame,
                    "start.pose.position"))
            target = conv.point_from_msg(request.goal.pose.position,
                                         request.goal.header.frame_id, self.frame,
                                         "goal.pose.position")
        except conv.ConversionError as exc:
            self.service.reject(rid, "service", str(exc))
            response.plan = self._empty_path()
            return response
        path = self.service.call(PlanRequest(rid, "service", start, target, config))
        response.plan = path if path is not None else self._empty_path()
        return response

    def _on_goal(self, msg: PointStamped, info) -> None:
        received = time.monotonic()
        since = int(info.get("received_timestamp", 0)) or time.time_ns()
        rid = self.service.next_id()
        try:
            target = conv.point_from_msg(msg.point, msg.header.frame_id, self.frame, "goal.point")
        except conv.ConversionError as exc:
            self.service.reject(rid, "goal", str(exc))
            return
        self.service.goal(rid, target, since, received)

    def _on_goal_joints(self, msg: JointState, info) -> None:
        received = time.monotonic()
        since = int(info.get("received_timestamp", 0)) or time.time_ns()
        rid = self.service.next_id()
        config = self.config
        try:
            q, qd = conv.joint_state_from_msg(msg, self.model.joint_names, "goal_joints")
            if np.any(qd != 0.0):
                raise conv.ConversionError("`goal_joints.velocity` must be empty or zero (a "
                                           f"target is at rest), got {qd.tolist()}")
            start = self._arm.start(config, since)
        except TocontrolError as exc:
            self.service.reject(rid, "goal_joints", str(exc))
            return
        self.service.submit(PlanRequest(rid, "goal_joints", start, self.model.point(q), config,
                                        received=received, target_q=q))

    def _on_goal_pose(self, msg: PoseStamped, info) -> None:
        received = time.monotonic()
        since = int(info.get("received_timestamp", 0)) or time.time_ns()
        rid = self.service.next_id()
        config = self.config
        try:
            start = self._arm.start(config, since)
            p, o = msg.pose.position, msg.pose.orientation
            pose = pose_target((p.x, p.y, p.z), (o.x, o.y, o.z, o.w), msg.header.frame_id,
                               self.model, self.frame.frame_id, start, "goal_pose")
        except TocontrolError as exc:
            self.service.reject(rid, "goal_pose", str(exc))
            return
        self.service.submit(PlanRequest(rid, "goal_pose", start,
                                        pose.position[list(self.model.task_axes)], config,
                                        received=received, target_pose=pose))

    def _on_tracker_status(self, msg: DiagnosticStatus) -> None:
        values = {kv.key: kv.value for kv in msg.values}
        if values.get("event") != "rejected" or "stamp" not in values:
            return
        try:
            stamp = float(values["stamp"])
        except ValueError:
            return
        self.service.tracker_rejected(stamp, msg.message)

    def _diagnostic_state(self):
        """``/diagnostics``: readiness, requests waiting, last plan, builds, controller."""
        service = self.service
        ready = service.ready.is_set()
        last = service.last_result
        values = {"state": "ready" if ready else "warming up",
                  "requests_waiting": len(service.slot.pending()),
                  "compile_builds_pending": compiled.pending_builds(),
                  "last_T": last.T if last is not None else "",
                  "last_status": last.status.name if last is not None else "",
                  "controller_action": self.config.controller_action,
                  "plan_motion": "served" if self._plan_action is not None else "not served",
                  "joint_states": self._arm.describe(self.config)}
        if not ready:
            return "WARN", "warming up (compiling the model's functions)", values
        return "OK", "ready", values

    def _on_scene(self, msg: MarkerArray) -> None:
        """A scene change: the next plan and replans avoid it; a bad one is refused whole."""
        from tocontrol_ros.core.errors import TocontrolError
        from tocontrol_ros.core.geometry.scene import Scene

        current = self.service.collision
        try:
            scene = scene_from_markers(msg, Scene() if current is None else current.scene,
                                       self.frame.frame_id)
            collision = planner_collision(self.config, self.model, scene) if current is None \
                else current.with_scene(scene)
        except TocontrolError as exc:
            self._outputs.status("WARN", f"scene refused: {exc}; the previous scene is kept",
                                 {"event": "scene_refused"})
            return
        self.service.collision = collision
        names = ", ".join(scene.names()) or "none"
        self._outputs.status("OK", f"scene: {len(scene.obstacles)} obstacles ({names}); the "
                             f"next plan avoids them", {"event": "scene",
                                                       "obstacles": names})

    def _empty_path(self) -> Path:
        return conv.empty_path(self.frame.frame_id, self.get_clock().now().to_msg())

    # --------------------------------------------------------------- shutdown
    def stop_worker(self, timeout: float = JOIN_TIMEOUT) -> None:
        """Stop the worker: cancel the running solve, answer the pending request, join."""
        self.service.stop(timeout)

    def destroy_node(self) -> None:
        """Stop the worker, then destroy the node."""
        self.stop_worker()
        if self._plan_action is not None:
            self._plan_action.destroy()
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
