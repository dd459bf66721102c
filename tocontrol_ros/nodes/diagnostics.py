"""``/diagnostics``: every node's state as a ``diagnostic_msgs/DiagnosticArray``, once a second.

What ``diagnostic_updater`` gives a C++ node (it is not a wheel here): one
``DiagnosticStatus`` per node, named by its fully qualified name, on the absolute topic
``/diagnostics`` that ``diagnostic_aggregator``, ``rqt_robot_monitor`` and Foxglove read
(msg_docs/diagnostics.md). Each node gives a function of its state; the timer calls it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from tocontrol_ros.nodes import qos

__all__ = ["DIAGNOSTICS_PERIOD", "DIAGNOSTICS_TOPIC", "Diagnostics", "LEVELS", "tracker_state"]

#: Seconds between two arrays (diagnostic_updater's default period is 1 s).
DIAGNOSTICS_PERIOD = 1.0
#: ROS's convention: absolute, whatever the node's namespace (the aggregator reads one topic).
DIAGNOSTICS_TOPIC = "/diagnostics"
LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN,
          "ERROR": DiagnosticStatus.ERROR, "STALE": DiagnosticStatus.STALE}


class Diagnostics:
    """Publishes ``state()`` of ``node`` on ``/diagnostics`` every :data:`DIAGNOSTICS_PERIOD`.

    Parameters
    ----------
    node : rclpy.node.Node
    hardware_id : str
        The robot's name.
    state : callable () -> (str, str, mapping)
        Level (``"OK"``, ``"WARN"``, ``"ERROR"``), message, values (each turned to text).
    period : float
        s.
    """

    def __init__(self, node, hardware_id: str,
                 state: Callable[[], tuple[str, str, Mapping[str, object]]],
                 period: float = DIAGNOSTICS_PERIOD) -> None:
        self._node = node
        self._hardware_id = hardware_id
        self._state = state
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                          qos.profile(10))
        self._timer = node.create_timer(period, self.publish)

    def message(self) -> DiagnosticArray:
        """The array now (one status)."""
        level, message, values = self._state()
        status = DiagnosticStatus(
            level=LEVELS[level], name=self._node.get_fully_qualified_name(), message=message,
            hardware_id=self._hardware_id,
            values=[KeyValue(key=str(k), value=_text(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self._node.get_clock().now().to_msg()
        return array

    def publish(self) -> None:
        """Publish the array now (the timer's callback)."""
        try:
            self._pub.publish(self.message())
        except Exception:  # noqa: BLE001  (publisher gone during shutdown)
            pass

    def destroy(self) -> None:
        """Stop the timer."""
        self._node.destroy_timer(self._timer)


def tracker_state(node) -> tuple[str, str, dict]:
    """The tracker's status: executing or holding, the simulated time, the plans received.

    ``node``: a :class:`~tocontrol_ros.nodes.tracker.TrackerNode` (its public ``tracker``,
    ``trajectories_received`` and ``config``).
    """
    running = node.tracker.running
    return "OK", "executing a trajectory" if running else "holding", {
        "state": "executing" if running else "holding", "sim_time": node.tracker.t,
        "trajectories_received": node.trajectories_received,
        "trajectory_topic": node.config.trajectory_topic}


def _text(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.9g}"
    return str(value)
