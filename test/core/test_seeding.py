"""Seeding of the multistart: full-turn branches, ranking order, the exhaustive mode."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.methods.seeding import (
    EXHAUSTIVE_STARTS,
    SEED_SPACING,
    branch_shifts,
    seed_grid,
    seed_pairs,
    shiftable_joints,
)
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem, joint_state, point


def _problem(model, limits=None, **kw):
    if limits is not None:
        kw["limits"] = limits
    return Problem(model, point(PAPER_START), point(PAPER_TARGET), k=4, **kw)


def _estimate(model, problem, qa, qb):
    mass = np.diag(np.array(model.function("M")(qa)))
    return np.max(2 * np.sqrt(np.abs(qb - qa) * mass / (model.tau_max * problem.torque_scale)))


def test_continuous_joints_get_long_way_branches(galicki):
    problem = _problem(galicki)
    assert shiftable_joints(problem).all()  # the paper's joints are continuous
    pairs = seed_pairs(problem, SolverOptions(starts=10_000))
    d = np.array([qb - qa for qa, qb in pairs])
    # Every joint is taken the long way (|d| > pi) by some seed, and every pattern of
    # short/long ways over the three joints occurs.
    assert (np.abs(d) > np.pi).any(axis=0).all()
    patterns = {tuple(row) for row in (np.abs(d) > np.pi + 1e-12)}
    assert len(patterns) == 2 ** galicki.n
    # At most one turn more than the short way: |d| < 3 pi; and both extra turns occur.
    assert np.abs(d).max() < 3 * np.pi
    assert (np.abs(d) > 2 * np.pi).any()


def test_no_branch_where_the_range_forbids_it(galicki):
    names = galicki.joint_names
    # Joint 2 limited to 6 rad (< 2 pi): no branch; joint 3 to 7 rad: branches inside only.
    limits = _problem(galicki).limits.narrowed({
        names[1]: {"has_position_limits": True, "min_position": -3.0, "max_position": 3.0},
        names[2]: {"has_position_limits": True, "min_position": -3.5, "max_position": 3.5}})
    problem = _problem(galicki, limits)
    assert shiftable_joints(problem).tolist() == [True, False, True]
    pairs = seed_pairs(problem, SolverOptions(starts=10_000))
    assert pairs
    q = np.array([qa for qa, _ in pairs] + [qb for _, qb in pairs])
    d = np.array([b - a for a, b in pairs])
    # Both ends inside the limits, so joint 2 never turns a full turn (its range is 6 rad).
    assert np.all((q[:, 1] >= -3.0) & (q[:, 1] <= 3.0))
    assert np.all((q[:, 2] >= -3.5) & (q[:, 2] <= 3.5))
    assert np.abs(d[:, 1]).max() <= 6.0
    assert (np.abs(d[:, 2]) > np.pi).any()  # joint 3 still turns the long way when it fits


def test_joint_state_target_has_no_branches(galicki):
    q_t = np.array([0.3, -0.4, 2.5])
    problem = Problem(galicki, point(PAPER_START), joint_state(q_t), k=4)
    assert not shiftable_joints(problem).any()
    pairs = seed_pairs(problem, SolverOptions(starts=10_000))
    assert pairs and all(np.allclose(qb, q_t, rtol=0, atol=1e-12) for _, qb in pairs)


def test_branch_shifts_are_minus_one_to_one_turn():
    shifts = branch_shifts(np.array([True, True, False]))
    assert shifts.shape == (9, 3)
    assert np.allclose(shifts[0], 0)  # the short way first
    assert {tuple(r) for r in np.round(shifts / (2 * np.pi)).astype(int)} == \
        {(a, b, 0) for a in (-1, 0, 1) for b in (-1, 0, 1)}
    assert branch_shifts(np.zeros(3, dtype=bool)).shape == (1, 3)


def _far(qa, qb, kept_a, kept_b):
    return all(max(np.max(np.abs(qa - a)), np.max(np.abs(qb - b))) >= SEED_SPACING
               for a, b in zip(kept_a, kept_b, strict=True))


def test_ranking_is_by_the_estimate_spread_over_the_manifold(galicki):
    problem = _problem(galicki)
    options = SolverOptions(starts=16)
    pairs = seed_pairs(problem, options)
    assert len(pairs) == 16
    est = np.array([_estimate(galicki, problem, qa, qb) for qa, qb in pairs])
    qa_all, dv, grid = seed_grid(problem, options)
    assert est[0] == pytest.approx(grid.min(), rel=1e-12)  # the best seed first
    # The leading pairs are far from each other and in the order of the estimate...
    lead = 1
    while lead < len(pairs) and _far(*pairs[lead], [p[0] for p in pairs[:lead]],
                                     [p[1] for p in pairs[:lead]]):
        lead += 1
    assert lead >= 8
    assert np.all(np.diff(est[:lead]) >= -1e-12)
    assert np.all(np.diff(est[lead:]) >= -1e-12)
    # ...and every seed of the grid ranked better than the last of them is one of them or
    # near one of them.
    s_idx, g_idx, v_idx = np.nonzero(grid < est[lead - 1] * (1 - 1e-12))
    for s, g, v in zip(s_idx, g_idx, v_idx, strict=True):
        qa, qb = qa_all[s], qa_all[s] + dv[s, g, v]
        assert not _far(qa, qb, [p[0] for p in pairs[:lead]], [p[1] for p in pairs[:lead]])
    # The seeds reach the end points.
    for qa, qb in pairs[:5]:
        assert np.allclose(galicki.point(qa), PAPER_START, atol=1e-8)
        assert np.allclose(galicki.point(qb), PAPER_TARGET, atol=1e-8)


def test_exhaustive_mode_covers_every_branch(galicki):
    problem = _problem(galicki)
    pairs = seed_pairs(problem, SolverOptions(starts=1), exhaustive=True)
    assert len(pairs) == EXHAUSTIVE_STARTS  # starts ignored
    ranked = seed_pairs(problem, SolverOptions(starts=10_000))
    _, dv, _ = seed_grid(problem, SolverOptions(), exhaustive=True)
    branches = dv.shape[2]
    assert branches == 3 ** galicki.n
    # The first 27 pairs are one per branch: their turns (relative to the short way) differ.
    d = np.array([b - a for a, b in pairs[:branches]])
    turns = {tuple(np.round((row - np.angle(np.exp(1j * row))) / (2 * np.pi)).astype(int))
             for row in d}
    assert len(turns) == branches
    # The grid is denser than the default's.
    assert dv.shape[0] > len({tuple(np.round(a, 9)) for a, _ in ranked})


def test_a_motion_a_full_turn_further_is_one_basin():
    """Direct solutions whose starts differ by 2 pi in a revolute joint and that turn by the
    same angles are one motion (bench/optimum.py's pair 10: the best direct solution three
    times among the six continued); other joints and other displacements stay distinct."""
    from types import SimpleNamespace

    from tocontrol_ros.core.methods.seeding import distinct_basins

    def sol(T, start, move):
        start = np.array(start, dtype=float)
        x = np.zeros((3, 4))
        x[0, :2], x[-1, :2] = start, start + np.array(move)
        return SimpleNamespace(T=T, x=x)

    a = sol(0.8, [-2.7294, -1.3156], [-0.7573, 2.0784])
    b = sol(0.8, [-2.7294 + 2 * np.pi, -1.3156], [-0.7573, 2.0784])   # a turn further
    c = sol(0.8, [-2.7294, -1.3156 - 2 * np.pi], [-0.7573, 2.0784])   # joint 2 not periodic
    d = sol(0.9, [-2.7294 + 2 * np.pi, -1.3156], [-0.7573 + 2 * np.pi, 2.0784])  # long way
    e = sol(0.95, [2 * np.pi - 1e-4, 0.0], [0.1, 0.1])                # across the wrap
    f = sol(0.95, [1e-4, 0.0], [0.1, 0.1])
    items = [a, b, c, d, e, f]
    wrap = np.array([True, False])
    assert distinct_basins(items, lambda s: s, 2, wrap) == [a, c, d, e]
    assert len(distinct_basins(items, lambda s: s, 2)) == 6  # nothing periodic: as before


def test_guess_tolerance_keeps_the_basins(galicki):
    """The multistart's direct guesses at the default ``guess_tol`` reach the same solutions
    as at 1e-8 (the paper's example's seed pairs): the looser tolerance only saves
    iterations."""
    from tocontrol_ros.core.direct.collocation import DirectCollocation, initial_paths
    from tocontrol_ros.core.methods.seeding import SAME_BASIN

    problem = _problem(galicki)
    options = SolverOptions()
    pairs = seed_pairs(problem, options)
    paths = initial_paths(galicki, np.array([p[0] for p in pairs]),
                          np.array([p[1] for p in pairs]), options.guess_intervals)
    tight = DirectCollocation(galicki, options.guess_intervals, tol=1e-8)
    loose = DirectCollocation(galicki, options.guess_intervals, tol=options.guess_tol)
    n, its = galicki.n, [0, 0]
    for i in range(len(pairs)):
        args = (problem.start.value, problem.target.value, 1.0,
                paths[0][i], paths[1][i], paths[2][i])
        a, b = tight.solve(*args), loose.solve(*args)
        assert a.success and b.success, (i, a.message, b.message)
        assert abs(a.T - b.T) <= 1e-5 * a.T, (i, a.T, b.T)
        assert np.max(np.abs(a.x[[0, -1], :n] - b.x[[0, -1], :n])) < SAME_BASIN, i
        its[0] += a.iterations
        its[1] += b.iterations
    assert its[1] < its[0], its


def test_the_same_problem_asked_again_gets_the_last_pairs(galicki, monkeypatch):
    """The planner node's first motion and its plan ask for one problem's pairs in turn: the
    second call skips the inverse kinematics, and gets copies (changing them changes
    nothing); another problem, or other options, are computed."""
    from tocontrol_ros.core.methods import seeding

    calls = []
    real = seeding.seed_grid
    monkeypatch.setattr(seeding, "seed_grid", lambda *a: calls.append(1) or real(*a))
    problem = Problem(galicki, point((1.0, 1.0)), point((2.2, 1.5)))
    options = SolverOptions(starts=4)
    first = seed_pairs(problem, options)
    first[0][0][:] = 99.0
    again = seed_pairs(problem, options)
    assert len(calls) == 1 and not np.any(again[0][0] == 99.0)
    fresh = seed_pairs(Problem(galicki, point((1.0, 1.0)), point((2.2, 1.5))), options)
    assert len(calls) == 2
    for (a, b), (c, d) in zip(again, fresh, strict=True):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)
    seed_pairs(problem, SolverOptions(starts=2))
    assert len(calls) == 3


class _Direct:
    """What :func:`recombined_pairs` reads of a direct solution: ``T`` and the states."""

    def __init__(self, T, q0, q1):
        self.T = T
        self.x = np.vstack([np.concatenate([q0, np.zeros(3)]),
                            np.concatenate([q1, np.zeros(3)])])


def test_recombined_seeds_join_one_parent_start_to_another_end(galicki):
    """Each recombined seed starts where a parent starts and ends where a parent ends
    (modulo full turns), each joint turning by the full turns nearest to one parent's own
    displacement; a parent's own basin, a seed tried before and repeats are left out, the
    slower parent's T decides the order, and at most ``count`` come back."""
    from tocontrol_ros.core.methods.seeding import recombined_pairs

    problem = _problem(galicki)
    fast = _Direct(1.0, np.array([0.1, 1.2, -0.4]), np.array([0.9, -3.6, 5.5]))
    slow = _Direct(1.2, np.array([2.0, -0.7, 1.0]), np.array([1.1, 2.9, -2.3]))
    tried = [(fast.x[0, :3], fast.x[-1, :3] + np.array([0.0, 2 * np.pi, 0.0]))]
    pairs = recombined_pairs(problem, [fast, slow], tried, count=100)
    assert pairs
    starts = [fast.x[0, :3], slow.x[0, :3]]
    ends = [fast.x[-1, :3], slow.x[-1, :3]]
    moves = [e - s for s, e in zip(starts, ends, strict=True)]

    def wrapped(d):
        return np.angle(np.exp(1j * d))

    for qa, qb in pairs:
        a = next(i for i, s in enumerate(starts) if np.allclose(qa, s))
        b = next(i for i, e in enumerate(ends) if np.allclose(wrapped(qb - e), 0.0, atol=1e-9))
        d = wrapped(ends[b] - starts[a])
        assert any(np.allclose(qb - qa, d + 2 * np.pi * np.round((moves[p] - d) / (2 * np.pi)))
                   for p in (a, b))
        # Not a parent's own motion, not the seed tried before.
        assert not any(np.allclose(qa, s) and np.allclose(qb - qa, m)
                       for s, m in zip(starts, moves, strict=True))
        assert not np.allclose(np.concatenate([qa, qb]), np.concatenate(tried[0]))
    flat = [np.concatenate(p) for p in pairs]
    assert all(np.max(np.abs(f - g)) > 1e-3 for i, f in enumerate(flat) for g in flat[:i])
    # Both crossings are there; the fast parent's own pair (its basin again) is not, so
    # the first seed is a crossing with the fast parent's turns.
    def ends_of(qa, qb):
        return (next(i for i, s in enumerate(starts) if np.allclose(qa, s)),
                next(i for i, e in enumerate(ends)
                     if np.allclose(wrapped(qb - e), 0.0, atol=1e-9)))

    assert {ends_of(qa, qb) for qa, qb in pairs} >= {(0, 1), (1, 0)}
    a, b = ends_of(*pairs[0])
    assert a != b
    d = wrapped(ends[b] - starts[a])
    assert np.allclose(pairs[0][1] - pairs[0][0],
                       d + 2 * np.pi * np.round((moves[0] - d) / (2 * np.pi)))
    two = recombined_pairs(problem, [fast, slow], tried, count=2)
    assert len(two) == 2
    assert all(np.array_equal(x, y) for p, q in zip(two, pairs, strict=False)
               for x, y in zip(p, q, strict=True))


def test_random_ik_families_get_more_seeds_where_limits_cut_the_manifold(panda, galicki,
                                                                         monkeypatch):
    """RANDOM_IK_FACTOR: an arm with joint limits whose family is random IK seeds draws
    ``ik_count`` times the factor of them per end point; without limits, or with the planar
    arm's angles (each with both elbows), ``ik_count``."""
    import tocontrol_ros.core.methods.seeding as seeding
    from tocontrol_ros.core.robot.ik import angle_family
    from tocontrol_ros.core.robot.limits import JointLimits

    assert angle_family(galicki) and not angle_family(panda)
    counts = []
    real = seeding.ik_family

    def counted(model, p, count, *args, **kwargs):
        counts.append(count)
        return real(model, p, count, *args, **kwargs)

    monkeypatch.setattr(seeding, "ik_family", counted)
    q0 = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.6, 0.5])
    target = panda.point(q0 + 0.3)
    limited = Problem(panda, joint_state(q0), point(target), k=4)
    assert limited.limits.active
    n = panda.n
    free = JointLimits(limited.limits.names, np.full(n, -np.inf), np.full(n, np.inf),
                       np.full(n, np.inf))
    options = SolverOptions(ik_count=5)
    _, dv, _ = seed_grid(limited, options)
    assert counts == [5 * seeding.RANDOM_IK_FACTOR] and seeding.RANDOM_IK_FACTOR > 1
    assert dv.shape[1] > 5  # more target configurations than ik_count seeds give
    counts.clear()
    seed_grid(Problem(panda, joint_state(q0), point(target), k=4, limits=free), options)
    assert counts == [5]
    counts.clear()
    seed_grid(_problem(galicki), options)  # limited or not, the angles are ik_count
    assert counts == [5, 5]


def test_limited_random_families_also_get_the_target_near_each_start(panda, monkeypatch):
    """NEAR_TARGETS: on an arm with random IK seeds and joint limits, the target point's
    configuration reached by Levenberg-Marquardt from each start configuration is a seed
    too (first), besides the random family; it moves the joints less than the family's."""
    import tocontrol_ros.core.methods.seeding as seeding
    from tocontrol_ros.core.robot.ik import ik_near

    q0 = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.6, 0.5])
    target = panda.point(q0 + 0.3)
    options = SolverOptions(ik_count=5)
    _, dv, est = seed_grid(Problem(panda, joint_state(q0), point(target), k=4), options)
    near = ik_near(panda, target, q0[None, :])
    assert len(near) == 1 and np.linalg.norm(panda.point(near[0]) - target) < 1e-9
    np.testing.assert_allclose(q0 + dv[0, 0, 0], near[0], atol=1e-12)
    assert np.max(np.abs(dv[0, 0, 0])) < np.min(np.max(np.abs(dv[0, 1:, 0]), axis=-1))
    monkeypatch.setattr(seeding, "NEAR_TARGETS", False)
    _, dv_off, _ = seed_grid(Problem(panda, joint_state(q0), point(target), k=4), options)
    assert dv_off.shape[1] == dv.shape[1] - 1
    np.testing.assert_allclose(dv_off, dv[:, 1:])


def test_limited_random_families_solve_half_as_many_starts_more(panda, galicki):
    """RANDOM_STARTS_EXTRA: 24 seed pairs for the default 16 on an arm with random IK seeds
    and joint limits (a single start stays one); a planar arm keeps ``starts``."""
    from tocontrol_ros.core.methods.seeding import seed_pairs, starts_solved

    q0 = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.6, 0.5])
    problem = Problem(panda, point(panda.point(q0)), point(panda.point(q0 + 0.3)), k=4)
    assert starts_solved(problem, SolverOptions()) == 24
    assert len(seed_pairs(problem, SolverOptions())) == 24
    assert starts_solved(problem, SolverOptions(starts=1)) == 1
    assert starts_solved(problem, SolverOptions(starts=5)) == 7
    planar = Problem(galicki, point([1.0, 1.0]), point([2.2, 1.5]), k=4)
    assert starts_solved(planar, SolverOptions()) == 16
    assert len(seed_pairs(planar, SolverOptions())) == 16
