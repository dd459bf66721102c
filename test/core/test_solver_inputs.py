"""Bad input raises ``ProblemError`` naming the argument; numerical outcomes never raise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tocontrol_ros.core.errors import ProblemError, TocontrolError
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import PlanResult, SolverOptions, Status, plan
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: One start: these tests do not depend on the basin, and multistart costs time.
SINGLE = SolverOptions(starts=1, candidates=1)

P_START, P_TARGET = PAPER_START, PAPER_TARGET
Q_OK = (0.1, 0.2, 0.3)


@pytest.mark.parametrize("start, target, kwargs, match", [
    (point((math.nan, 1.0)), point(P_TARGET), {}, r"`start point` must be finite"),
    (point(P_START), point((2.2, math.inf)), {}, r"`target point` must be finite"),
    (point((1.0, 1.0, 0.0)), point(P_TARGET), {}, r"`start point` must have shape \(2,\)"),
    (point(P_START), point((2.2,)), {}, r"`target point` must have shape \(2,\)"),
    (point(P_START), point((10.0, 0.0)), {}, r"`target` point .* not reachable"),
    (point((0.0, -7.0)), point(P_TARGET), {}, r"`start` point .* not reachable"),
    (point(P_START), point(P_TARGET), {"k": 0.5}, r"`k` must be in \[1, 64\]"),
    (point(P_START), point(P_TARGET), {"k": 100.0}, r"`k` must be in \[1, 64\]"),
    (point(P_START), point(P_TARGET), {"k": math.nan}, r"`k` must be in"),
    (point(P_START), point(P_TARGET), {"k": "four"}, r"`k` must be a number"),
    (point(P_START), point(P_TARGET), {"reserve": 1.0}, r"`reserve` must be in \[0, 1\)"),
    (point(P_START), point(P_TARGET), {"reserve": -0.1}, r"`reserve` must be in \[0, 1\)"),
    (point(P_START), point(P_TARGET), {"reserve": math.nan}, r"`reserve` must be in"),
    (point(P_START), joint_state(Q_OK, (0.0, 0.1, 0.0)), {},
     r"`target` joint state must be at rest"),
    (joint_state((0.1, 0.2)), point(P_TARGET), {}, r"`start joint state` must have shape \(6,\)"),
    (point(P_START), joint_state((0.1, 0.2, 0.3, 0.4)), {},
     r"`target joint state` must have shape \(6,\)"),
    (joint_state((0.1, math.nan, 0.3)), point(P_TARGET), {},
     r"`start joint state` must be finite"),
    ((1.0, 1.0), point(P_TARGET), {}, r"`start` must be an Endpoint"),
], ids=["nan-start", "inf-target", "start-3d", "target-1d", "target-unreachable",
        "start-unreachable", "k-small", "k-large", "k-nan", "k-string", "reserve-1",
        "reserve-negative", "reserve-nan", "target-moving", "start-state-short",
        "target-state-long", "start-state-nan", "start-not-endpoint"])
def test_bad_problem_raises_problem_error(galicki, start, target, kwargs, match):
    with pytest.raises(ProblemError, match=match) as info:
        Problem(galicki, start, target, **kwargs)
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, TocontrolError)


def test_start_equal_to_target_is_trivial(galicki):
    res = plan(Problem(galicki, point(P_START), point(P_START), k=4))
    assert isinstance(res, PlanResult)
    assert res.success
    assert res.status is Status.TRIVIAL
    assert res.T == 0.0
    assert res.iterations == 0


def test_resting_state_on_the_target_point_is_trivial(galicki):
    q = np.array(Q_OK)
    res = plan(Problem(galicki, joint_state(q), point(galicki.point(q))))
    assert res.status is Status.TRIVIAL
    assert res.T == 0.0


def test_moving_state_on_the_target_point_is_not_trivial(galicki):
    q = np.array(Q_OK)
    problem = Problem(galicki, joint_state(q, (0.0, 0.0, 0.5)), point(galicki.point(q)))
    assert not problem.is_trivial()


@pytest.mark.parametrize("kwargs, match", [
    ({"tol": 0.0}, r"`tol` must be a positive number"),
    ({"tol": math.nan}, r"`tol` must be a positive number"),
    ({"time_limit": -1.0}, r"`time_limit` must be a positive number"),
    ({"integration_tol": math.inf}, r"`integration_tol` must be a positive number"),
    ({"guess_tol": 0.0}, r"`guess_tol` must be a positive number"),
    ({"max_newton": 0}, r"`max_newton` must be an integer >= 1"),
    ({"intervals": 2.5}, r"`intervals` must be an integer >= 1"),
    ({"starts": 0}, r"`starts` must be an integer >= 1"),
    ({"candidates": -1}, r"`candidates` must be an integer >= 1"),
    ({"smoothing": ()}, r"`smoothing` must be a non-empty strictly decreasing"),
    ({"smoothing": (1e-4, 1e-3)}, r"`smoothing` must be a non-empty strictly decreasing"),
    ({"smoothing": (1e-3, -1e-4)}, r"`smoothing` must be a non-empty strictly decreasing"),
])
def test_bad_options_raise(kwargs, match):
    # SolverOptions raises ProblemError (a ValueError) naming the field.
    with pytest.raises(ValueError, match=match):
        SolverOptions(**kwargs)


def test_options_defaults_are_valid_and_frozen():
    opts = SolverOptions(smoothing=[1e-3, 0])
    assert opts.smoothing == (1e-3, 0.0)
    with pytest.raises(AttributeError):
        opts.tol = 1.0  # type: ignore[misc]


def test_tiny_time_limit_returns_time_limit_status(galicki):
    res = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4),
               SolverOptions(time_limit=1e-9))
    assert not res.success
    assert res.status is Status.TIME_LIMIT
    assert math.isnan(res.T)
    assert res.trajectory is None
    assert res.message.startswith(Status.TIME_LIMIT.value)


def test_should_stop_cancels(galicki):
    calls = []

    def stop():
        calls.append(1)
        return True

    res = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4), SINGLE,
               should_stop=stop)
    assert not res.success
    assert res.status is Status.CANCELLED
    assert res.trajectory is None
    assert calls


def test_status_values_are_distinct_readable_strings():
    values = [status.value for status in Status]
    assert all(isinstance(v, str) and v for v in values)
    assert len(set(values)) == len(values)


def test_a_reachable_point_is_checked_once_per_model(galicki, monkeypatch):
    # Problems of a replan share their target: the reachability IK runs once per point and
    # model; an unreachable point is refused every time.
    import tocontrol_ros.core.robot.ik as ik

    calls = []
    real = ik.solve_ik
    monkeypatch.setattr(ik, "solve_ik", lambda *a, **k: calls.append(1) or real(*a, **k))
    start, target = point((1.013, 0.987)), point((1.913, 1.371))  # in no other test
    Problem(galicki, start, target)
    first = len(calls)
    assert first >= 2  # start and target
    Problem(galicki, start, target)
    assert len(calls) == first
    for _ in range(2):
        with pytest.raises(ProblemError, match="not reachable"):
            Problem(galicki, start, point((10.0, 0.0)))
    assert len(calls) > first + 1


def test_a_point_near_a_known_configuration_is_shown_reachable_without_ik(galicki,
                                                                          monkeypatch):
    # A replan's target, a fraction of a millimetre from where the motion it continues
    # ends: Gauss-Newton from that end shows it reachable and the problem runs no IK.
    import tocontrol_ros.core.robot.ik as ik
    from tocontrol_ros.core.types.problem import note_reachable

    calls = []
    real = ik.solve_ik
    monkeypatch.setattr(ik, "solve_ik", lambda *a, **k: calls.append(1) or real(*a, **k))
    q = np.array([0.41, 0.77, -0.9])
    p = galicki.point(q) + np.array([3e-4, -2e-4])  # in no other test
    assert note_reachable(galicki, p, q)
    Problem(galicki, joint_state(q), point(p))
    assert calls == []
    # Not shown: a point out of reach, a fully stretched arm (singular), bad input; the
    # problem's own check then decides.
    assert not note_reachable(galicki, (10.0, 0.0), q)
    stretched = np.zeros(3)
    assert not note_reachable(galicki, galicki.point(stretched), stretched)
    assert not note_reachable(galicki, (np.nan, 0.0), q)
    assert not note_reachable(galicki, p, q[:2])
    with pytest.raises(ProblemError, match="not reachable"):
        Problem(galicki, point(p), point((10.0, 0.0)))


def test_note_reachable_decides_as_gauss_newton_by_lstsq_and_svd(galicki):
    """The steps solved with J J^T and the singularity test on its eigenvalues (issue 47:
    a replan's reachability check in fewer operations) give the verdict of the form before
    them, lstsq steps and the SVD of J, over random ends and offsets up to out of reach and
    at the stretched arm's boundary."""
    import tocontrol_ros.core.types.problem as problem_module
    from tocontrol_ros.core.robot.ik import IK_TOL

    def before(model, p, q):
        for _ in range(problem_module.NEAR_STEPS):
            e = model.point(q) - p
            if np.linalg.norm(e) < 1e-3 * IK_TOL:
                break
            q = q - np.linalg.lstsq(model.jacobian(q), e, rcond=None)[0]
        sigma = np.linalg.svd(model.jacobian(q), compute_uv=False)
        singular = sigma.size < model.m or \
            sigma[-1] < problem_module.SINGULAR_TOL * model.reach()
        return bool(np.linalg.norm(model.point(q) - p) < IK_TOL
                    and np.all(np.isfinite(q)) and not singular)

    rng = np.random.default_rng(47)
    cases = [(np.zeros(3), galicki.point(np.zeros(3)))]  # stretched: singular
    for scale in (1e-4, 1e-2, 0.05, 0.3, 3.0):
        for _ in range(12):
            q = rng.uniform(-math.pi, math.pi, 3)
            cases.append((q, galicki.point(q) + rng.normal(size=2) * scale))
    verdicts = []
    for q, p in cases:  # each point new (none remembered: drawn here only)
        expect = before(galicki, p, q.copy())
        assert problem_module.note_reachable(galicki, p, q) == expect, (q, p)
        verdicts.append(expect)
    assert any(verdicts) and not all(verdicts)
