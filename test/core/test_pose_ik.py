"""Inverse kinematics of poses (position and orientation): ``ik_pose`` and ``pose_errors``.

Every solution is checked by an independent route: the numeric forward kinematics of
``kinematics.tip_pose`` (one configuration at a time, its own rotation code) against the
pose, and the joint limits. Poses come from random configurations (reachable by
construction); an unreachable one is far outside the arm's reach.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from skip_policy import panda_urdf

from tocontrol_ros.core.robot.ik import ik_pose, pose_errors
from tocontrol_ros.core.robot.kinematics import tip_pose
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot


@pytest.fixture(scope="module")
def panda():
    return load_robot(str(panda_urdf()), tip_link="panda_hand")


def _check_reaches(model, sols, position, rotation, tol=1e-7):
    assert sols
    for q in sols:
        rot, pos = tip_pose(model, q)
        assert np.linalg.norm(pos - position) < tol
        angle = np.linalg.norm(Rotation.from_matrix(rot.T @ rotation).as_rotvec())
        assert angle < tol
        assert np.all(q >= model.q_lower - 1e-12) and np.all(q <= model.q_upper + 1e-12)


def test_panda_poses_are_reached_within_the_limits_from_many_seeds(panda):
    rng = np.random.default_rng(7)
    lo, hi = panda.q_lower, panda.q_upper
    for _ in range(5):
        rotation, position = tip_pose(panda, rng.uniform(lo, hi))
        sols, pos_err, ang_err = ik_pose(panda, position, rotation,
                                         rng.uniform(lo, hi, size=(16, panda.n)))
        _check_reaches(panda, sols, position, rotation)
        assert pos_err < 1e-8 and ang_err < 1e-8
        # Distinct: a redundant arm's solutions differ (the self-motion manifold).
        for i, a in enumerate(sols):
            for b in sols[:i]:
                assert np.linalg.norm(a - b) > 1e-6


def test_the_planners_limits_are_kept(panda):
    """Narrower limits (``limit_margin``) than the model's: solutions inside them."""
    rng = np.random.default_rng(3)
    middle, half = (panda.q_lower + panda.q_upper) / 2, (panda.q_upper - panda.q_lower) / 2
    lower, upper = middle - 0.8 * half, middle + 0.8 * half
    rotation, position = tip_pose(panda, rng.uniform(lower, upper))
    sols, _, _ = ik_pose(panda, position, rotation, rng.uniform(lower, upper, size=(16, 7)),
                         lower, upper)
    assert sols
    for q in sols:
        assert np.all(q >= lower) and np.all(q <= upper)


def test_pose_errors_agree_with_the_per_configuration_kinematics(panda):
    rng = np.random.default_rng(11)
    qs = rng.uniform(panda.q_lower, panda.q_upper, size=(6, 7))
    rotation = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    position = np.array([0.3, 0.1, 0.5])
    pos_err, ang_err = pose_errors(panda, qs, position, rotation)
    for q, pe, ae in zip(qs, pos_err, ang_err, strict=True):
        rot, pos = tip_pose(panda, q)
        assert pe == pytest.approx(np.linalg.norm(pos - position), abs=1e-12)
        # The angle of R^T R_goal from its trace: a second formula for the same angle.
        cos = np.clip((np.trace(rot.T @ rotation) - 1) / 2, -1, 1)
        assert ae == pytest.approx(np.arccos(cos), abs=1e-6)


def test_an_unreachable_pose_gives_no_solution_and_how_far_the_closest_is(panda):
    rng = np.random.default_rng(0)
    sols, pos_err, ang_err = ik_pose(panda, [2.0, 0.0, 0.5], np.eye(3),
                                     rng.uniform(panda.q_lower, panda.q_upper, size=(8, 7)))
    assert sols == []
    assert pos_err > 0.5  # the Panda reaches about 0.86 m from its shoulder


def test_planar_arm_poses_in_its_plane_both_elbows():
    model = load_robot(default_urdf_path())
    rotation, position = tip_pose(model, [1.2, -0.4, 0.7])
    rng = np.random.default_rng(0)
    sols, _, _ = ik_pose(model, position, rotation, rng.uniform(-np.pi, np.pi, (16, 3)))
    _check_reaches(model, sols, position, rotation)
    assert len(sols) == 2  # elbow up and elbow down: a 3R has no more for a planar pose
    assert any(np.allclose(q, [1.2, -0.4, 0.7], atol=1e-7) for q in sols)
    # A pose tilted out of the plane is not reachable by a planar arm.
    tilted = Rotation.from_rotvec([0.2, 0.0, 0.0]).as_matrix() @ rotation
    sols, _, ang_err = ik_pose(model, position, tilted, rng.uniform(-np.pi, np.pi, (8, 3)))
    assert sols == [] and ang_err == pytest.approx(0.2, abs=1e-6)
