"""Pose goals without ROS: the message fields' checks, and the planning service's pose route.

The conversions are table-driven (a frame not accepted, NaN, quaternions near and far from
unit length, a link frame with and without a joint-state start). The service's route runs
with the real planner on the paper's arm (a pose in its plane: two IK solutions, elbow up
and down, each a joint goal) and its published motion is checked by the numeric forward
kinematics; with a fake planner whose motion ends elsewhere, the end-pose check refuses to
publish.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_planning_service import WAIT, FakeClock, FakeOutputs, FakePlanner

from tocontrol_ros.core.robot.kinematics import tip_pose
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.planner_config import config_from_values, planner_limits
from tocontrol_ros.nodes.planning_service import PlanningService
from tocontrol_ros.nodes.pose_goals import (
    PoseGoalError,
    accepted_frames,
    pose_target,
    rotation_from_quaternion,
)
from tocontrol_ros.nodes.requests import PlanRequest

MODEL = load_robot(default_urdf_path())
START_Q = np.array([0.3, 1.0, -0.5])
#: A pose of the tip in the arm's plane (that of a configuration, so reachable).
GOAL_ROTATION, GOAL_POSITION = tip_pose(MODEL, [1.2, -0.4, 0.7])
IDENTITY = (0.0, 0.0, 0.0, 1.0)
STATE = ("state", START_Q, np.zeros(3))


@pytest.mark.parametrize("position, quaternion, frame, start, match", [
    ((1.0, 1.0, 0.0), IDENTITY, "world", STATE, r"'world' is not a frame .* accepted: "
     r"base_link, link1, link2, link3, tool"),
    ((np.nan, 1.0, 0.0), IDENTITY, "base_link", STATE, r"goal_pose.pose.position.x` must "
     "be finite"),
    ((1.0, 1.0, 0.0), (np.nan, 0.0, 0.0, 1.0), "base_link", STATE,
     r"goal_pose.pose.orientation` must be finite"),
    ((1.0, 1.0, 0.0), (0.0, 0.0, 0.0, 0.0), "base_link", STATE, r"not a unit quaternion: "
     r"\|q\| = 0"),
    ((1.0, 1.0, 0.0), (0.0, 0.0, 0.5, 0.5), "base_link", STATE, r"not a unit quaternion: "
     r"\|q\| = 0.707"),
    ((1.0, 1.0, 0.0), IDENTITY, "link2", ("point", np.array([1.0, 1.0])),
     r"'link2' is a moving link"),
])
def test_bad_pose_fields_are_refused_naming_them(position, quaternion, frame, start, match):
    with pytest.raises(PoseGoalError, match=match):
        pose_target(position, quaternion, frame, MODEL, "base_link", start, "goal_pose")


def test_a_nearly_unit_quaternion_is_normalised_as_tf2_does():
    q = np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)]) * 1.004  # |q|^2 = 1.008
    target = pose_target((1.0, 1.0, 0.0), q, "base_link", MODEL, "base_link", STATE, "p")
    np.testing.assert_allclose(target.rotation,
                               Rotation.from_rotvec([0, 0, 0.6]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(target.quaternion, q / np.linalg.norm(q), atol=1e-12)


def test_rotation_from_quaternion_agrees_with_scipy():
    rng = np.random.default_rng(0)
    for q in Rotation.random(5, random_state=1).as_quat():
        q = q * rng.uniform(0.996, 1.004)
        np.testing.assert_allclose(rotation_from_quaternion(*q, name="q"),
                                   Rotation.from_quat(q).as_matrix(), atol=1e-12)


def test_a_pose_in_a_link_frame_is_taken_at_the_start_configuration():
    """The tool's frame at the start, moved 0.1 m along its x: the base-frame pose."""
    target = pose_target((0.1, 0.0, 0.0), IDENTITY, "tool", MODEL, "base_link", STATE, "p")
    rot, pos = tip_pose(MODEL, START_Q)
    np.testing.assert_allclose(target.position, pos + rot @ [0.1, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(target.rotation, rot, atol=1e-12)
    assert "link2" in accepted_frames(MODEL, "base_link")


def final(out, req) -> dict:
    """The final status of ``req`` (not ``accepted`` nor the IK's ``candidates``)."""
    events = [e for e in out.statuses() if e[3].get("request_id") == req.id
              and e[3]["event"] not in ("accepted", "candidates")]
    assert len(events) == 1, events
    _, level, message, values = events[0]
    return {"level": level, "event": values["event"], "message": message, "values": values}


class Outputs(FakeOutputs):
    """The fake outputs, for real sampled trajectories too."""

    def trajectory(self, sample, stamp_ns):
        self._add("trajectory", len(sample.t), stamp_ns)
        return ("trajectory", stamp_ns)

    def path(self, sample, stamp_ns):
        self._add("path", len(sample.t))
        return ("path", len(sample.t), stamp_ns)


def _service(planner_factory=None, **params):
    config = config_from_values(params, task_dim=MODEL.m)
    out = Outputs()
    service = PlanningService(MODEL, planner_limits(config, MODEL), config, "base_link", out,
                              None, FakeClock().clock(), planner_factory=planner_factory)
    service.start()
    assert service.ready.wait(120.0), "no warm-up"
    return service, out


def _pose_request(service, rotation, position) -> PlanRequest:
    pose = pose_target(position, Rotation.from_matrix(rotation).as_quat(), "base_link",
                       MODEL, "base_link", STATE, "goal_pose")
    return PlanRequest(service.next_id(), "goal_pose", STATE, pose.position[:2],
                       service.config, target_pose=pose)


def test_a_pose_goal_publishes_the_least_time_motion_of_its_ik_solutions_reaching_the_pose():
    service, out = _service()
    try:
        req = _pose_request(service, GOAL_ROTATION, GOAL_POSITION)
        service.submit(req)
        assert req.done.wait(120.0), "no outcome"
        outcome = final(out, req)
        assert outcome["event"] == "solved", outcome["message"]
        values = outcome["values"]
        assert values["ik_solutions"] == 2 and values["pose_candidates"] == 2
        assert "pose reached within" in outcome["message"]
        # The published motion, checked here by the per-configuration kinematics.
        sample = req.result.trajectory.sample(0.01)
        rot, pos = tip_pose(MODEL, sample.q[-1])
        assert np.linalg.norm(pos - GOAL_POSITION) <= 1e-4
        assert np.linalg.norm(Rotation.from_matrix(rot.T @ GOAL_ROTATION).as_rotvec()) <= 1e-3
        assert values["position_error"] <= 1e-4 and values["orientation_error"] <= 1e-3
        np.testing.assert_allclose(sample.q[0], START_Q, atol=1e-9)
        assert req.result.certificate.passed
        assert out.kinds().count("trajectory") == 1
    finally:
        service.stop()


def test_an_unreachable_pose_fails_with_the_closest_distance_and_publishes_nothing():
    service, out = _service(FakePlanner)
    try:
        tilted = Rotation.from_rotvec([0.3, 0.0, 0.0]).as_matrix() @ GOAL_ROTATION
        req = _pose_request(service, tilted, GOAL_POSITION)
        service.submit(req)
        assert req.done.wait(WAIT)
        outcome = final(out, req)
        assert outcome["event"] == "failed" and outcome["level"] == "ERROR"
        assert "unreachable within the joint limits" in outcome["message"]
        assert "0.3 rad away" in outcome["message"]
        assert "trajectory" not in out.kinds()
    finally:
        service.stop()


def test_a_motion_whose_end_misses_the_pose_is_not_published():
    """The fake planner's motions end at q = 0, not at the pose: the check refuses them."""
    service, out = _service(FakePlanner)
    try:
        service.planner.hold.set()
        service.planner.gate.set()
        req = _pose_request(service, GOAL_ROTATION, GOAL_POSITION)
        service.submit(req)
        assert req.done.wait(WAIT)
        outcome = final(out, req)
        assert outcome["event"] == "failed", outcome["message"]
        assert "misses the pose" in outcome["message"] and "nothing published" in \
            outcome["message"]
        assert outcome["values"]["position_error"] > 1.0
        assert "trajectory" not in out.kinds()
    finally:
        service.stop()


def test_a_start_at_rest_on_the_pose_has_nothing_to_plan():
    service, out = _service(FakePlanner)
    try:
        rotation, position = tip_pose(MODEL, START_Q)
        req = _pose_request(service, rotation, position)
        service.submit(req)
        assert req.done.wait(WAIT)
        outcome = final(out, req)
        assert outcome["event"] == "solved" and outcome["level"] == "OK"
        assert "nothing to plan: the start at rest is on the pose" in outcome["message"]
        assert "trajectory" not in out.kinds()
    finally:
        service.stop()


def test_the_end_pose_check_agrees_with_the_ik_residuals():
    """Two implementations of the errors (the check's, the IK's) on random configurations."""
    from tocontrol_ros.core.robot.ik import pose_errors
    from tocontrol_ros.nodes.pose_goals import PoseTarget, end_pose_errors

    rng = np.random.default_rng(4)
    goal = PoseTarget(np.array([1.0, 2.0, 0.0]), Rotation.from_rotvec([0, 0, 2.9]).as_matrix(),
                      "base_link")
    for q in rng.uniform(-np.pi, np.pi, size=(10, 3)):
        pos_err, ang_err = end_pose_errors(MODEL, q, goal)
        ref_pos, ref_ang = pose_errors(MODEL, q, goal.position, goal.rotation)
        assert pos_err == pytest.approx(ref_pos[0], abs=1e-12)
        assert ang_err == pytest.approx(ref_ang[0], abs=1e-9)


@pytest.mark.slow  # the Panda's collision model (seconds), its IK and exact distances
def test_a_pose_whose_ik_solutions_touch_an_obstacle_is_planned_to_a_clear_one():
    """A ball on the forearm of the pose's only IK solution (``pose_ik_seeds`` 1: the start's).

    The solution is refused as a target in collision; the search with the scene finds
    another, clear by the margin, and the planner is asked to plan to it (a fake planner:
    whose motions fail: what is tested is the target it is given).
    """
    pytest.importorskip("coal")
    from skip_policy import panda_srdf, panda_urdf
    from test_planning_service import FakeArm, FakeResult

    from tocontrol_ros.core.geometry.collision import body_frames, collision_model
    from tocontrol_ros.core.geometry.scene import scene_from_dict
    from tocontrol_ros.core.robot.ik import pose_errors
    from tocontrol_ros.nodes.pose_goals import PoseGoals

    urdf = panda_urdf()
    panda = load_robot(urdf, tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
    rotation, position = tip_pose(panda, q0 + np.array([1.2, 0.3, 0.0, 0.3, 0.0, -0.2, 0.0]))
    config = config_from_values({"pose_ik_seeds": 1}, task_dim=panda.m)
    out = Outputs()
    service = PlanningService(panda, planner_limits(config, panda), config, "panda_link0",
                              out, FakeArm(), FakeClock().clock(), planner_factory=FakePlanner)
    start = ("state", q0, np.zeros(7))
    pose = pose_target(position, Rotation.from_matrix(rotation).as_quat(), "panda_link0",
                       panda, "panda_link0", start, "goal_pose")
    req = PlanRequest(service.next_id(), "goal_pose", start, pose.position, config,
                      target_pose=pose)
    [first] = PoseGoals(service).solutions(req)  # the pose's IK solution from the start
    frames = body_frames(panda, first[None])[1][0]
    forearm = 0.5 * (frames[3] + frames[5])  # between the elbow and the wrist
    service.collision = collision_model(panda, urdf, panda_srdf(), scene_from_dict(
        {"obstacles": [{"name": "ball", "type": "sphere", "radius": 0.05,
                        "position": forearm.tolist()}]}))
    assert service.collision.clearance(first).minimum < 0.0
    assert service.collision.clearance(q0).minimum > service.collision.margin
    service.start()
    try:
        assert service.ready.wait(WAIT), "no warm-up"
        # The fake's motions (a 3-joint arm's) fail: the request ends without a motion.
        service.planner.first_result = FakeResult(T=2.0, success=False, message="fake")
        service.planner.optimum = FakeResult(T=1.5, success=False, message="fake")
        service.planner.hold.set()
        service.planner.gate.set()
        service.submit(req)
        assert req.done.wait(6 * WAIT), "no outcome"
        outcome = final(out, req)
        assert "no certified motion to the pose's IK solutions" in outcome["message"]
        assert outcome["values"]["ik_solutions"] == 2 and outcome["values"]["ik_refused"] == 1
        [problem] = service.planner.solved  # the clear solution, planned to
        q = problem.target.value[:7]
        assert service.collision.clearance(q).minimum >= service.collision.margin
        pos_err, ang_err = pose_errors(panda, q, position, rotation)
        assert pos_err[0] < 1e-6 and ang_err[0] < 1e-6
    finally:
        service.planner.gate.set()
        service.stop()
