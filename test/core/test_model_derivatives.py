"""CasADi derivatives of the model against central finite differences.

The solver differentiates ``f(x, u)`` once (linearisation, costate equations) and twice
(the costates' own Jacobian), and ``P(q)``, ``J(q)`` for the boundary conditions. Each
derivative is compared with central differences of the next-lower one, with a step that
balances truncation (h^2) against rounding (eps / h).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

#: Central differences with H ~ eps^(1/3) are good to ~1e-8 relative; leave margin.
REL_TOL = 1e-6
H = 1e-5
N_POINTS = 3


def _central_jacobian(func, x, h=H):
    """Jacobian of ``func`` (array -> array) at ``x`` by central differences, (out, in)."""
    columns = []
    for k in range(x.size):
        step = h * max(1.0, abs(x[k]))
        e = np.zeros_like(x)
        e[k] = step
        columns.append((_flat(func(x + e)) - _flat(func(x - e))) / (2 * step))
    return np.column_stack(columns)


def _flat(value):
    """A float vector from a CasADi DM or numpy value (np.array first: no numpy ufunc on DM)."""
    return np.array(value, dtype=float).ravel()


def _assert_rel_close(actual, expected, tol=REL_TOL):
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape
    error = np.linalg.norm(actual - expected) / max(1.0, np.linalg.norm(expected))
    assert error < tol, f"relative error {error:.2e} >= {tol:.0e}"


class Derivatives:
    """CasADi functions for one model, built once: f, its Jacobians and a Hessian."""

    def __init__(self, model):
        n = model.n
        x = ca.SX.sym("x", 2 * n)
        u = ca.SX.sym("u", n)
        psi = ca.SX.sym("psi", 2 * n)
        q = ca.SX.sym("q", n)
        self.model = model
        self.f = model.function("f")
        # The compiled function's own Jacobian, as the solver may request it.
        self.jac_f = self.f.jacobian()
        xd = self.f(x, u)
        hamiltonian = ca.dot(psi, xd)
        self.grad_h = ca.Function("grad_h", [x, u, psi], [ca.gradient(hamiltonian, x)])
        self.hess_h = ca.Function("hess_h", [x, u, psi], [ca.hessian(hamiltonian, x)[0]])
        self.hess_hu = ca.Function("hess_hu", [x, u, psi],
                                   [ca.jacobian(ca.gradient(hamiltonian, x), u)])
        self.point = model.function("P")
        self.jac = model.function("J")
        jq = self.jac(q)
        self.djac = ca.Function("dJ", [q], [ca.jacobian(ca.vec(jq), q)])

    def points(self, seed=3):
        rng = np.random.default_rng(seed)
        n = self.model.n
        lower = np.maximum(self.model.q_lower, -np.pi)
        upper = np.minimum(self.model.q_upper, np.pi)
        # Stay clear of the limits so that x +- h is inside them too.
        margin = 0.1 * (upper - lower)
        for _ in range(N_POINTS):
            q = rng.uniform(lower + margin, upper - margin)
            x = np.concatenate([q, rng.uniform(-1.0, 1.0, n)])
            yield x, rng.uniform(-1.0, 1.0, n), rng.normal(size=2 * n)


@pytest.fixture(scope="module", params=["galicki", "rpr", "panda"])
def deriv(request):
    return Derivatives(request.getfixturevalue(request.param))


def test_state_jacobians(deriv):
    n = deriv.model.n
    for x, u, _ in deriv.points():
        jx, ju = (np.array(a) for a in deriv.jac_f(x, u, np.zeros(2 * n)))
        _assert_rel_close(jx, _central_jacobian(lambda y, u=u: deriv.f(y, u), x))
        _assert_rel_close(ju, _central_jacobian(lambda v, x=x: deriv.f(x, v), u))
        # Structure: d qdot / d qd = I, d qdot / d (q, u) = 0.
        np.testing.assert_array_equal(jx[:n], np.hstack([np.zeros((n, n)), np.eye(n)]))
        np.testing.assert_array_equal(ju[:n], 0.0)


def test_point_jacobian(deriv):
    for x, _, _ in deriv.points():
        q = x[:deriv.model.n]
        _assert_rel_close(np.array(deriv.jac(q)), _central_jacobian(deriv.point, q))


def test_jacobian_derivative(deriv):
    for x, _, _ in deriv.points():
        q = x[:deriv.model.n]
        expected = _central_jacobian(lambda y: np.array(deriv.jac(y)).ravel(order="F"), q)
        _assert_rel_close(np.array(deriv.djac(q)), expected)


def test_hamiltonian_gradient(deriv):
    for x, u, psi in deriv.points():
        expected = _central_jacobian(lambda y, u=u, psi=psi: float(psi @ _flat(deriv.f(y, u))),
                                     x)
        _assert_rel_close(_flat(deriv.grad_h(x, u, psi)), _flat(expected))


def test_hamiltonian_hessian(deriv):
    """Second derivatives of ``psi^T f(x, u)``: FD of the exact gradient."""
    for x, u, psi in deriv.points():
        hess = np.array(deriv.hess_h(x, u, psi))
        _assert_rel_close(hess, hess.T, tol=1e-12)
        _assert_rel_close(hess, _central_jacobian(lambda y, u=u, psi=psi: deriv.grad_h(y, u, psi),
                                                  x))
        _assert_rel_close(np.array(deriv.hess_hu(x, u, psi)),
                          _central_jacobian(lambda v, x=x, psi=psi: deriv.grad_h(x, v, psi), u))
