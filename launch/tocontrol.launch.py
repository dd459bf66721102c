"""Start the planner, the tracker and (by default) the recorder with config/ parameters.

    ros2 launch tocontrol_ros tocontrol.launch.py [record:=false] [output:=runs/x.mcap]

Then send a goal, e.g.
    ros2 topic pub --once /planner/goal geometry_msgs/msg/PointStamped \
      "{header: {frame_id: base_link}, point: {x: 2.2, y: 1.5}}"

The same three nodes, a plan of the paper's example, its execution, the recording and the
report run without `launch` through `ros2 run tocontrol_ros demo`.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "tocontrol_ros"


def generate_launch_description():
    """Planner, tracker and recorder, each with its YAML file from the package's config/."""
    config = PathJoinSubstitution([FindPackageShare(PACKAGE), "config"])
    record = LaunchConfiguration("record")
    output = LaunchConfiguration("output")
    return LaunchDescription([
        DeclareLaunchArgument("record", default_value="true",
                              description="also start the recorder"),
        DeclareLaunchArgument("output", default_value="",
                              description="recording path (default runs/<timestamp>.mcap)"),
        Node(package=PACKAGE, executable="planner", name="planner", output="screen",
             parameters=[PathJoinSubstitution([config, "planner.yaml"])]),
        Node(package=PACKAGE, executable="tracker", name="tracker", output="screen",
             parameters=[PathJoinSubstitution([config, "tracker.yaml"])]),
        Node(package=PACKAGE, executable="recorder", name="recorder", output="screen",
             parameters=[PathJoinSubstitution([config, "recorder.yaml"]),
                         {"output": output}],
             condition=IfCondition(record)),
    ])
