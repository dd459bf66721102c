"""Recall: a hit is a certified warm re-solve in the basin of the nearest stored motions.

The paper's arm: a memory of a few motions from the paper's start, requests near and far.
A hit's motion is checked independently of the recall: its certificate (the nominal torques
re-integrated through the model land on the target at rest) and the cold multistart's T of
the same request (the recalled T within 1e-6 of it, relative). A far request is a miss and
nothing is solved.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tocontrol_ros.core import Planner, Problem, SolverOptions, load_robot, point
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.memory.recall import choose, distances, open_memory, recall, remember
from tocontrol_ros.core.robot.model import default_urdf_path

MODEL = load_robot(default_urdf_path())
STORED = ([2.2, 1.5], [2.0, 1.8], [1.6, 2.2])
OPTIONS = SolverOptions(starts=8, candidates=3)


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    planner = Planner(MODEL)
    path = tmp_path_factory.mktemp("memory") / "paper.sqlite"
    store = None
    for target in STORED:
        res = planner.plan(Problem(MODEL, point(PAPER_START), point(target), k=4), OPTIONS)
        assert res.success, res.message
        store = store or open_memory(path, res.problem, create=True)
        assert remember(store, res, "test", 0.0)
    yield planner, store
    store.close()


def test_a_near_request_is_a_certified_hit_as_good_as_the_cold_plan(memory):
    planner, store = memory
    problem = Problem(MODEL, point(PAPER_START), point([2.25, 1.45]), k=4)
    found = recall(planner, problem, OPTIONS, store)
    assert found.hit and found.result is not None, found.messages
    res = found.result
    assert res.success and res.certificate is not None and res.certificate.passed
    assert 0.0 < found.distance <= 1.0
    # Independent of the recall: the open loop re-integrated lands on the target.
    cert = certify_open_loop(problem, res.trajectory, res.certificate.options)
    assert cert.passed, cert.summary()
    assert np.linalg.norm(MODEL.point(res.trajectory.state(res.T)[0, :MODEL.n]) -
                          problem.target_point) < 1e-4
    cold = planner.plan(problem, OPTIONS)
    assert cold.success
    assert res.T <= cold.T * (1 + 1e-6), (res.T, cold.T)
    assert found.entries and found.entries[0] == int(store.keys()["id"][0])


def test_a_far_request_is_a_miss_and_solves_nothing(memory):
    planner, store = memory
    problem = Problem(MODEL, point(PAPER_START), point([3.0, -1.0]), k=4)
    found = recall(planner, problem, OPTIONS, store)
    assert not found.hit and found.result is None and found.entries == ()
    assert found.distance > 1.0 and found.timings["solve"] == 0.0


def test_other_kinds_are_infinitely_far_and_basins_are_distinct(memory):
    _, store = memory
    keys = store.keys()
    from tocontrol_ros.core.types.problem import joint_state

    state_start = Problem(MODEL, joint_state([0.3, 1.2, -0.4]), point([2.2, 1.5]), k=4)
    assert np.all(np.isinf(distances(keys, state_start, 0.05)))
    d = np.array([0.1, 0.2, 0.3])
    end_q = keys["end_q"]
    fake = dict(keys, end_q=np.vstack([end_q[0], end_q[0] + 0.01, end_q[0] + 1.0]))
    assert choose(fake, d, 1.0, 3) == [0, 2], "the second is the first's basin"
    assert choose(fake, d, 0.15, 3) == [0]
    del end_q


def test_first_success_stops_at_the_nearest_basin_that_solves(memory):
    planner, store = memory
    problem = Problem(MODEL, point(PAPER_START), point([2.25, 1.45]), k=4)
    chosen = choose(store.keys(), distances(store.keys(), problem, 0.05), 10.0, 3)
    assert len(chosen) >= 2, "the stored motions are distinct basins"
    every = recall(planner, problem, OPTIONS, store, radius=10.0, basins=3)
    first = recall(planner, problem, OPTIONS, store, radius=10.0, basins=3,
                   first_success=True)
    assert len(every.messages) == len(chosen), every.messages  # each basin re-solved
    assert first.result is not None and len(first.messages) == 1, first.messages
    assert first.starts == ("own mesh",) and first.iterations == first.result.iterations
    assert every.result is not None and every.result.T <= first.result.T


def test_maximum_principle_basins_stay_one_after_the_other(memory, monkeypatch):
    """With workers, the maximum principle's stored motions are not handed to the pool (its
    results hold CasADi expressions that do not pickle): re-solved one after the other, the
    same answer as with one worker. (The bounded motions' side by side: test_serve.py.)"""
    planner, store = memory
    problem = Problem(MODEL, point(PAPER_START), point([2.25, 1.45]), k=4)
    alone = recall(planner, problem, OPTIONS, store, radius=10.0, basins=3)
    maps = []
    real = type(planner).map

    def recorded(self, fn, ctx, items):
        maps.append((fn.__name__, len(items), ctx.options.workers))
        return real(self, fn, ctx, items)
    monkeypatch.setattr(type(planner), "map", recorded)
    side = recall(planner, problem, replace(OPTIONS, workers=2), store, radius=10.0, basins=3)
    assert maps == [], maps
    assert len(alone.entries) >= 2 and side.entries == alone.entries
    assert side.result is not None and alone.result is not None
    assert side.result.T == alone.result.T and side.result.success
    assert (side.starts, side.iterations) == (alone.starts, alone.iterations)


def test_a_maximum_principle_hit_with_a_first_receiver_gives_the_answer_alone(memory):
    """The maximum principle's method makes no first motion from a warm state (the
    contract's default) and its re-solve offers no iterates: a ``first`` receiver gets
    nothing, and the hit's answer is the one without it."""
    planner, store = memory
    problem = Problem(MODEL, point(PAPER_START), point([2.25, 1.45]), k=4)
    plain = recall(planner, problem, OPTIONS, store, radius=10.0)
    firsts = []
    found = recall(planner, problem, OPTIONS, store, radius=10.0, first=firsts.append)
    assert plain.result is not None and plain.result.method != "direct"
    assert firsts == [] and found.first is None and np.isnan(found.first_time)
    assert found.result.T == plain.result.T and found.iterations == plain.iterations
