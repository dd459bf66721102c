"""The whole-tree joint frames and the quaternion of a rotation (ROS-free, no model)."""

import math

import numpy as np
import pytest

from tocontrol_ros.core.errors import ModelError
from tocontrol_ros.core.robot.kinematics import (
    axis_rotation,
    joint_transform,
    quaternion_from_matrix,
)
from tocontrol_ros.core.robot.urdf import joint_frames

TREE = """<robot name="t">
  <link name="base"/><link name="a"/><link name="b"/><link name="f1"/><link name="tool"/>
  <joint name="j1" type="continuous"><parent link="base"/><child link="a"/>
    <origin xyz="0 0 1" rpy="0 0 0"/><axis xyz="0 0 2"/></joint>
  <joint name="fixed" type="fixed"><parent link="a"/><child link="tool"/>
    <origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/></joint>
  <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/>
    <axis xyz="1 0 0"/><limit lower="0.1" upper="0.5" effort="1" velocity="1"/></joint>
  <joint name="finger" type="revolute"><parent link="b"/><child link="f1"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="-0.2" effort="1" velocity="1"/></joint>
</robot>"""


@pytest.mark.parametrize("axis, angle", [((0, 0, 1), 0.3), ((1, 0, 0), math.pi),
                                         ((0, 1, 0), -2.9), ((1, 2, 3), 1.7),
                                         ((1, -1, 0.5), 3.1)])
def test_quaternion_is_the_rotation_about_the_axis(axis, angle):
    u = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    q = quaternion_from_matrix(axis_rotation(u, angle))
    # q = (u sin(angle/2), cos(angle/2)) up to sign; w >= 0 fixes the sign.
    want = np.append(u * math.sin(angle / 2), math.cos(angle / 2))
    want = -want if want[3] < 0 else want
    np.testing.assert_allclose(q, want, atol=1e-12)


def test_joint_frames_cover_the_tree_parents_first():
    frames = joint_frames(TREE)
    assert [f.joint for f in frames][0] == "j1"
    order = {f.child: i for i, f in enumerate(frames)}
    for f in frames:
        assert f.parent == "base" or order[f.parent] < order[f.child]
    by = {f.joint: f for f in frames}
    assert {n: f.kind for n, f in by.items()} == {
        "j1": "revolute", "fixed": "fixed", "j2": "prismatic", "finger": "revolute"}
    np.testing.assert_allclose(by["j1"].axis, [0, 0, 1])  # normalised
    # Rest: 0 moved into the limits (continuous: 0).
    assert [by[n].rest for n in ("j1", "j2", "finger")] == [0.0, 0.1, -0.2]
    rot, pos = joint_transform(by["j1"], math.pi / 2)
    np.testing.assert_allclose(rot @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(pos, [0, 0, 1])
    rot, pos = joint_transform(by["j2"], 0.3)
    np.testing.assert_allclose(pos, [0.3, 0, 0])
    rot, pos = joint_transform(by["fixed"], 123.0)  # a fixed joint ignores the position
    np.testing.assert_allclose(pos, [1, 0, 0])
    np.testing.assert_allclose(rot @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_joint_frames_reject_a_malformed_urdf():
    with pytest.raises(ModelError, match="malformed URDF"):
        joint_frames("<robot name='x'><joint/></robot>")
