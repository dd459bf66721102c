"""Joint limits: the limits object, the problem's checks, and plans that keep to them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from skip_policy import missing

from tocontrol_ros.core.direct.collocation import DirectCollocation, initial_path
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.planning.solver import SolverOptions, Status, plan, verify
from tocontrol_ros.core.robot.limits import (
    JointLimits,
    load_joint_limits_yaml,
    parse_joint_limits_yaml,
)
from tocontrol_ros.core.types.problem import Problem, joint_state, point

P_START = np.array([1.0, 1.0])
P_TARGET = np.array([2.2, 1.5])
#: Velocity limits (rad/s) that bind on the paper's example (its optimum reaches 1.1 and
#: 6.3 rad/s at joints 2 and 3).
TIGHT = np.array([0.4, 1.0, 1.0])
#: The first bounded solve of a kind compiles its NLP (tens of seconds on a loaded machine):
#: not a time the solver's budget should be judged on here.
SLOW_OK = 600.0

YAML = """
joint_limits:
  joint1:
    has_position_limits: true
    min_position: -1.0
    max_position: 2.0
    has_velocity_limits: true
    max_velocity: 0.5
    has_acceleration_limits: false
    max_acceleration: 0.0
  joint3:
    has_velocity_limits: true
    max_velocity: 500.0
"""


def _tight(model, velocity=TIGHT, margin=0.0):
    base = JointLimits.from_model(model)
    return JointLimits(base.names, base.lower, base.upper, np.asarray(velocity), margin)


# ----------------------------------------------------------------- the limits object
def test_urdf_limits_narrowed_by_moveit_yaml(galicki):
    base = JointLimits.from_model(galicki)
    assert np.all(np.isinf(base.lower)) and np.allclose(base.velocity, 100.0)
    lim = base.narrowed(parse_joint_limits_yaml(YAML))
    assert (lim.lower[0], lim.upper[0], lim.velocity[0]) == (-1.0, 2.0, 0.5)
    # A YAML limit wider than the URDF's leaves the URDF's (the tighter of the two).
    assert lim.velocity[2] == 100.0
    assert np.isinf(lim.lower[1]) and lim.velocity[1] == 100.0


def test_margin_shrinks_ranges_and_speeds(galicki):
    lim = JointLimits.from_model(galicki).narrowed(parse_joint_limits_yaml(YAML)).with_margin(0.1)
    assert lim.plan_lower[0] == pytest.approx(-1.0 + 0.15)
    assert lim.plan_upper[0] == pytest.approx(2.0 - 0.15)
    assert lim.plan_velocity[0] == pytest.approx(0.45)
    assert np.isinf(lim.plan_lower[1])  # a continuous joint stays unlimited


@pytest.mark.parametrize("text, match", [
    ("joint_limits:\n  elbow: {has_velocity_limits: true, max_velocity: 1.0}",
     "'elbow' is not a moving joint"),
    ("joint_limits:\n  joint1: {has_velocity_limits: yes please}", "must be true or false"),
    ("joint_limits:\n  joint1: {has_velocity_limits: true}", "has no `max_velocity`"),
    ("joint_limits:\n  joint1: {has_velocity_limits: true, max_velocity: -2}", "must be > 0"),
    ("joint_limits:\n  joint1: {has_position_limits: true, min_position: 1, max_position: 0}",
     "not below max_position"),
    ("joint_limits:\n  joint1: {has_velocity_limits: true, max_velocity: .nan}",
     "finite number"),
    ("limits: {}", "top-level mapping `joint_limits:`"),
    ("joint_limits: [", "not valid YAML"),
])
def test_bad_joint_limits_yaml_is_named(galicki, text, match):
    with pytest.raises(ProblemError, match=match):
        JointLimits.from_model(galicki).narrowed(parse_joint_limits_yaml(text))


def test_joint_limits_file(tmp_path, galicki):
    with pytest.raises(ProblemError, match="does not exist"):
        load_joint_limits_yaml(str(tmp_path / "nope.yaml"))
    path = tmp_path / "joint_limits.yaml"
    path.write_text(YAML)
    lim = JointLimits.from_model(galicki).narrowed(load_joint_limits_yaml(path))
    assert lim.velocity[0] == 0.5


def test_violations_are_fractions_of_range_and_limit(galicki):
    lim = JointLimits.from_model(galicki).narrowed(parse_joint_limits_yaml(YAML))
    q = np.array([[2.3, 0.0, 0.0], [0.0, 50.0, 0.0]])
    qd = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0]])
    pos, vel = lim.violations(q, qd)
    assert pos == pytest.approx(0.3 / 3.0) and vel == pytest.approx(0.1 / 0.5)
    assert lim.violations(np.zeros((2, 3)), np.zeros((2, 3))) == (0.0, 0.0)


# ----------------------------------------------------------------- the problem
def test_start_outside_limits_is_rejected_naming_the_joint(panda):
    q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    target = point(panda.point(q + 0.1))
    Problem(panda, joint_state(q), target)  # inside: fine
    bad = q.copy()
    bad[3] = 0.1  # panda_joint4 is limited to [-3.07, -0.07]
    with pytest.raises(ProblemError, match="panda_joint4"):
        Problem(panda, joint_state(bad), target)
    # Inside the URDF's limits but within a margin of 20 % of the range from them.
    lim = JointLimits.from_model(panda, margin=0.2)
    near = q.copy()
    near[3] = -0.2
    with pytest.raises(ProblemError, match="shrunk by the margin 0.2"):
        Problem(panda, joint_state(near), target, limits=lim)
    with pytest.raises(ProblemError, match="velocity .* not below its limit"):
        Problem(panda, joint_state(q, np.full(7, 3.0)), target)


def test_a_small_overshoot_of_a_velocity_limit_is_taken_back(panda):
    lim = JointLimits.from_model(panda, margin=0.1)
    v = lim.plan_velocity
    qd = np.zeros(7)
    qd[0], qd[1], qd[2], qd[3] = 1.05 * v[0], -1.0 * v[1], 0.5 * v[2], -1.2 * v[3]
    out = lim.admissible_velocity(qd)
    assert out[0] == pytest.approx(v[0]) and out[0] < v[0]
    assert out[1] == pytest.approx(-v[1]) and out[1] > -v[1]
    assert out[2] == qd[2] and out[3] == qd[3]  # inside; too far over (refused by the check)
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    ok = out.copy()
    ok[3] = 0.0
    lim.check_state("start", q, ok)
    with pytest.raises(ProblemError, match="panda_joint4"):
        lim.check_state("start", q, out)


def test_limits_of_another_model_are_rejected(galicki, panda):
    with pytest.raises(ProblemError, match="`limits` must be a JointLimits"):
        Problem(galicki, point(P_START), point(P_TARGET), limits=JointLimits.from_model(panda))


# ----------------------------------------------------------------- plans within limits
@pytest.fixture(scope="module")
def limited(galicki):
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4.0,
                      limits=_tight(galicki))
    return plan(problem, SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK))


def test_binding_velocity_limits_are_kept_on_reintegration(limited):
    res = limited
    assert res.success, res.message
    assert res.method == "direct"
    checks = res.verification
    assert checks["velocity_limits"] <= 1e-6
    assert checks["position_limits"] <= 1e-6
    assert checks["point_error"] < 1e-6
    fine = res.trajectory.evaluate(np.linspace(0.0, res.T, 4001))
    assert np.all(np.abs(fine.qd) <= TIGHT * (1 + 1e-9))
    # Every control inside the convexified set (torque limits).
    assert np.max(np.sum(fine.u ** 8, axis=1)) <= 1 + 1e-9
    # A limit binds: some joint runs at (nearly) its limit.
    assert np.max(np.abs(fine.qd) / TIGHT) > 0.99


def test_bounded_time_agrees_with_an_independent_fine_collocation(galicki, limited):
    """T agrees with Hermite-Simpson on 192 intervals, bounds at its mesh points.

    Started from the returned motion: another transcription of the same problem.
    """
    res = limited
    problem = res.problem
    N = 192
    dc = DirectCollocation(galicki, N)
    tau = np.linspace(0.0, res.T, N + 1)
    sample = res.trajectory.evaluate(tau)
    x = np.hstack([sample.q, sample.qd])
    bounds = (np.concatenate([-np.full(3, np.inf), -TIGHT]),
              np.concatenate([np.full(3, np.inf), TIGHT]))
    ref = dc.solve(problem.start.value, problem.target.value, 4.0, res.T, x, sample.u,
                   x_bounds=bounds)
    assert ref.success, ref.message
    assert abs(res.T - ref.T) <= 1e-3 * ref.T


def test_limits_cost_time(galicki, limited):
    free = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4.0),
                SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK))
    assert free.method == "indirect" and free.success
    assert limited.T > free.T


def _moved(limited, by=(0.02, 0.0)):
    problem = limited.problem
    return Problem(problem.model, problem.start, point(P_TARGET + np.asarray(by)), k=4.0,
                   limits=problem.limits)


def test_a_bounded_plan_is_continued_warm_to_a_moved_target(galicki, limited):
    """``warm_only``: the previous B-spline solution solved again on its mesh for a target
    moved by 2 cm, without the multistart; a local optimum of the moved problem (an
    independent fine collocation from it agrees), certified, itself warm-startable."""
    moved = _moved(limited)
    assert limited.can_warm_start(moved)
    warm = plan(moved, SolverOptions(starts=4, candidates=1, warm_only=True,
                                     time_limit=SLOW_OK), warm_start=limited)
    assert warm.success, warm.message
    assert warm.method == "direct" and warm.certificate.passed
    assert [(r.index, r.status) for r in warm.starts] == [(-1, "returned")]
    assert warm.timings["guess"] == 0.0  # no multistart ran
    assert any("warm from the previous solution" in w for w in warm.warnings)
    assert warm.intervals == limited.intervals  # the previous mesh
    assert warm.verification["point_error"] < 1e-6
    assert warm.T != limited.T
    N = 192
    tau = np.linspace(0.0, warm.T, N + 1)
    sample = warm.trajectory.evaluate(tau)
    bounds = (np.concatenate([-np.full(3, np.inf), -TIGHT]),
              np.concatenate([np.full(3, np.inf), TIGHT]))
    ref = DirectCollocation(galicki, N).solve(moved.start.value, moved.target.value, 4.0,
                                              warm.T, np.hstack([sample.q, sample.qd]),
                                              sample.u, x_bounds=bounds)
    assert ref.success, ref.message
    assert abs(warm.T - ref.T) <= 1e-3 * ref.T
    # And on: the warm result warm-starts the next move.
    again = _moved(limited, (0.02, 0.02))
    assert warm.can_warm_start(again)
    assert plan(again, SolverOptions(warm_only=True, time_limit=SLOW_OK),
                warm_start=warm).starts[0].index == -1


def test_a_bounded_warm_re_solve_starts_from_the_previous_multipliers(limited):
    """The previous solve's multipliers come with its warm state and start IPOPT's warm
    re-solve: the same motion as from the path alone, in fewer iterations; multipliers that
    do not fit the NLP (another kind of start: other rows) are left out. (IPOPT's route:
    the parametric step, which is tried first by default, is test_sensitivity's.)"""
    state = limited.warm_state
    assert state.lam_g is not None and np.all(np.isfinite(state.lam_g))
    assert len(state.lam_x) == state.P.size + 1
    moved = _moved(limited)
    options = SolverOptions(warm_only=True, time_limit=SLOW_OK, warm_parametric=False)
    dual = plan(moved, options, warm_start=limited)
    path_only = plan(moved, options, warm_start=replace(
        limited, warm_state=replace(state, lam_g=None, lam_x=None)))
    assert dual.success and path_only.success, (dual.message, path_only.message)
    assert dual.starts[0].index == path_only.starts[0].index == -1
    assert abs(dual.T - path_only.T) <= 1e-6 * dual.T
    assert dual.iterations < path_only.iterations
    misfit = plan(moved, options, warm_start=replace(
        limited, warm_state=replace(state, lam_g=state.lam_g[:-1])))
    assert misfit.success and misfit.starts[0].index == -1
    assert misfit.iterations == path_only.iterations


def test_a_replan_keeps_bounded_solves_on_a_coarse_uniform_mesh(limited):
    """``replan_spans``: the warm start (on its refined mesh) is solved again on that many
    uniform spans from its path fitted there, certified, ``T`` within 4e-3 of the warm
    re-solve on its own mesh; the next replan continues on that mesh; a replan without a
    warm start keeps the uniform mesh of the multistart, unrefined."""
    from tocontrol_ros.core.direct.tuning import SPANS

    moved = _moved(limited)
    fine = plan(moved, SolverOptions(warm_only=True, time_limit=SLOW_OK), warm_start=limited)
    options = SolverOptions(warm_only=True, replan_spans=24, time_limit=SLOW_OK)
    coarse = plan(moved, options, warm_start=limited)
    assert fine.success and coarse.success, (fine.message, coarse.message)
    assert coarse.method == "direct" and coarse.certificate.passed
    assert coarse.starts[0].index == -1 and coarse.intervals == 24 != limited.intervals
    assert any("uniform mesh of 24 spans" in w for w in coarse.warnings)
    assert fine.T <= coarse.T <= (1 + 4e-3) * fine.T  # 2.7e-3 here (a 0.66 s motion)
    again = plan(_moved(limited, (0.02, 0.02)), options, warm_start=coarse)
    assert again.success and again.intervals == 24, again.message
    assert any("its mesh of 24 spans" in w for w in again.warnings)
    cold_options = replace(options, warm_only=False, starts=4, candidates=1)
    cold = plan(moved, cold_options)
    full = plan(moved, replace(cold_options, replan_spans=0))
    assert cold.success and full.success, (cold.message, full.message)
    assert cold.intervals == SPANS < full.intervals
    assert full.T <= cold.T <= full.T * (1 + 5e-3)


@pytest.mark.parametrize("spans", [-1, 2, 1.5, True])
def test_replan_spans_is_validated(spans):
    with pytest.raises(ProblemError, match="replan_spans"):
        SolverOptions(replan_spans=spans)


def test_a_bounded_warm_start_is_one_candidate_next_to_the_multistart(limited):
    moved = _moved(limited)
    options = SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK)
    both = plan(moved, options, warm_start=limited)
    cold = plan(moved, options)
    assert both.success and cold.success
    warm = [r for r in both.starts if r.index == -1]
    assert len(warm) == 1 and warm[0].status in ("warm start", "returned")
    assert len(both.starts) == len(cold.starts) + 1
    assert both.T <= cold.T


def test_a_failed_warm_start_falls_back_to_the_multistart(limited, monkeypatch):
    from tocontrol_ros.core.direct import method as solver

    def failing(planner, ctx, warm, timings, t_start, trajectory=None, solved=None):
        return replace(limited, success=False, status=Status.LIMITS_INFEASIBLE,
                       message="the warm bounded solve failed (test)", problem=ctx.problem)

    monkeypatch.setattr(solver, "plan_limited_warm", failing)
    res = plan(_moved(limited), SolverOptions(starts=4, candidates=1, warm_only=True,
                                              time_limit=SLOW_OK), warm_start=limited)
    assert res.success, res.message
    assert res.starts[0].index == -1 and "warm start failed" in res.starts[0].status
    assert any(r.status == "returned" for r in res.starts[1:])
    assert res.timings["guess"] > 0.0


def test_a_uniform_solve_that_fails_at_k_is_continued_in_k(galicki, monkeypatch):
    """The bounded solve on the uniform mesh, when it fails at the requested k from the
    guess (forced here), is solved at k = 1 from the guess and continued in k (the planar
    8R's fallback: test_solver_stages.py)."""
    from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
    from tocontrol_ros.core.direct.limited import SPANS, k_steps

    solve, calls = FlatTranscription.solve, []

    def failing_at_k(self, start, target, k, *args, **kwargs):
        calls.append((self.spans, self.warm, k))
        if self.spans == SPANS and not self.warm and k == 4.0:
            return FlatResult(False, "Maximum_Iterations_Exceeded", np.nan, 300, 0.0,
                              P=np.full((self.K, 3), np.nan), residual=np.inf)
        return solve(self, start, target, k, *args, **kwargs)

    monkeypatch.setattr(FlatTranscription, "solve", failing_at_k)
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4.0,
                      limits=_tight(galicki))
    res = plan(problem, SolverOptions(starts=1, candidates=1, time_limit=SLOW_OK))
    assert res.success, res.message
    assert res.method == "direct" and res.certificate.passed
    assert k_steps(4.0) == [1.0, 2.0, 3.0, 4.0]
    uniform = [(warm, k) for spans, warm, k in calls if spans == SPANS]
    assert uniform == [(False, 4.0), (False, 1.0), (True, 2.0), (True, 3.0), (True, 4.0)]


def test_verification_fails_a_motion_that_leaves_the_limits(galicki):
    free_problem = Problem(galicki, point(P_START), point(P_TARGET), k=1.0)
    free = plan(free_problem, SolverOptions(starts=1, candidates=1, time_limit=SLOW_OK))
    assert free.success and free.verification["velocity_limits"] == 0.0
    tight = Problem(galicki, point(P_START), point(P_TARGET), k=1.0, limits=_tight(galicki))
    checks = verify(tight, free.trajectory)
    assert checks["velocity_limit_violation"] > 1.0  # joint 3 runs at 6.3 rad/s against 1


def test_unreachable_within_limits_is_a_named_failure(galicki):
    """Joint 1 confined to a sliver: the target is out of reach within the limits."""
    base = JointLimits.from_model(galicki)
    lim = JointLimits(base.names, np.array([-0.75, -np.inf, -np.inf]),
                      np.array([-0.74, np.inf, np.inf]), TIGHT)
    q0 = np.array([-0.745, 2.38, 0.72])
    res = plan(Problem(galicki, joint_state(q0), point(P_TARGET), k=1.0, limits=lim),
               SolverOptions(starts=2, candidates=1, time_limit=SLOW_OK))
    assert not res.success
    assert res.status in (Status.LIMITS_INFEASIBLE, Status.NO_GUESS), res.message
    assert res.trajectory is None


def test_direct_guess_respects_bounds(galicki):
    dc = DirectCollocation(galicki, 12)
    qa = np.array([-0.74958167, 2.38183072, 0.72394544])
    qb = np.array([-0.63884071, 2.11297099, 0.09666605])
    bounds = (np.concatenate([-np.full(3, np.inf), -TIGHT]),
              np.concatenate([np.full(3, np.inf), TIGHT]))
    res = dc.solve(P_START, P_TARGET, 1.0, *initial_path(galicki, qa, qb, 12, 1.0, TIGHT),
                   x_bounds=bounds)
    assert res.success
    assert np.all(np.abs(res.x[:, 3:]) <= TIGHT + 1e-7)
    free = dc.solve(P_START, P_TARGET, 1.0, *initial_path(galicki, qa, qb, 12))
    assert np.max(np.abs(free.x[:, 3:]) - TIGHT) > 0.1


def test_a_gripper_below_the_tip_is_locked_without_being_named(robot_specs):
    """The Panda as it comes: its fingers (below panda_hand) are locked at 0 (closed)."""
    from tocontrol_ros.core.robot.model import load_robot

    if "panda" not in robot_specs:
        missing("example-robot-data (pip install '.[test]')")
    source = robot_specs["panda"]["source"]
    model = load_robot(source, tip_link="panda_hand")
    assert model.n == 7
    assert dict(model.locked) == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    opened = load_robot(source, tip_link="panda_hand",
                        locked_joints={"panda_finger_joint1": 0.04})
    assert dict(opened.locked)["panda_finger_joint1"] == 0.04
    # Fingers opened: the hand's lumped inertia moves, so the dynamics differ.
    q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    assert not np.allclose(opened.mass_matrix(q), model.mass_matrix(q))


# ------------------------------------------------------- the candidates' refinement race
def test_repeats_of_one_bounded_solution_are_refined_once():
    from tocontrol_ros.core.direct.flat import FlatResult
    from tocontrol_ros.core.direct.limited import _distinct_solutions

    P = np.linspace(0.0, 1.0, 12).reshape(4, 3)

    def sol(T, shift=0.0):
        return (FlatResult(True, "ok", T, 10, 0.1, P=P + shift, residual=0.0), None, None)

    first = [(0, sol(0.5)), (3, sol(0.5 * (1 + 1e-8), 1e-5)), (5, sol(0.5, 0.1)),
             (7, sol(0.6))]
    kept = _distinct_solutions(first)
    assert [idx for idx, _ in kept] == [0, 5, 7]



def test_bounded_solve_at_a_k_that_is_not_an_integer(galicki):
    """The set is sum |u_i|^(2k): at k = 2.5, u^5 would leave negative torques unbounded.

    (and at k = 2.25 a negative u^4.5 is NaN).
    """
    for k in (2.5, 2.25):
        problem = Problem(galicki, point(P_START), point(P_TARGET), k=k,
                          limits=_tight(galicki))
        res = plan(problem, SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK))
        assert res.success, (k, res.message)
        assert res.method == "direct"
        fine = res.trajectory.evaluate(np.linspace(0.0, res.T, 4001))
        assert np.max(np.sum(np.abs(fine.u) ** (2 * k), axis=1)) <= 1 + 1e-9


def test_refined_candidates_are_held_inside_the_set_fastest_first_while_they_can_win(
        monkeypatch):
    """Only a candidate that can still beat the best one held inside the set is re-solved."""
    from types import SimpleNamespace

    from tocontrol_ros.core.direct import limited as lim
    from tocontrol_ros.core.direct.flat import FlatResult

    P = np.zeros((4, 3))
    monkeypatch.setattr(lim, "refined_breaks", lambda traj: traj.breaks)  # no refinement
    held = []

    def hold(cost):
        def inside(planner, ctx, bounds, out, traj, flat):
            held.append(traj.idx)
            return replace(out, T=out.T * (1 + cost)), traj
        return inside

    planner = SimpleNamespace(map=lambda fn, ctx, items: iter([fn(*i) for i in items]))

    def race(Ts, cost):
        held.clear()
        monkeypatch.setattr(lim, "_inside_set", hold(cost))
        first = [(idx, (FlatResult(True, "ok", T, 10, 0.1, P=P, residual=0.0),
                        SimpleNamespace(breaks=np.linspace(0, 1, 5), idx=idx), None))
                 for idx, T in Ts]
        out = lim._race(planner, SimpleNamespace(problem=None), None, first)
        return [(idx, round(res.T, 9), contender) for idx, res, _, contender in out]

    # Holding costs 1e-5 of T: the second (1e-5 behind) cannot win by more than INSIDE_TIE.
    assert race([(3, 0.500005), (1, 0.5), (2, 0.5001), (4, 0.505)], 1e-5) == [
        (3, 0.500005, False), (1, 0.500005, True), (2, 0.5001, False), (4, 0.505, False)]
    assert held == [1]
    # Holding the first costs 2e-3: the second can still win, and is held too.
    assert race([(1, 0.5), (3, 0.5002)], 2e-3) == [(1, 0.501, True), (3, 0.5012004, True)]
    assert held == [1, 3]


def test_guesses_far_above_the_best_are_solved_only_when_those_near_it_fail(galicki,
                                                                            monkeypatch):
    """GUESS_WINDOW: the bounded candidates are the guesses near the best one's k = 1 T."""
    from tocontrol_ros.core.direct import limited as lim

    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4.0, limits=_tight(galicki))
    options = SolverOptions(starts=4, candidates=4, time_limit=SLOW_OK)
    original = lim._uniform_item
    solved = []

    def uniform(planner, ctx, bounds, guess, fallback, fail_first=False):
        solved.append(guess.T)
        out = original(planner, ctx, bounds, guess, fallback)
        if fail_first and len(solved) == 1:
            return replace(out, success=False, message="made to fail")
        return out

    monkeypatch.setattr(lim, "GUESS_WINDOW", 0.0)  # only the best guess is near
    monkeypatch.setattr(lim, "_uniform_item", uniform)
    res = plan(problem, options)
    assert res.success, res.message
    assert len(solved) == 1
    monkeypatch.setattr(lim, "_uniform_item",
                        lambda *a: uniform(*a, fail_first=True))
    solved.clear()
    again = plan(problem, options)
    assert again.success, again.message
    assert len(solved) > 1 and solved[0] == min(solved)  # the next ones, once it failed
    assert any("made to fail" in s.status for s in again.starts)


def test_a_multistart_whose_bounded_solves_all_fail_says_why(galicki, monkeypatch):
    """The failure's message is what the starts that were solved said, not a guess's record."""
    from tocontrol_ros.core.direct import limited as lim

    original = lim._uniform_item

    def uniform(*args):
        return replace(original(*args), success=False, message="made to fail")

    monkeypatch.setattr(lim, "_uniform_item", uniform)
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4.0, limits=_tight(galicki))
    res = plan(problem, SolverOptions(starts=4, candidates=2, time_limit=SLOW_OK))
    assert not res.success and res.trajectory is None
    assert res.status == Status.LIMITS_INFEASIBLE
    assert "no bounded solve succeeded" in res.message
    assert "bounded solve failed: made to fail" in res.message
    assert "guess only" not in res.message
    tried = [s for s in res.starts if "made to fail" in s.status]
    assert f"({len(tried)} of {len(res.starts)} starts)" in res.message


def test_bounded_guesses_solve_the_requested_k_the_others_k_1(galicki, monkeypatch):
    """Within the limits the multistart's guesses solve k (the bounded solve's starts)."""
    from tocontrol_ros.core.direct import limited as lim

    calls, starts = [], []
    original_solve = DirectCollocation.solve

    def solve(self, start, target, k, *args, x_bounds=None, **kw):
        calls.append((k, x_bounds is not None))
        return original_solve(self, start, target, k, *args, x_bounds=x_bounds, **kw)

    original_uniform = lim._uniform_item

    def uniform(planner, ctx, bounds, guess, fallback):
        starts.append(guess)
        return original_uniform(planner, ctx, bounds, guess, fallback)

    monkeypatch.setattr(DirectCollocation, "solve", solve)
    monkeypatch.setattr(lim, "_uniform_item", uniform)
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=4.0, limits=_tight(galicki))
    res = plan(problem, SolverOptions(starts=4, candidates=2, time_limit=SLOW_OK))
    assert res.success, res.message
    assert res.method == "direct"
    assert len(calls) >= 4 and all(k == 4.0 and bounded for k, bounded in calls)
    assert starts
    for guess in starts:
        # Inside the k = 4 set, and outside the k = 1 set (the unit ball) somewhere: a
        # motion only k = 4's larger set allows.
        assert np.max(np.sum(guess.u ** 8, axis=1)) <= 1 + 1e-4  # guess_tol 1e-5
        assert np.max(np.linalg.norm(guess.u, axis=1)) > 1.05
    recorded = {s.index: s.guess_T for s in res.starts}
    assert all(any(abs(g.T - t) <= 1e-12 for t in recorded.values()) for g in starts)
    # Limits that do not bind (the paper's arm's 100 rad/s placeholders): the first guess
    # tried within them at k, then all without them at k = 1 (the maximum principle's).
    calls.clear()
    free = plan(Problem(galicki, point(P_START), point(P_TARGET), k=4.0),
                SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK))
    assert free.success, free.message
    assert free.method != "direct"
    assert calls[0] == (4.0, True)
    assert [k for k, bounded in calls[1:5]] == [1.0] * 4 and not any(b for _, b in calls[1:5])
