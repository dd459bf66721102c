"""The planner's input topics served on a thread of their own (issue 47).

A goal of a stream is answered by the planner's worker thread; its callback only converts the
message and queues the request. Served by the node's own executor, every goal woke that
executor twice (the message, then the callback's completion), and each time it rebuilt its
wait set over every entity of the node (parameter services, ``~/plan``, the action, timers,
the subscriptions): Python that held the GIL while the worker, woken by the goal, waited to
start its quick replan (docs/speed.md, "`wait`"). :class:`InputThread` serves the input
subscriptions (goals, scene, the tracker's status) by a single-threaded executor of their own,
spun in a thread, whose wait set holds only them: the node's executor sleeps through a goal.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

__all__ = ["InputThread", "JOIN_TIMEOUT"]

#: Seconds :meth:`InputThread.destroy` waits for the thread (a callback in progress ends).
JOIN_TIMEOUT = 5.0


class InputThread:
    """Subscriptions of ``node`` served in a thread of their own, one callback at a time.

    They belong to a hidden helper node (name starting with ``_``, in ``node``'s namespace and
    context, its topic names resolved by ``node``: its namespace and remappings), spun by a
    :class:`~rclpy.executors.SingleThreadedExecutor` in a daemon thread: one callback at a
    time (as a mutually exclusive callback group of ``node`` would run them), beside
    ``node``'s executor. A callback that raises is logged through ``log_error`` and the
    thread goes on serving.

    Parameters
    ----------
    node : rclpy.node.Node
        The owner.
    name : str
        The helper node's name after ``_<owner>_``.
    log_error : callable
        Takes a message (str): a callback's exception.
    """

    def __init__(self, node: Node, name: str, log_error: Callable[[str], None]) -> None:
        self._resolve = node.resolve_topic_name
        # No command-line arguments (a global `-r __node:=...` would rename it to its owner).
        self._helper = Node(f"_{node.get_name()}_{name}", namespace=node.get_namespace(),
                            context=node.context, use_global_arguments=False,
                            start_parameter_services=False, enable_rosout=False)
        self._log_error = log_error
        self._context = node.context
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self._helper)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"{node.get_name()}-{name}",
                                        daemon=True)

    def subscribe(self, msg_type, topic: str, callback: Callable, qos_profile: QoSProfile):
        """A subscription to ``topic`` (resolved by the owner) served in the thread."""
        return self._helper.create_subscription(msg_type, self._resolve(topic), callback,
                                                qos_profile)

    def start(self) -> None:
        """Start serving (once)."""
        self._thread.start()

    @property
    def topics(self) -> list[str]:
        """The subscribed topics' names, as resolved."""
        return [sub.topic_name for sub in self._helper.subscriptions]

    @property
    def thread(self) -> threading.Thread:
        """The serving thread."""
        return self._thread

    def _spin(self) -> None:
        while not self._stop.is_set() and self._context.ok():
            try:
                self._executor.spin_once()  # no timeout: a message or destroy() ends it
            except ExternalShutdownException:
                return
            except Exception as exc:  # noqa: BLE001  (a bad callback must not stop the inputs)
                if self._stop.is_set() or not self._context.ok():
                    return  # the context went away while the wait set was built
                self._log_error(f"input callback failed: {exc!r}")

    def destroy(self, timeout: float = JOIN_TIMEOUT) -> None:
        """Stop the thread (a callback in progress ends first), then the helper node."""
        self._stop.set()
        self._executor.shutdown(timeout_sec=timeout)  # its wait returns
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._helper.destroy_node()
