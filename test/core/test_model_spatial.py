"""Spatial chains against Pinocchio: Panda, UR5 and a revolute-prismatic-revolute chain.

Pinocchio's ``nle`` and ``aba`` leave out the URDF's viscous damping (it only stores it in
``model.damping``), while our bias forces include ``D qd``; the comparisons add it.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

pin = pytest.importorskip("pinocchio")

#: Both sides are double-precision recursive algorithms on the same numbers.
RTOL = 1e-9
N_SAMPLES = 10


def _pinocchio_model(spec: dict):
    """Pinocchio's reduced model of a robot spec: same locked joints, same gravity."""
    source, kwargs = spec["source"], spec["kwargs"]
    full = (pin.buildModelFromXML(source) if isinstance(source, str)
            else pin.buildModelFromUrdf(str(source)))
    q_ref = pin.neutral(full)
    ids = []
    for name, value in kwargs["locked_joints"].items():
        jid = full.getJointId(name)
        q_ref[full.joints[jid].idx_q] = value
        ids.append(jid)
    model = pin.buildReducedModel(full, ids, q_ref) if ids else full
    model.gravity.linear = np.asarray(kwargs["gravity"], dtype=float)
    return model


@pytest.fixture(scope="module", params=["panda", "ur5", "xarm7", "rpr"])
def case(request, robot_specs):
    """(our model, Pinocchio model and data, tip frame id, random states) of one robot."""
    ours = request.getfixturevalue(request.param)
    spec = robot_specs[request.param]
    model = _pinocchio_model(spec)
    assert model.nq == model.nv == ours.n, "Pinocchio and we disagree on the chain"
    rng = np.random.default_rng(7)
    states = []
    for _ in range(N_SAMPLES):
        q = rng.uniform(ours.q_lower, ours.q_upper)
        qd = rng.uniform(-1.5, 1.5, ours.n)
        tau = rng.uniform(-0.5, 0.5, ours.n) * ours.tau_max
        states.append((q, qd, tau))
    frame = model.getFrameId(spec["kwargs"]["tip_link"])
    assert frame < model.nframes
    return ours, model, model.createData(), frame, states


def _close(actual, desired):
    scale = max(1.0, float(np.max(np.abs(desired))))
    assert_allclose(actual, desired, rtol=RTOL, atol=RTOL * scale)


def test_chain_matches(case):
    ours, model, _, _, _ = case
    assert list(ours.joint_names) == list(model.names)[1:]
    assert ours.task_axes == (0, 1, 2)
    assert_allclose(ours.tau_max, model.effortLimit)
    assert_allclose(ours.q_lower, model.lowerPositionLimit)
    assert_allclose(ours.q_upper, model.upperPositionLimit)
    assert_allclose(ours.qd_max, model.velocityLimit)
    assert_allclose(ours.damping, model.damping)


def test_mass_matrix(case):
    ours, model, data, _, states = case
    for q, _, _ in states:
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T  # crba fills the upper triangle only
        _close(ours.mass_matrix(q), mass)


def test_diagonal_inertia_of_several_configurations(case):
    """One mapped call gives each configuration's inertia diagonal (Pinocchio's CRBA)."""
    ours, model, data, _, states = case
    qs = np.array([q for q, _, _ in states])
    diagonal = ours.diagonal_inertia(qs)
    assert diagonal.shape == (len(qs), ours.n)
    for q, row in zip(qs, diagonal, strict=True):
        _close(row, np.diag(pin.crba(model, data, q)))
    assert ours.diagonal_inertia(qs[0]).shape == (1, ours.n)  # one configuration: one row


def test_bias(case):
    ours, model, data, _, states = case
    for q, qd, _ in states:
        _close(ours.bias(q, qd), pin.nle(model, data, q, qd) + ours.damping * qd)


def test_forward_dynamics(case):
    ours, model, data, _, states = case
    for q, qd, tau in states:
        _close(ours.forward_dynamics(q, qd, tau),
               pin.aba(model, data, q, qd, tau - ours.damping * qd))


def test_inverse_dynamics(case):
    ours, model, data, _, states = case
    for q, qd, _ in states:
        qdd = np.linspace(-2.0, 2.0, ours.n)
        _close(ours.inverse_dynamics(q, qd, qdd),
               pin.rnea(model, data, q, qd, qdd) + ours.damping * qd)


def test_tip_point_and_jacobian(case):
    ours, model, data, frame, states = case
    for q, _, _ in states:
        pin.framesForwardKinematics(model, data, q)
        _close(ours.point(q), data.oMf[frame].translation)
        jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)
        _close(ours.jacobian(q), jac[:3])


def test_damping_is_in_our_bias_only(case):
    """Guards the comparison above: a model with damping must differ from plain ``nle``."""
    ours, model, data, _, states = case
    if not np.any(ours.damping):
        pytest.skip("no damping in this URDF")
    q, qd, _ = states[0]
    gap = ours.bias(q, qd) - pin.nle(model, data, q, qd)
    assert_allclose(gap, ours.damping * qd, rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(gap)) > 1e-4


def test_self_check_passes(case):
    ours = case[0]
    report = ours.check_dynamics(seed=3, samples=3)
    assert report.splitlines()[0].endswith(": OK"), report


@pytest.mark.parametrize("name", ["rpr", "panda"])
def test_tip_poses_at_once_equal_one_by_one(name, request):
    """The batched forward kinematics (messages) against the per-configuration one."""
    from tocontrol_ros.core.robot.kinematics import tip_pose, tip_poses

    model = request.getfixturevalue(name)
    rng = np.random.default_rng(7)
    lo = np.where(np.isfinite(model.q_lower), model.q_lower, -np.pi)
    hi = np.where(np.isfinite(model.q_upper), model.q_upper, np.pi)
    q = rng.uniform(lo, hi, (20, model.n))
    rots, positions = tip_poses(model, q)
    for k in range(len(q)):
        rot, pos = tip_pose(model, q[k])
        np.testing.assert_allclose(rots[k], rot, atol=1e-12)
        np.testing.assert_allclose(positions[k], pos, atol=1e-12)
    # ...and against the model's own (CasADi) kinematics, where the task space is xyz.
    if model.m == 3:
        np.testing.assert_allclose(positions, [model.point(qk) for qk in q], atol=1e-9)


@pytest.mark.parametrize("name", ["panda", "ur5", "xarm7"])
def test_ik_family_reaches_the_point_within_the_limits(name, request):
    """The batched Levenberg-Marquardt of ``ik_family`` on a redundant or 6-joint arm: every
    configuration returned reaches the point and lies within the URDF limits, and most
    seeds find one."""
    from tocontrol_ros.core.robot.ik import IK_TOL, _lm_batch, ik_family

    model = request.getfixturevalue(name)
    rng = np.random.default_rng(3)
    lo = np.where(np.isfinite(model.q_lower), model.q_lower, -np.pi)
    hi = np.where(np.isfinite(model.q_upper), model.q_upper, np.pi)
    found = 0
    for _ in range(4):
        p = model.point(lo + rng.uniform(0.1, 0.9, model.n) * (hi - lo))
        family = ik_family(model, p, 8, rng=np.random.default_rng(0))
        for q in family:
            assert np.linalg.norm(model.point(q) - p) < IK_TOL
            assert np.all(q >= model.q_lower - 1e-9) and np.all(q <= model.q_upper + 1e-9)
        q, err = _lm_batch(model, p, np.array([rng.uniform(lo, hi) for _ in range(8)]))
        found += int(np.sum(err < IK_TOL))
    assert found >= 20, found
