"""Energy balance along simulated motions: Delta(T + V) = work of tau - friction losses.

The forward dynamics are integrated together with ``W = int tau . qd dt`` and
``L = int qd^T D qd dt``. The balance involves M (through T), the Coriolis terms (they do no
work only if ``C`` is consistent with ``M``), gravity (through V) and friction, so a wrong
term in any of them breaks it. The Panda with gravity makes V matter.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp

#: Integration much tighter than the check, so the check measures the model.
RTOL_IVP, ATOL_IVP = 1e-11, 1e-12
BALANCE_RTOL = 1e-7


def _torque(model, t, fraction):
    """Smooth torques within the limits: a different sine per joint (N m)."""
    k = np.arange(model.n)
    return fraction * model.tau_max * np.sin((1.3 + 0.7 * k) * t + 0.5 * k)


def _simulate(model, q0, qd0, duration, fraction):
    n = model.n
    fd = model.function("fd")
    damping = model.damping

    def rhs(t, y):
        q, qd = y[:n], y[n:2 * n]
        tau = _torque(model, t, fraction)
        qdd = np.asarray(fd(q, qd, tau)).ravel()
        return np.concatenate([qd, qdd, [tau @ qd, qd @ (damping * qd)]])

    y0 = np.concatenate([q0, qd0, [0.0, 0.0]])
    sol = solve_ivp(rhs, (0.0, duration), y0, method="DOP853", rtol=RTOL_IVP, atol=ATOL_IVP)
    assert sol.success, sol.message
    return sol.y[:, -1]


def _check_balance(model, q0, qd0, duration, fraction):
    n = model.n
    y = _simulate(model, q0, qd0, duration, fraction)
    kin0, pot0 = model.energy(q0, qd0)
    kin1, pot1 = model.energy(y[:n], y[n:2 * n])
    work, loss = y[2 * n], y[2 * n + 1]
    terms = np.array([kin1 - kin0, pot1 - pot0, work, loss])
    # Guard: the motion is not trivial, every term of the balance is exercised.
    assert np.all(np.abs(terms[[0, 2, 3]]) > 1e-2), terms
    scale = np.abs(terms).max()
    assert_allclose((kin1 - kin0) + (pot1 - pot0), work - loss, rtol=0,
                    atol=BALANCE_RTOL * scale)
    return terms


def test_planar_3r_energy_balance(galicki):
    terms = _check_balance(galicki, np.array([0.3, -0.9, 1.4]), np.array([0.5, -0.4, 1.0]),
                           duration=3.0, fraction=0.6)
    assert terms[1] == 0.0  # horizontal plane


def test_panda_energy_balance_with_gravity(panda):
    q0 = np.array([0.1, -0.4, 0.2, -1.8, 0.3, 1.6, 0.5])
    terms = _check_balance(panda, q0, np.array([0.2, -0.3, 0.1, 0.4, -0.5, 0.3, 0.6]),
                           duration=0.6, fraction=0.15)
    assert abs(terms[1]) > 0.1, "the Panda should rise or fall in gravity"


def test_rpr_energy_balance_with_gravity_and_prismatic_joint(rpr):
    terms = _check_balance(rpr, np.array([0.4, 0.1, -0.6]), np.array([-0.5, 0.3, 0.8]),
                           duration=1.5, fraction=0.3)
    assert abs(terms[1]) > 0.1


@pytest.mark.parametrize("name", ["panda", "rpr"])
def test_gravity_torque_is_gradient_of_potential(name, request):
    """``b(q, 0) = dV/dq`` (central differences of the model's own potential energy)."""
    model = request.getfixturevalue(name)
    rng = np.random.default_rng(11)
    h = 1e-6
    for _ in range(5):
        q = rng.uniform(model.q_lower, model.q_upper)
        zero = np.zeros(model.n)
        grad = np.array([
            (model.energy(q + h * e, zero)[1] - model.energy(q - h * e, zero)[1]) / (2 * h)
            for e in np.eye(model.n)])
        gravity = model.bias(q, zero)
        assert_allclose(gravity, grad, rtol=1e-6, atol=1e-7 * np.abs(gravity).max())
