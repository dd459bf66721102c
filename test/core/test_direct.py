"""The direct transcription: its assembled derivatives against plain automatic differentiation.

``DirectCollocation`` assembles the constraint Jacobian and the Lagrangian's Hessian from
per-point derivatives of the dynamics and per-interval chain rules
(``collocation_nlp._point_functions``, ``_interval_functions``, ``_assembly_functions``).
Here the same NLP is written as one CasADi SX
expression, as a plain transcription would, and differentiated by CasADi: values must agree to
rounding for every kind of boundary condition, the box and the smooth control set, several
exponents; and IPOPT must reach the same solution and multipliers from the same guess with
either set of derivatives, compiled or in the virtual machine.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from tocontrol_ros.core.direct.collocation import (
    GUESS_LOAD,
    DirectCollocation,
    initial_path,
    initial_paths,
)
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)


def _plain_nlp(model, N, start_kind, target_kind, box, torque_scale):
    """The NLP as one SX expression (variables, constraints and parameters in the same order)."""
    n, m = model.n, model.m
    x_sym = ca.SX.sym("x", 2 * n)
    u_sym = ca.SX.sym("u", n)
    scale = ca.DM(model.tau_max * torque_scale)
    qdd = model.forward_dynamics_sym(x_sym[:n], x_sym[n:], scale * u_sym)
    f = ca.Function("f", [x_sym, u_sym], [ca.vertcat(x_sym[n:], qdd)])
    fk = ca.Function("P", [x_sym[:n]], [model.point_sym(x_sym[:n])])
    X = ca.SX.sym("X", 2 * n, N + 1)
    U = ca.SX.sym("U", n, N + 1)
    UM = ca.SX.sym("UM", n, N)
    T = ca.SX.sym("T")
    ns = m if start_kind == "point" else 2 * n
    nt = m if target_kind == "point" else 2 * n
    par = ca.SX.sym("p", ns + nt + 1)
    k = par[-1]
    h = T / N
    F = f.map(N + 1)(X, U)
    XM = 0.5 * (X[:, :-1] + X[:, 1:]) + h / 8 * (F[:, :-1] - F[:, 1:])
    FM = f.map(N)(XM, UM)
    g = [ca.vec(X[:, 1:] - X[:, :-1] - h / 6 * (F[:, :-1] + 4 * FM + F[:, 1:]))]
    if not box:
        g.append(ca.sum1(ca.horzcat(U, UM) ** (2 * k)).T - 1)
    for kind, col, offset, size in ((start_kind, 0, 0, ns), (target_kind, N, ns, nt)):
        xc = X[:, col]
        target = par[offset:offset + size]
        g += [fk(xc[:n]) - target, xc[n:]] if kind == "point" else [xc - target]
    w = ca.vertcat(ca.vec(X), ca.vec(U), ca.vec(UM), T)
    return {"x": w, "f": T, "g": ca.vertcat(*g), "p": par}


def _dense(value):
    return np.array(ca.densify(value))


@pytest.mark.parametrize("kinds,box", [(("point", "point"), False), (("state", "point"), False),
                                       (("point", "state"), True), (("state", "state"), False)])
def test_assembled_derivatives_match_automatic_differentiation(galicki, kinds, box):
    N = 4
    dc = DirectCollocation(galicki, N, *kinds, box=box, torque_scale=0.9)
    plain = ca.nlpsol("plain", "ipopt", _plain_nlp(galicki, N, *kinds, box, 0.9),
                      {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})
    rng = np.random.default_rng(3)
    nw = dc.lbx.size
    ng = dc.lbg.size
    assert plain.size1_in(0) == nw and plain.size1_in(1) == dc.solver.size1_in(1)
    for k in (1.0, 2.0, 3.5):
        w = rng.normal(size=nw)
        w[dc._nx:-1] = rng.uniform(0.1, 1.0, nw - dc._nx - 1)  # u^(2k) for a non-integer k
        w[-1] = 0.7
        p = rng.normal(size=plain.size1_in(1))
        p[-1] = k
        lam = rng.normal(size=ng)
        for name, args in (("nlp_g", (w, p)), ("nlp_jac_g", (w, p)),
                           ("nlp_hess_l", (w, p, 1.0, lam))):
            ref = plain.get_function(name)(*args)
            new = dc.solver.get_function(name)(*args)
            ref = _dense(ref[-1] if isinstance(ref, (list, tuple)) else ref)
            new = _dense(new[-1] if isinstance(new, (list, tuple)) else new)
            if name == "nlp_hess_l":
                assert dc.solver.get_function(name).sparsity_out(0).is_triu()
            err = np.max(np.abs(ref - new)) / max(1.0, np.max(np.abs(ref)))
            assert err < 1e-12, (name, k, err)


def _guess(model, dc):
    """The paper example's first multistart seed pair (inverse kinematics of the points)."""
    qa = np.array([-0.74958167, 2.38183072, 0.72394544])
    qb = np.array([-0.63884071, 2.11297099, 0.09666605])
    return initial_path(model, qa, qb, dc.N)


@pytest.mark.parametrize("compile_env", ["1", "0"])
def test_same_solution_as_plain_transcription(galicki, monkeypatch, compile_env):
    monkeypatch.setenv("TOCONTROL_COMPILE", compile_env)
    N = 12
    dc = DirectCollocation(galicki, N)
    if compile_env == "0":
        assert dc.compile_status.startswith("virtual machine")
    t_guess, x_guess, u_guess = _guess(galicki, dc)
    res = dc.solve(P_START, P_TARGET, 1.0, t_guess, x_guess, u_guess)
    assert res.success, res.message
    # The same NLP, options and guess with CasADi's own derivatives.
    plain = ca.nlpsol("plain", "ipopt", _plain_nlp(galicki, N, "point", "point", False, 1.0),
                      {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                       "ipopt.tol": 1e-8, "ipopt.acceptable_tol": 1e-8,
                       "ipopt.mu_strategy": "adaptive", "calc_lam_p": False})
    um = 0.5 * (u_guess[:-1] + u_guess[1:])
    w0 = np.concatenate([x_guess.ravel(), u_guess.ravel(), um.ravel(), [t_guess]])
    sol = plain(x0=w0, p=np.concatenate([P_START, P_TARGET, [1.0]]), lbx=dc.lbx, ubx=dc.ubx,
                lbg=dc.lbg, ubg=dc.ubg)
    assert plain.stats()["success"]
    # Same iterates up to rounding (the derivatives differ in the last bits).
    assert abs(res.iterations - plain.stats()["iter_count"]) <= 2
    w = np.array(sol["x"]).ravel()
    assert abs(res.T - w[-1]) < 1e-12 * w[-1]
    assert np.max(np.abs(res.x.ravel() - w[:dc._nx])) < 1e-9
    lam = np.array(sol["lam_g"]).ravel()[:2 * galicki.n * N].reshape(N, 2 * galicki.n)
    # psi at the interior nodes is the average of the neighbouring defect multipliers.
    psi = 0.5 * (lam[:-1] + lam[1:])
    assert np.max(np.abs(res.psi[1:-1] - psi)) < 1e-7 * max(1.0, np.max(np.abs(psi)))


def test_failure_is_reported(galicki):
    dc = DirectCollocation(galicki, 12, max_iter=2)
    res = dc.solve(P_START, P_TARGET, 1.0, *_guess(galicki, dc))
    assert not res.success
    assert res.message == "Maximum_Iterations_Exceeded"
    assert res.iterations == 2


def test_initial_path_is_rest_to_rest(galicki):
    qa = np.array([0.2, 1.2, -0.9])
    qb = np.array([0.1, 0.9, -0.2])
    N = 12
    t_final, x, u = initial_path(galicki, qa, qb, N, torque_scale=0.9)
    n = galicki.n
    assert t_final > 0
    assert np.allclose(x[0, :n], qa) and np.allclose(x[-1, :n], qb)
    assert np.allclose(x[0, n:], 0) and np.allclose(x[-1, n:], 0)
    # The torques are the path's inverse dynamics, node by node, normalised and clipped.
    tau = np.linspace(0, 1, N + 1)
    qdd = np.outer((6 - 12 * tau) / t_final ** 2, qb - qa)
    expected = np.array([galicki.inverse_dynamics(x[i, :n], x[i, n:], qdd[i])
                         for i in range(N + 1)])
    expected = expected / (galicki.tau_max * 0.9)
    assert np.allclose(u, np.clip(expected, -0.9, 0.9), rtol=1e-12, atol=1e-12)
    # Timed to the control set: the largest torques are at the ends, at rest, where they are
    # M qdd alone (no gravity in this arm's plane) and scale like 1 / T^2 exactly.
    assert np.max(np.linalg.norm(expected, axis=1)) == pytest.approx(GUESS_LOAD, rel=1e-9)


def test_initial_paths_are_initial_path_seed_by_seed(galicki):
    rng = np.random.default_rng(3)
    q0, qT = rng.uniform(-4, 4, (2, 9, galicki.n))
    qT[4] = q0[4]  # no motion: its peak is zero, it keeps its first time
    velocity = np.array([1.0, 2.0, 3.0])
    for vel in (None, velocity):
        t_all, x_all, u_all = initial_paths(galicki, q0, qT, 12, 0.9, vel)
        for i in range(len(q0)):
            t_one, x_one, u_one = initial_path(galicki, q0[i], qT[i], 12, 0.9, vel)
            # The same arithmetic per seed: equal to the last bit.
            assert t_all[i] == t_one
            assert np.array_equal(x_all[i], x_one) and np.array_equal(u_all[i], u_one)
