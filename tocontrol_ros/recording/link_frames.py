"""The robot and its link frames in a recording, as robot_state_publisher broadcasts them.

A viewer (Foxglove, RViz) draws a moving arm from three topics: ``/robot_description`` (the
URDF, ``std_msgs/msg/String``, reliable and transient local), ``/tf_static`` (the fixed
joints, once, reliable and transient local) and ``/tf`` (the moving joints at each joint
state), each transform the child link's frame in its parent's. :class:`LinkFrames` computes
them from a URDF and ``sensor_msgs/msg/JointState`` messages with the project's kinematics
(:func:`tocontrol_ros.core.robot.urdf.joint_frames`,
:func:`tocontrol_ros.core.robot.kinematics.joint_transform`); the recorder writes them next
to the joint states it records.

One difference from robot_state_publisher: a moving joint that the joint states never name
(a gripper's finger that no node moves) is broadcast at a fixed position (``fixed`` below,
else its ``rest`` position) instead of being left out, so the viewer draws the whole arm.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from tocontrol_ros.core.robot.kinematics import joint_transform, quaternion_from_matrix
from tocontrol_ros.core.robot.urdf import joint_frames

__all__ = ["DESCRIPTION_TOPIC", "TF_TOPIC", "TF_STATIC_TOPIC", "DESCRIPTION_TYPE", "TF_TYPE",
           "QOS_DESCRIPTION", "QOS_TF", "QOS_TF_STATIC", "LinkFrames", "tf_message_class"]

DESCRIPTION_TOPIC = "/robot_description"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
DESCRIPTION_TYPE = "std_msgs/msg/String"
TF_TYPE = "tf2_msgs/msg/TFMessage"
#: robot_state_publisher's ``/robot_description`` publisher: the last URDF for late joiners.
QOS_DESCRIPTION = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: tf2_ros ``StaticTransformBroadcaster`` (``StaticBroadcasterQoS``).
QOS_TF_STATIC = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: tf2_ros ``TransformBroadcaster`` (``DynamicBroadcasterQoS``).
QOS_TF = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)


def tf_message_class():
    """``tf2_msgs.msg.TFMessage``, imported when needed (the pip route builds it).

    Raises
    ------
    ImportError
        With a message that says how to get it, when ``tf2_msgs`` is not installed.
    """
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as exc:
        raise ImportError("tf2_msgs is not installed: a ROS install has it "
                          "(ros-jazzy-tf2-msgs); the pip route builds it from interfaces/ "
                          "(scripts/dev setup)") from exc
    return TFMessage


class LinkFrames:
    """Transforms between a URDF's links for joint states.

    Parameters
    ----------
    urdf : str
        URDF XML (or a URDF file path).
    fixed : mapping of str to float, optional
        Positions (rad, m) of moving joints that joint states may not name (e.g. the
        ``locked_joints`` of the nodes); others default to their ``rest`` position.

    Raises
    ------
    ModelError
        A URDF the core cannot read.
    """

    def __init__(self, urdf: str, fixed: Mapping[str, float] | None = None) -> None:
        frames = joint_frames(urdf)
        self.fixed_joints = tuple(f for f in frames if f.kind == "fixed")
        self.moving_joints = tuple(f for f in frames if f.kind != "fixed")
        fixed = dict(fixed or {})
        #: Position (rad, m) of each moving joint that a joint state does not name.
        self.defaults = {f.joint: float(fixed.get(f.joint, f.rest)) for f in self.moving_joints}

    @property
    def moving_joint_names(self) -> tuple[str, ...]:
        """Names of the moving joints (those on ``/tf``), parents first."""
        return tuple(f.joint for f in self.moving_joints)

    def moving_transforms(self, positions: Mapping[str, float]) -> list[tuple]:
        """Each moving joint's child frame in its parent's frame.

        Parameters
        ----------
        positions : mapping of str to float
            Joint name -> position (rad, m); joints it does not name take their default.

        Returns
        -------
        list of (str, str, ndarray (3, 3), ndarray (3,))
            ``(parent, child, rotation, translation)`` per moving joint, translation in m.
        """
        out = []
        for f in self.moving_joints:
            rot, pos = joint_transform(f, float(positions.get(f.joint, self.defaults[f.joint])))
            out.append((f.parent, f.child, rot, pos))
        return out

    def static_transforms(self) -> list[tuple]:
        """Each fixed joint's child frame in its parent's: as :meth:`moving_transforms`."""
        return [(f.parent, f.child, f.rotation, f.translation) for f in self.fixed_joints]

    def tf_message(self, joint_state):
        """``/tf`` for one ``sensor_msgs/msg/JointState``: its stamp, every moving joint.

        A joint state whose ``name`` and ``position`` differ in length gives positions for
        the first ``min(len)`` names only (robot_state_publisher rejects such a message;
        here the defaults stand in).
        """
        positions = dict(zip(joint_state.name, joint_state.position, strict=False))
        return self._message(joint_state.header.stamp, self.moving_transforms(positions))

    def tf_static_message(self, stamp):
        """``/tf_static``: every fixed joint, stamped `stamp` (``builtin_interfaces/Time``)."""
        return self._message(stamp, self.static_transforms())

    @staticmethod
    def _message(stamp, transforms):
        out = tf_message_class()()
        out.transforms = [
            TransformStamped(
                header=Header(stamp=stamp, frame_id=parent), child_frame_id=child,
                transform=Transform(translation=Vector3(x=float(p[0]), y=float(p[1]),
                                                        z=float(p[2])),
                                    rotation=_quaternion(rot)))
            for parent, child, rot, p in transforms]
        return out


def _quaternion(rotation: np.ndarray) -> Quaternion:
    x, y, z, w = quaternion_from_matrix(rotation)
    return Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))
