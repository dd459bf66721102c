"""The maximum principle's pieces: control law (15), canonical system, RK4 step Jacobians."""

import casadi as ca
import numpy as np
import pytest

from tocontrol_ros.core.indirect.pmp import CanonicalSystem, control_law
from tocontrol_ros.core.types.law import LawParams


@pytest.mark.parametrize("k", [1, 2, 4, 16])
def test_control_law_is_on_the_boundary_and_keeps_signs(k):
    rng = np.random.default_rng(k)
    s = rng.normal(size=(3, 50))
    u = control_law(s, k)
    np.testing.assert_allclose(np.sum(u ** (2 * k), axis=0), 1.0, rtol=1e-12)
    assert np.all(np.sign(u) == np.sign(s))
    assert np.all(np.abs(u) < 1)
    # Homogeneous of degree 0 in S (a positive factor on psi changes nothing).
    np.testing.assert_allclose(control_law(7.3 * s, k), u, rtol=1e-12)


@pytest.mark.parametrize("k", [1, 3, 8])
def test_control_law_maximises_the_hamiltonian_term(k):
    # u* maximises S.u on sum u^2k <= 1: compare with random points of the boundary.
    rng = np.random.default_rng(0)
    s = rng.normal(size=3)
    best = s @ control_law(s, k)
    v = rng.normal(size=(3, 2000))
    v /= np.sum(v ** (2 * k), axis=0) ** (1 / (2 * k))
    assert np.max(s @ v) <= best + 1e-12


def test_control_law_k1_is_normalised_s_and_tends_to_sign():
    s = np.array([0.3, -2.0, 0.01])
    np.testing.assert_allclose(control_law(s, 1), s / np.linalg.norm(s), rtol=1e-14)
    np.testing.assert_allclose(control_law(s, 1000), np.sign(s), atol=0.02)


def test_smoothing_is_inside_the_set_and_vanishes_with_delta():
    s = np.array([[1.0, 1e-4, -0.5]]).T
    exact = control_law(s, 4)
    for delta in (1e-2, 1e-4, 1e-6):
        u = control_law(s, 4, delta)
        assert np.sum(u ** 8) < 1
    np.testing.assert_allclose(control_law(s, 4, 1e-9), exact, rtol=1e-6)


def test_symbolic_and_numeric_laws_agree():
    s_sym = ca.SX.sym("s", 3)
    fun = ca.Function("u", [s_sym], [control_law(s_sym, 4.0, 1e-3)])
    s = np.array([0.2, -1.5, 0.7])
    np.testing.assert_allclose(np.array(fun(s)).ravel(), control_law(s, 4.0, 1e-3),
                               rtol=1e-14)


def test_canonical_system_is_hamiltonian(galicki):
    """xd = dH/dpsi and psid = -dH/dx, with H evaluated at u*(x, psi) (envelope theorem)."""
    cs = CanonicalSystem(galicki)
    par = LawParams(4.0, 0.0, 1.0).array()
    rng = np.random.default_rng(2)
    z = rng.normal(size=12) * 0.5
    f, _, _, _ = cs.pointwise()(z, par)
    ham = ca.Function("H", [cs.z, cs.par], [cs.ham])
    eps = 1e-6
    grad = np.array([(float(ham(z + eps * e, par)) - float(ham(z - eps * e, par))) / (2 * eps)
                     for e in np.eye(12)])
    f = np.array(f).ravel()
    np.testing.assert_allclose(f[:6], grad[6:], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(f[6:], -grad[:6], rtol=1e-6, atol=1e-7)


def test_stagewise_step_jacobian_equals_the_whole_step_one(galicki):
    """The two ways of differentiating an RK4 step (large and small models) agree."""
    cs = CanonicalSystem(galicki)
    rng = np.random.default_rng(0)
    z = rng.normal(size=(12, 5)) * 0.3
    h = np.full((1, 5), 0.01)
    par = LawParams(4.0, 1e-3, 1.0).array()
    cs.stagewise = False
    z1, a1, b1 = cs.step_batch(z, h, par)
    cs.stagewise = True
    z2, a2, b2 = cs.step_batch(z, h, par)
    np.testing.assert_allclose(z2, z1, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(a2, a1, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(b2, b1, rtol=1e-11, atol=1e-11)
    # ...and both agree with finite differences of the plain step.
    eps = 1e-7
    col = 0
    for j in range(12):
        dz = np.zeros((12, 1))
        dz[j] = eps
        plus = cs.step_batch(z[:, [col]] + dz, h[:, [col]], par, False)[0]
        minus = cs.step_batch(z[:, [col]] - dz, h[:, [col]], par, False)[0]
        np.testing.assert_allclose((plus - minus).ravel() / (2 * eps), a1[col][:, j],
                                   rtol=1e-5, atol=1e-6)


def test_chunked_evaluations_do_not_depend_on_the_chunk(galicki):
    """pointwise_batch and step_rows give each row the same values whatever the row count
    (chunks of 16, 64 and 256 rows, the last one padded)."""
    system = CanonicalSystem(galicki)
    rng = np.random.default_rng(5)
    z = rng.normal(scale=0.5, size=(300, 12))
    h = rng.uniform(1e-3, 1e-2, size=300)
    par = LawParams(4.0, 1e-3, 1.0).array()
    f_all, u_all, s_all, h_all = system.pointwise_batch(z, par)
    step_all = system.step_rows(z, h, par)
    for count in (1, 16, 17, 64, 65, 257):
        f, u, s, ham = system.pointwise_batch(z[:count], par)
        assert f.shape == (count, 12) and u.shape == (count, 3) and ham.shape == (count,)
        np.testing.assert_array_equal(f, f_all[:count])
        np.testing.assert_array_equal(ham, h_all[:count])
        np.testing.assert_array_equal(system.step_rows(z[:count], h[:count], par),
                                      step_all[:count])
    one = np.array(system.pointwise()(z[7], par)[0]).ravel()  # the plain function
    np.testing.assert_allclose(f_all[7], one, rtol=1e-14, atol=1e-14)
