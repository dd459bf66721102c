"""The common main loop of the planner and tracker executables."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import InvalidHandle, ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["run_node", "spin_slice"]

#: The main loop waits at most this long (s) for a callback before it looks at the stop
#: flag again (see run_node).
SHUTDOWN_POLL = 0.25


def spin_slice(executor: Executor, timeout_sec: float) -> None:
    """One executor iteration, waiting at most ``timeout_sec`` (s) for a callback.

    An entity destroyed while the executor waited on it is skipped, not fatal: rclpy's
    executors then raise ``InvalidHandle`` (a ``RuntimeError``; ros2/rclpy#1284), which
    stopped the planner's executor when ``use_sim_time`` was set back to false (rclpy
    destroys its ``/clock`` subscription from the parameter service's thread). The next
    iteration builds its wait set without that entity.
    """
    try:
        executor.spin_once(timeout_sec=timeout_sec)
    except InvalidHandle:
        pass


def run_node(prog: str, args: list[str] | None, make_node: Callable[[], Node],
             make_executor: Callable[[], Executor] = SingleThreadedExecutor,
             parser: argparse.ArgumentParser | None = None) -> int:
    """Initialise rclpy, build the node and spin it until SIGINT, SIGTERM or a shutdown.

    The executables' ``main``: the non-ROS part of the command line goes to ``parser``
    first (``--help`` prints it and exits; the settings are ROS parameters).

    SIGINT and SIGTERM only set a stop flag (rclpy's own handlers are not installed): the
    loop then ends, the node is destroyed (the planner stops its worker) and rclpy shut
    down. Further signals during that are ignored (and after it: the caller is expected to
    exit), so that Ctrl-C under ``ros2 launch`` (SIGINT to the process group, then launch's
    own SIGINT to each node) ends with exit status 0 and no traceback.

    Parameters
    ----------
    prog : str
        Program name for the start-up error message.
    args : list of str or None
        The whole command line, program name first, ROS arguments included (passed to
        ``rclpy.init``); ``sys.argv`` if None.
    make_node : callable
        Builds the node; a ``TocontrolError`` or ``ParameterException`` means it cannot start.
    make_executor : callable
        Builds the executor that spins the node.
    parser : argparse.ArgumentParser, optional
        The executable's command line without its ROS arguments.

    Returns
    -------
    int
        0 after a clean shutdown, 1 when the node could not start (bad parameters or URDF).
    """
    argv = list(sys.argv if args is None else args)
    if parser is not None:
        parser.parse_args(remove_ros_args(argv)[1:])
    stop: list[int] = []

    def on_signal(signum, _frame):
        stop.append(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    try:
        try:
            node = make_node()
        except (TocontrolError, ParameterException) as exc:
            print(f"{prog}: cannot start: {exc}", file=sys.stderr)
            return 1
        executor = make_executor()
        executor.add_node(node)
        # Bounded slices: a Python signal handler runs only between them (the executor
        # waits in C), so a stop is noticed within SHUTDOWN_POLL.
        while not stop and rclpy.ok():
            spin_slice(executor, SHUTDOWN_POLL)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # An external rclpy.shutdown while the executor builds its wait set raises RCLError
        # "the given context is not valid" (ros2/rclpy#402). That is a shutdown.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        if executor is not None:
            # Joins an executor's thread pool, so that interpreter exit does not wait on it.
            executor.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown()
        # The process is ending: a signal now (launch's second SIGINT) must not kill it.
        # Ignored, not handled: Python's finalisation puts handled signals back to their
        # default action (death, status -2), but leaves ignored ones alone.
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
    return 0
