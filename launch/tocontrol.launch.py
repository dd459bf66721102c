r"""Start the planner, the simulated arm (tracker) and the recorder for your robot.

    ros2 launch tocontrol_ros tocontrol.launch.py [robot:=/path/arm.urdf]
        [params_file:=/path/params.yaml] [use_sim_time:=false]
        [controller_action:=/tracker/follow_joint_trajectory] [simulate:=true]
        [record:=true] [output:=runs/x.mcap] [namespace:=arm1]

- ``robot``: a URDF file (no xacro); empty (the default): the nodes read the URDF from the
  ``/robot_description`` topic, as ``robot_state_publisher`` publishes it (start that first,
  or alongside). The package's own arm: ``robot:=$(ros2 pkg prefix
  tocontrol_ros)/share/tocontrol_ros/config/galicki_3r.urdf``.
- ``params_file``: a ROS parameters file given to every node after the package's defaults
  (``/**:`` or ``planner:``/``tracker:``/``recorder:`` sections).
- ``use_sim_time``: every node follows ``/clock``.
- ``controller_action``: the ``FollowJointTrajectory`` action the planner sends each plan to:
  ``/tracker/follow_joint_trajectory`` (the simulated arm's) or a ros2_control
  ``joint_trajectory_controller``'s ``/<controller>/follow_joint_trajectory``. Empty (the
  default): the plans reach the tracker on the ``/planner/trajectory`` topic only. When set,
  the tracker takes goals on its action only (not also the topic).
- ``simulate``: start the tracker (the simulated arm); ``false`` with a real controller.
- ``record``, ``output``: the recorder and its file.
- ``namespace``: every node in this namespace (``/<namespace>/planner``, ...), their topics
  with them (the defaults are relative: ``planner/trajectory``, ``joint_states``,
  ``robot_description``); two arms side by side are two launches with two namespaces. A
  relative ``controller_action`` (``tracker/follow_joint_trajectory``) resolves in it too.
  ``/diagnostics`` and ``/clock`` stay global, as ROS has them.

Then send a goal, e.g.
    ros2 topic pub --once /planner/goal geometry_msgs/msg/PointStamped \
      "{header: {frame_id: base_link}, point: {x: 2.2, y: 1.5}}"

The same three nodes, a plan of the paper's example, its execution, the recording and the
report run without ``launch`` through ``ros2 run tocontrol_ros demo``.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "tocontrol_ros"
#: Where the nodes read the robot when no ``robot`` file is given (in their namespace).
ROBOT_TOPIC = "robot_description"

ARGUMENTS = (
    ("robot", "", "URDF file of the arm; empty: read it from /robot_description"),
    ("params_file", "", "ROS parameters file for every node, after the package's defaults"),
    ("use_sim_time", "false", "every node follows /clock"),
    ("controller_action", "", "FollowJointTrajectory action the planner sends its plans to "
     "(e.g. /tracker/follow_joint_trajectory); empty: the topic only"),
    ("simulate", "true", "start the tracker (the simulated arm)"),
    ("record", "true", "also start the recorder"),
    ("output", "", "recording path (default runs/<timestamp>.mcap)"),
    ("namespace", "", "namespace of every node (and of their relative topics); empty: none"),
)


def _true(text: str) -> bool:
    value = text.strip().lower()
    if value not in ("true", "false", "1", "0", "yes", "no"):
        raise ValueError(f"expected true or false, got {text!r}")
    return value in ("true", "1", "yes")


def _nodes(context):
    """The nodes, from the arguments' values (plain Python: conditions on strings)."""
    arg = {name: context.launch_configurations.get(name, default)
           for name, default, _ in ARGUMENTS}
    config = FindPackageShare(PACKAGE).perform(context) + "/config/"
    robot = ({"robot_description_file": arg["robot"]} if arg["robot"]
             else {"robot_description_topic": ROBOT_TOPIC})
    common = {"use_sim_time": _true(arg["use_sim_time"])}
    extra = [arg["params_file"]] if arg["params_file"] else []
    action = arg["controller_action"]
    planner = {**robot, **common, "controller_action": action}
    # With an action, the tracker takes the plan as a goal only: not twice.
    tracker = {**robot, **common,
               "trajectory_topic": "planner/trajectory" if not action else "~/unused"}
    ns = arg["namespace"]
    nodes = [Node(package=PACKAGE, executable="planner", name="planner", namespace=ns,
                  output="screen", parameters=[config + "planner.yaml", planner, *extra])]
    if _true(arg["simulate"]):
        nodes.append(Node(package=PACKAGE, executable="tracker", name="tracker",
                          namespace=ns, output="screen",
                          parameters=[config + "tracker.yaml", tracker, *extra]))
    if _true(arg["record"]):
        nodes.append(Node(package=PACKAGE, executable="recorder", name="recorder",
                          namespace=ns, output="screen",
                          parameters=[config + "recorder.yaml",
                                      {**robot, **common, "output": arg["output"]},
                                      *extra]))
    return nodes


def generate_launch_description():
    """The arguments, then planner, tracker and recorder (see the module docstring)."""
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, default, text in ARGUMENTS),
        OpaqueFunction(function=_nodes),
    ])
