"""The planner node's side of the planning service: its publishers and the arm's state.

:class:`PlannerOutputs` implements :class:`~tocontrol_ros.nodes.planning_service.Outputs`
with the node's publishers (each call converts with :mod:`tocontrol_ros.nodes.conversions`
and publishes); :class:`MeasuredArm` implements
:class:`~tocontrol_ros.nodes.planning_service.Arm` with ``joint_states`` taken on demand
(:class:`~tocontrol_ros.nodes.latest_message.LatestMessage`).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from nav_msgs.msg import Path
from trajectory_msgs.msg import JointTrajectory

from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.latest_message import LatestMessage
from tocontrol_ros.nodes.planner_config import PlannerConfig
from tocontrol_ros.nodes.scene_markers import scene_marker_list
from tocontrol_ros.nodes.trajectory_cdr import trajectory_cdr

__all__ = ["FRESH_STATE_WAIT", "MeasuredArm", "PlannerOutputs", "Sent"]

#: A request that starts from the robot's current state waits up to this long (s) for a joint
#: state that arrived after it (a goal: received after the goal; a service request: processed
#: after the request), so that a state still queued when the request came is not used while
#: the arm moves. Else the newest one within ``joint_state_timeout`` is used after the wait.
FRESH_STATE_WAIT = 0.1


class Sent(NamedTuple):
    """A trajectory published on ``~/trajectory``: its bytes, samples, stamp, names, frame."""

    data: bytes
    sample: Any
    stamp_ns: int
    joint_names: tuple
    frame_id: str

    def message(self) -> JointTrajectory:
        """The ``JointTrajectory`` it was published as, built again from the samples.

        The same contents as :attr:`data` (``test/nodes/test_trajectory_cdr.py``).
        """
        return conv.trajectory_msg(self.sample, self.joint_names, self.frame_id,
                                   conv.time_from_ns(self.stamp_ns))


class PlannerOutputs:
    """The planning service's outputs as the planner node's messages.

    Parameters
    ----------
    node : rclpy.node.Node
        Its name, clock and logger.
    model : RobotModel
    frame : TaskFrame
    publishers : mapping of str to Publisher
        ``trajectory``, ``path``, ``markers``, ``status``.
    controller : ControllerClient, optional
        Sends published plans to ``controller_action`` (when set); also settable later
        (the client reports through :meth:`status`).
    """

    def __init__(self, node, model, frame: conv.TaskFrame, publishers: Mapping[str, Any],
                 controller=None) -> None:
        self._node = node
        self._model = model
        self._frame = frame
        self._pubs = dict(publishers)
        self.controller = controller
        self._status_lock = threading.Lock()
        #: request id -> ``listener(event, message, values)``, told each status event of that
        #: request (the ``~/plan_motion`` action's progress and outcome).
        self.listeners: dict[int, Any] = {}

    def status(self, level: str, message: str, values: Mapping[str, Any],
               routine: bool = False) -> None:
        """``~/status`` and the log (a ``routine`` event, e.g. ``accepted``, at DEBUG)."""
        # rclpy's logger reads its caller's source file, about 1 ms a message: a goal waited.
        listener = self.listeners.get(values.get("request_id"))
        if listener is not None:
            listener(values.get("event", ""), message, values)
        msg = conv.status_msg(level, self._node.get_fully_qualified_name(), message,
                              self._model.name, values)
        with self._status_lock:
            if not self._publish("status", msg):
                return
        logger = self._node.get_logger()
        if level == "ERROR":
            logger.error(message)
        elif level == "WARN":
            logger.warning(message)
        elif routine:
            logger.debug(message)
        else:
            logger.info(message)

    def log_error(self, message: str) -> None:
        """An error in the node's log."""
        self._node.get_logger().error(message)

    def trajectory(self, sample, stamp_ns: int) -> Sent | None:
        """``~/trajectory``, stamped ``stamp_ns``; what was sent, None in shutdown.

        Published as its CDR bytes (:func:`~tocontrol_ros.nodes.trajectory_cdr.trajectory_cdr`,
        the message a subscriber receives, built in numpy: a replan's publication waits for
        no message objects); the ``JointTrajectory`` object is built only for a controller
        (:meth:`follow`).
        """
        names, frame = tuple(self._model.joint_names), self._frame.frame_id
        data = trajectory_cdr(sample, names, frame, stamp_ns)
        sent = Sent(data, sample, int(stamp_ns), names, frame)
        return sent if self._publish("trajectory", data) else None

    def path(self, sample, stamp_ns: int) -> Path | None:
        """``~/ee_path``, stamped ``stamp_ns``; the path, None in shutdown."""
        path = conv.path_msg(self._model, sample, self._frame.frame_id,
                             conv.time_from_ns(stamp_ns))
        return path if self._publish("path", path) else None

    def follow(self, request_id: int, trajectory: Sent, config: PlannerConfig) -> None:
        """The plan to ``controller_action`` (nothing without one): the published message."""
        if self.controller is not None:
            self.controller.send(request_id, trajectory.message(), config)

    def markers(self, result, path: Path, config: PlannerConfig, start_point: np.ndarray,
                target: np.ndarray) -> None:
        """The viewer's markers, after the answer: the caller does not wait for them."""
        snaps = result.trajectory.evaluate(np.linspace(0.0, result.T,
                                                       config.marker_snapshots)).q
        ee = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                       for p in path.poses])
        msg = conv.markers_msg(
            self._model, snaps, ee, conv.embed_point(self._frame, start_point),
            conv.embed_point(self._frame, target), self._frame.frame_id, path.header.stamp)
        collision = getattr(getattr(result, "problem", None), "collision", None)
        if collision is not None:  # the scene this plan avoided
            msg.markers.extend(scene_marker_list(collision.scene, msg.markers[0].header))
        self._publish("markers", msg)

    def rest_path(self, point: np.ndarray) -> Path:
        """The one-pose answer at ``point`` (m), stamped now."""
        return conv.point_path(self._frame, point, self._frame.frame_id,
                               self._node.get_clock().now().to_msg())

    def _publish(self, name: str, msg) -> bool:
        try:
            self._pubs[name].publish(msg)
        except Exception:  # noqa: BLE001  (publisher gone during shutdown)
            return False
        return True


class MeasuredArm:
    """The arm's state from ``joint_states``, in the model's joint order, taken on demand.

    Parameters
    ----------
    joint_states : LatestMessage
        The ``sensor_msgs/JointState`` subscription.
    model : RobotModel
    """

    def __init__(self, joint_states: LatestMessage, model, warn=None) -> None:
        self.joint_states = joint_states
        self._model = model
        #: Called with a message when a goal starts from ``default_start`` although the
        #: topic has a publisher (the node's logger; None: silent).
        self.warn = warn

    def start(self, config: PlannerConfig, since_ns: int, fresh: bool = True) -> tuple:
        """The robot's current state if a recent joint state is there, else default_start.

        Parameters
        ----------
        config : PlannerConfig
        since_ns : int
            When the request came (``time.time_ns()``, or a goal's DDS receive time): with a
            recent joint state, wait up to :data:`FRESH_STATE_WAIT` for one received after
            this, so that a state still queued when the request came is not used.
        fresh : bool
            False: no wait.

        Raises
        ------
        ConversionError
            Neither a recent joint state of this arm's joints nor ``default_start``.
        """
        # A publisher matched but nothing received yet (its first states on their way):
        # wait for one up to joint_state_timeout rather than plan from default_start.
        latest = self.joint_states.newest(since_ns, config.joint_state_timeout,
                                          FRESH_STATE_WAIT if fresh else 0.0,
                                          first_wait=config.joint_state_timeout)
        if latest is not None:
            q, qd = conv.joint_state_from_msg(latest, self._model.joint_names)
            return ("state", q, qd)
        publishers = self.joint_states.publisher_count()
        if publishers and config.default_start and self.warn is not None:
            age = self.joint_states.age()
            self.warn(f"no recent joint state on joint_states although {publishers} "
                      f"publisher(s) are matched ("
                      + ("none received yet" if age is None else f"the newest {age:.2f} s old")
                      + f", joint_state_timeout = {config.joint_state_timeout:g} s): the goal "
                      "starts from default_start, not from where the arm is")
        if not config.default_start:
            raise conv.ConversionError(
                f"no recent joint state on joint_states (within "
                f"joint_state_timeout = {config.joint_state_timeout:g} s) and no "
                f"`default_start` for this arm: publish its joint states, set default_start "
                f"({self._model.m} values) or give the start in the request")
        return ("point", np.array(config.default_start))

    def describe(self, config: PlannerConfig) -> str:
        """The joint states as ``/diagnostics`` reports them.

        ``receiving``, ``stale`` (the newest older than ``joint_state_timeout``) or ``none
        received``, with the newest one's age (s) and the publishers matched.
        """
        age, publishers = self.joint_states.age(), self.joint_states.publisher_count()
        if age is None:
            return f"none received ({publishers} publishers)"
        kind = "receiving" if age <= config.joint_state_timeout else "stale"
        return f"{kind} (newest {age:.2f} s old, {publishers} publishers)"

    def latest(self, config: PlannerConfig) -> tuple[int, np.ndarray | None]:
        """The latest joint state's stamp (ns, 0: none) and positions (None: not this arm's)."""
        latest = self.joint_states.newest(0, config.joint_state_timeout, 0.0)
        if latest is None:
            return 0, None
        origin = conv.nanoseconds(latest.header.stamp)
        try:
            q, _ = conv.joint_state_from_msg(latest, self._model.joint_names)
        except conv.ConversionError:
            return origin, None  # not this arm's joints: no replan
        return origin, q
