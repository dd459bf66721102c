"""A memory hit's first motion at once: the stored motion moved onto the request's ends.

The paper's arm with the velocity limits of test_bounded.py (the bounded B-spline solve), a
motion stored with its 64-span serving state, and hits 5 and 8 cm away (test_early.py's).
Checked: the blends keep each end's first three control points together (position,
velocity and acceleration at the ends kept) and move nothing when the ends do not move;
through ``recall``, the moved motion is offered before any re-solve (no iteration),
certified, and checked again independently (the start and the target, rest at both ends,
the velocity limits and the torque set along a fine sampling), never faster than the
optimum; the answer is the same to the bit with it; where no time factor holds the rows, or
the moved motion's checks raise, IPOPT's first certified iterate is offered instead and the
answer is unchanged. (Side by side with a receiver: test_serve.py.)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from limited_arm import LIMITS, OPTIONS, SPANS, check_motion, problem, served_memory

import tocontrol_ros.core.direct.shifted as shifted
from tocontrol_ros.core.memory.codec import warm_result
from tocontrol_ros.core.memory.recall import recall, stored_problem

STORED = np.array([2.2, 1.5])
HITS = (STORED + np.array([0.04, 0.03]), STORED + np.array([0.08, 0.0]))
#: Generous: the first solve of a kind compiles its NLP (an event bound, not a timing).
SLOW_OK = 600.0
FAR = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True, time_limit=SLOW_OK)


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    """The planner and a memory holding the stored motion with its serving state."""
    planner, store = served_memory(tmp_path_factory.mktemp("shifted") / "m.sqlite", STORED)
    yield planner, store
    store.close()


def _warm(store, target):
    entry = store.get(int(store.keys()["id"][0]))
    return warm_result(stored_problem(problem(target), entry.request), "path", entry.serve,
                       entry.method, "stored")


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


def _recall(planner, store, target, first=None):
    return recall(planner, problem(target), replace(OPTIONS, time_limit=SLOW_OK), store,
                  spans=SPANS, first=first)


def test_spans_stretched_run_a_too_fast_path_slower_where_it_breaks_the_limits(memory):
    """The stored path run at half its time breaks the velocity rows and the set: stretched
    span by span, it takes more time and breaks the rows by less."""
    from tocontrol_ros.core.direct.limited import state_bounds
    from tocontrol_ros.core.direct.tuning import PAD

    planner, store = memory
    own = problem(STORED)
    warm = _warm(store, STORED).warm_state
    flat = planner.flat(own, warm.breaks, warm="dual_far")
    P, T = np.asarray(warm.P), 0.5 * float(warm.T)
    values = (own.start.value, own.target.value, own.k)
    bounds = state_bounds(own, PAD)
    breaks, T_spans = shifted.span_stretched(flat, P, T, own.k, LIMITS.velocity)
    assert len(breaks) == len(flat.breaks) and breaks[0] == 0.0 and breaks[-1] == 1.0
    assert np.all(np.diff(breaks) > 0.0) and T_spans > T
    fast = flat.residual(*values, T, P, *bounds)
    stretched = flat.on(breaks).residual(*values, T_spans, P, *bounds)
    assert stretched < 0.5 * fast, (stretched, fast)


@pytest.mark.parametrize("target", HITS, ids=["5cm", "8cm"])
def test_a_hit_offers_its_stored_motion_moved_before_any_re_solve(memory, target):
    planner, store = memory
    plain = _recall(planner, store, target)
    assert plain.result is not None and plain.result.success, plain.messages
    firsts = []
    found = _recall(planner, store, target, firsts.append)
    assert len(firsts) == 1 and found.first is firsts[0]
    first = firsts[0]
    assert first.success and first.certificate is not None and first.certificate.passed
    assert first.iterations == 0 and any("route: shifted" in w for w in first.warnings)
    optimum = found.result
    assert first.T >= optimum.T * (1 - 1e-4), (first.T, optimum.T)
    check_motion(first, target)  # independently of the certificate
    # Offered before the re-solves: the answer is the same to the bit.
    assert optimum.T == plain.result.T and found.iterations == plain.iterations
    np.testing.assert_array_equal(optimum.warm_state.P, plain.result.warm_state.P)


def test_the_moved_motion_of_a_warm_state_by_its_method(memory):
    """The bounded method's ``first_from`` (what recall calls): with its ``why``; and the
    default of a method that has none."""
    from tocontrol_ros.core.methods.context import SolveContext
    from tocontrol_ros.core.methods.contract import method_named, method_owning

    planner, store = memory
    warm = _warm(store, HITS[0])
    ctx = SolveContext(planner.system, problem(HITS[0]), FAR, float("inf"))
    result, why = method_owning(warm.warm_state).first_from(planner, ctx, warm)
    assert result is not None and result.success and "times the stored T" in why, why
    none, why = method_named("first").first_from(planner, ctx, warm)
    assert none is None and "no first motion" in why


def test_without_a_time_that_holds_ipopts_iterate_is_offered(memory, monkeypatch):
    planner, store = memory
    monkeypatch.setattr(shifted, "SHIFT_FACTORS", (0.5,))  # far too fast: no row holds
    firsts = []
    found = _recall(planner, store, HITS[1], firsts.append)
    assert found.result is not None and found.result.success, found.messages
    assert len(firsts) == 1 and firsts[0].iterations > 0
    assert any("before it converged" in w for w in firsts[0].warnings)


def test_an_exception_in_the_moved_motion_leaves_ipopts_iterate_and_the_answer(
        memory, monkeypatch):
    planner, store = memory
    plain = _recall(planner, store, HITS[0])

    def broken(*args, **kwargs):
        raise RuntimeError("broken check")
    monkeypatch.setattr(shifted, "checked_iterate", broken)
    firsts = []
    found = _recall(planner, store, HITS[0], firsts.append)
    assert len(firsts) == 1 and firsts[0].iterations > 0  # IPOPT's, as before
    assert found.result.T == plain.result.T and found.iterations == plain.iterations
