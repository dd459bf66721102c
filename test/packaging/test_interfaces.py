"""The control_msgs interfaces built from interfaces/ are the released Jazzy types.

Their type hashes (RIHS01, over field names and types) equal those of a build of the released
definitions (interfaces/README.md says where they come from): a goal sent to a real
joint_trajectory_controller, or a real client's goal to the tracker, is the same type.
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
}


def _built_hashes() -> dict[str, str]:
    share = Path(sys.prefix) / "share" / "control_msgs"
    files = sorted(share.glob("*/*.json"))
    if not files:
        if os.environ.get("TOCONTROL_DEV_VENV"):
            pytest.fail(f"scripts/dev should have built control_msgs into {sys.prefix}")
        pytest.skip(f"control_msgs is not built into {sys.prefix} (not the pip route)")
    hashes = {}
    for path in files:
        for entry in json.loads(path.read_text())["type_hashes"]:
            hashes[entry["type_name"]] = entry["hash_string"]
    return hashes


def test_built_types_hash_like_the_released_ones():
    built = _built_hashes()
    assert {name: built.get(name) for name in RELEASED} == RELEASED


def test_the_python_types_import():
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTrajectoryControllerState

    assert FollowJointTrajectory.Result.GOAL_TOLERANCE_VIOLATED == -5
    assert hasattr(JointTrajectoryControllerState(), "speed_scaling_factor")
