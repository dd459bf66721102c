"""The executing solution's tail as a warm start, the warm replan and the hand-off lead."""

import numpy as np
import pytest

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.planning.replan import (
    TAIL_MIN_REMAINING,
    LatencyEstimate,
    tail_warm_start,
    warm_replan,
)
from tocontrol_ros.core.planning.solver import Planner, SolverOptions
from tocontrol_ros.core.types.problem import point


@pytest.fixture(scope="module")
def planner(galicki):
    return Planner(galicki)


@pytest.mark.parametrize("key", ["nodes", "uniform"])
def test_tail_to_the_same_target_is_the_rest_of_the_motion(solved, planner, key):
    # Principle of optimality: from x(t) the rest of the motion is optimal, with the same
    # costates; the cut mesh (switch nodes included) is already a solution.
    result = solved[key]
    t = 0.3 * result.T
    tail = tail_warm_start(result, t)
    z = result.trajectory.state(t)[0]
    n = result.problem.model.n
    assert tail.problem.start.kind == "state"
    np.testing.assert_allclose(tail.problem.start.value, z[:2 * n], atol=1e-12)
    again = warm_replan(planner, tail.problem, tail, SolverOptions())
    assert again.success, again.message
    assert again.T == pytest.approx(result.T - t, rel=1e-6)
    assert again.iterations < result.iterations  # no guess, no continuation


def test_tail_warm_replan_to_a_moved_target(solved, planner):
    result = solved["nodes"]
    tail = tail_warm_start(result, 0.2 * result.T)
    moved = result.problem.target_point + np.array([0.01, -0.01])
    problem = tail.problem.__class__(tail.problem.model, tail.problem.start, point(moved),
                                     k=tail.problem.k)
    again = warm_replan(planner, problem, tail, SolverOptions())
    assert again.success, again.message
    end = again.trajectory.evaluate(again.T)
    np.testing.assert_allclose(result.problem.model.point(end.q[0]), moved, atol=1e-6)
    np.testing.assert_allclose(end.qd[0], 0.0, atol=1e-6)


def test_no_tail_near_the_end_or_without_a_shooting_solution(solved):
    result = solved["nodes"]
    assert tail_warm_start(result, result.T * (1 - TAIL_MIN_REMAINING / 2)) is None
    from dataclasses import replace
    assert tail_warm_start(replace(result, warm_state=None), 0.1) is None


@pytest.mark.parametrize("t", [-0.1, float("nan"), float("inf")])
def test_tail_rejects_a_bad_time(solved, t):
    with pytest.raises(ProblemError, match="`t` must be a finite time >= 0"):
        tail_warm_start(solved["nodes"], t)


def test_latency_estimate_lead():
    est = LatencyEstimate(2.0, 0.02, window=5, initial=0.1)
    assert est.lead() == pytest.approx(0.02 + 2 * 0.1)
    for v in (0.01, 0.01, 0.01, 0.01, 0.5):  # one slow solve does not set the lead
        est.record(v)
    assert est.lead() < 0.02 + 2 * 0.5
    est.record(0.5)
    est.record(0.5)  # slow solves that persist do
    assert est.lead() > 0.02 + 2 * 0.4


def test_latency_estimate_lead_is_numpys_quantile():
    """The lead's high quantile, in plain Python since issue 47, is numpy's (linear)."""
    from tocontrol_ros.core.planning.tuning import HIGH_QUANTILE

    rng = np.random.default_rng(3)
    for size in (1, 2, 3, 7, 10, 15):
        est = LatencyEstimate(1.5, 0.02, window=10, initial=0.1)
        values = rng.exponential(0.02, size)
        for v in values:
            est.record(v)
        expect = 0.02 + 1.5 * np.quantile(values[-10:], HIGH_QUANTILE)
        assert est.lead() == pytest.approx(expect, rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("args, match", [
    ((0.5, 0.02), "`margin` must be a finite number >= 1"),
    ((2.0, 0.0), "`floor` must be a finite time > 0"),
    ((2.0, 0.02, 0), "`window` must be an integer >= 1"),
])
def test_latency_estimate_rejects_bad_arguments(args, match):
    with pytest.raises(ProblemError, match=match):
        LatencyEstimate(*args)


def _circle(model, angles):
    """bench/replan.py's circle (0.15 m about the arm's point at ``q0``) at ``angles`` (rad):
    ``q0`` and the points, shape (len(angles), 2)."""
    q0 = np.array([0.3, 0.9, 0.6])
    p0 = np.asarray(model.point(q0))
    return q0, p0 + 0.15 * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def _rest_stream(planner, q_from, targets, options):
    """Rest-to-rest problems along ``targets``, each from the last one's end (cold, one start)."""
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model = planner.model
    out, q = [], np.asarray(q_from, dtype=float)
    for p in targets:
        problem = Problem(model, joint_state(q), point(p), k=4.0)
        result = planner.plan(problem, options)
        assert result.success, result.message
        out.append(result)
        q = result.trajectory.state(result.T)[0][:model.n]
    return out


def test_wider_joint_radius_warm_starts_the_next_goal_of_a_stream(planner):
    # A stream of goals 1.9 cm apart (bench/replan.py's circle): the next rest-to-rest
    # problem starts where the last ended; its joint-state start is beyond the core's
    # warm-start radius, within the replans' one, and the warm solve lands on the motion a
    # cold solve finds (an independent check: T and the reached point).
    from tocontrol_ros.core.planning.tuning import REPLAN_JOINT_RADIUS
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model = planner.model
    q0, circle = _circle(model, np.linspace(0.0, 0.5, 6))
    one = SolverOptions(starts=1, candidates=1)
    stream = _rest_stream(planner, q0, circle[:2], one)
    last = stream[-1]
    q = last.trajectory.state(last.T)[0][:model.n]
    problem = Problem(model, joint_state(q), point(circle[2]), k=4.0)
    assert not last.can_warm_start(problem)
    assert last.can_warm_start(problem, REPLAN_JOINT_RADIUS)
    narrow = warm_replan(planner, problem, last, SolverOptions(warm_only=True))
    assert not narrow.success and "does not apply" in narrow.message
    wide = SolverOptions(warm_only=True, warm_joint_radius=REPLAN_JOINT_RADIUS)
    warm = warm_replan(planner, problem, [None, last], wide)
    assert warm.success, warm.message
    cold = planner.plan(problem, SolverOptions())
    assert warm.T == pytest.approx(cold.T, rel=1e-6)
    end = warm.trajectory.evaluate(warm.T)
    np.testing.assert_allclose(model.point(end.q[0]), circle[2], atol=1e-6)


def test_warm_replan_tries_its_warm_starts_in_turn(solved, planner):
    # The first warm start does not apply (another kind of start); the second does.
    result = solved["nodes"]
    tail = tail_warm_start(result, 0.2 * result.T)
    moved = result.problem.target_point + np.array([0.01, -0.01])
    problem = tail.problem.__class__(tail.problem.model, tail.problem.start, point(moved),
                                     k=tail.problem.k)
    assert not result.can_warm_start(problem)
    again = warm_replan(planner, problem, [result, tail], SolverOptions())
    assert again.success, again.message
    alone = warm_replan(planner, problem, tail, SolverOptions())
    assert again.T == pytest.approx(alone.T, rel=1e-12)
    failed = warm_replan(planner, problem, [result], SolverOptions())
    assert not failed.success and "does not apply" in failed.message


def test_warm_joint_radius_is_validated():
    with pytest.raises(ProblemError, match="warm_joint_radius"):
        SolverOptions(warm_joint_radius=0.0)


@pytest.mark.slow  # the default run keeps the stream's first warm step (wider radius)
def test_a_stream_of_replans_stays_warm_when_its_switches_change(planner):
    # Goals 1.9 cm apart along bench/replan.py's circle, each replan from rest at the last
    # goal, warm from the last solution (cold, one start, when that fails, as the node
    # does). Along the way the control gains or loses switches, which the warm start's
    # switch mesh cannot follow: 3 of these 6 warm solves converged with it alone, 5
    # with the warm motion resampled on a uniform mesh and smoothed again. Each warm one
    # lands where the default multistart from the same start lands (an independent check).
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model = planner.model
    q0, circle = _circle(model, 2 * np.pi * np.arange(8) / 50)
    wide = replan_options(SolverOptions())
    prev = _rest_stream(planner, q0, circle[:2], wide)[-1]
    warm_ones = 0
    for p in circle[2:]:
        q = prev.trajectory.state(prev.T)[0][:model.n]
        problem = Problem(model, joint_state(q), point(p), k=4.0)
        result = warm_replan(planner, problem, prev, wide)
        if result.success:
            warm_ones += 1
            cold = planner.plan(problem, SolverOptions())
            assert result.T == pytest.approx(cold.T, rel=1e-6)
        else:
            result = planner.plan(problem, wide)
            assert result.success, result.message
        prev = result
    assert warm_ones >= 5


def test_a_smoothed_replan_continues_a_finer_solution_at_its_smoothing(planner):
    # replan_options(smoothing=1e-3): the warm solve of the stream's next goal stays at that
    # delta (a few Newton iterations), is certified with the Hamiltonian tolerance raised to
    # it, and lands within 1e-4 (relative T) of the unsmoothed default plan (independent).
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.types.problem import Problem, joint_state

    model = planner.model
    q0, circle = _circle(model, 2 * np.pi * np.arange(3) / 50)
    fine = replan_options(SolverOptions())
    assert fine.smoothing == SolverOptions().smoothing and fine.starts == 1
    prev = _rest_stream(planner, q0, circle[:2], fine)[-1]
    assert prev.delta < 1e-5
    q = prev.trajectory.state(prev.T)[0][:model.n]
    problem = Problem(model, joint_state(q), point(circle[2]), k=4.0)
    smoothed = replan_options(SolverOptions(), 1e-3)
    assert smoothed.certificate.hamiltonian_tol == 1e-3
    result = warm_replan(planner, problem, prev, smoothed)
    assert result.success, result.message
    assert result.delta == 1e-3
    assert result.verification["max_abs_H"] <= 1e-3
    cold = planner.plan(problem, SolverOptions())
    assert abs(result.T / cold.T - 1) < 1e-4
    again = warm_replan(planner, problem, result, smoothed)  # the same problem: at once
    assert again.success and again.iterations <= 2


def test_a_quick_motions_rest_warm_starts_the_bounded_optimum(panda):
    """The Panda with its limits: a quick motion from a moving state (what a replan
    publishes first), its rest from a later time as the bounded solve's warm start
    (path_tail_warm_start): the optimum from that state, certified, to the same target,
    and faster than the rest of the quick motion; none at the motion's end."""
    from tocontrol_ros.core.direct.first_motion import first_motion, quick_motion
    from tocontrol_ros.core.planning.replan import path_tail_warm_start, replan_options
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state

    limits = JointLimits.from_model(panda).with_margin(0.05)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    p0 = panda.point(q0)
    running = first_motion(Problem(panda, joint_state(q0, np.zeros(7)),
                                   point(p0 + [0.2, 0.0, 0.0]), k=4.0, limits=limits))
    assert running.success, running.message
    t = 0.4 * running.T
    z = running.trajectory.state(t)[0]
    problem = Problem(panda, joint_state(z[:7], z[7:14]), point(p0 + [0.2, 0.05, 0.0]), k=4.0,
                      limits=limits)
    quick = quick_motion(problem, running.trajectory.state(running.T)[0][:7],
                         running.T - t)
    assert quick.success, quick.message
    t2 = 0.3 * quick.T
    tail = path_tail_warm_start(quick, t2)
    assert tail is not None and tail.T == pytest.approx(quick.T - t2)
    np.testing.assert_allclose(tail.trajectory.evaluate(np.array([0.0])).q[0],
                               quick.trajectory.state(t2)[0][:7], atol=1e-12)
    assert tail.can_warm_start(tail.problem)
    result = Planner(panda).plan(tail.problem, replan_options(SolverOptions(), 0.0, 24),
                                 warm_start=tail)
    assert result.success and result.certificate.passed, result.message
    assert result.method == "direct" and result.T < tail.T
    assert path_tail_warm_start(quick, quick.T) is None

