"""The interface packages built from interfaces/ are the released Jazzy types.

Their type hashes (RIHS01, over field names and types) equal those of a build of the released
definitions (interfaces/README.md says where they come from): a goal sent to a real
joint_trajectory_controller, or a real client's goal to the tracker, is the same type, and a
recording's /tf is the type that tf2 and the viewers know.
"""

import json
import os
import sys
from pathlib import Path

import pytest

#: Type -> RIHS01 hash of the released control_msgs (5.x, the Jazzy line).
RELEASED = {
    "control_msgs/action/FollowJointTrajectory":
        "RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6",
    "control_msgs/action/FollowJointTrajectory_Goal":
        "RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205",
    "control_msgs/action/FollowJointTrajectory_Result":
        "RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220",
    "control_msgs/action/FollowJointTrajectory_Feedback":
        "RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49",
    "control_msgs/action/FollowJointTrajectory_SendGoal":
        "RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f",
    "control_msgs/action/FollowJointTrajectory_GetResult":
        "RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b",
    "control_msgs/action/FollowJointTrajectory_FeedbackMessage":
        "RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71",
    "control_msgs/msg/JointTolerance":
        "RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648",
    "control_msgs/msg/JointComponentTolerance":
        "RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4",
    "tf2_msgs/msg/TFMessage":
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
}


def _built_hashes(package: str = "control_msgs") -> dict[str, str]:
    share = Path(sys.prefix) / "share" / package
    files = sorted(share.glob("*/*.json"))
    if not files:
        if os.environ.get("TOCONTROL_DEV_VENV"):
            pytest.fail(f"scripts/dev should have built {package} into {sys.prefix}")
        pytest.skip(f"{package} is not built into {sys.prefix} (not the pip route)")
    hashes = {}
    for path in files:
        for entry in json.loads(path.read_text())["type_hashes"]:
            hashes[entry["type_name"]] = entry["hash_string"]
    return hashes


def test_built_types_hash_like_the_released_ones():
    built = {**_built_hashes("control_msgs"), **_built_hashes("tf2_msgs")}
    assert {name: built.get(name) for name in RELEASED} == RELEASED


def test_tf_message_hashes_as_an_independent_implementation_says():
    """rosbags computes RIHS01 itself from its own copy of Jazzy's definitions."""
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    name = "tf2_msgs/msg/TFMessage"
    assert _built_hashes("tf2_msgs")[name] == store.hash_rihs01(name) == RELEASED[name]


def test_the_python_types_import():
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTrajectoryControllerState

    assert FollowJointTrajectory.Result.GOAL_TOLERANCE_VIOLATED == -5
    assert hasattr(JointTrajectoryControllerState(), "speed_scaling_factor")


def test_tf2_msgs_is_upstream_jazzy_byte_for_byte():
    """The built TFMessage.msg is ros2/geometry2's (jazzy): a recording's schema text equals
    the one rosbag2 would write in a ROS install."""
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    share = Path(sys.prefix) / "share" / "tf2_msgs" / "msg" / "TFMessage.msg"
    if not share.is_file():
        pytest.skip("tf2_msgs is not built into this prefix (not the pip route)")
    assert share.read_bytes() == b"geometry_msgs/TransformStamped[] transforms\n"
    assert isinstance(TFMessage(transforms=[TransformStamped()]).transforms[0],
                      TransformStamped)


#: The project's own action (interfaces/tocontrol_msgs): its hashes as released with it. A
#: change of a field name or type changes them; a client built against the old definition
#: could then no longer decode goals, feedback or results: change these only with a new
#: interface version (and say so in msg_docs/plan_motion_action.md).
OWN = {
    "tocontrol_msgs/action/PlanMotion":
        "RIHS01_72186d51c4688751d9f6887c7d30ba9b222ce8362c27b3876f57ec83df44aee6",
    "tocontrol_msgs/action/PlanMotion_Goal":
        "RIHS01_0b52dfafb24cf82b3759762550b1ebd93ab285321d43135de09a7b1f0e8d3b90",
    "tocontrol_msgs/action/PlanMotion_Result":
        "RIHS01_47bce968a5d68c3e7f14594cc75e4f16b029750fe9b8793d86208096b92d8f49",
    "tocontrol_msgs/action/PlanMotion_Feedback":
        "RIHS01_98cc66a5edbce98033e46832c0d8a3bcfa77201b9a3800ab6492797b53b36aee",
}


def test_plan_motion_hashes_as_released():
    built = _built_hashes("tocontrol_msgs")
    assert {name: built.get(name) for name in OWN} == OWN


def test_plan_motion_hashes_as_an_independent_implementation_says(repo):
    """rosbags computes RIHS01 on its own from the .action's three parts (goal, result,
    feedback) and Jazzy's definitions of the messages they use."""
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    text = (repo / "interfaces" / "tocontrol_msgs" / "action" / "PlanMotion.action").read_text()
    parts = text.split("\n---\n")
    assert len(parts) == 3
    built = _built_hashes("tocontrol_msgs")
    for part, kind in zip(parts, ("Goal", "Result", "Feedback"), strict=True):
        name = f"tocontrol_msgs/action/PlanMotion_{kind}"
        store.register(typesys.get_types_from_msg(part, name))
        assert store.hash_rihs01(name) == built[name] == OWN[name]


def test_plan_motion_defaults():
    """A goal left at its defaults plans from the current state to a point, with the
    planner's parameters, and publishes nothing (``execute`` false)."""
    from tocontrol_msgs.action import PlanMotion

    goal = PlanMotion.Goal()
    assert goal.start_type == PlanMotion.Goal.START_CURRENT
    assert goal.target_type == PlanMotion.Goal.TARGET_POINT
    assert (goal.k, goal.time_limit, goal.limit_margin, goal.execute) == (-1.0, -1.0, -1.0,
                                                                          False)
