"""A memory's hit by parametric path following (issue 50; core/direct/path_following.py).

The paper's arm with the velocity limits of test_bounded.py (solved by the bounded B-spline
transcription), a motion stored and converted to a 64-span serving state (solution and
multipliers), then a request 5 cm away: one parametric step from the stored solution does
not converge there (rows change activity), the walk in sub-moves does. Checked: the route
the plan's warnings name, the certificate and an independent re-integration, ``T`` against
the cold multistart's (the issue's 1e-3) and against IPOPT converged on the same NLP from the
same stored state (a second method); a walk that cannot arrive falls back to IPOPT and says
why; :func:`follow` on the transcription itself against IPOPT; and the distant warm start
that recall now asks (``warm_far``: IPOPT's barrier from 1e-5, no single step), the same
optimum as the replans' route.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
from limited_arm import MODEL, OPTIONS, SPANS, problem

import tocontrol_ros.core.direct.path_following as path_following
from tocontrol_ros.core import Planner, SolverOptions
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.limited import state_bounds
from tocontrol_ros.core.direct.tuning import PAD, SET_PAD
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.memory.serve import serve_result
from tocontrol_ros.core.planning.solver import solve_once

STORED = np.array([2.2, 1.5])
#: 5 cm from the stored target: 3 sub-moves of at most 2 cm.
NEAR = STORED + np.array([0.04, 0.03])
#: Generous: the first solve of a kind compiles its NLP (an event bound, not a timing).
SLOW_OK = 600.0


def _route(result) -> str:
    text = " ".join(result.warnings)
    return "parametric" if "(route: parametric)" in text else \
        "ipopt" if "(route: ipopt)" in text else "none"


@pytest.fixture(scope="module")
def served():
    """The planner, the stored motion's serving state on 64 spans and the near request."""
    planner = Planner(MODEL)
    stored = planner.plan(problem(STORED), OPTIONS)
    assert stored.success and stored.method == "direct", stored.message
    serve, blob = serve_result(planner, stored, replace(OPTIONS, time_limit=SLOW_OK), SPANS)
    assert blob is not None and serve.success, serve.message
    return planner, serve


def _warm(planner, serve, target, follow: bool):
    options = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_follow=follow,
                      time_limit=SLOW_OK)
    return solve_once(planner, problem(target), options, serve, None,
                      time.perf_counter() + SLOW_OK)


def test_sub_moves_split_each_end_by_its_step():
    a, b = np.zeros(3), np.array([0.05, 0.0, 0.0])
    assert path_following.sub_moves((a, a, 4.0), (a, b, 4.0)) == 3
    assert path_following.sub_moves((a, a, 4.0), (a, a + 0.01, 4.0)) == 1
    q = np.zeros(14)
    assert path_following.sub_moves((q, a, 4.0), (q + 0.12, a, 4.0)) == 3


def test_warm_follow_must_be_a_bool():
    with pytest.raises(ProblemError, match="warm_follow"):
        SolverOptions(warm_follow="yes")


def test_a_hit_by_the_walk_is_certified_and_as_good_as_the_multistart(served):
    planner, serve = served
    walked = _warm(planner, serve, NEAR, follow=True)
    assert walked.success, walked.message
    assert _route(walked) == "parametric", walked.warnings
    assert any("parametric path following: converged" in w for w in walked.warnings)
    assert walked.certificate is not None and walked.certificate.passed
    near = problem(NEAR)
    cert = certify_open_loop(near, walked.trajectory, walked.certificate.options)
    assert cert.passed, cert.summary()
    # The same NLP solved by IPOPT from the same stored state: the same optimum.
    single = _warm(planner, serve, NEAR, follow=False)
    assert single.success, single.message
    assert _route(single) == "ipopt", single.warnings  # one step does not arrive here
    assert walked.T == pytest.approx(single.T, rel=1e-6)
    cold = planner.plan(near, OPTIONS)
    assert cold.success, cold.message
    assert walked.T == pytest.approx(cold.T, rel=1e-3)


def test_a_walk_that_cannot_arrive_falls_back_to_ipopt_and_says_so(served, monkeypatch):
    planner, serve = served
    # No halving and no spare sub-move: the first sub-move that does not converge ends it.
    monkeypatch.setattr(path_following, "HALVINGS", 0)
    monkeypatch.setattr(path_following, "MAX_MOVES", 3)
    res = _warm(planner, serve, NEAR, follow=True)
    assert res.success, res.message
    text = " ".join(res.warnings)
    assert _route(res) == "ipopt", res.warnings
    assert "parametric path following: a sub-move failed" in text
    assert "solved by IPOPT instead" in text


def test_follow_on_the_transcription_matches_ipopt(served):
    planner, serve = served
    near = problem(NEAR)
    state = serve.warm_state
    flat = planner.flat(near, state.breaks, warm="dual")
    bounds = state_bounds(near, PAD)
    old = (serve.problem.start.value, serve.problem.target.value, serve.problem.k)
    new = (near.start.value, near.target.value, near.k)
    w0 = np.concatenate([state.P.ravel(), [state.T]])
    res, out = path_following.follow(flat, w0, state.lam_g, state.lam_x, old, new, *bounds,
                                     SET_PAD)
    assert res.success and out.reason == "converged", res.message
    assert out.reached == 1.0 and out.planned == 3 and out.moves >= out.planned
    assert res.iterations == out.steps > 0
    ipopt = flat.solve(*new, state.T, state.P, *bounds, SET_PAD, lam_g0=state.lam_g,
                       lam_x0=state.lam_x)
    assert ipopt.success, ipopt.message
    assert res.T == pytest.approx(ipopt.T, rel=1e-6)
    # The rows hold at the answer (its own residual, IPOPT's measure).
    assert res.residual < 1e-6


def test_a_distant_warm_start_goes_to_ipopt_with_its_wider_barrier(served):
    """``warm_far`` (what recall asks): IPOPT from the multipliers with its barrier from
    FAR_MU, no single parametric step; the same optimum of the same NLP as the replans'
    route, certified."""
    planner, serve = served
    options = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True,
                      time_limit=SLOW_OK)
    far = solve_once(planner, problem(NEAR), options, serve, None,
                     time.perf_counter() + SLOW_OK)
    assert far.success and far.certificate.passed, far.message
    text = " ".join(far.warnings)
    assert "a distant warm start (warm_far)" in text and "(route: ipopt)" in text
    assert "parametric step" not in text
    near = problem(NEAR)
    assert certify_open_loop(near, far.trajectory, far.certificate.options).passed
    single = _warm(planner, serve, NEAR, follow=False)
    assert far.T == pytest.approx(single.T, rel=1e-6)


@pytest.mark.parametrize("move, step", [(0.004, True), (0.013, False)])
def test_a_near_hit_tries_the_step_then_the_distant_start(served, move, step):
    """``warm_far`` whatever the move: a hit within ``FAR_STEP_MOVE`` sub-moves (0.6 cm)
    tries the single parametric step first (where it fails, IPOPT goes on from the distant
    start and says so); a farther one, 1.3 cm here, goes to IPOPT's distant start at once,
    no step. Each answer certified, the same optimum of the NLP as the replans' route."""
    from tocontrol_ros.core.direct.tuning import FAR_MU

    planner, serve = served
    target = STORED + move * np.array([0.6, 0.8])
    options = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True,
                      time_limit=SLOW_OK)
    res = solve_once(planner, problem(target), options, serve, None,
                     time.perf_counter() + SLOW_OK)
    assert res.success and res.certificate.passed, res.message
    assert certify_open_loop(problem(target), res.trajectory, res.certificate.options).passed
    text = " ".join(res.warnings)
    if step:
        assert _route(res) == "parametric" or (
            "parametric step" in text and f"barrier from {FAR_MU:g} (route: ipopt)" in text), text
    else:
        assert "a distant warm start (warm_far)" in text and "parametric step" not in text
    single = _warm(planner, serve, target, follow=False)
    assert res.T == pytest.approx(single.T, rel=1e-6)


def test_recall_re_solves_a_hit_as_a_distant_warm_start(served, tmp_path):
    from tocontrol_ros.core.memory.recall import open_memory, recall, remember
    from tocontrol_ros.core.memory.serve import convert

    planner, serve = served
    stored = planner.plan(problem(STORED), OPTIONS)
    with open_memory(tmp_path / "m.sqlite", stored.problem, create=True) as store:
        assert remember(store, stored, "test", 0.0)
        done = convert(store, planner, stored.problem, replace(OPTIONS, time_limit=SLOW_OK),
                       SPANS)
        assert done.converted == 1, done.messages
        found = recall(planner, problem(NEAR), replace(OPTIONS, time_limit=SLOW_OK), store,
                       spans=SPANS)
        before = recall(planner, problem(NEAR), replace(OPTIONS, time_limit=SLOW_OK), store,
                        spans=SPANS, far=False)
    assert found.hit and found.result is not None and found.result.success, found.messages
    assert found.starts[0] == "serve+multipliers"
    assert any("warm_far" in w for w in found.result.warnings)
    assert before.result is not None and before.result.success, before.messages
    assert not any("warm_far" in w for w in before.result.warnings)
    assert found.result.T == pytest.approx(before.result.T, rel=1e-6)
