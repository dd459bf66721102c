"""The planner's goals pass the checks of a default-configured Jazzy joint_trajectory_controller.

``jtc_checks`` is the JTC's goal validation written from its documentation; the planner's
trajectory, made into a goal for a controller without an effort interface, must pass it, and
goals that break one rule are refused with the code a JTC's documentation gives that class.
No node is spun here.
"""

import copy
import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance

from tocontrol_ros.core import Problem, SolverOptions, plan
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.problem import point
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes import jtc_checks as jtc
from tocontrol_ros.nodes.controller_client import controller_goal

JTC = jtc.ControllerOptions()  # a default Jazzy JTC: no effort, whole goals, end at rest
NOW = 1000.0


@pytest.fixture(scope="module")
def published():
    """The planner's ``~/trajectory`` of the paper's example (one start), stamped at NOW."""
    model = load_robot(default_urdf_path())
    result = plan(Problem(model, point(PAPER_START), point(PAPER_TARGET), k=4),
                  SolverOptions(starts=1, candidates=1))
    assert result.success, result.message
    sample = result.trajectory.sample(0.01)
    return conv.trajectory_msg(sample, model.joint_names, "base_link",
                               conv.time_from_seconds(NOW - 5.0))


def test_the_planners_goal_is_accepted_by_a_default_jtc(published):
    goal = controller_goal(published, effort=False, goal_time_tolerance=1.0)
    check = jtc.check_goal(goal.trajectory, published.joint_names, NOW, JTC)
    assert check.accepted, check.reason
    last = goal.trajectory.points[-1]
    assert list(last.velocities) == [0.0] * 3 and list(last.accelerations) == [0.0] * 3
    assert goal.trajectory.header.stamp == Time()
    assert all(len(p.effort) == 0 for p in goal.trajectory.points)
    # The published message itself is not modified; its end is at rest to 1e-6 rad/s only.
    assert np.max(np.abs(published.points[-1].velocities)) < 1e-6
    assert len(published.points[-1].effort) == 3


def test_a_replan_keeps_its_future_hand_off_stamp(published):
    """A replan is stamped with its hand-off, ahead of the controller's clock: the goal keeps
    that stamp (the JTC joins it to the running trajectory there, issue 52), and a default
    JTC accepts it; a stamp not ahead of the clock becomes zero (start now)."""
    stamp_ns = conv.nanoseconds(published.header.stamp)
    ahead = controller_goal(published, now_ns=stamp_ns - 1)
    assert ahead.trajectory.header.stamp == published.header.stamp
    check = jtc.check_goal(ahead.trajectory, published.joint_names, NOW - 5.0 - 1e-3, JTC)
    assert check.accepted, check.reason
    for now_ns in (stamp_ns, stamp_ns + 1):
        assert controller_goal(published, now_ns=now_ns).trajectory.header.stamp == Time()


def test_the_published_trajectory_as_is_would_be_refused(published):
    # Why the goal is rewritten: effort without an effort interface, and a stamp in the past
    # (or an end velocity within 1e-6 of zero but not zero).
    check = jtc.check_goal(published, published.joint_names, NOW, JTC)
    assert check.code == jtc.INVALID_GOAL and "effort" in check.reason
    with_effort = jtc.ControllerOptions(effort_interface=True)
    old = jtc.check_goal(published, published.joint_names, NOW, with_effort)
    assert old.code == jtc.OLD_HEADER_TIMESTAMP, old.reason
    goal = controller_goal(published, effort=True)
    assert jtc.check_goal(goal.trajectory, published.joint_names, NOW, with_effort).accepted


def _names(traj):
    traj.joint_names = ["joint1", "joint2", "nowhere"]


def _short(traj):
    traj.joint_names = ["joint1", "joint2"]
    for p in traj.points:
        for field in ("positions", "velocities", "accelerations"):
            setattr(p, field, list(getattr(p, field))[:2])


def _duplicate(traj):
    traj.joint_names = ["joint1", "joint1", "joint3"]


def _empty_names(traj):
    traj.joint_names = []


def _time_order(traj):
    traj.points[5].time_from_start = traj.points[4].time_from_start


def _end_velocity(traj):
    traj.points[-1].velocities = [0.0, 1e-9, 0.0]


def _effort(traj):
    traj.points[3].effort = [1.0, 2.0, 3.0]


def _past(traj):
    traj.header.stamp = conv.time_from_seconds(NOW - 100.0)


def _size(traj):
    traj.points[2].velocities = [0.0]


def _nan(traj):
    traj.points[7].positions = [0.0, math.nan, 0.0]


def _no_points(traj):
    traj.points = []


@pytest.mark.parametrize("change, code, match", [
    (_names, jtc.INVALID_JOINTS, "not the controller's joints"),
    (_short, jtc.INVALID_JOINTS, "lacks joints"),
    (_duplicate, jtc.INVALID_JOINTS, "duplicates"),
    (_empty_names, jtc.INVALID_JOINTS, "names no joints"),
    (_time_order, jtc.INVALID_GOAL, "not strictly increasing: point 5"),
    (_end_velocity, jtc.INVALID_GOAL, "last point's velocity is not zero: joint2"),
    (_effort, jtc.INVALID_GOAL, "point 3 has effort"),
    (_past, jtc.OLD_HEADER_TIMESTAMP, "before now"),
    (_size, jtc.INVALID_GOAL, "point 2: velocities has 1 values"),
    (_nan, jtc.INVALID_GOAL, "point 7: positions is not finite"),
    (_no_points, jtc.INVALID_GOAL, "no points"),
])
def test_bad_goals_are_refused_with_their_code(published, change, code, match):
    goal = controller_goal(published)
    traj = copy.deepcopy(goal.trajectory)
    change(traj)
    check = jtc.check_goal(traj, published.joint_names, NOW, JTC)
    assert (check.code, jtc.CODE_NAMES[check.code]) == (code, jtc.CODE_NAMES[code])
    assert match in check.reason


def test_a_tolerance_for_an_unknown_joint_is_refused(published):
    goal = controller_goal(published)
    check = jtc.check_goal(goal.trajectory, published.joint_names, NOW, JTC,
                           [JointTolerance(name="elbow", position=0.1)])
    assert check.code == jtc.INVALID_JOINTS and "elbow" in check.reason


def test_tolerances_combine_goal_and_controller_defaults():
    options = jtc.ControllerOptions(path_tolerance=0.2, goal_tolerance=0.05, goal_time=2.0)
    goal = FollowJointTrajectory.Goal(
        path_tolerance=[JointTolerance(name="joint2", position=0.1, velocity=-1.0),
                        JointTolerance(name="joint3", position=-1.0)],
        goal_tolerance=[JointTolerance(name="joint1", position=0.01)])
    tol = jtc.resolve_tolerances(goal, ["joint1", "joint2", "joint3"], options)
    # > 0 sets, 0 keeps the default, < 0 removes the check (inf)
    np.testing.assert_array_equal(tol.path[:, 0], [0.2, 0.1, np.inf])
    np.testing.assert_array_equal(tol.path[:, 1], [np.inf] * 3)
    np.testing.assert_array_equal(tol.goal[:, 0], [0.01, 0.05, 0.05])
    np.testing.assert_array_equal(tol.goal[:, 1], [0.01] * 3)  # stopped velocity
    assert tol.goal_time == 2.0
    goal.goal_time_tolerance = conv.duration_from_seconds(0.5)
    assert jtc.resolve_tolerances(goal, ["joint1", "joint2", "joint3"], options).goal_time == 0.5
    assert jtc.resolve_tolerances(goal, ["joint1", "joint2", "joint3"]).path[0, 0] == np.inf


def test_violations_name_the_joint_and_the_component():
    goal = FollowJointTrajectory.Goal(
        path_tolerance=[JointTolerance(name="joint2", position=0.1)])
    joints = ["joint1", "joint2", "joint3"]
    tol = jtc.resolve_tolerances(goal, joints)
    zero = np.zeros(3)
    assert jtc.path_violation(tol, np.array([5.0, 0.05, 0.0]), zero, zero, joints) is None
    text = jtc.path_violation(tol, np.array([0.0, -0.2, 0.0]), zero, zero, joints)
    assert text == "joint2 position error -0.2 exceeds its tolerance 0.1"
    moving = jtc.goal_reached(tol, zero, np.array([0.0, 0.0, 0.02]), zero, joints)
    assert moving == "joint3 velocity error 0.02 exceeds its tolerance 0.01"
    assert jtc.goal_reached(tol, zero, np.full(3, 0.005), zero, joints) is None
