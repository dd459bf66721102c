"""The newest message of a topic, taken from the middleware only when a request needs it.

The planner keeps ``joint_states`` subscribed this way (:class:`LatestMessage`): by a
helper node that no executor spins, so that incoming messages cost nothing until a request
takes the newest one.
"""

from __future__ import annotations

import threading
import time

from rclpy.node import Node
from rclpy.qos import QoSProfile

__all__ = ["LatestMessage", "STATE_POLL"]

#: Poll period (s) of a request waiting for a joint state newer than itself.
STATE_POLL = 0.005


class LatestMessage:
    """The newest message of a topic, taken from the middleware only when asked for.

    The subscription belongs to a hidden helper node (name starting with ``_``) that no
    executor spins: incoming messages never wake the planner's executor, the middleware keeps
    only the newest (depth 1), and :meth:`newest` takes it when a request needs it. A
    subscription with a callback would cost an executor iteration per message (most of a
    core at 500 Hz with rclpy's executors).

    Parameters
    ----------
    node : rclpy.node.Node
        The owner: its context and namespace are used, and it resolves the topic name (with
        its remappings).
    msg_type : type
    topic : str
    qos_profile : QoSProfile
    """

    def __init__(self, node: Node, msg_type, topic: str, qos_profile: QoSProfile) -> None:
        self._msg_type = msg_type
        # The owner resolves the name (its namespace and remappings); the helper takes no
        # command-line arguments, so that a global `-r __node:=...` (as `ros2 launch` passes)
        # does not give it the owner's name.
        resolved = node.resolve_topic_name(topic)
        self._helper = Node(f"_{node.get_name()}_{topic.strip('/').replace('/', '_')}",
                            namespace=node.get_namespace(), context=node.context,
                            use_global_arguments=False, start_parameter_services=False,
                            enable_rosout=False)
        self._sub = self._helper.create_subscription(msg_type, resolved, lambda _msg: None,
                                                     qos_profile)
        self._lock = threading.Lock()
        self._latest = None  # (message, DDS receive time in ns)

    def _take(self) -> None:
        """Take everything queued; keep the newest. Holds ``self._lock``."""
        while True:
            try:
                with self._sub.handle:
                    taken = self._sub.handle.take_message(self._msg_type, False)
            except Exception:  # noqa: BLE001  (subscription gone during shutdown)
                return
            if taken is None or taken[0] is None:
                return
            msg, info = taken
            self._latest = (msg, int(info.get("received_timestamp", 0)) or time.time_ns())

    def newest(self, since_ns: int, max_age: float, wait: float, first_wait: float = 0.0):
        """The newest message not older than ``max_age`` s, or None.

        When the newest one is recent but received before ``since_ns`` (``time.time_ns()``
        scale), wait up to ``wait`` s for a newer one. When none was ever received but the
        topic has a matched publisher (its first messages still on their way: a publisher
        discovered moments ago, a loaded machine), wait up to ``first_wait`` s for the first.
        """
        deadline = time.monotonic() + wait
        with self._lock:
            self._take()
            first_deadline = time.monotonic() + first_wait
            while (self._latest is None and time.monotonic() < first_deadline
                   and self.publisher_count() > 0):
                time.sleep(STATE_POLL)
                self._take()
            while (self._latest is not None and self._latest[1] < since_ns
                   and time.time_ns() - self._latest[1] <= max_age * 1e9
                   and time.monotonic() < deadline):
                time.sleep(STATE_POLL)
                self._take()
            latest = self._latest
        if latest is None or time.time_ns() - latest[1] > max_age * 1e9:
            return None
        return latest[0]

    def publisher_count(self) -> int:
        """The topic's publishers matched by the subscription (0 once it is destroyed)."""
        try:
            return int(self._sub.get_publisher_count())
        except Exception:  # noqa: BLE001  (subscription gone during shutdown)
            return 0

    def age(self) -> float | None:
        """Seconds since the newest message was received (queued ones taken), None: none yet."""
        with self._lock:
            self._take()
            latest = self._latest
        return None if latest is None else (time.time_ns() - latest[1]) * 1e-9

    def destroy(self) -> None:
        """Destroy the helper node."""
        with self._lock:
            self._helper.destroy_node()
