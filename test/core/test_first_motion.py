"""The first motion (issue 32): a certified motion inside every limit, before the optimum."""

from __future__ import annotations

import numpy as np
import pytest
from first_motion_cases import panda_problem

from tocontrol_ros.core.direct import first_motion as fm
from tocontrol_ros.core.direct import time_scaling as ts
from tocontrol_ros.core.direct.first_motion import first_motion
from tocontrol_ros.core.direct.scaled_path import PolynomialPath, ScaledPath
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import Planner, SolverOptions, Status, plan
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: Velocity limits (rad/s) that bind on the paper's example (as in test_limits.py).
TIGHT = np.array([0.4, 1.0, 1.0])
#: The first motion is one path's best timing: slower than the optimum, but not by more
#: than this factor on these cases (measured 1.3-1.6 on the paper's arm, up to 3.7 on a
#: 7-joint arm whose optimum picks its end configuration on the self-motion manifold).
FACTOR = 4.0


def _tight(model, margin=0.0):
    base = JointLimits.from_model(model)
    return JointLimits(base.names, base.lower, base.upper, TIGHT, margin)


def _check_motion(problem: Problem, res) -> None:
    """Certified, inside the set and the limits everywhere, from the start to the target."""
    assert res.success, res.message
    assert res.status is Status.SUCCESS and res.method == "first"
    assert res.certificate is not None and res.certificate.passed, res.certificate.summary()
    traj, model, n = res.trajectory, problem.model, problem.model.n
    # Between the gridpoints too, on both sides of every acceleration jump.
    _, u, qd = traj.segment_samples(9)
    fine = traj.evaluate(np.linspace(0.0, res.T, 3001))
    for us in (u, fine.u):
        assert np.max(np.sum(np.abs(us) ** (2 * problem.k), axis=1)) <= 1.0 + 1e-12
    lim = problem.limits
    for q, v in ((fine.q, fine.qd), (fine.q, qd)):
        assert lim.violations(q[: len(v)], v) == (0.0, 0.0)
    ends = traj.evaluate(np.array([0.0, res.T]))
    if problem.start.kind == "state":
        np.testing.assert_allclose(ends.q[0], problem.start.value[:n], atol=1e-12)
        np.testing.assert_allclose(ends.qd[0], problem.start.value[n:], atol=1e-12)
    else:
        np.testing.assert_allclose(model.point(ends.q[0]), problem.start_point, atol=1e-8)
        np.testing.assert_allclose(ends.qd[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(model.point(ends.q[1]), problem.target_point, atol=1e-8)
    np.testing.assert_allclose(ends.qd[1], 0.0, atol=1e-9)
    # The published effort is the inverse dynamics of the published motion.
    tau = np.array([model.inverse_dynamics(q, v, a) for q, v, a in
                    zip(fine.q[::300], fine.qd[::300], fine.qdd[::300], strict=True)])
    np.testing.assert_allclose(fine.tau[::300], tau, rtol=1e-9, atol=1e-9)


# ----------------------------------------------------------------- the paper's arm
@pytest.fixture(scope="module")
def paper_optimum(galicki):
    """The paper's example as the planner node plans it (default multistart)."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    return problem, plan(problem)


def test_paper_example_first_motion_is_certified_and_slower_than_the_optimum(paper_optimum):
    problem, optimum = paper_optimum
    assert optimum.success
    res = first_motion(problem)
    _check_motion(problem, res)
    assert optimum.T <= res.T <= FACTOR * optimum.T
    assert res.timings["total"] > 0 and res.iterations >= 2 and res.intervals == ts.GRIDPOINTS
    assert "first motion: the straight joint path" in res.message and not res.warnings


def test_the_planner_offers_the_first_motion(paper_optimum):
    problem, _ = paper_optimum
    res = Planner(problem.model).first(problem, SolverOptions())
    assert res.method == "first" and res.success


@pytest.mark.parametrize("moving", [False, True], ids=["rest", "moving"])
def test_paper_arm_with_binding_velocity_limits(galicki, moving):
    """From a joint state (at rest, or moving at 60 % of a velocity limit off the path)."""
    q0 = np.array([0.3, 1.2, -0.9])
    qd0 = np.array([0.0, -0.6, 0.6]) * TIGHT if moving else np.zeros(3)
    problem = Problem(galicki, joint_state(q0, qd0), point(PAPER_TARGET), k=4.0,
                      limits=_tight(galicki))
    res = first_motion(problem)
    _check_motion(problem, res)
    assert ("parabola from the moving start" in res.message) == moving
    optimum = plan(problem, SolverOptions(starts=4, candidates=1, time_limit=600.0))
    assert optimum.success, optimum.message
    assert optimum.T <= res.T * (1 + 1e-9) <= FACTOR * optimum.T
    # The limits bind: some joint runs at (nearly: the bound holds between the gridpoints
    # too, so a curved path keeps a little below it) its velocity limit.
    fine = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001))
    assert np.max(np.abs(fine.qd) / TIGHT) > 0.97


def test_friction_is_bounded_not_ignored(galicki):
    """The paper's arm has 1 N m s/rad of viscous friction against an 8 N m joint: timed as
    if there were none, the torques leave the box TOPP-RA was given; bounded, they do not."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    res = first_motion(problem)
    assert res.success
    s = np.linspace(0.0, 1.0, ts.GRIDPOINTS + 1)
    traj = res.trajectory
    coef = ts._Coefficients(problem, traj.path, s)
    cube = np.full((len(s), 3), 3 ** (-1 / 8))
    x, _ = ts._toppra(coef, s, 0.0, cube, None)  # friction left out
    careless = ScaledPath(galicki, traj.path, s, x, 4.0, 1.0)
    assert np.max(np.abs(careless.segment_samples(5)[1])) > 1.01 * cube[0, 0]
    x, _ = ts._toppra(coef, s, 0.0, cube, x)  # friction bounded
    bounded = ScaledPath(galicki, traj.path, s, x, 4.0, 1.0)
    assert np.max(np.abs(bounded.segment_samples(5)[1])) < 1.001 * cube[0, 0]


# ----------------------------------------------------------------------- the Panda
@pytest.mark.parametrize("moving", [False, True], ids=["rest", "moving"])
def test_panda_first_motion_is_certified_within_its_limits(panda, moving):
    problem = panda_problem(panda, moving)
    res = first_motion(problem)
    _check_motion(problem, res)


@pytest.mark.slow
@pytest.mark.parametrize("moving", [False, True], ids=["rest", "moving"])
def test_panda_first_motion_is_slower_than_the_optimum(panda, moving):
    problem = panda_problem(panda, moving)
    res = first_motion(problem)
    optimum = plan(problem, SolverOptions(starts=4, candidates=1, time_limit=600.0))
    assert res.success and optimum.success, (res.message, optimum.message)
    assert optimum.T <= res.T <= FACTOR * optimum.T


# ----------------------------------------------------------------- what can go wrong
def test_a_trivial_problem_is_nothing_to_move(galicki):
    problem = Problem(galicki, point(PAPER_START), point(PAPER_START), k=4.0)
    res = first_motion(problem)
    assert res.status is Status.TRIVIAL and res.T == 0.0 and res.trajectory is None


def test_too_little_torque_to_hold_the_arm_is_a_named_failure(panda):
    """With 95 % of the torque held in reserve the Panda cannot hold itself up."""
    q0 = np.array([0.0, 0.5, 0.0, -1.5, 0.0, 1.5, 0.5])
    problem = Problem(panda, joint_state(q0), point(panda.point(q0 + 0.2)), k=4.0,
                      reserve=0.95)
    res = first_motion(problem)
    assert not res.success and res.status is Status.SCALING_FAILED
    assert res.trajectory is None and np.isnan(res.T)
    assert res.message.startswith(Status.SCALING_FAILED.value + ": the first motion")


def test_a_certificate_that_fails_says_so(galicki):
    """An impossible tolerance on the open loop's end velocity: the motion is reported, not
    passed off as a success."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    res = first_motion(problem, SolverOptions(verify_velocity_tol=1e-15))
    assert not res.success and res.status is Status.VERIFICATION_FAILED
    assert "end_velocity" in res.message and res.trajectory is not None


# -------------------------------------------------------------------- the pieces
def test_boxes_have_their_corner_on_the_set():
    rng = np.random.default_rng(0)
    demand = rng.uniform(0, 1, (50, 7))
    for k in (1.0, 4.0, 16.0):
        boxes = ts._boxes(demand, k)
        np.testing.assert_allclose(np.sum(boxes ** (2 * k), axis=1), 1.0, rtol=1e-12)
        assert np.all(boxes > 0)


def test_friction_lines_bound_the_friction_torque(galicki):
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET))
    s = np.linspace(0.0, 1.0, 11)
    path = PolynomialPath.straight(np.array([0.1, 0.5, -2.0]), np.array([1.0, -0.5, 1.0]))
    coef = ts._Coefficients(problem, path, s)
    x_prev = np.linspace(0.2, 3.0, 11)
    u0, u1, l0, l1, cap = ts._friction_lines(coef, x_prev)
    for x in np.linspace(0.0, cap[0], 50):
        true = coef.f * np.sqrt(x)
        assert np.all(l0 + l1 * x <= true + 1e-12) and np.all(true <= u0 + u1 * x + 1e-12)


def test_scaled_path_kinematics_are_exact(galicki):
    """q(t) of a timed parabola: velocities and accelerations are its derivatives, the
    segments join, and the open loop of its own torques follows it."""
    path = PolynomialPath.parabola(np.zeros(3), np.array([1.0, -0.5, 0.3]),
                                   np.array([0.2, 0.1, -0.4]))
    s = np.linspace(0.0, 1.0, 21)
    x = 4.0 * np.sin(np.pi * np.linspace(0.1, 1.0, 21)) ** 2
    traj = ScaledPath(galicki, path, s, x, 1.0, 1.0)
    assert traj.T == pytest.approx(np.sum(2 * np.diff(s) / np.add(*np.sqrt([x[:-1], x[1:]]))))
    t = np.linspace(0.0, traj.T, 4001)[1:-1]
    e = traj.evaluate(t)
    h = 1e-6
    ep, em = traj.evaluate(t + h), traj.evaluate(t - h)
    inner = np.all(np.abs(traj.t_grid[:, None] - t[None, :]) > 2 * h, axis=0)
    np.testing.assert_allclose(((ep.q - em.q) / (2 * h))[inner], e.qd[inner], atol=1e-6)
    np.testing.assert_allclose(((ep.qd - em.qd) / (2 * h))[inner], e.qdd[inner], atol=1e-5)
    polys = traj._segment_polynomials()
    for j in (0, 7, 19):
        sigma = np.array([0.0, 0.3, 1.0])
        q = traj.evaluate(traj.t_grid[j] + sigma * traj.h[j]).q
        want = np.array([np.polynomial.polynomial.polyval(sg, polys[j].T) for sg in sigma])
        np.testing.assert_allclose(q, want, atol=1e-12)
    _, xs, ok = traj.open_loop(1e-12, 1e-13)
    assert ok
    np.testing.assert_allclose(xs[-1], traj.state(traj.T)[0, :6], atol=1e-8)


def test_the_followed_target_is_reached_near_the_start(panda):
    """A 2 cm move: the followed configuration reaches the target and moves little; the
    self-motion families of the seed pairs end anywhere on the manifold."""
    q0 = np.array([0.3, 0.2, -0.4, -1.9, 0.2, 1.8, 0.6])
    target = panda.point(q0) + np.array([0.02, -0.01, 0.01])
    problem = Problem(panda, joint_state(q0), point(target), k=4.0)
    q = fm._followed(problem, q0)
    assert q is not None
    assert np.linalg.norm(panda.point(q) - target) <= 1e-9
    assert np.max(np.abs(q - q0)) < 0.1
    lim = problem.limits
    assert np.all(q >= lim.plan_lower) and np.all(q <= lim.plan_upper)


def test_joint_state_to_joint_state(galicki):
    """A joint-state target: the path ends on it exactly (no inverse kinematics)."""
    q0, q1 = np.array([0.3, 1.2, -0.9]), np.array([1.0, -0.4, 0.7])
    problem = Problem(galicki, joint_state(q0), joint_state(q1), k=4.0,
                      limits=_tight(galicki))
    res = first_motion(problem)
    _check_motion(problem, res)
    np.testing.assert_allclose(res.trajectory.evaluate(res.T).q[0], q1, atol=1e-12)
    assert res.certificate.item("end_position").passed


# ------------------------------------------------------- the quick replan (issue 47)
def _running_and_moved(problem: Problem, result, t: float, shift: np.ndarray):
    """The replan of ``result`` at its time ``t`` to its target moved by ``shift`` (m)."""
    n = problem.model.n
    z = result.trajectory.state(t)[0]
    return Problem(problem.model, joint_state(z[:n], z[n:2 * n]),
                   point(problem.target_point + shift), k=problem.k, limits=problem.limits)


@pytest.mark.parametrize("t", [0.0, 0.2, 0.45], ids=["start", "moving", "tail"])
def test_quick_motion_replans_the_paper_example_from_its_own_states(paper_optimum, t):
    """From rest and from moving states of the optimum, to a target moved by 4 cm: the
    target's configuration found near the old end, certified, from the hand-off state
    (position and velocity) to the new target at rest, and not faster than the optimum of
    the same problem (a quick motion is one path's best timing)."""
    problem, optimum = paper_optimum
    assert optimum.success, optimum.message
    moved = _running_and_moved(problem, optimum, t, np.array([0.03, -0.025]))
    q_end = optimum.trajectory.state(optimum.T)[0][:problem.model.n]
    quick = fm.quick_motion(moved, q_end, optimum.T - t)
    _check_motion(moved, quick)
    assert quick.timings["guess"] >= 0.0 and quick.iterations >= 1
    reference = plan(moved)
    assert reference.success, reference.message
    assert quick.T >= reference.T * (1.0 - 1e-6)


def test_quick_motion_on_the_panda_from_a_moving_state(panda):
    """The Panda with its limits from a moving state of a first motion: certified within the
    limits at every time, the end configuration near the given one."""
    problem = panda_problem(panda, True)
    running = first_motion(problem)
    assert running.success, running.message
    moved = _running_and_moved(problem, running, 0.3 * running.T, np.array([0.02, 0.03, -0.02]))
    q_end = running.trajectory.state(running.T)[0][:7]
    quick = fm.quick_motion(moved, q_end, 0.7 * running.T)
    _check_motion(moved, quick)
    end_q = quick.trajectory.state(quick.T)[0][:7]
    assert np.max(np.abs(end_q - q_end)) < 0.5  # found near the old end, not anywhere


def test_quick_motion_failures_are_named(galicki):
    """A point start is refused; a target out of reach says so."""
    start = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    with pytest.raises(fm.ProblemError, match="joint-state start"):
        fm.quick_motion(start, np.zeros(3))
    q = np.array([0.3, 0.9, 0.6])
    with pytest.raises(fm.ProblemError, match="not reachable"):
        far = Problem(galicki, joint_state(q, np.zeros(3)), point((6.0, 0.0)), k=4.0)
        fm.quick_motion(far, q)  # reach 5.5 m


# ------------------------------------------- issue 47: the quick motion's parts, cut
@pytest.mark.parametrize("robot, moving", [("galicki", False), ("galicki", True),
                                           ("panda", False), ("panda", True)],
                         ids=["paper-rest", "paper-moving", "panda-rest", "panda-moving"])
def test_seidel_driver_times_as_toppras_algorithm_does(robot, moving, request):
    """TOPP-RA driven over toppra's compiled Seidel solver (the default) against toppra's own
    algorithm object on the same rows: the same squared path speeds, friction lines and
    adapted boxes included, and the same number of passes."""
    model = request.getfixturevalue(robot)
    n = model.n
    rng = np.random.default_rng(47)
    limits = JointLimits.from_model(model)
    lo, hi = np.nan_to_num(limits.plan_lower, nan=-2.0), np.nan_to_num(limits.plan_upper,
                                                                          nan=2.0)
    q0, q1 = (np.clip(0.5 * (lo + hi) + rng.uniform(-0.3, 0.3, n), lo, hi) for _ in range(2))
    v = rng.uniform(-0.5, 0.5, n) if moving else np.zeros(n)
    path = PolynomialPath.parabola(q0, q1, v) if moving else PolynomialPath.straight(q0, q1)
    problem = Problem(model, joint_state(q0, v), point(model.point(q1)), k=4.0, limits=limits)
    sd0 = 1.0 if moving else 0.0
    new = ts.time_scaling(problem, path, sd0, 30)
    old = ts.time_scaling(problem, path, sd0, 30, engine="toppra")
    assert not isinstance(new[0], Status), new[1]
    assert not isinstance(old[0], Status), old[1]
    np.testing.assert_allclose(new[0].x, old[0].x, rtol=1e-9, atol=1e-12)
    assert new[1] == old[1] and new[0].T == pytest.approx(old[0].T, rel=1e-12)


def test_seidel_driver_names_an_uncontrollable_start(galicki):
    """A start speed no deceleration within the torques can bring to rest by the end: both
    drivers fail, the default one saying why."""
    q0, q1 = np.array([0.3, 0.9, 0.6]), np.array([0.32, 0.9, 0.6])
    path = PolynomialPath.straight(q0, q1)
    problem = Problem(galicki, joint_state(q0), point(galicki.point(q1)), k=4.0)
    out = ts.time_scaling(problem, path, 500.0, 30)
    assert out[0] is Status.SCALING_FAILED and "not controllable" in out[1], out
    assert ts.time_scaling(problem, path, 500.0, 30, engine="toppra")[0] is \
        Status.SCALING_FAILED
    with pytest.raises(ValueError, match="`engine`"):
        ts.time_scaling(problem, path, 0.0, 30, engine="cvxpy")


def test_first_pass_is_handed_on_only_for_its_own_path(galicki):
    """time_scaling takes a ranking's first pass of the same path and arguments (one pass
    fewer, the same timing) and refuses one of another path."""
    q0, q1 = np.array([0.3, 0.9, 0.6]), np.array([0.8, 0.4, 1.0])
    problem = Problem(galicki, joint_state(q0), point(galicki.point(q1)), k=4.0)
    path = PolynomialPath.straight(q0, q1)
    first = ts.first_pass(problem, path, 0.0, 30)
    handed = ts.time_scaling(problem, path, 0.0, 30, first=first)
    alone = ts.time_scaling(problem, path, 0.0, 30)
    np.testing.assert_array_equal(handed[0].x, alone[0].x)
    assert handed[1] == alone[1] - 1 and np.isfinite(first.T) and first.T >= alone[0].T
    with pytest.raises(ValueError, match="`first`"):
        ts.time_scaling(problem, PolynomialPath.straight(q0, q1), 0.0, 30, first=first)


@pytest.mark.parametrize("t", [0.0, 0.2, 0.45], ids=["start", "moving", "tail"])
def test_quick_motion_is_as_before_issue_47s_cuts(paper_optimum, t):
    """The quick motion now (the Seidel driver, the ranking pass handed on) and with the
    TOPP-RA before (toppra's algorithm object, the scales ranked in the full cube): the same
    path and T on the paper example's replans."""
    problem, optimum = paper_optimum
    moved = _running_and_moved(problem, optimum, t, np.array([0.03, -0.025]))
    q_end = optimum.trajectory.state(optimum.T)[0][:problem.model.n]
    now = fm.quick_motion(moved, q_end)
    before = fm.quick_motion(moved, q_end, engine="toppra")
    _check_motion(moved, now)
    assert before.success, before.message
    assert now.T == pytest.approx(before.T, rel=1e-9)
    # Every time scale's ranking pass is made ahead in one call: at most two more than the
    # search reads (three of the five at least); the timing's passes are not repeated.
    assert now.iterations <= before.iterations + 2


def test_open_loop_in_one_call_is_the_segments_one_by_one(panda):
    """The certificate's re-integration of a Panda quick motion by CVODES: every segment in
    one mapaccum call gives the states of the segments integrated one by one from Python, to
    the bit. (The explicit steps tried first: test_explicit_open_loop.py.)"""
    problem = panda_problem(panda, True)
    res = first_motion(problem)
    assert res.success, res.message
    one = res.trajectory.open_loop(1e-12, 1e-13, explicit=False)
    each = res.trajectory.open_loop(1e-12, 1e-13, one_call=False)
    assert one[2] and each[2]
    np.testing.assert_array_equal(one[0], each[0])
    np.testing.assert_array_equal(one[1], each[1])


def test_open_loop_of_the_deviation_is_the_open_loop_of_the_state(panda):
    """The certificate's re-integration as the deviation from each segment's path (the
    default) against CVODES on the state itself (before; here in CasADi's virtual machine,
    the same equation and tolerances): the same states to the integrators' accuracy on a
    Panda quick motion, its end on the path's end; and a real integration, not an identity:
    from a start 1e-3 off the path, one segment of each gives the same perturbed states,
    which leave the path."""
    import casadi as ca

    from tocontrol_ros.core.direct.flat_trajectory import (
        OPEN_LOOP_POINTS,
        integrate_segments,
        polynomial_segment_ode,
    )
    from tocontrol_ros.core.direct.scaled_path import open_loop_integrator

    problem = panda_problem(panda, True)
    traj = first_motion(problem).trajectory
    n, degree = panda.n, 2 * traj.path.degree
    sig, x, c, h, ode = polynomial_segment_ode(panda, degree)
    grid = np.linspace(0.0, 1.0, OPEN_LOOP_POINTS + 1)[1:]
    state = ca.integrator("state", "cvodes", {"t": sig, "x": x, "p": ca.vertcat(ca.vec(c), h),
                                              "ode": ode}, 0.0, grid.tolist(),
                          {"reltol": 1e-12, "abstol": 1e-13, "max_num_steps": 100000,
                           "linear_multistep_method": "adams",
                           "nonlinear_solver_iteration": "functional"})
    coefs = traj._segment_polynomials()
    t_dev, x_dev, ok_dev = traj.open_loop(1e-12, 1e-13)
    t_x, x_x, ok_x = integrate_segments(
        state, traj.state(0.0)[0, :2 * n],
        ((coefs[j], traj.h[j], traj.t_grid[j] + traj.h[j] * grid) for j in range(len(traj.h))))
    assert ok_dev and ok_x
    np.testing.assert_allclose(t_dev, t_x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x_dev, x_x, rtol=0, atol=1e-8)
    np.testing.assert_allclose(x_dev[-1], traj.state(traj.T)[0, :2 * n], rtol=0, atol=1e-10)
    # One segment from a perturbed start, both forms.
    j = 7
    p = np.concatenate([coefs[j].ravel(order="F"), [traj.h[j]]])
    x0 = traj.state(traj.t_grid[j])[0, :2 * n] + 1e-3
    dev = np.array(open_loop_integrator(panda, degree, 1e-12, 1e-13)(x0=x0, p=p)["xf"])
    off = np.array(state(x0=x0, p=p)["xf"])
    np.testing.assert_allclose(dev, off, rtol=0, atol=1e-10)
    on_path = traj.state(traj.t_grid[j + 1])[0, :2 * n]
    assert np.max(np.abs(dev[:, -1] - on_path)) > 1e-3  # it moved off the path


def test_scaled_path_torques_are_the_models_inverse_dynamics(panda):
    """The compiled inverse dynamics, mapped over a multiple of MAP_STEP samples (padded):
    the model's own (CasADi's virtual machine) at every sample, whatever their count."""
    problem = panda_problem(panda, True)
    traj = first_motion(problem).trajectory
    for count in (1, 31, 32, 33, 70):
        e = traj.evaluate(np.linspace(0.0, traj.T, count))
        tau = np.array([panda.inverse_dynamics(q, v, a)
                        for q, v, a in zip(e.q, e.qd, e.qdd, strict=True)])
        assert e.tau.shape == (count, 7)
        np.testing.assert_allclose(e.tau, tau, rtol=1e-10, atol=1e-10)


def test_stage_interval_in_closed_form_is_seidels(panda):
    """Each stage's controllable interval by Fourier-Motzkin elimination (the fallback where
    Seidel's solver gives no answer) against Seidel's, stage by stage on a Panda path."""
    from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

    problem = panda_problem(panda, False)
    n = panda.n
    q0 = problem.start.value[:n]
    path = PolynomialPath.parabola(q0, q0 + 0.3, np.linspace(-0.2, 0.2, n))
    s = np.linspace(0.0, 1.0, 31)
    coef = ts._Coefficients(problem, path, s)
    cube = np.full((31, n), n ** (-1 / 8))
    u0, u1, l0, l1, _ = ts._friction_lines(coef, None)
    rows = (np.hstack([coef.a / cube, -coef.a / cube]),
            np.hstack([(coef.b + u1) / cube, -(coef.b + l1) / cube]),
            np.hstack([(coef.c + u0) / cube, -(coef.c + l0) / cube]),
            np.minimum(coef.xv, 1e8))
    wrapper = seidelWrapper([ts._constraint_class()(*rows)], ts._path_class()(n), s,
                            solve_lp1d=True)
    K = np.zeros((31, 2))
    for i in range(29, -1, -1):
        hi = wrapper.solve_stagewise_optim(i, None, np.array([1e-9, -1.0]), np.nan, np.nan,
                                           *K[i + 1])[1]
        lo = wrapper.solve_stagewise_optim(i, None, np.array([-1e-9, 1.0]), np.nan, np.nan,
                                           *K[i + 1])[1]
        closed = ts._stage_interval(rows, s, i, K[i + 1])
        np.testing.assert_allclose(closed, (max(lo, 0.0), hi), rtol=1e-7, atol=1e-9)
        K[i] = max(lo, 0.0), hi
    assert K[0, 1] > 0.0


def test_quick_motion_from_an_almost_resting_start(panda):
    """A hand-off moving at 1e-5 rad/s (the end of a running motion, bench/replan.py's Panda):
    the parabola's tangent at s = 0 is 1e-8, Seidel's solver gives no bound for its first
    stage, and toppra's algorithm found no timing; the closed-form stage makes it a certified
    quick motion from that exact state."""
    limits = JointLimits.from_model(panda).with_margin(0.05)
    q0 = np.array([0.0822120481, -1.19994496, 0.0932206312, -2.78194884, -0.126023813,
                   1.7790865, 0.0741365004])
    qd0 = np.array([-1.24099355e-05, -1.72708524e-07, -1.42019146e-05, -4.48031613e-09,
                    -7.00615653e-06, -6.50390202e-07, 0.0])
    problem = Problem(panda, joint_state(q0, qd0), point((0.241279919, -0.0920311382,
                                                          0.515513206)),
                      k=4.0, reserve=0.1, limits=limits)
    quick = fm.quick_motion(problem, q0)
    _check_motion(problem, quick)
    assert not fm.quick_motion(problem, q0, engine="toppra").success


@pytest.mark.parametrize("degree", [0, 1, 2, 4])
def test_path_evaluation_is_numpys_polyval_to_the_bit(degree):
    """The path and its derivatives by the Horner steps written out (issue 47: a replan
    evaluates paths about thirty times) are numpy's ``polyval`` to the bit, and the position
    range found for all candidates at once is the one found candidate by candidate."""
    from numpy.polynomial import polynomial as poly

    rng = np.random.default_rng(degree)
    for _ in range(50):
        c = rng.normal(size=(degree + 1, 7)) * rng.choice([1e-9, 1.0, 30.0])
        c[:, rng.integers(7)] = 0.0  # a joint that does not move
        path = PolynomialPath(c)
        s = np.sort(rng.uniform(-0.1, 1.1, size=rng.integers(1, 60)))
        for order in range(4):
            coef = c if order == 0 else poly.polyder(c, order, axis=0) \
                if degree >= order else np.zeros((1, 7))
            out = path(s, order)
            assert out.shape == (len(s), 7)
            np.testing.assert_array_equal(out, poly.polyval(s, coef).T)
            assert np.array_equal(np.signbit(out), np.signbit(poly.polyval(s, coef).T))
        cands = [np.zeros(7), np.ones(7)]
        if degree == 2:
            with np.errstate(divide="ignore", invalid="ignore"):
                vertex = -c[1] / (2.0 * c[2])
            cands.append(np.where(np.isfinite(vertex), np.clip(vertex, 0.0, 1.0), 0.0))
        elif degree > 2:
            cands += [np.full(7, v) for v in np.linspace(0.0, 1.0, 201)]
        powers = np.arange(degree + 1)[:, None]
        values = np.array([np.sum(c * v[None, :] ** powers, axis=0) for v in cands])
        low, high = path.position_range()
        np.testing.assert_array_equal(low, values.min(axis=0))
        np.testing.assert_array_equal(high, values.max(axis=0))


@pytest.mark.parametrize("degree", [1, 2, 4])
def test_paths_evaluated_together_are_each_path_to_the_bit(degree):
    """Several paths of one degree evaluated and bounded at once (the time scales' ranking
    in one go): each path's own evaluation and position range, to the bit."""
    rng = np.random.default_rng(degree)
    paths = [PolynomialPath(rng.normal(size=(degree + 1, 7))) for _ in range(5)]
    s = np.linspace(0.0, 1.0, 31)
    for order in range(3):
        together = PolynomialPath.evaluate_many(paths, s, order)
        for got, path in zip(together, paths, strict=True):
            np.testing.assert_array_equal(got, path(s, order))
    low, high = PolynomialPath.position_ranges(paths)
    for i, path in enumerate(paths):
        one = path.position_range()
        np.testing.assert_array_equal(low[i], one[0])
        np.testing.assert_array_equal(high[i], one[1])


def test_scaled_path_state_at_its_ends_is_its_evaluation(panda):
    """A quick motion's state at its start and end (a replan's open loop and the running
    motion's end) comes from the gridpoints' states made with the path: the numbers of the
    general evaluation, to the bit; other times are evaluated as before."""
    from tocontrol_ros.core.types.trajectory import InverseDynamicsTrajectory

    lim = JointLimits.from_model(panda)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    problem = Problem(panda, joint_state(q0), point(panda.point(q0) + [0.1, 0.05, -0.05]),
                      k=4.0, limits=lim)
    traj = fm.quick_motion(problem, q0).trajectory
    for t in (0.0, traj.T, 0.5 * traj.T, np.float64(traj.T)):
        np.testing.assert_array_equal(traj.state(t), InverseDynamicsTrajectory.state(traj, t))
    assert traj.state(traj.T) is not traj.state(traj.T)  # a copy each time


def test_limits_with_a_margin_are_made_once_per_margin():
    """``with_margin`` keeps what it made (a node makes a problem per goal) and its planning
    bounds are read-only (shared by every reader)."""
    lim = JointLimits(("a", "b"), np.array([-1.0, -2.0]), np.array([1.0, 2.0]),
                      np.array([1.0, 3.0]))
    wide = lim.with_margin(0.1)
    assert wide is lim.with_margin(0.1) and wide.margin == 0.1
    np.testing.assert_allclose(wide.plan_upper, [0.9, 1.8])
    np.testing.assert_allclose(wide.plan_velocity, [0.9, 2.7])
    with pytest.raises(ValueError):
        wide.plan_lower[0] = 0.0
    many = [lim.with_margin(m) for m in np.linspace(0.0, 0.5, 20)]
    assert all(m.margin == pytest.approx(v) for m, v in zip(many, np.linspace(0.0, 0.5, 20),
                                                             strict=True))


def test_segment_samples_take_each_end_from_the_segment_it_ends(panda):
    """The check between the gridpoints samples every segment at both ends, each from its own
    segment (both sides of an acceleration jump), in one evaluation: the numbers of the
    general evaluation from the right at a segment's start and from the left at its end, to
    the bit."""
    problem = panda_problem(panda, True)
    traj = first_motion(problem).trajectory
    points = 5
    t, u, qd = traj.segment_samples(points)
    ends = np.tile(np.linspace(0.0, 1.0, points) == 1.0, len(traj.h))
    for mask, left in ((~ends, False), (ends, True)):
        q_ref, qd_ref, qdd_ref = traj._path(t[mask], left=left)
        np.testing.assert_array_equal(qd[mask], qd_ref)
        np.testing.assert_array_equal(u[mask], traj._controls(q_ref, qd_ref, qdd_ref))
    np.testing.assert_array_equal(t[ends], traj.t_grid[1:])
