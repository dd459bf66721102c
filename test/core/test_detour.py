"""The detour seed: a collision-free joint path from OMPL for the bounded solve (issue 51).

:mod:`tocontrol_ros.core.direct.detour`: the spheres' distances bound the exact ones from
below; the detour's waypoints are clear of the scene by Coal along their straight segments;
the same request gives the same path to the bit (OMPL seeded per query, stopped by a count
of checks), also after other OMPL queries in the process.
"""

from __future__ import annotations

import numpy as np
import pytest

coal = pytest.importorskip("coal")
ompl = pytest.importorskip("ompl")

from tocontrol_ros.core.direct.detour import (  # noqa: E402
    MAX_CHECKS,
    detour_guess,
    path_collides,
    sphere_distances,
)
from tocontrol_ros.core.geometry.scene import scene_from_dict  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

Q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
#: A target across a wall from the start: the straight joint path goes through it.
Q1 = np.array([1.6, -0.3, 0.0, -2.0, 0.0, 1.7, 0.8])


@pytest.fixture(scope="module")
def panda(panda_collision):
    model, _, _, col = panda_collision  # one for the session (conftest.py)
    return model, col


def _wall_problem(model, col):
    """A vertical board between the start's hand and the target's (and the table)."""
    p0, p1 = model.point(Q0), model.point(Q1)
    mid = 0.5 * (p0 + p1)
    scene = scene_from_dict({"obstacles": [
        {"name": "table", "type": "box", "size": [1.6, 1.6, 0.04], "position": [0.3, 0, -0.02]},
        {"name": "wall", "type": "box", "size": [0.02, 0.3, 0.3],
         "position": [float(mid[0]), float(mid[1]), float(mid[2])],
         "orientation": _facing(p1 - p0)}],
        "allowed": [["panda_link0", "table"], ["panda_link1", "table"]]})
    return Problem(model, joint_state(Q0), point(p1), k=4.0,
                   limits=JointLimits.from_model(model), collision=col.with_scene(scene))


def _facing(direction):
    """A quaternion (x, y, z, w) turning the box's x axis to the horizontal ``direction``."""
    yaw = float(np.arctan2(direction[1], direction[0]))
    return [0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2))]


def test_sphere_distances_bound_the_exact_ones_from_below(panda):
    """At random configurations, no pair's sphere distance exceeds Coal's distance."""
    model, col = panda
    problem = _wall_problem(model, col)
    rng = np.random.default_rng(3)
    lim = problem.limits
    q = lim.plan_lower + rng.uniform(0, 1, (25, model.n)) * (lim.plan_upper - lim.plan_lower)
    spheres = sphere_distances(problem.collision, q)
    exact = problem.collision.clearance(q).pair_distances
    pairs = problem.collision.obstacle_pairs() + problem.collision.self_pairs
    assert spheres.shape == (25, len(pairs))
    for j, pair in enumerate(pairs):
        assert np.all(spheres[:, j] <= exact[pair] + 1e-9), pair


def test_the_detour_goes_around_the_wall_and_is_the_same_every_time(panda):
    model, col = panda
    problem = _wall_problem(model, col)
    straight = Q0 + np.linspace(0, 1, 101)[:, None] * (Q1 - Q0)
    assert path_collides(problem.collision, straight)  # the seed a multistart would start on
    first = detour_guess(problem)
    assert first.guess is not None, first.note
    assert 0 < first.checks <= 3 * MAX_CHECKS
    guess = first.guess
    way = guess.waypoints
    np.testing.assert_array_equal(way[0], Q0)
    np.testing.assert_allclose(model.point(way[-1]), problem.target.value, atol=1e-6)
    # Every straight segment between the waypoints is clear by the margin (Coal).
    dense = np.concatenate([a + np.linspace(0, 1, 40)[:, None] * (b - a)
                            for a, b in zip(way[:-1], way[1:], strict=True)])
    assert problem.collision.clearance(dense).minimum >= problem.collision.margin
    # The timed guess: from the start at rest to the goal at rest, its samples in order.
    n = model.n
    assert guess.T > 0 and guess.t[0] == 0 and guess.t[-1] == pytest.approx(guess.T)
    np.testing.assert_allclose(guess.x[0, :n], Q0)
    np.testing.assert_allclose(guess.x[-1, :n], way[-1], atol=1e-12)
    np.testing.assert_allclose(guess.x[[0, -1], n:], 0.0, atol=1e-12)
    # The same request again, after an unrelated OMPL query: the same path to the bit.
    other = _wall_problem(model, col)
    detour_guess(other)
    again = detour_guess(problem)
    np.testing.assert_array_equal(again.guess.waypoints, way)
    assert again.guess.T == guess.T and again.checks == first.checks


def test_the_speed_term_scales_only_the_clearance_rows(panda):
    """``with_speed_term(0)``: the clearance rows without the bound between the samples.

    The other rows are the same numbers; each clearance row is at least as high (each
    sphere's term is >= 0) and some far higher on a 1.6 rad move, a scale between lies
    between; scale 1 is the transcription itself.
    """
    from tocontrol_ros.core.planning.solver import Planner

    model, col = panda
    problem = _wall_problem(model, col)
    flat = Planner(model).flat(problem, 8)
    assert flat.with_speed_term(1.0) is flat
    with pytest.raises(ValueError, match="scale"):
        flat.with_speed_term(-1.0)
    path = Q0 + np.linspace(0, 1, 41)[:, None] * (Q1 - Q0)
    t = np.linspace(0.0, 2.0, 41)
    P = flat.fit(2.0, t, path, np.tile((Q1 - Q0) / 2.0, (41, 1)))
    w = np.concatenate([P.ravel(), [2.0]])
    ends = (problem.start.value, problem.target.value, 4.0)
    zero, half = flat.with_speed_term(0.0), flat.with_speed_term(0.5)
    g1 = np.array(flat.row_function(w, flat.parameters(*ends))).ravel()
    g0 = np.array(zero.row_function(w, zero.parameters(*ends))).ravel()
    rows = flat._ng_clear
    np.testing.assert_array_equal(g0[:-rows], g1[:-rows])
    assert np.all(g0[-rows:] >= g1[-rows:]) and np.any(g0[-rows:] > g1[-rows:] + 1e-3)
    half = np.array(half.row_function(w, half.parameters(*ends))).ravel()
    # Each sphere's term is >= 0, so a row falls as the scale grows.
    assert np.all(half[-rows:] <= g0[-rows:]) and np.all(half[-rows:] >= g1[-rows:])


def test_a_detour_only_where_the_seeds_paths_collide(panda):
    """The bounded solve's candidates get the detour when a seed's guess goes through the wall."""
    from types import SimpleNamespace

    from tocontrol_ros.core.direct.limited import _detour

    model, col = panda
    problem = _wall_problem(model, col)
    ctx = SimpleNamespace(problem=problem, check=lambda: None)
    t = np.linspace(0.0, 1.0, 25)

    def guess(q1):
        q = Q0 + (3 * t**2 - 2 * t**3)[:, None] * (q1 - Q0)
        return SimpleNamespace(T=1.0, t=t, x=np.hstack([q, np.zeros_like(q)]))

    wrist = Q0 + np.array([0, 0, 0, 0, 0, 0, 1.0])  # the hand turns in place: clear
    records, notes = [], []
    assert _detour(ctx, [], [(0, guess(wrist))], records, notes) == []
    assert records == [] and notes == []
    out = _detour(ctx, [], [(0, guess(wrist)), (1, guess(Q1))], records, notes)
    assert len(out) == 1 and out[0][0] == 0 and len(records) == 1
    assert records[0].status == "detour seed" and "RRTConnect" in notes[0]
    np.testing.assert_array_equal(out[0][1].waypoints[0], Q0)


def test_a_detour_that_fails_on_its_spans_is_solved_again_on_finer_ones(panda, monkeypatch):
    """``_detour_solve``: its steps on ``SPANS``; where one fails, all again on ``DETOUR_SPANS``.

    A stand-in planner records the solves (spans, speed-term scale, exponent) and fails the
    true rows on ``SPANS``: the steps are run again on ``DETOUR_SPANS`` from the guess, and
    the result has that mesh's control points (``plan_limited`` builds its trajectory on the
    spans of the result).
    """
    from types import SimpleNamespace

    from tocontrol_ros.core.direct import limited

    model, col = panda
    problem = _wall_problem(model, col)
    n, calls = model.n, []

    class Flat:
        def __init__(self, spans, scale=1.0):
            self.spans, self.scale = spans, scale

        def fit(self, T, t, q, qd):
            return np.zeros((self.spans + 3, n))

        def with_speed_term(self, scale):
            return Flat(self.spans, scale)

        def solve(self, start, target, k, T, P, lower, upper, **budget):
            calls.append((self.spans, self.scale, k))
            ok = not (self.spans == limited.SPANS and self.scale == 1.0)
            return SimpleNamespace(success=ok, T=T * 0.9, P=np.ones((self.spans + 3, n)),
                                   message="Solve_Succeeded" if ok else "stopped")

    planner = SimpleNamespace(flat=lambda problem, spans, warm=False: Flat(spans))
    ctx = SimpleNamespace(problem=problem, check=lambda: None, deadline=np.inf,
                          should_stop=None)
    guess = SimpleNamespace(T=2.0, t=np.linspace(0, 2, 5), x=np.zeros((5, 2 * n)))
    out = limited._detour_solve(planner, ctx, (None, None), guess)
    steps = [(1.0, 0.0), (4.0, 0.0), (4.0, 1.0)]
    assert calls == [(limited.SPANS, s, k) for k, s in steps] + \
        [(limited.DETOUR_SPANS, s, k) for k, s in steps]
    assert out.success and out.P.shape == (limited.DETOUR_SPANS + 3, n)
    assert limited.DETOUR_SPANS > limited.SPANS


#: Draws 13 and 25 of bench/collision.py's table stream: start joint states (rad) and target
#: hand points (m), each low over the table on the other side of the base.
TABLE_DRAWS = {
    13: ([0.7676883784319524, -0.66987192105332, 2.586024063934725, -2.1133950210454104,
          -2.800645792255568, 2.9316036789713413, -2.702685025334956],
         [0.5784100301509182, 0.2357042291468865, 0.10632463568848585]),
    25: ([0.18924609623768482, -1.591823141703669, -1.9077044175198494, -1.8317329811602316,
          -2.578154398670878, 2.300149624247468, 2.786248454072743],
         [0.04956826700555722, 0.6970174356100234, 0.1526618623742641])}


@pytest.mark.slow
@pytest.mark.parametrize("draw", [13, 25])
def test_the_table_draws_whose_seeds_fail_plan_on_the_detour(panda, draw):
    """Draws 13 and 25 of the bench's table (4 starts, 1 candidate) plan, clear by Coal.

    Before session 38 both were ``LIMITS_INFEASIBLE``: every basin's bounded solve stopped
    at its iteration limit. Draw 13 got no detour (the coarse guess of its first basin was
    clear of the table; the finer guess its solve starts from goes through it); draw 25's
    detour stopped at 300 iterations on 32 spans and converges on 64. The motion returned is
    the detour's (the last start record).
    """
    from tocontrol_ros.core import SolverOptions, plan

    model, col = panda
    q0, target = TABLE_DRAWS[draw]
    scene = scene_from_dict({"obstacles": [
        {"name": "table", "type": "box", "size": [1.6, 1.6, 0.04], "position": [0.3, 0, -0.02]}],
        "allowed": [["panda_link0", "table"], ["panda_link1", "table"]]})
    problem = Problem(model, joint_state(np.array(q0)), point(np.array(target)), k=4.0,
                      limits=JointLimits.from_model(model), collision=col.with_scene(scene))
    res = plan(problem, SolverOptions(starts=4, candidates=1, time_limit=600))
    assert res.success, res.message
    assert res.starts[-1].status == "returned" and any("detour" in w for w in res.warnings)
    q = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001)).q
    assert problem.collision.clearance(q).minimum >= problem.collision.margin
    np.testing.assert_allclose(model.point(q[-1]), target, atol=1e-4)
