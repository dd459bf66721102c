"""A memory hit's first motion at once: the stored motion moved onto the request's ends.

The paper's arm with the velocity limits of test_bounded.py (the bounded B-spline solve), a
motion stored with its 64-span serving state, and hits 5 and 8 cm away (test_early.py's).
Checked: the blends keep each end's first three control points together (position,
velocity and acceleration at the ends kept) and move nothing when the ends do not move;
the moved motion is offered before IPOPT starts (no iteration), certified, and checked
again independently (the start and the target, rest at both ends, the velocity limits and
the torque set along a fine sampling), never faster than the optimum; the optimum is the
same to the bit with it; where no time factor holds the rows, IPOPT's first certified
iterate is offered instead; an exception in the moved motion's checks ends the checks, not
the solve.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
from limited_arm import LIMITS, MODEL, OPTIONS, SPANS, problem

import tocontrol_ros.core.direct.shifted as shifted
from tocontrol_ros.core import Planner
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.memory.codec import warm_result
from tocontrol_ros.core.memory.recall import open_memory, remember, stored_problem
from tocontrol_ros.core.memory.serve import convert
from tocontrol_ros.core.methods.context import EarlyMotion
from tocontrol_ros.core.planning.solver import solve_once

STORED = np.array([2.2, 1.5])
HITS = (STORED + np.array([0.04, 0.03]), STORED + np.array([0.08, 0.0]))
#: Generous: the first solve of a kind compiles its NLP (an event bound, not a timing).
SLOW_OK = 600.0
FAR = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True, time_limit=SLOW_OK)


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    """The planner and a memory holding the stored motion with its serving state."""
    planner = Planner(MODEL)
    stored = planner.plan(problem(STORED), OPTIONS)
    assert stored.success and stored.method == "direct", stored.message
    store = open_memory(tmp_path_factory.mktemp("shifted") / "m.sqlite", stored.problem,
                        create=True)
    assert remember(store, stored, "test", 0.0)
    done = convert(store, planner, stored.problem, replace(OPTIONS, time_limit=SLOW_OK), SPANS)
    assert done.converted == 1, done.messages
    yield planner, store
    store.close()


def _warm(store, target):
    entry = store.get(int(store.keys()["id"][0]))
    return warm_result(stored_problem(problem(target), entry.request), "path", entry.serve,
                       entry.method, "stored")


def _hit(planner, store, target, early=None):
    """The nearest's warm re-solve as recall makes it (its serving state, warm_far)."""
    return solve_once(planner, problem(target), FAR, _warm(store, target), None,
                      time.perf_counter() + SLOW_OK, early)


def test_the_blends_keep_the_ends_and_move_nothing_without_a_move(memory):
    planner, store = memory
    warm = _warm(store, HITS[0]).warm_state
    flat = planner.flat(problem(HITS[0]), warm.breaks, warm="dual_far")
    P, T = np.asarray(warm.P), float(warm.T)
    w = shifted.blend_weights(flat)
    assert w.shape == (flat.K,) and np.all(w[:3] == 0.0) and np.all(w[-3:] == 1.0)
    assert np.all(np.diff(w) >= 0.0)
    speed = LIMITS.velocity
    np.testing.assert_allclose(shifted.slack_moved(flat, P, T, P[0], P[-1], speed), P,
                               atol=1e-12)
    qa, qb = P[0] + 0.01, P[-1] + np.array([0.05, -0.03, 0.02])
    moved = shifted.slack_moved(flat, P, T, qa, qb, speed)
    np.testing.assert_allclose(moved[:3], P[:3] + (qa - P[0]), atol=1e-12)
    np.testing.assert_allclose(moved[-3:], P[-3:] + (qb - P[-1]), atol=1e-12)
    # Without a speed limit every joint takes the smooth blend's share: the sums of the
    # derivative's control points give the smooth blend's points, the ends included.
    smooth = P + (1.0 - w[:, None]) * (qa - P[0]) + w[:, None] * (qb - P[-1])
    np.testing.assert_allclose(shifted.slack_moved(flat, P, T, qa, qb, np.full(3, np.inf)),
                               smooth, atol=1e-12)


@pytest.mark.parametrize("target", HITS, ids=["5cm", "8cm"])
def test_a_hit_offers_its_stored_motion_moved_before_ipopt_starts(memory, target):
    planner, store = memory
    optimum = _hit(planner, store, target)
    assert optimum.success, optimum.message
    offered = []
    early = EarlyMotion(offer=lambda r: offered.append(r) or True)
    again = _hit(planner, store, target, early)
    assert len(offered) == 1 and early.done, early.seen
    first = offered[0]
    assert first.success and first.certificate is not None and first.certificate.passed
    assert first.iterations == 0 and any("route: shifted" in w for w in first.warnings)
    assert early.seen[0]["shifted"] and early.seen[0]["certified"], early.seen
    assert len(early.seen) == 1, "IPOPT's iterates not checked once a motion was offered"
    assert first.T >= optimum.T * (1 - 1e-4), (first.T, optimum.T)
    # Checked independently of the certificate, along a fine sampling of the motion.
    s = first.trajectory.sample(1e-3)
    np.testing.assert_allclose(MODEL.point(s.q[0]), PAPER_START, atol=1e-6)
    np.testing.assert_allclose(MODEL.point(s.q[-1]), target, atol=1e-5)
    np.testing.assert_allclose(s.qd[[0, -1]], 0.0, atol=1e-5)
    assert np.all(np.abs(s.qd) <= LIMITS.velocity * (1 + 1e-6) + 1e-9)
    assert np.max(np.sum(np.abs(s.u) ** (2 * first.k), axis=1)) <= 1.0 + 1e-6
    # Offered before the solve: the optimum is the same to the bit.
    assert again.success and again.T == optimum.T and again.iterations == optimum.iterations
    np.testing.assert_array_equal(again.warm_state.P, optimum.warm_state.P)


def test_without_a_time_that_holds_ipopts_iterate_is_offered(memory, monkeypatch):
    planner, store = memory
    monkeypatch.setattr(shifted, "SHIFT_FACTORS", (0.5,))  # far too fast: no row holds
    offered = []
    early = EarlyMotion(offer=lambda r: offered.append(r) or True)
    res = _hit(planner, store, HITS[1], early)
    assert res.success, res.message
    assert early.seen[0]["shifted"] and "none of" in early.seen[0]["why"], early.seen[0]
    assert len(offered) == 1 and offered[0].iterations > 0
    assert any("before it converged" in w for w in offered[0].warnings)


def test_an_exception_in_the_moved_motions_checks_ends_the_checks_not_the_solve(
        memory, monkeypatch):
    planner, store = memory
    plain = _hit(planner, store, HITS[0])

    def broken(*args, **kwargs):
        raise RuntimeError("broken check")
    monkeypatch.setattr(shifted, "checked_iterate", broken)
    offered = []
    early = EarlyMotion(offer=lambda r: offered.append(r) or True)
    res = _hit(planner, store, HITS[0], early)
    assert offered == [] and early.done
    assert "broken check" in early.seen[0]["error"], early.seen
    assert res.success and res.T == plain.T and res.iterations == plain.iterations
