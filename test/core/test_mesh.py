"""The shooting mesh: switch nodes, RK4 error estimates, splitting and merging."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.indirect.mesh import Mesh, interval_errors, merge_pairs
from tocontrol_ros.core.indirect.shooting import integrate
from tocontrol_ros.core.planning.solver import SolverOptions


def test_switch_nodes_sit_on_sign_changes_of_s(solved, solved_grid):
    res = solved["nodes"]
    assert res.success, res.message
    grid, nodes, t_final, _ = solved_grid
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


def test_final_mesh_meets_the_tolerance_and_merging_respects_switches(solved, solved_grid):
    """Every interval of the returned mesh passes the RK4 estimate; merging keeps switch
    nodes and graded intervals and only merges what stays under tol / MERGE_MARGIN."""
    from tocontrol_ros.core.indirect.mesh import MERGE_MARGIN

    res = solved["nodes"]
    grid, nodes, t_final, lengths = solved_grid
    system = grid.system
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
    from tocontrol_ros.core.indirect.mesh import CASCADE_RATIO, graded_split

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
