"""The arm's own pairs as rows of the bounded solve (issue 51).

A self pair is a row only when the collision model's ``row_pairs`` names it (the planner
adds the pairs a motion refused by the certificate brought close); the rows are the
smooth minimum over the two links' sphere pairs of their distance less the margin.
"""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pytest

coal = pytest.importorskip("coal")

from tocontrol_ros.core.direct.clearance import (  # noqa: E402
    SOFTMIN_SHARPNESS,
    clearance_functions,
    clearance_rows,
)
from tocontrol_ros.core.geometry.collision import body_frames  # noqa: E402

Q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
PAIRS = [("panda_link6", "panda_link1"), ("panda_link0", "panda_hand")]


@pytest.fixture(scope="module")
def panda(panda_collision):
    model, _, _, col = panda_collision  # one for the session (conftest.py)
    return model, col


def test_row_pairs_are_checked_self_pairs_and_part_of_the_key(panda):
    _, col = panda
    assert col.row_pairs == ()
    rows = col.with_row_pairs(PAIRS)
    # either order; stored as the model lists them
    assert set(rows.row_pairs) == {("panda_link1", "panda_link6"),
                                   ("panda_link0", "panda_hand")}
    assert rows.key() != col.key()
    assert rows.with_row_pairs(PAIRS[:1]).row_pairs == rows.row_pairs  # no duplicate
    with pytest.raises(ValueError, match="panda_link5.*not a checked self pair"):
        col.with_row_pairs([("panda_link5", "panda_link6")])  # adjacent: never checked
    again = pickle.loads(pickle.dumps(rows))  # a worker process's copy keeps them
    assert again.row_pairs == rows.row_pairs and again.key() == rows.key()
    assert col.with_scene(col.scene).row_pairs == ()


def test_self_rows_are_the_sphere_pairs_distance_less_the_margin(panda):
    """At rest (no speed term) each pair row is the smooth minimum of its sphere pairs'
    distances less the margin: at most the least of them, within log(count) / sharpness.
    A pair with the base (``panda_link0``, whose hull is tighter than its spheres) holds the
    other link's spheres against the hull's planes (:meth:`LinkHull.distance`)."""
    model, col = panda
    rows = clearance_rows(col.with_row_pairs(PAIRS))
    assert len(rows.radius) == 0 and len(rows.pair_radius) + len(rows.hull_radius) \
        == rows.count > 0
    assert set(rows.pair_names) == {("panda_link1", "panda_link6")}
    assert set(rows.hull_names) == {("panda_link0", "panda_hand")}
    hull = col.row_hull("panda_link0")
    groups = rows.groups()
    assert len(groups) == 2  # one row per pair of bodies
    value = clearance_functions(model, rows, 3)[0]
    rng = np.random.default_rng(5)
    Q = len(rows.pair_radius)
    for q in [Q0, *(Q0 + rng.uniform(-0.8, 0.8, size=(3, model.n)))]:
        b = np.zeros((1, 4))
        b[0, 0] = 1.0
        g = np.array(value(np.tile(q[:, None], (1, 4)), 1.0, b, np.zeros(4))).ravel()
        rots, poss = body_frames(model, q[None])
        for gi, idx in zip(g, groups, strict=True):
            d = []
            for i in idx:
                if i >= Q:  # a hand sphere against the base's hull
                    j, body = i - Q, rows.hull_body[i - Q]
                    c = poss[0, body + 1] + rots[0, body + 1] @ rows.hull_center[j]
                    d.append(float(hull.distance(c[None])[0]) - rows.hull_radius[j]
                             - col.margin)
                    continue
                ends = [poss[0, body + 1] + rots[0, body + 1] @ rows.pair_center[i, k]
                        for k, body in enumerate(rows.pair_body[i])]
                d.append(np.linalg.norm(ends[0] - ends[1]) - rows.pair_radius[i].sum()
                         - col.margin)
            assert min(d) - np.log(len(idx)) / SOFTMIN_SHARPNESS - 1e-9 <= gi <= min(d) + 1e-9


def test_the_base_hull_bounds_coal_from_below_and_is_tighter_than_its_spheres(panda):
    """The hull's smooth plane distance is never above Coal's exact distance to
    ``panda_link0``'s mesh, and stands far closer to it than the base's spheres: on 3000
    points around the base up to 5 cm out, worst shortfall under 1 cm (the spheres': over
    3 cm); the recorded gap is what the probes found."""
    _, col = panda
    hull = col.row_hull("panda_link0")
    assert hull is not None and hull.body == -1 and len(hull.planes) < 150
    spheres = next(s for s in col.spheres if s.link == "panda_link0")
    assert 0.0 <= hull.gap < 0.01 < 0.03 < spheres.gap
    shape = next(s for s in col.shapes if s.link == "panda_link0")
    rng = np.random.default_rng(34)
    pts = rng.uniform([-0.3, -0.25, -0.05], [0.25, 0.25, 0.3], size=(3000, 3))
    request, point = coal.DistanceRequest(), coal.Sphere(1e-9)
    exact = np.array([coal.distance(shape.geometry(), coal.Transform3s(shape.rotation,
                                                                          shape.translation),
                                    point, coal.Transform3s(np.eye(3), x), request,
                                    coal.DistanceResult()) for x in pts])
    bound = hull.distance(pts)
    outside = np.any(pts @ hull.planes[:, :3].T + hull.planes[:, 3] > 0, axis=1)
    near = outside & (exact < 0.05)
    assert near.sum() > 200
    assert np.all(bound[outside] <= exact[outside] + 1e-8)  # a lower bound everywhere out
    assert np.max(exact[near] - bound[near]) < 0.01
    by_spheres = np.min(np.linalg.norm(pts[:, None] - spheres.centers[None], axis=2)
                        - spheres.radii, axis=1)
    assert np.max(exact[near] - by_spheres[near]) > 0.03


def test_the_hull_rows_derivatives_are_the_distances_own(panda):
    """The hull rows enter the Hessian through a second-order expansion about a stand-in
    point replaced by the sphere's centre: their gradient and the Lagrangian's Hessian
    match central finite differences of the values and of the gradient."""
    model, col = panda
    rows = clearance_rows(col.with_row_pairs(PAIRS))
    assert len(rows.hull_radius) > 0
    value, grad, hess = clearance_functions(model, rows, 3)
    n = model.n
    rng = np.random.default_rng(34)
    P = np.tile(np.array([0.0, 0.9, 0.0, -2.2, 0.0, 2.0, 0.8])[:, None], (1, 4)) \
        + rng.normal(0.0, 0.05, (n, 4))
    b, geo = np.array([[0.2, 0.5, 0.25, 0.05]]), np.array([0.01, 3.0, 3.0, 3.0])
    lam = rng.uniform(0.5, 1.5, len(rows.groups()))
    z = np.concatenate([P.ravel(order="F"), [1.0]])

    def at(fun, w, *extra):
        return fun(w[:-1].reshape(n, 4, order="F"), w[-1], b, geo, *extra)

    jac = np.array(at(grad, z)[1])
    eps, eye = 1e-6, np.eye(len(z))
    fd = np.column_stack([(np.array(at(value, z + eps * e)) - np.array(at(value, z - eps * e)))
                          .ravel() / (2 * eps) for e in eye])
    assert np.max(np.abs(fd - jac)) < 1e-7
    upper = np.array(at(hess, z, lam)).ravel()
    full = np.zeros((len(z), len(z)))
    k = 0
    for c in range(len(z)):
        for r in range(c + 1):
            full[r, c] = full[c, r] = upper[k]
            k += 1
    fd = np.column_stack([(lam @ np.array(at(grad, z + eps * e)[1])
                           - lam @ np.array(at(grad, z - eps * e)[1])) / (2 * eps) for e in eye])
    assert np.max(np.abs(fd - full)) < 1e-6 * max(1.0, np.max(np.abs(full)))


#: A joint-state move of the wrist (joints 5 and 6) past the upper arm: its obstacle-free
#: optimum brings the hand 1.7 cm from link 2 (Coal), inside a 3 cm margin, while both
#: ends are clear of every pair by more (5.3 cm, 4.3 cm).
SELF_START = np.array([0.802, -0.13, 1.248, -2.822, -0.595, 1.544, -0.291])
SELF_TARGET = np.array([0.802, -0.13, 1.248, -2.822, 0.6, 1.017, -0.291])
SELF_MARGIN = 0.03


# Two Panda plans, the second with self rows after a refused motion (over a minute under
# load): with the slow tests. The default run keeps the rows' values and derivatives against
# the sphere pairs and Coal, the pairs in the key, and a self-row round's warm solve and its
# retry (test_the_rows_added_retry_solves_the_warm_solves_nlp).
@pytest.mark.slow
def test_a_self_row_turns_a_refused_motion_into_a_certified_one(panda):
    """Without self rows the motion is refused by the certificate on ``panda_link2`` /
    ``panda_hand``; the planner makes the pairs it brought close rows, solves again and
    publishes a motion that the certificate and Coal at 2001 times find clear."""
    from tocontrol_ros.core import SolverOptions, plan
    from tocontrol_ros.core.checks.certificate import certify_open_loop
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model, col = panda
    col = col.with_scene(margin=SELF_MARGIN)
    for end in (SELF_START, SELF_TARGET):  # both ends are acceptable
        assert col.clearance(end[None]).minimum > SELF_MARGIN + 0.01
    limits = JointLimits.from_model(model)
    options = SolverOptions(starts=1, candidates=1, time_limit=600)
    ends = (joint_state(SELF_START), joint_state(SELF_TARGET))
    problem = Problem(model, *ends, limits=limits, collision=col)

    # The motion the planner has without any self row: refused by the exact check.
    free = plan(Problem(model, *ends, limits=limits), options)
    assert free.success, free.message
    refused = certify_open_loop(problem, free.trajectory)
    assert not refused.passed and not refused.item("clearance").passed
    assert refused.figures["closest_pair"] == "panda_link2/panda_hand"
    assert refused.figures["min_clearance"] < SELF_MARGIN

    res = plan(problem, options)
    assert res.success, res.message
    assert "self pairs made rows after a refused motion" in res.message
    assert "panda_link2/panda_hand" in res.message
    assert res.certificate.passed and res.certificate.item("clearance").passed
    sample = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001))
    exact = col.clearance(sample.q)  # every self pair, the rows' and the others
    assert exact.minimum >= SELF_MARGIN, (exact.minimum, exact.pair)
    assert np.allclose(sample.q[-1], SELF_TARGET, atol=1e-4)


def test_the_rows_added_retry_solves_the_warm_solves_nlp(panda, monkeypatch):
    """A self-row round's warm solve (``PathWarmState.rows_added``) that fails is tried
    again from IPOPT's default start on the same NLP: the same mesh, rows, parameters,
    start point and bounds, the set's pads per sample read off the refused motion included
    (session 35: the retry solved at the default pad). Both solves are made to fail here
    (recorded, not run): the plan then reports the failure."""
    from tocontrol_ros.core import SolverOptions
    from tocontrol_ros.core.direct import set_pads
    from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
    from tocontrol_ros.core.direct.tuning import SET_PAD
    from tocontrol_ros.core.direct.warm import PathWarmState
    from tocontrol_ros.core.planning.solver import Planner, solve_once
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state
    from tocontrol_ros.core.types.result import Status

    model, col = panda
    col = col.with_scene(margin=SELF_MARGIN).with_row_pairs([("panda_link2", "panda_hand")])
    limits = JointLimits.from_model(model)
    options = SolverOptions(starts=1, candidates=1, time_limit=600)
    ends = (joint_state(SELF_START), joint_state(SELF_TARGET))
    planner = Planner(model)
    free = planner.plan(Problem(model, *ends, limits=limits), options)
    assert free.success, free.message
    traj = free.trajectory
    warm = replace(free, warm_state=PathWarmState(np.array(traj.breaks), np.array(traj.result.P),
                                                  traj.T, None, None, rows_added=True))
    # This motion's own pads per sample are all the default (its torques peak at the
    # samples): pads that differ, so that the check below is not void.
    monkeypatch.setattr(set_pads, "row_pads",
                        lambda trajectory, samples: np.linspace(SET_PAD, 0.02, len(samples)))
    calls = []

    def recorded(self, start, target, k, T, P, lower, upper, set_pad=SET_PAD, **kw):
        calls.append({"warm": self.warm, "breaks": np.array(self.breaks), "rows": self.rows,
                      "par": self.parameters(start, target, k), "T": T, "P": np.array(P),
                      "pad": np.array(set_pad, dtype=float),
                      "bounds": self.bounds(lower, upper, set_pad, (start, target))})
        return FlatResult(success=False, message="failed on purpose (test)", T=T,
                          iterations=0, solve_time=0.0, P=np.asarray(P), residual=np.inf)

    monkeypatch.setattr(FlatTranscription, "solve", recorded)
    res = solve_once(planner, Problem(model, *ends, limits=limits, collision=col), options,
                     warm, None, np.inf)
    assert res.status is Status.LIMITS_INFEASIBLE and "failed on purpose" in res.message
    assert [c["warm"] for c in calls] == [True, "restart"]
    first, retry = calls
    assert first["pad"].ndim == 1 and np.any(first["pad"] > SET_PAD), first["pad"]
    assert first["rows"] == retry["rows"] and first["T"] == retry["T"]
    for key in ("breaks", "par", "P", "pad"):
        assert np.array_equal(first[key], retry[key]), key
    for a, b in zip(first["bounds"], retry["bounds"], strict=True):
        assert np.array_equal(a, b)


def test_with_a_scene_the_refinement_stops_at_the_span_cap(panda, monkeypatch):
    """With a collision model no refinement level finer than ``SCENE_MAX_SPANS`` spans is
    solved (the coarser mesh stands, certified); without one the same motion refines past
    it. The cap is lowered here to 48 spans (the free wrist move refines to 88)."""
    from tocontrol_ros.core import SolverOptions
    from tocontrol_ros.core.direct import limited
    from tocontrol_ros.core.direct.flat import FlatTranscription
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model, col = panda
    cap = 48
    monkeypatch.setattr(limited, "SCENE_MAX_SPANS", cap)
    spans = []
    solve = FlatTranscription.solve

    def recorded(self, *args, **kw):
        spans.append(self.spans)
        return solve(self, *args, **kw)

    monkeypatch.setattr(FlatTranscription, "solve", recorded)
    limits = JointLimits.from_model(model)
    options = SolverOptions(starts=1, candidates=1, workers=1, time_limit=600)
    ends = (joint_state(SELF_START), joint_state(SELF_TARGET))
    planner = Planner(model)
    free = planner.plan(Problem(model, *ends, limits=limits), options)
    assert free.success and free.intervals > cap, (free.message, free.intervals)
    spans.clear()
    # A margin that this motion keeps (no self row needed): only the cap differs.
    res = planner.plan(Problem(model, *ends, limits=limits,
                               collision=col.with_scene(margin=0.01)), options)
    assert res.success, res.message
    assert res.certificate.passed and res.intervals <= cap, res.intervals
    assert spans and max(spans) <= cap, spans
    assert res.T >= free.T * (1 - 1e-9), (res.T, free.T)


#: Case 1 table of bench/collision.py (seed 51, draw 1): the Panda from rest to a point
#: beside and below its base, the table at z = 0. Its obstacle-free optimum's basin (and the
#: detour) end with ``panda_link6`` touching ``panda_link1`` (session 34).
TABLE_START = np.array([-0.5058236111869907, 1.55925457731147, -1.5040060817705547,
                        -1.8126770703394903, 2.311806764435881, 2.1396296091672635,
                        1.2294727671857915])
TABLE_TARGET = np.array([-0.07706082819959903, -0.16913943229740502, 0.1827177659078575])


@pytest.mark.slow
def test_a_point_target_whose_free_basins_touch_themselves_is_planned_clear(panda):
    """The bench's case 1 table: planned (about 75 s here), certified, and clear of the
    table and of every self pair by the margin by Coal at 2001 times (session 34: the
    self-row round from the refused motion converges from IPOPT's default start, where
    warm it stopped at its work limit)."""
    from tocontrol_ros.core import SolverOptions, plan
    from tocontrol_ros.core.geometry.scene import scene_from_dict
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    model, col = panda
    scene = scene_from_dict({"frame": "panda_link0", "obstacles": [
        {"name": "table", "type": "box", "size": [1.6, 1.6, 0.04],
         "position": [0.3, 0.0, -0.02]}],
        "allowed": [["panda_link0", "table"], ["panda_link1", "table"]]}, "table")
    col = col.with_scene(scene)
    problem = Problem(model, joint_state(TABLE_START), point(TABLE_TARGET), k=4.0,
                      limits=JointLimits.from_model(model), collision=col)
    res = plan(problem, SolverOptions(starts=4, candidates=1, time_limit=600))
    assert res.success, res.message
    assert res.certificate.passed and res.certificate.item("clearance").passed
    sample = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001))
    exact = col.clearance(sample.q)
    assert exact.minimum >= col.margin, (exact.minimum, exact.pair)
    assert np.linalg.norm(model.point(sample.q[-1]) - TABLE_TARGET) < 1e-4
