"""Multiple shooting: graded steps, switch nodes, the sparse Jacobian and chord Newton."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.indirect.newton import newton_solve
from tocontrol_ros.core.indirect.shooting import (
    ShootingGrid,
    integrate,
    step_fractions,
)
from tocontrol_ros.core.planning.solver import Planner
from tocontrol_ros.core.types.law import LawParams
from tocontrol_ros.core.types.problem import Problem, point

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)


def test_step_fractions_sum_to_one_and_grade_towards_the_switch():
    fr = step_fractions(np.array([0, 1, -1]), 6)
    np.testing.assert_allclose(fr.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(fr[0], 1 / 6)
    assert np.all(np.diff(fr[2]) > 0) and np.all(np.diff(fr[1]) < 0)  # small at the switch
    np.testing.assert_allclose(fr[1], fr[2][::-1])
    assert fr[2][0] == pytest.approx((1 / 6) ** 4)
    # Doubling the steps splits every step of the graded mesh (Richardson estimates).
    fine = np.cumsum(step_fractions(np.array([-1]), 12)[0])[1::2]
    np.testing.assert_allclose(fine, np.cumsum(fr[2]), rtol=1e-13)


def _fd_jacobian(grid, w, values, par, eps=1e-7):
    cols = []
    for i in range(len(w)):
        d = np.zeros_like(w)
        d[i] = eps * max(1.0, abs(w[i]))
        gp = grid.residual(w + d, values, par, jacobian=False)[0]
        gm = grid.residual(w - d, values, par, jacobian=False)[0]
        cols.append((gp - gm) / (2 * d[i]))
    return np.array(cols).T


def test_jacobian_with_switch_nodes_matches_finite_differences(galicki, solved):
    res, problem = solved["nodes"], solved["problem"]
    st = res.warm_state
    assert st.breaks, "the k = 4 solution should have switch nodes"
    system = Planner(galicki).system
    grid = st.grid(system, "point", "point")
    # Away from the solution, and with a smooth law, so that differences are meaningful.
    rng = np.random.default_rng(3)
    w = st.w * (1 + 1e-3 * rng.standard_normal(len(st.w)))
    par = LawParams(4.0, 1e-2, 1.0).array()
    values = problem.boundary_values
    _, jac = grid.residual(w, values, par)
    fd = _fd_jacobian(grid, w, values, par)
    scale = np.maximum(1.0, np.abs(fd))
    err = np.abs(jac.toarray() - fd) / scale
    print(f"{grid.size} unknowns, {grid.B} breaks: max scaled |J - FD| = {err.max():.2e}")
    assert err.max() < 1e-5
    # The break-time columns are there and not zero.
    assert np.abs(jac.toarray()[:, grid.size - grid.B:]).max() > 1e-3


def test_one_switch_node_residual_and_jacobian(galicki, solved):
    """A mesh with a single switch node (the switching function's outputs are then one
    column) gives the same equations as the full mesh's, and a Jacobian that matches finite
    differences."""
    res, problem = solved["nodes"], solved["problem"]
    st = res.warm_state
    system = Planner(galicki).system
    full = st.grid(system, "point", "point")
    node, comp = st.breaks[0]
    one = ShootingGrid(system, st.lengths, st.steps, "point", "point",
                       kinds=st.kinds, breaks=[(node, comp)])
    assert one.B == 1
    # Unknowns of the one-break grid at the full solution: every break time but the first
    # is dropped, and the intervals between the kept nodes keep their lengths.
    w_full = st.w
    w = np.concatenate([w_full[:one.size - 1], [w_full[full.size - full.B]]])
    par = LawParams(4.0, res.delta, 1.0).array()
    values = problem.boundary_values
    g_one, _ = one.residual(w, values, par)
    g_full = full.residual(w_full, values, par, jacobian=False)[0]
    assert np.allclose(g_one, g_full[:one.size], atol=1e-9)
    # Away from the solution, with a smooth law, so that differences are meaningful.
    w = w * (1 + 1e-3 * np.random.default_rng(3).standard_normal(len(w)))
    par = LawParams(4.0, 1e-2, 1.0).array()
    _, jac = one.residual(w, values, par)
    fd = _fd_jacobian(one, w, values, par)
    assert np.max(np.abs(jac.toarray() - fd) / np.maximum(1.0, np.abs(fd))) < 1e-5


def test_broyden_chord_steps_match_the_explicit_update():
    """The product form of the chord steps (Kelley's brsol) equals Broyden's good update of
    an explicit matrix, and on a linear system it converges where plain chord steps on the
    same stale factors crawl."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    from tocontrol_ros.core.indirect.newton import _Broyden

    rng = np.random.default_rng(3)
    n = 12
    a = np.eye(n) * 4 + rng.normal(size=(n, n))
    b = rng.normal(size=n)
    b0 = a + 0.8 * rng.normal(size=(n, n)) / np.sqrt(n)  # stale Jacobian
    lu = splu(sp.csc_matrix(b0))

    def g_of(x):
        return a @ x - b

    x = np.zeros(n)
    mat = b0.copy()
    step = -lu.solve(g_of(x))
    chain = _Broyden(lu)
    chain.taken(step)
    for _ in range(6):
        x_new = x + step
        g_new = g_of(x_new)
        mat = mat + np.outer(g_new, step) / (step @ step)  # B+ = B + (y - B s) s^T / s^T s
        step_explicit = -np.linalg.solve(mat, g_new)
        step = chain.step(g_new)
        np.testing.assert_allclose(step, step_explicit, rtol=1e-9, atol=1e-12)
        chain.taken(step)
        x = x_new
    # Convergence: Broyden (at most 2n steps on a linear system, Gay 1979) against chords.
    x_b, x_c = np.zeros(n), np.zeros(n)
    step = -lu.solve(g_of(x_b))
    chain = _Broyden(lu)
    chain.taken(step)
    for _ in range(2 * n):
        x_b = x_b + step
        if np.max(np.abs(g_of(x_b))) < 1e-12:
            break
        step = chain.step(g_of(x_b))
        chain.taken(step)
    for _ in range(2 * n):
        x_c = x_c - lu.solve(g_of(x_c))
    res_b, res_c = np.max(np.abs(g_of(x_b))), np.max(np.abs(g_of(x_c)))
    print(f"after {2 * n} steps: Broyden {res_b:.1e}, plain chord {res_c:.1e}")
    assert res_b < 1e-10 and res_b < 1e-3 * res_c


def test_chord_newton_converges_to_the_newton_solution(galicki, solved):
    res = solved["nodes"]
    st = res.warm_state
    system = Planner(galicki).system
    grid = st.grid(system, "point", "point")
    moved = Problem(galicki, point(P_START), point(P_TARGET + [0.003, 0.004]), k=4)
    par = LawParams(res.k, res.delta, 1.0).array()
    plain = newton_solve(grid, st.w, moved.boundary_values, par, contraction=0.0)
    chord = newton_solve(grid, st.w, moved.boundary_values, par)
    print(f"plain Newton {plain.iterations} iterations, with chord steps {chord.iterations}")
    assert plain.converged and chord.converged
    np.testing.assert_allclose(chord.w, plain.w, rtol=0, atol=1e-8)


def test_integrate_sensitivities_with_graded_steps(galicki, solved_grid):
    """dz1/dz0 and dz1/dT of graded intervals against central differences."""
    system = Planner(galicki).system
    grid, nodes, t_final, all_lengths = solved_grid
    sel = np.flatnonzero(grid.kinds != 0)[:4]
    lengths = all_lengths[sel]
    par = LawParams(4.0, 1e-2, 1.0).array()
    fr = grid.fractions[sel]
    z0 = nodes[sel]
    _, a, b = integrate(system, z0, lengths, grid.steps, t_final, par, True, fr)
    eps = 1e-6
    up = integrate(system, z0, lengths, grid.steps, t_final + eps, par, False, fr)[0]
    dn = integrate(system, z0, lengths, grid.steps, t_final - eps, par, False, fr)[0]
    np.testing.assert_allclose(b, (up - dn) / (2 * eps), rtol=1e-5, atol=1e-6)
    d = np.zeros_like(z0)
    d[:, 5] = eps
    up = integrate(system, z0 + d, lengths, grid.steps, t_final, par, False, fr)[0]
    dn = integrate(system, z0 - d, lengths, grid.steps, t_final, par, False, fr)[0]
    np.testing.assert_allclose(a[:, :, 5], (up - dn) / (2 * eps), rtol=1e-5, atol=1e-6)


def test_compiled_intervals_equal_the_step_by_step_chain(galicki, solved_grid):
    """One compiled call per interval (Jacobians chained in C) against per-step numpy."""
    system = Planner(galicki).system
    grid, nodes, t_final, lengths = solved_grid
    par = LawParams(4.0, 1e-4, 1.0).array()
    assert not system.stagewise
    fast = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, True,
                     grid.fractions)
    plain = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, False,
                      grid.fractions)[0]
    system.stagewise = True  # the step-by-step path (large models)
    try:
        slow = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, True,
                         grid.fractions)
    finally:
        system.stagewise = False
    np.testing.assert_allclose(plain, slow[0], rtol=0, atol=1e-12)
    for got, want in zip(fast, slow, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want)))


