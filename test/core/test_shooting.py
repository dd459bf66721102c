"""Multiple shooting: graded steps, switch nodes, the sparse Jacobian and chord Newton."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.mesh import Mesh, interval_errors, merge_pairs
from tocontrol_ros.core.pmp import LawParams
from tocontrol_ros.core.problem import Problem, point
from tocontrol_ros.core.shooting import ShootingGrid, integrate, newton_solve, step_fractions
from tocontrol_ros.core.solver import Planner, SolverOptions, plan

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)
SINGLE = SolverOptions(starts=1, candidates=1)


@pytest.fixture(scope="module")
def solved(galicki):
    """The paper's example at k = 4 (one start) with switch nodes, and without."""
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4)
    return {"problem": problem, "nodes": plan(problem, SINGLE),
            "uniform": plan(problem, SolverOptions(starts=1, candidates=1,
                                                   switch_nodes=False))}


def _solved_grid(system, result):
    """The final grid of ``result`` and its nodes, T and interval lengths."""
    st = result.warm_state
    grid = st.grid(system, "point", "point")
    nodes, t_final, _, _ = grid.unpack(st.w)
    return grid, nodes, t_final, grid.lengths_of(st.w)


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


def test_switch_nodes_sit_on_sign_changes_of_s(galicki, solved):
    res = solved["nodes"]
    assert res.success, res.message
    system = Planner(galicki).system
    grid, nodes, t_final, _ = _solved_grid(system, res)
    tau = grid.tau_of(res.warm_state.w)
    for node, i in grid.breaks:
        t = tau[node] * t_final
        s_node = res.trajectory.evaluate(t).S[0, i]
        before = res.trajectory.evaluate(t - 1e-4).S[0, i]
        after = res.trajectory.evaluate(t + 1e-4).S[0, i]
        print(f"switch of S_{i} at t = {t:.6f} s: S = {s_node:.1e}, "
              f"S(t -/+ 0.1 ms) = {before:.2e} / {after:.2e}")
        assert abs(s_node) < 1e-9
        assert before * after < 0
    assert grid.kinds[[j for j, _ in grid.breaks]].tolist() == [-1] * grid.B
    assert grid.kinds[[j - 1 for j, _ in grid.breaks]].tolist() == [1] * grid.B


def test_switch_nodes_give_the_same_answer_as_a_uniform_refinement(galicki, solved):
    a, b = solved["nodes"], solved["uniform"]
    assert a.success and b.success, (a.message, b.message)
    assert not b.warm_state.breaks
    print(f"T with switch nodes {a.T:.12f} ({a.intervals} intervals, {a.iterations} "
          f"iterations), uniform refinement {b.T:.12f} ({b.intervals}, {b.iterations})")
    assert a.T == pytest.approx(b.T, rel=1e-8)
    for r in (a, b):
        assert r.verification["max_abs_H"] < 1e-6
        assert r.verification["point_error"] < 1e-5


def test_broyden_chord_steps_match_the_explicit_update():
    """The product form of the chord steps (Kelley's brsol) equals Broyden's good update of
    an explicit matrix, and on a linear system it converges where plain chord steps on the
    same stale factors crawl."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    from tocontrol_ros.core.shooting import _Broyden

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


def test_integrate_sensitivities_with_graded_steps(galicki, solved):
    """dz1/dz0 and dz1/dT of graded intervals against central differences."""
    system = Planner(galicki).system
    grid, nodes, t_final, all_lengths = _solved_grid(system, solved["nodes"])
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


def test_compiled_intervals_equal_the_step_by_step_chain(galicki, solved):
    """One compiled call per interval (Jacobians chained in C) against per-step numpy."""
    system = Planner(galicki).system
    grid, nodes, t_final, lengths = _solved_grid(system, solved["nodes"])
    par = LawParams(4.0, 1e-4, 1.0).array()
    assert not system.stagewise
    fast = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, True,
                     grid.fractions)
    plain = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, False,
                      grid.fractions)[0]
    system._cache["stagewise"] = True  # the step-by-step path (large models)
    try:
        slow = integrate(system, nodes[:-1], lengths, grid.steps, t_final, par, True,
                         grid.fractions)
    finally:
        system._cache["stagewise"] = False
    np.testing.assert_allclose(plain, slow[0], rtol=0, atol=1e-12)
    for got, want in zip(fast, slow, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want)))


def test_final_mesh_meets_the_tolerance_and_merging_respects_switches(galicki, solved):
    """Every interval of the returned mesh passes the RK4 estimate; merging keeps switch
    nodes and graded intervals and only merges what stays under tol / MERGE_MARGIN."""
    from tocontrol_ros.core.mesh import MERGE_MARGIN

    res = solved["nodes"]
    system = Planner(galicki).system
    grid, nodes, t_final, lengths = _solved_grid(system, res)
    par = res.trajectory.law.array()
    tol = SolverOptions().integration_tol
    err = interval_errors(system, nodes[:-1], lengths, grid.steps, t_final, par, grid.kinds)
    assert np.all(err <= tol), err.max()
    # Halve every uniform interval: merging must give pairs back, never across a switch.
    starts, halves, kinds = [], [], []
    for j in range(grid.N):
        if grid.kinds[j] == 0:
            mid = integrate(system, nodes[j:j + 1], lengths[j:j + 1] / 2, grid.steps,
                            t_final, par, False)[0][0]
            starts += [nodes[j], mid]
            halves += [lengths[j] / 2] * 2
            kinds += [0, 0]
        else:
            starts.append(nodes[j])
            halves.append(lengths[j])
            kinds.append(grid.kinds[j])
    starts, halves, kinds = np.array(starts), np.array(halves), np.array(kinds)
    old_node = np.concatenate([[0], np.cumsum(np.where(grid.kinds == 0, 2, 1))])
    break_nodes = old_node[[j for j, _ in grid.breaks]]
    h_err = interval_errors(system, starts, halves, grid.steps, t_final, par, kinds)
    out = merge_pairs(system, Mesh(starts, halves, kinds, h_err), break_nodes, grid.steps,
                      t_final, par, tol)
    assert out is not None
    merged_mesh, keep = out
    m_starts, m_lengths, m_kinds = merged_mesh.starts, merged_mesh.lengths, merged_mesh.kinds
    assert keep[break_nodes].all() and keep[0] and keep[-1]
    assert len(m_lengths) < len(halves)
    np.testing.assert_allclose(m_lengths.sum(), 1.0, atol=1e-12)
    assert sorted(m_kinds[m_kinds != 0]) == sorted(grid.kinds[grid.kinds != 0])
    merged = np.flatnonzero(~keep[1:-1])  # removed node j + 1: intervals j, j + 1 merged
    assert len(merged) == len(halves) - len(m_lengths)
    m_err = interval_errors(system, m_starts, m_lengths, grid.steps, t_final, par, m_kinds)
    grown = ~np.isin(m_lengths, halves)  # the merged intervals
    assert grown.any() and np.all(m_err[grown] <= tol / MERGE_MARGIN * 1.001)


@pytest.mark.parametrize("kind", [1, -1])
def test_graded_split_puts_a_short_graded_part_at_the_switch(kind):
    from tocontrol_ros.core.mesh import CASCADE_RATIO, graded_split

    parts = graded_split(0.08, kind, err=5e-6, tol=1e-6, k=4.0)
    np.testing.assert_allclose(parts.sum(), 0.08, rtol=1e-14)
    outward = parts if kind == -1 else parts[::-1]  # from the switch away
    # err ~ length^(8/7): 1/10 of the error needs (1/10)^(7/8) of the length.
    assert outward[0] == pytest.approx(0.08 * (0.5e-6 / 5e-6) ** (7 / 8))
    reach = np.cumsum(outward)
    assert np.all(reach[1:-1] / reach[:-2] == pytest.approx(CASCADE_RATIO))
    assert reach[-2] * CASCADE_RATIO >= 0.08 - 1e-15
    # A small excess still halves the interval at most; a huge one takes 1/16.
    assert graded_split(0.08, kind, 1.1e-6, 1e-6, 4.0).max() == pytest.approx(0.04)
    assert min(graded_split(0.08, kind, 1.0, 1e-6, 4.0)) == pytest.approx(0.005)


def test_check_sampling_finds_the_extremes_of_a_fine_sampling(solved):
    """The result checks sample at the RK4 step points (filled in to T / SAMPLE_GAPS):
    max |u| and the joint extremes agree with a 100001-point sampling."""
    from tocontrol_ros.core.verification import SAMPLE_GAPS, fine_sample

    traj = solved["nodes"].trajectory
    sample = fine_sample(traj)
    assert np.all(np.diff(sample.t) <= traj.T / SAMPLE_GAPS * (1 + 1e-12))
    fine = traj.evaluate(np.linspace(0.0, traj.T, 100001))
    assert np.max(np.abs(sample.u)) == pytest.approx(np.max(np.abs(fine.u)), abs=1e-6)
    for a, b in ((sample.q, fine.q), (sample.qd, fine.qd)):
        np.testing.assert_allclose(a.max(axis=0), b.max(axis=0), atol=1e-4)
        np.testing.assert_allclose(a.min(axis=0), b.min(axis=0), atol=1e-4)
    assert np.max(np.abs(sample.H)) == pytest.approx(np.max(np.abs(fine.H)), abs=1e-7)


def test_settled_stops_only_on_a_geometric_tail_below_tol():
    from tocontrol_ros.core.solver import _settled

    # T changes of the paper's example at k = 4 for delta = 1e-3 -> 1e-4 -> 1e-5: a ratio of
    # about 1/87, so the rest of the series is ~2e-10, below 1e-8 * T.
    assert _settled([1.33e-6, 1.52e-8], 5.4e-9)
    assert not _settled([1.52e-8], 5.4e-9)               # one change says nothing
    assert not _settled([1e-6, 6e-7], 1e-6)              # shrinking, but not by half
    assert not _settled([1e-3, 1e-5], 5.4e-9)            # geometric, but the tail 1e-7
    assert not _settled([0.0, 1e-9], 5.4e-9)


def test_final_smoothing_is_confirmed_on_the_refined_mesh(galicki):
    """Stopping the coarse schedule early still ends with a solve at the next smaller
    delta on the final mesh that changes T by less than smoothing_tol."""
    opts = SolverOptions(starts=1, candidates=1, verify=False)
    res = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4.0), opts)
    assert res.success
    (k_a, d_a, t_a, *_), (k_b, d_b, t_b, *_) = res.continuation[-2:]
    assert k_a == k_b == 4.0 and d_b < d_a
    assert abs(t_b - t_a) <= opts.smoothing_tol * t_b
    assert res.delta == d_b


def test_k1_newton_is_retried_on_twice_the_intervals(galicki, monkeypatch):
    """A k = 1 Newton failure on `intervals` intervals is retried once on twice as many
    (planar 8R in bench/scaling.py: initial residual 18 on 12 intervals, stall; converges
    on 24); a failure on both is reported as NEWTON_FAILED."""
    from tocontrol_ros.core import context, solver

    sizes = []
    real = context.newton_solve

    def fail_on(bad):
        def newton(grid, *args, **kwargs):
            sizes.append(grid.N)
            if grid.N in bad:
                return solver.NewtonReport(False, args[0], 1.0, 1, "stalled (forced)")
            return real(grid, *args, **kwargs)
        return newton

    problem = Problem(galicki, point(P_START), point(P_TARGET), k=1.0)
    opts = SolverOptions(starts=1, candidates=1, verify=False, intervals=6)
    monkeypatch.setattr(context, "newton_solve", fail_on({6}))
    res = plan(problem, opts)
    assert res.success and sizes[:2] == [6, 12]
    sizes.clear()
    monkeypatch.setattr(context, "newton_solve", fail_on({6, 12}))
    res = plan(problem, opts)
    assert res.status is solver.Status.NEWTON_FAILED and sizes == [6, 12]
    assert "forced" in res.message
