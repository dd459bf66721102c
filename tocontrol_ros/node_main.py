"""The common main loop of the planner and tracker executables."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["run_node"]

#: The main loop waits at most this long (s) for a callback before it looks at the context
#: again (see run_node).
SHUTDOWN_POLL = 0.25


def run_node(prog: str, argv: list[str], make_node: Callable[[], Node],
             make_executor: Callable[[], Executor] = SingleThreadedExecutor) -> int:
    """Initialise rclpy, build the node and spin it until Ctrl-C, SIGTERM or a shutdown.

    Parameters
    ----------
    prog : str
        Program name for the start-up error message.
    argv : list of str
        The whole command line, ROS arguments included (passed to ``rclpy.init``).
    make_node : callable
        Builds the node; a ``TocontrolError`` or ``ParameterException`` means it cannot start.
    make_executor : callable
        Builds the executor that spins the node.

    Returns
    -------
    int
        0 after a clean shutdown, 1 when the node could not start (bad parameters or URDF).
    """
    rclpy.init(args=argv)
    node = executor = None
    try:
        try:
            node = make_node()
        except (TocontrolError, ParameterException) as exc:
            print(f"{prog}: cannot start: {exc}", file=sys.stderr)
            return 1
        executor = make_executor()
        executor.add_node(node)
        # executor.spin() waits without a timeout and relies on the wake-up that rclpy's
        # signal handler sends when it shuts the context down. The planner has, rarely,
        # not exited after a SIGTERM during a solve (never after SIGINT, which also raises
        # KeyboardInterrupt in this thread); a lost wake-up is the likely cause. Waiting in
        # bounded slices notices a shut-down context within SHUTDOWN_POLL either way.
        while rclpy.ok():
            executor.spin_once(timeout_sec=SHUTDOWN_POLL)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # rclpy's signal handler shuts the context down from its own thread; an executor
        # building its wait set at that moment raises RCLError "the given context is not
        # valid" (a known race: ros2/rclpy#402, ros2/ros2cli#854). That is a shutdown.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        if executor is not None:
            # Joins an executor's thread pool, so that interpreter exit does not wait on it.
            executor.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown()
    return 0
