"""Parameter tables of the nodes, without ROS: one spec type, the robot's parameters, the model.

Each node keeps a tuple of :class:`ParameterSpec` (its only definition of its parameters);
:mod:`tocontrol_ros.nodes.params` declares them on a node with the descriptors rclpy
enforces. The robot is the same parameter on every node, :data:`ROBOT_DESCRIPTION` (the ROS 2
convention: URDF XML, as robot_state_publisher and MoveIt take it), with
:data:`ROBOT_DESCRIPTION_FILE` for a path; :func:`load_model` turns them into a model with a
one-line error for anything else. Nothing here imports rclpy or a message package, so that
the configs built from these tables (``planner_config``, ``tracker_config``) and the planning
service (:mod:`tocontrol_ros.nodes.planning_service`) load without ROS.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

import numpy as np

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["ParamType", "ParameterSpec", "ROBOT_DESCRIPTION", "ROBOT_DESCRIPTION_FILE",
           "ROBOT_DESCRIPTION_TOPIC", "ROBOT_DESCRIPTION_TIMEOUT", "LOCKED_JOINTS",
           "RobotDescriptionError", "load_model", "parse_locked_joints", "parameters_help",
           "parameters_parser"]


class ParamType:
    """The values of ``rcl_interfaces/msg/ParameterType`` that the tables use.

    Fixed by the message definition; repeated here so that a table needs no ROS import
    (``test/nodes/test_params.py`` checks them against the message).
    """

    PARAMETER_BOOL = 1
    PARAMETER_INTEGER = 2
    PARAMETER_DOUBLE = 3
    PARAMETER_STRING = 4
    PARAMETER_DOUBLE_ARRAY = 8
    PARAMETER_STRING_ARRAY = 9


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
    optional: int = ParamType.PARAMETER_DOUBLE_ARRAY

    @property
    def type(self) -> int:
        """The ``rcl_interfaces/ParameterType`` of the default."""
        d = self.default
        if d is None:
            return self.optional
        if isinstance(d, bool):
            return ParamType.PARAMETER_BOOL
        if isinstance(d, int):
            return ParamType.PARAMETER_INTEGER
        if isinstance(d, float):
            return ParamType.PARAMETER_DOUBLE
        if isinstance(d, str):
            return ParamType.PARAMETER_STRING
        if d and all(isinstance(v, str) for v in d):
            return ParamType.PARAMETER_STRING_ARRAY
        return ParamType.PARAMETER_DOUBLE_ARRAY

    def with_description(self, description: str) -> ParameterSpec:
        """The same spec with another description."""
        return ParameterSpec(self.name, self.default, description, self.low, self.high,
                             self.read_only, self.constraints, self.optional)


def parameters_help(specs: tuple[ParameterSpec, ...]) -> str:
    """One line per parameter, for a ``--help`` epilog."""
    return "\n".join(f"  {spec.name}: {spec.description}" for spec in specs)


def parameters_parser(prog: str, description: str, specs: tuple[ParameterSpec, ...]
                      ) -> argparse.ArgumentParser:
    """A command line with only ``--help``, whose epilog lists the (read-only) parameters."""
    return argparse.ArgumentParser(
        prog=prog, formatter_class=argparse.RawDescriptionHelpFormatter,
        description=description, epilog="parameters (all read-only):\n" + parameters_help(specs))


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
