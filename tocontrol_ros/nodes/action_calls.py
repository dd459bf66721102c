"""An rclpy action client whose requests are made on the executor (rclpy's race avoided).

rclpy 7.1 (the Jazzy wheel here) sends a goal, cancel or result request and only then
registers its sequence number; when the executor takes the response in between (a request
made from another thread, a fast server, a busy machine), the response is dropped ("Ignoring
unexpected goal response") and the request's future never completes (ros2/rclpy#1123; the
fix, a lock, was backported to Jazzy in 2025, after this wheel). :class:`SerialActionClient`
makes every request from a guard condition's callback in the client's own mutually exclusive
callback group: never while the executor handles the client's responses. Its services keep
:data:`~tocontrol_ros.nodes.qos.ACTION_SERVICES` deep (rclpy's default, 10, lost the oldest
of a burst of requests).
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable

from rclpy.action import ActionClient
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.task import Future

from tocontrol_ros.nodes import qos

__all__ = ["SerialActionClient"]


class SerialActionClient:
    """``rclpy.action.ActionClient`` with its requests made on the executor.

    Parameters
    ----------
    node : rclpy.node.Node
        Spun by an executor (any thread may call the methods).
    action_type : type
        The action (e.g. ``control_msgs.action.FollowJointTrajectory``).
    name : str
        The action's name (relative names resolve in the node's namespace).
    """

    def __init__(self, node, action_type, name: str) -> None:
        self._node = node
        group = MutuallyExclusiveCallbackGroup()
        self.client = ActionClient(node, action_type, name, callback_group=group,
                                   goal_service_qos_profile=qos.ACTION_SERVICES,
                                   result_service_qos_profile=qos.ACTION_SERVICES,
                                   cancel_service_qos_profile=qos.ACTION_SERVICES)
        self._queue: collections.deque = collections.deque()
        self._lock = threading.Lock()
        self._wake = node.create_guard_condition(self._drain, callback_group=group)

    def wait_for_server(self, timeout: float) -> bool:
        """Whether the server is discovered within ``timeout`` s."""
        return self.client.wait_for_server(timeout_sec=timeout)

    def send_goal(self, goal, feedback_callback: Callable | None = None) -> Future:
        """A future of the goal handle (``send_goal_async``)."""
        return self._call(lambda: self.client.send_goal_async(goal, feedback_callback))

    def get_result(self, handle) -> Future:
        """A future of the goal's result response (``get_result_async``)."""
        return self._call(handle.get_result_async)

    def cancel(self, handle) -> Future:
        """A future of the cancel response (``cancel_goal_async``)."""
        return self._call(handle.cancel_goal_async)

    def _call(self, request: Callable[[], Future]) -> Future:
        out = Future()
        with self._lock:
            self._queue.append((request, out))
        self._wake.trigger()
        return out

    def _drain(self) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    return
                request, out = self._queue.popleft()
            try:
                inner = request()
            except Exception as exc:  # noqa: BLE001  (the caller's future says it)
                out.set_exception(exc)
                continue
            inner.add_done_callback(lambda f, out=out: _relay(f, out))

    def destroy(self) -> None:
        """Destroy the client and its guard condition."""
        self._node.destroy_guard_condition(self._wake)
        self.client.destroy()


def _relay(inner: Future, out: Future) -> None:
    if inner.exception() is not None:
        out.set_exception(inner.exception())
    else:
        out.set_result(inner.result())
