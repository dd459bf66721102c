"""The robot from a topic, as robot_state_publisher publishes /robot_description.

The tracker started with ``robot_description_topic`` builds its model from the latched
``std_msgs/String`` on that topic (the planner reads it the same way, ``robot_from_topic``);
without one it stops at once with a message naming the topic.
"""

import os
import time
from pathlib import Path

import pytest
import rclpy
from node_process import NodeProcess
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from tocontrol_ros.core.robot.model import default_urdf_path

pytestmark = pytest.mark.ros


def _wait(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.05)


def test_the_tracker_takes_the_robot_from_the_topic(tmp_path):
    ns = f"/rd_{os.getpid()}"
    xml = Path(default_urdf_path()).read_text()
    renamed = xml.replace('name="galicki_3r"', 'name="from_topic"', 1)
    assert renamed != xml
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("robot_state_publisher_stand_in", context=context)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_publisher(String, f"{ns}/robot_description", latched).publish(
        String(data=renamed))
    tracker = NodeProcess("tracker", ["--ros-args", "-r", f"__ns:={ns}", "-p",
                                      f"robot_description_topic:={ns}/robot_description",
                                      "-p", f"trajectory_topic:={ns}/unused"], tmp_path)
    try:
        _wait(lambda: "tracking on 'from_topic'" in tracker.log.read_text(), 60.0,
              "the tracker's start on the topic's robot")
        assert f"robot description read from {ns}/robot_description" in \
            tracker.log.read_text()
    finally:
        code = tracker.stop()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert code == 0, tracker.log.read_text()


def test_no_robot_on_the_topic_stops_the_node_with_the_reason(tmp_path):
    ns = f"/rd_none_{os.getpid()}"
    tracker = NodeProcess("tracker", ["--ros-args", "-r", f"__ns:={ns}", "-p",
                                      f"robot_description_topic:={ns}/nothing", "-p",
                                      "robot_description_timeout:=0.5"], tmp_path)
    code = tracker.proc.wait(60)
    log = tracker.log.read_text()
    assert code == 1, log
    assert f"no robot description on `robot_description_topic` '{ns}/nothing'" in log
