"""The paper's planar 3R arm against closed-form planar n-link formulas.

The reference is written from absolute link angles ``theta_i = q_1 + ... + q_i``, without
any recursion: ``M = sum_i m_i Jv_i^T Jv_i + I_i Jw_i^T Jw_i`` with ``Jv_i`` the Jacobian of
link i's centre of mass, and the Coriolis/centrifugal forces from the Christoffel symbols of
``M``. The derivatives of ``M`` are taken by complex step, which is exact to rounding (no
subtraction), so the comparison can be tight.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

LENGTHS = np.array([2.5, 2.0, 1.0])
MASSES = np.array([5.0, 4.0, 2.0])
DAMPING = np.array([1.0, 1.0, 1.0])
TAU_MAX = np.array([80.0, 90.0, 8.0])
#: Complex-step size: d f/dx = Im f(x + ih) / h has no cancellation, any tiny h works.
CSTEP = 1e-30
TOL = 1e-10
N_SAMPLES = 20


def _unit(theta):
    return np.array([np.cos(theta), np.sin(theta)])


def _unit_prime(theta):
    return np.array([-np.sin(theta), np.cos(theta)])


def closed_form_mass(q, lengths=LENGTHS, masses=MASSES):
    """Mass matrix of a planar chain of uniform rods, COM mid-link (works for complex q)."""
    n = len(lengths)
    # d theta / d q: theta_k = q_1 + ... + q_k.
    s = np.tril(np.ones((n, n)))
    theta = s @ q
    mass = np.zeros((n, n), dtype=np.result_type(q, float))
    for i in range(n):
        # Centre of mass of link i: sum_{k<i} l_k e(theta_k) + l_i / 2 e(theta_i).
        dcom_dtheta = np.zeros((2, n), dtype=mass.dtype)
        for k in range(i + 1):
            lever = lengths[k] if k < i else lengths[k] / 2
            dcom_dtheta[:, k] = lever * _unit_prime(theta[k])
        jv = dcom_dtheta @ s
        jw = s[i]  # omega_i = theta_i dot
        inertia = masses[i] * lengths[i] ** 2 / 12
        mass = mass + masses[i] * jv.T @ jv + inertia * np.outer(jw, jw)
    return mass


def closed_form_coriolis(q, qd, lengths=LENGTHS, masses=MASSES):
    """``C(q, qd) qd`` from the Christoffel symbols of :func:`closed_form_mass`."""
    n = len(q)
    # dmass[k] = dM/dq_k, by complex step.
    dmass = np.array([
        closed_form_mass(q + 1j * CSTEP * np.eye(n)[k], lengths, masses).imag / CSTEP
        for k in range(n)])
    # c_i = sum_jk (dM_ij/dq_k - 1/2 dM_jk/dq_i) qd_j qd_k (Christoffel, symmetrised in jk).
    return (np.einsum("kij,j,k->i", dmass, qd, qd)
            - 0.5 * np.einsum("ijk,j,k->i", dmass, qd, qd))


def closed_form_point(q, lengths=LENGTHS):
    theta = np.cumsum(q)
    return sum(length * _unit(t) for length, t in zip(lengths, theta, strict=True))


def closed_form_jacobian(q, lengths=LENGTHS):
    theta = np.cumsum(q)
    n = len(q)
    columns = [lengths[k] * _unit_prime(theta[k]) for k in range(n)]
    return np.column_stack([sum(columns[k:]) for k in range(n)])


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(2024)
    return [(rng.uniform(-np.pi, np.pi, 3), rng.uniform(-3.0, 3.0, 3))
            for _ in range(N_SAMPLES)]


# ------------------------------------------------------- the reference itself
def test_reference_matches_textbook_two_link():
    """The closed form reduces to the textbook planar 2R (Spong, Robot Modeling, 7.4)."""
    lengths, masses = np.array([1.3, 0.7]), np.array([2.0, 1.5])
    lc = lengths / 2
    inertia = masses * lengths ** 2 / 12
    q, qd = np.array([0.4, -1.1]), np.array([0.9, -0.6])
    c2, h = np.cos(q[1]), -masses[1] * lengths[0] * lc[1] * np.sin(q[1])
    d12 = masses[1] * (lc[1] ** 2 + lengths[0] * lc[1] * c2) + inertia[1]
    textbook = np.array([
        [masses[0] * lc[0] ** 2 + masses[1] * (lengths[0] ** 2 + lc[1] ** 2
                                               + 2 * lengths[0] * lc[1] * c2)
         + inertia.sum(), d12],
        [d12, masses[1] * lc[1] ** 2 + inertia[1]]])
    coriolis = np.array([h * qd[1] * qd[1] + 2 * h * qd[0] * qd[1], -h * qd[0] ** 2])
    assert_allclose(closed_form_mass(q, lengths, masses), textbook, rtol=1e-14)
    assert_allclose(closed_form_coriolis(q, qd, lengths, masses), coriolis, rtol=1e-12)


# ---------------------------------------------------------- the model's data
def test_model_constants(galicki):
    assert galicki.joint_names == ("joint1", "joint2", "joint3")
    assert galicki.tip_link == "tool"
    assert_allclose([b.mass for b in galicki.bodies], MASSES)
    assert_allclose(galicki.tau_max, TAU_MAX)
    assert_allclose(galicki.damping, DAMPING)
    assert np.all(np.isinf(galicki.q_lower)) and np.all(np.isinf(galicki.q_upper))


def test_summary_reports_planar_task_space(galicki):
    assert galicki.task_axes == (0, 1)
    assert (galicki.n, galicki.m) == (3, 2)
    text = galicki.summary()
    assert "task space xy" in text
    assert "n - m = 1" in text


@pytest.mark.parametrize("declaration", ["", '<?xml version="1.0" encoding="utf-8"?>\n'])
def test_loads_from_string_path_and_file_with_declaration(galicki, tmp_path, declaration):
    """Same model from a path, a str path and XML text, with an encoding declaration too.

    lxml rejects a Python str that carries ``encoding="..."`` (xacro writes one); the loader
    must cope with it both in a file and in a ``robot_description`` string.
    """
    body = default_urdf_path().read_text()
    body = body[body.index("?>") + 2:] if body.lstrip().startswith("<?xml") else body
    text = declaration + body.lstrip()
    path = tmp_path / "arm.urdf"
    path.write_text(text, encoding="utf-8")
    q = np.array([0.3, -0.8, 1.9])
    for source in (path, str(path), text):
        model = load_robot(source)
        assert_allclose(model.mass_matrix(q), galicki.mass_matrix(q), rtol=0, atol=0)


# ------------------------------------------------------ dynamics vs closed form
def test_mass_matrix(galicki, states):
    for q, _ in states:
        assert_allclose(galicki.mass_matrix(q), closed_form_mass(q), rtol=TOL, atol=TOL)


def test_mass_matrix_symmetric_positive_definite(galicki, states):
    for q, _ in states:
        mass = galicki.mass_matrix(q)
        assert_allclose(mass, mass.T, rtol=0, atol=1e-13)
        # The last link alone rotating about joint 3: m l^2 / 3 at any q (a fixed point).
        assert_allclose(mass[2, 2], MASSES[2] * LENGTHS[2] ** 2 / 3, rtol=1e-13)
        assert np.linalg.eigvalsh(mass).min() > 1e-3


def test_bias(galicki, states):
    for q, qd in states:
        expected = closed_form_coriolis(q, qd) + DAMPING * qd
        assert_allclose(galicki.bias(q, qd), expected, rtol=TOL, atol=TOL)


def test_gravity_does_no_work(galicki, states):
    """Horizontal plane: no gravity torque, constant potential energy."""
    for q, qd in states:
        assert_allclose(galicki.bias(q, np.zeros(3)), 0.0, atol=1e-12)
        assert_allclose(galicki.energy(q, qd)[1], 0.0, atol=1e-12)


def test_forward_and_inverse_dynamics(galicki, states):
    rng = np.random.default_rng(5)
    for q, qd in states:
        tau = rng.uniform(-1, 1, 3) * TAU_MAX
        expected = np.linalg.solve(closed_form_mass(q), tau - closed_form_coriolis(q, qd)
                                   - DAMPING * qd)
        qdd = galicki.forward_dynamics(q, qd, tau)
        assert_allclose(qdd, expected, rtol=1e-9, atol=1e-9)
        assert_allclose(galicki.inverse_dynamics(q, qd, qdd), tau, rtol=TOL, atol=1e-9)


def test_kinetic_energy(galicki, states):
    for q, qd in states:
        assert_allclose(galicki.energy(q, qd)[0], 0.5 * qd @ closed_form_mass(q) @ qd,
                        rtol=TOL)


def test_point_and_jacobian(galicki, states):
    for q, _ in states:
        assert_allclose(galicki.point(q), closed_form_point(q), rtol=TOL, atol=TOL)
        assert_allclose(galicki.jacobian(q), closed_form_jacobian(q), rtol=TOL, atol=TOL)


def test_stretched_arm_reaches_sum_of_lengths(galicki):
    assert_allclose(galicki.point(np.zeros(3)), [LENGTHS.sum(), 0.0], atol=1e-15)
    assert_allclose(galicki.reach(), LENGTHS.sum(), rtol=1e-15)


def test_ik_family_spans_both_elbows_and_reaches_the_point(galicki):
    """The closed-form family of the planar 3R: every configuration reaches the point, they
    are distinct modulo full turns, and each end angle that can reach it gives both elbows."""
    from tocontrol_ros.core.robot.ik import ik_family

    p = np.array([2.0, 1.5])
    family = ik_family(galicki, p, 8)
    qs = np.array(family)
    assert qs.shape == (16, 3)  # well inside the workspace: every angle, both elbows
    points = np.array([galicki.point(q) for q in qs])
    assert np.max(np.linalg.norm(points - p, axis=1)) < 1e-9
    ends = qs.sum(axis=1)  # absolute angle of the last link
    for phi in np.linspace(-np.pi, np.pi, 8, endpoint=False):
        assert np.sum(np.abs(np.angle(np.exp(1j * (ends - phi)))) < 1e-9) == 2
    assert np.all(np.abs(qs) <= np.pi + 1e-12)  # continuous joints wrapped into (-pi, pi]
    gaps = np.angle(np.exp(1j * (qs[:, None] - qs[None, :])))
    dist = np.linalg.norm(gaps, axis=2) + np.eye(len(qs))
    assert dist.min() > 1e-6
    # Near the boundary of the workspace only some end angles reach: fewer, still exact.
    edge = np.array([5.3, 0.0])
    near = np.array(ik_family(galicki, edge, 8))
    assert 0 < len(near) < 16
    assert np.max(np.linalg.norm([galicki.point(q) - edge for q in near], axis=1)) < 1e-9
    assert ik_family(galicki, np.array([6.0, 0.0]), 8) == []  # out of reach


@pytest.mark.parametrize("robot", ["galicki", "panda"])
def test_point_and_jacobian_are_point_and_jacobian_to_the_bit(robot, request):
    """One buffered evaluation of both (issue 47: the Newton steps of a replan's inverse
    kinematics) gives what the two calls give, bit for bit, so that a quick motion's end
    configuration did not change."""
    model = request.getfixturevalue(robot)
    rng = np.random.default_rng(11)
    for _ in range(200):
        q = rng.uniform(np.maximum(model.q_lower, -np.pi), np.minimum(model.q_upper, np.pi))
        point, jac = model.point_and_jacobian(q)
        assert point.shape == (model.m,) and jac.shape == (model.m, model.n)
        # CasADi's own calls of P and J (model.point is this buffered evaluation since)
        np.testing.assert_array_equal(point, np.array(model.function("P")(q)).ravel())
        np.testing.assert_array_equal(point, model.point(q))
        np.testing.assert_array_equal(jac, model.jacobian(q))
