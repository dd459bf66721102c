"""A memory hit's first motion: a certified IPOPT iterate before the re-solve converges.

The paper's arm with the velocity limits of test_bounded.py (the bounded B-spline solve), a
motion stored with its 64-span serving state, then hits 5 and 8 cm away (distant warm
starts, ``warm_far``: tens of IPOPT iterations). Checked: the iterate offered is a motion
(within the NLP's residual tolerance, certified, and checked again independently: the end
point, the velocity limits and the torque set along a fine sampling), offered before the
solve converged, no faster than the optimum by more than the certificate's tolerance; the
optimum is the same to the bit with and without the watcher; through ``recall``, the first
motion goes to its receiver once and the hit's result is unchanged; a hit whose iterates are
never within the residual's tolerance before convergence offers nothing (the converged
motion alone); an exception in the checks or the receiver ends the checks, not the solve.
Here the stored motion moved onto the request (offered before IPOPT starts since session 40,
test_shifted.py) is switched off: these are IPOPT's iterates.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
from limited_arm import OPTIONS, SPANS, check_motion, problem, served_memory

import tocontrol_ros.core.direct.early as early_mod
import tocontrol_ros.core.direct.shifted as shifted
from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL
from tocontrol_ros.core.memory.recall import recall
from tocontrol_ros.core.methods.context import EarlyMotion
from tocontrol_ros.core.planning.solver import solve_once

STORED = np.array([2.2, 1.5])
#: Hits 5 and 8 cm from the stored target: distant warm starts (more than one 2 cm sub-move).
HITS = (STORED + np.array([0.04, 0.03]), STORED + np.array([0.08, 0.0]))
#: Generous: the first solve of a kind compiles its NLP (an event bound, not a timing).
SLOW_OK = 600.0
FAR = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True, time_limit=SLOW_OK)


@pytest.fixture(autouse=True)
def iterates_only(monkeypatch):
    """IPOPT's iterates alone (no moved stored motion before them)."""
    monkeypatch.setattr(shifted, "SHIFTED_FIRST", False)


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    """The planner and a memory holding the stored motion with its serving state."""
    planner, store = served_memory(tmp_path_factory.mktemp("early") / "m.sqlite", STORED)
    yield planner, store
    store.close()


def _hit(planner, store, target, early=None):
    """The nearest's warm re-solve as recall makes it (its serving state, warm_far)."""
    from tocontrol_ros.core.memory.codec import warm_result
    from tocontrol_ros.core.memory.recall import stored_problem

    entry = store.get(int(store.keys()["id"][0]))
    warm = warm_result(stored_problem(problem(target), entry.request), "path", entry.serve,
                       entry.method, "stored")
    return solve_once(planner, problem(target), FAR, warm, None,
                      time.perf_counter() + SLOW_OK, early)


def test_every_must_be_a_count():
    with pytest.raises(ValueError, match="every"):
        EarlyMotion(offer=lambda r: True, every=0)


def test_a_motion_is_given_when_certified_and_not_slower_than_max_t():
    """The one rule every source of a first motion offers through (IPOPT's iterates, the
    parametric steps', a hit's moved stored motion)."""
    from types import SimpleNamespace

    offered = []
    early = EarlyMotion(offer=lambda r: offered.append(r) or True, max_T=1.0)
    seen: dict = {}
    early.give(SimpleNamespace(success=False, T=0.5), seen)
    early.give(SimpleNamespace(success=True, T=1.5), seen)
    assert offered == [] and not early.done and seen == {"slow": True}
    fast = SimpleNamespace(success=True, T=0.9)
    early.give(fast)
    assert offered == [fast] and early.done


@pytest.mark.parametrize("target", HITS, ids=["5cm", "8cm"])
def test_a_hits_first_iterate_is_a_certified_motion_before_the_optimum(memory, target):
    planner, store = memory
    optimum = _hit(planner, store, target)
    assert optimum.success, optimum.message
    offered = []
    early = EarlyMotion(offer=lambda r: offered.append(r) or True)
    again = _hit(planner, store, target, early)
    assert len(offered) == 1 and early.done, early.seen
    first = offered[0]
    assert first.success and first.certificate is not None and first.certificate.passed
    assert first.residual <= RESIDUAL_TOL
    # Before convergence, by IPOPT's count, and slower than the optimum (to the tolerance of
    # its certificate: an iterate may sit a hair inside the rows the optimum touches).
    assert 0 < first.iterations < optimum.iterations
    assert first.T >= optimum.T * (1 - 1e-4), (first.T, optimum.T)
    assert any("before it converged" in w for w in first.warnings)
    check_motion(first, target)  # independently of the certificate
    # The watcher only reads: the optimum is the same to the bit.
    assert again.success and again.T == optimum.T and again.iterations == optimum.iterations
    np.testing.assert_array_equal(again.warm_state.P, optimum.warm_state.P)
    np.testing.assert_array_equal(again.warm_state.lam_g, optimum.warm_state.lam_g)


def test_recall_hands_the_first_motion_over_once_and_the_hit_is_unchanged(memory):
    planner, store = memory
    options = replace(OPTIONS, time_limit=SLOW_OK)
    firsts = []
    found = recall(planner, problem(HITS[1]), options, store, spans=SPANS,
                   first=firsts.append)
    plain = recall(planner, problem(HITS[1]), options, store, spans=SPANS)
    assert found.result is not None and found.result.success, found.messages
    assert len(firsts) == 1 and found.first is firsts[0]
    assert firsts[0].certificate.passed and firsts[0].T >= found.result.T * (1 - 1e-4)
    assert 0.0 < found.first_time and firsts[0].iterations < found.iterations
    assert plain.first is None and np.isnan(plain.first_time)
    assert found.result.T == plain.result.T and found.iterations == plain.iterations


def test_a_first_motion_much_slower_than_the_stored_one_is_not_offered(memory, monkeypatch):
    """The bound on a hit's first motion: at FIRST_MAX_RATIO times the stored motion's T
    (0.5 here, below any motion of the request) no iterate is offered, the slow ones are
    not even checked, and the hit's answer is the one without a receiver."""
    from tocontrol_ros.core.memory import recall as recall_mod

    planner, store = memory
    options = replace(OPTIONS, time_limit=SLOW_OK)
    plain = recall(planner, problem(HITS[1]), options, store, spans=SPANS)
    monkeypatch.setattr(recall_mod, "FIRST_MAX_RATIO", 0.5)
    firsts = []
    found = recall(planner, problem(HITS[1]), options, store, spans=SPANS,
                   first=firsts.append)
    assert firsts == [] and found.first is None
    assert found.result is not None and found.result.T == plain.result.T
    assert found.iterations == plain.iterations
    with pytest.raises(ValueError, match="max_T"):
        EarlyMotion(offer=firsts.append, max_T=0.0)


def test_a_hit_never_feasible_before_convergence_offers_nothing(memory, monkeypatch):
    # Every iterate taken as outside the residual's tolerance (the watcher's test alone: the
    # converged answer is judged by the bounded solve's own, unchanged).
    monkeypatch.setattr(early_mod, "RESIDUAL_TOL", -1.0)
    planner, store = memory
    firsts = []
    found = recall(planner, problem(HITS[0]), replace(OPTIONS, time_limit=SLOW_OK), store,
                   spans=SPANS, first=firsts.append)
    assert found.result is not None and found.result.success, found.messages
    assert firsts == [] and found.first is None


def test_an_error_in_the_checks_ends_them_and_never_the_solve(memory):
    planner, store = memory
    optimum = _hit(planner, store, HITS[1])

    def offer(result):
        raise RuntimeError("the receiver broke")

    early = EarlyMotion(offer=offer)
    again = _hit(planner, store, HITS[1], early)
    assert early.done and "RuntimeError: the receiver broke" in early.seen[-1]["error"]
    assert sum("error" in s for s in early.seen) == 1  # no check after it
    assert again.success and again.T == optimum.T and again.iterations == optimum.iterations
