"""Declaring the nodes' parameter tables on a node: the descriptors rclpy enforces.

The tables themselves (:class:`ParameterSpec`, the robot's parameters, :func:`load_model`)
are ROS-free, in :mod:`tocontrol_ros.nodes.parameter_specs`, and re-exported here. Each node
calls :func:`declare_all` once with its table; rclpy then enforces types, ranges and
read-only flags from the descriptors built by :func:`descriptor`. :func:`robot_from_topic`
reads the robot from ``robot_description_topic`` at start-up. Nothing here needs a running
node.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from tocontrol_ros.nodes.parameter_specs import (
    LOCKED_JOINTS,
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_FILE,
    ROBOT_DESCRIPTION_TIMEOUT,
    ROBOT_DESCRIPTION_TOPIC,
    ParameterSpec,
    RobotDescriptionError,
    load_model,
    parameters_help,
    parameters_parser,
    parse_locked_joints,
)

__all__ = ["ParameterSpec", "descriptor", "declare_all", "ROBOT_DESCRIPTION",
           "ROBOT_DESCRIPTION_FILE", "ROBOT_DESCRIPTION_TOPIC", "ROBOT_DESCRIPTION_TIMEOUT",
           "robot_from_topic", "LOCKED_JOINTS", "RobotDescriptionError", "load_model",
           "parse_locked_joints", "parameters_help", "parameters_parser"]

_RESTART = " Read-only: a change needs a restart."


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of one parameter (type, description, range, read_only)."""
    description = spec.description
    if spec.read_only and _RESTART.strip() not in description:
        description += _RESTART
    d = ParameterDescriptor(name=spec.name, type=spec.type, description=description,
                            additional_constraints=spec.constraints,
                            read_only=spec.read_only)
    if spec.low is not None:
        if spec.type == ParameterType.PARAMETER_INTEGER:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                            step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    return d


def declare_all(node, specs: tuple[ParameterSpec, ...]) -> dict[str, Any]:
    """Declare every spec on `node`; return name -> value (``None`` for an unset optional).

    Raises
    ------
    rclpy.exceptions.ParameterException
        A value (from the command line or a parameter file) of the wrong type or out of range.
    """
    values: dict[str, Any] = {}
    for spec in specs:
        if spec.default is None:
            node.declare_parameter(spec.name, _PYTHON_TYPES[spec.optional], descriptor(spec))
            try:
                values[spec.name] = list(node.get_parameter(spec.name).value)
            except ParameterUninitializedException:
                values[spec.name] = None
        else:
            values[spec.name] = node.declare_parameter(spec.name, spec.default,
                                                       descriptor(spec)).value
    return values


_PYTHON_TYPES = {ParameterType.PARAMETER_DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
                 ParameterType.PARAMETER_STRING_ARRAY: Parameter.Type.STRING_ARRAY,
                 ParameterType.PARAMETER_STRING: Parameter.Type.STRING}


def robot_from_topic(node, values: dict) -> dict:
    """``values`` with ``robot_description`` read from ``robot_description_topic`` if due.

    Reads the topic (``std_msgs/String``, reliable, transient local: the last message of a
    ``robot_state_publisher`` started before or after this node) only when the topic is set
    and neither ``robot_description`` nor ``robot_description_file`` is; spins ``node``
    until the message arrives (at most ``robot_description_timeout`` s), before the node has
    any other callbacks.

    Parameters
    ----------
    node : rclpy.node.Node
    values : dict
        The node's parameter values (:func:`declare_all`).

    Returns
    -------
    dict
        A copy, ``robot_description`` filled in when it was read.

    Raises
    ------
    RobotDescriptionError
        Nothing arrived within the timeout (the message names the topic).
    """
    topic = str(values.get("robot_description_topic", "")).strip()
    if not topic or str(values.get("robot_description", "")).strip() or \
            str(values.get("robot_description_file", "")).strip():
        return dict(values)
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.task import Future
    from std_msgs.msg import String

    received: Future = Future()

    def on_message(msg: String) -> None:
        if not received.done():
            received.set_result(msg.data)

    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    subscription = node.create_subscription(String, topic, on_message, qos)
    executor = SingleThreadedExecutor(context=node.context)
    timeout = float(values.get("robot_description_timeout", 30.0))
    try:
        executor.add_node(node)
        executor.spin_until_future_complete(received, timeout_sec=timeout)
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_subscription(subscription)
    if not received.done():
        raise RobotDescriptionError(
            f"no robot description on `robot_description_topic` {topic!r} within "
            f"{timeout:g} s (robot_description_timeout): start robot_state_publisher, or set "
            f"robot_description or robot_description_file")
    node.get_logger().info(f"robot description read from {topic} "
                           f"({len(received.result())} characters)")
    return {**values, "robot_description": received.result()}
