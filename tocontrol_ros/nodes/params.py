"""Parameter tables of the nodes: one spec type, one descriptor builder, one declare loop.

Each node keeps a tuple of :class:`ParameterSpec` (its only definition of its parameters)
and calls :func:`declare_all` once; rclpy then enforces types, ranges and read-only flags
from the descriptors built here. The robot is the same parameter on every node,
:data:`ROBOT_DESCRIPTION` (the ROS 2 convention: URDF XML, as robot_state_publisher and
MoveIt take it), with :data:`ROBOT_DESCRIPTION_FILE` for a path; :func:`load_model` turns
them into a model with a one-line error for anything else. Nothing here needs a running node.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

import numpy as np
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["ParameterSpec", "descriptor", "declare_all", "ROBOT_DESCRIPTION",
           "ROBOT_DESCRIPTION_FILE", "ROBOT_DESCRIPTION_TOPIC", "ROBOT_DESCRIPTION_TIMEOUT",
           "robot_from_topic", "LOCKED_JOINTS", "RobotDescriptionError", "load_model",
           "parse_locked_joints", "parameters_help"]

_RESTART = " Read-only: a change needs a restart."


class RobotDescriptionError(TocontrolError, ValueError):
    """``robot_description`` / ``robot_description_file`` that cannot give a model."""


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its default (which fixes its type), range and meaning.

    Attributes
    ----------
    name : str
    default : bool, int, float, str, list of float, list of str or None
        ``None`` declares an optional parameter of type `optional` (unset by default).
    description : str
        Shown by ``ros2 param describe``; includes the unit.
    low, high : float or int, optional
        Inclusive range of a scalar number (rclpy enforces it).
    read_only : bool
        A change needs a restart (e.g. the model is built once, at start-up).
    constraints : str
        Conditions that rclpy cannot express (checked by the node).
    optional : int
        The ``ParameterType`` of a parameter whose default is ``None``.
    """

    name: str
    default: Any
    description: str
    low: float | int | None = None
    high: float | int | None = None
    read_only: bool = False
    constraints: str = ""
    optional: int = ParameterType.PARAMETER_DOUBLE_ARRAY

    @property
    def type(self) -> int:
        """The ``rcl_interfaces/ParameterType`` of the default."""
        d = self.default
        if d is None:
            return self.optional
        if isinstance(d, bool):
            return ParameterType.PARAMETER_BOOL
        if isinstance(d, int):
            return ParameterType.PARAMETER_INTEGER
        if isinstance(d, float):
            return ParameterType.PARAMETER_DOUBLE
        if isinstance(d, str):
            return ParameterType.PARAMETER_STRING
        if d and all(isinstance(v, str) for v in d):
            return ParameterType.PARAMETER_STRING_ARRAY
        return ParameterType.PARAMETER_DOUBLE_ARRAY

    def with_description(self, description: str) -> ParameterSpec:
        """The same spec with another description."""
        return ParameterSpec(self.name, self.default, description, self.low, self.high,
                             self.read_only, self.constraints, self.optional)


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


def parameters_help(specs: tuple[ParameterSpec, ...]) -> str:
    """One line per parameter, for a ``--help`` epilog."""
    return "\n".join(f"  {spec.name}: {spec.description}" for spec in specs)


def parameters_parser(prog: str, description: str, specs: tuple[ParameterSpec, ...]
                      ) -> argparse.ArgumentParser:
    """A command line with only ``--help``, whose epilog lists the (read-only) parameters."""
    return argparse.ArgumentParser(
        prog=prog, formatter_class=argparse.RawDescriptionHelpFormatter,
        description=description, epilog="parameters (all read-only):\n" + parameters_help(specs))


_PYTHON_TYPES = {ParameterType.PARAMETER_DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
                 ParameterType.PARAMETER_STRING_ARRAY: Parameter.Type.STRING_ARRAY,
                 ParameterType.PARAMETER_STRING: Parameter.Type.STRING}

# ----------------------------------------------------------------- the robot
#: The robot, on every node: URDF XML, the ROS 2 convention.
ROBOT_DESCRIPTION = ParameterSpec(
    "robot_description", "", "URDF XML of the arm (as robot_state_publisher and MoveIt take "
    "it). Empty: robot_description_file, or else the bundled config/galicki_3r.urdf (the "
    "paper's planar 3R arm).", read_only=True,
    constraints="URDF XML (starts with '<'); not together with robot_description_file")
#: The robot as a file, for the command line (``-p robot_description_file:=arm.urdf``).
ROBOT_DESCRIPTION_FILE = ParameterSpec(
    "robot_description_file", "", "Path of a URDF file, used when robot_description is "
    "empty. Empty: the bundled arm.", read_only=True)
#: The robot from a topic, as robot_state_publisher publishes it (and ros2_control's
#: controller manager reads it since Jazzy): ``std_msgs/String``, transient local.
ROBOT_DESCRIPTION_TOPIC = ParameterSpec(
    "robot_description_topic", "", "Topic of a std_msgs/String with the URDF XML "
    "(transient local, as robot_state_publisher publishes /robot_description), read once at "
    "start-up when robot_description and robot_description_file are empty. Empty: not read "
    "(the bundled arm).", read_only=True)
#: How long a node waits at start-up for the robot on ``robot_description_topic`` (s).
ROBOT_DESCRIPTION_TIMEOUT = ParameterSpec(
    "robot_description_timeout", 30.0, "Longest wait (s) at start-up for the URDF on "
    "robot_description_topic; then the node stops with an error.", 0.1, 3600.0,
    read_only=True)
#: Joints held fixed, on every node that loads the robot (planner and tracker must agree).
LOCKED_JOINTS = ParameterSpec(
    "locked_joints", "", "Moving joints held fixed, as 'name=position' pairs separated by "
    "spaces or commas (rad, m), e.g. 'panda_finger_joint1=0.04'. Joints at or below the tip "
    "link (a gripper's fingers) are locked without being named: at 0, or at the nearer "
    "position limit when 0 is outside the limits.", read_only=True,
    constraints="name=number pairs")


def parse_locked_joints(text: str) -> dict[str, float]:
    """``locked_joints`` as a mapping, joint name -> position (rad, m).

    Raises
    ------
    RobotDescriptionError
        An entry that is not ``name=number`` with a finite number, or a name given twice.
    """
    out: dict[str, float] = {}
    for entry in text.replace(",", " ").split():
        name, sep, value = entry.partition("=")
        try:
            position = float(value)
        except ValueError:
            position = float("nan")
        if not sep or not name or not np.isfinite(position):
            raise RobotDescriptionError(f"`locked_joints` entry {_quote(entry)} must be "
                                        f"name=position with a finite number")
        if name in out:
            raise RobotDescriptionError(f"`locked_joints` names joint {name!r} twice")
        out[name] = position
    return out


#: How much of a bad value an error message quotes (characters).
_QUOTE = 40


def _quote(text: str) -> str:
    text = " ".join(text.split())
    return repr(text if len(text) <= _QUOTE else text[:_QUOTE] + "...")


def load_model(description: str, description_file: str = "", **kwargs):
    """The robot model of the two robot parameters.

    Parameters
    ----------
    description : str
        ``robot_description``: URDF XML, or empty.
    description_file : str
        ``robot_description_file``: a URDF path, or empty.
    **kwargs
        Passed to :func:`tocontrol_ros.core.robot.model.load_robot` (base_link, tip_link, ...).

    Returns
    -------
    model : RobotModel
    bundled : bool
        True when neither was set (the bundled arm).

    Raises
    ------
    RobotDescriptionError
        Both set, a description that is not XML, a file that cannot be read; one line that
        quotes at most the first characters of the value.
    ModelError
        A URDF the core cannot turn into a model.
    """
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    text, path = description.strip(), description_file.strip()
    if text and path:
        raise RobotDescriptionError("set `robot_description` or `robot_description_file`, "
                                    "not both")
    if text:
        if not text.startswith("<"):
            raise RobotDescriptionError(
                f"`robot_description` must be URDF XML (starting with '<'), got "
                f"{_quote(text)} ({len(text)} characters); for a file use "
                f"`robot_description_file`")
        return load_robot(text, **kwargs), False
    if path:
        try:
            with open(path, encoding="utf-8") as f:
                xml = f.read()
        except (OSError, UnicodeDecodeError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else \
                type(exc).__name__
            raise RobotDescriptionError(f"`robot_description_file` {_quote(path)} cannot be "
                                        f"read: {reason}") from None
        if not xml.lstrip().startswith("<"):
            raise RobotDescriptionError(f"`robot_description_file` {_quote(path)} is not "
                                        f"URDF XML")
        return load_robot(xml, **kwargs), False
    return load_robot(default_urdf_path(), **kwargs), True


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
