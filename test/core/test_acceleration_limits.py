"""Acceleration limits from joint_limits.yaml, held on the whole motion (issue 52).

The limits object reads ``has_acceleration_limits``/``max_acceleration`` (MoveIt's keys); the
bounded B-spline solve holds them at every time through the convex hull of the second
derivative's control points; the certificate checks them. On the Panda, with MoveIt's
acceleration limits for it: the motion without them accelerates 10-50 times over them, the
one with them keeps to them on a fine sampling and when its torques are re-integrated
(scipy's DOP853, the accelerations from the model's state function at the integrated
states: a second method, not the spline's own derivative).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.robot.limits import JointLimits, parse_joint_limits_yaml
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: MoveIt's panda_moveit_config joint_limits.yaml accelerations (rad/s^2).
PANDA_ACCELERATION = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
PANDA_Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
PANDA_Q1 = np.array([0.9, 0.3, -0.4, -1.5, 0.5, 1.5, -0.2])
#: A first bounded solve compiles the per-sample functions of the model: not a time the
#: solver's budget should be judged on here.
OPTIONS = SolverOptions(starts=1, candidates=1, time_limit=900.0)

YAML = """
joint_limits:
  joint1: {has_acceleration_limits: true, max_acceleration: 3.0}
  joint2: {has_acceleration_limits: false, max_acceleration: 1.0}
  joint3: {has_acceleration_limits: true, max_acceleration: 2.0, has_jerk_limits: true,
           max_jerk: 100.0}
"""


def test_yaml_accelerations_are_read(galicki):
    lim = JointLimits.from_model(galicki)
    assert not lim.has_acceleration and np.all(np.isinf(lim.acceleration))
    lim = lim.narrowed(parse_joint_limits_yaml(YAML))
    assert lim.has_acceleration and lim.active
    assert lim.acceleration[0] == 3.0 and np.isinf(lim.acceleration[1])
    assert lim.acceleration[2] == 2.0
    assert lim.with_margin(0.1).plan_acceleration[0] == pytest.approx(2.7)
    # A second file narrows, never widens.
    wider = parse_joint_limits_yaml(
        "joint_limits:\n  joint1: {has_acceleration_limits: true, max_acceleration: 9.0}")
    assert lim.narrowed(wider).acceleration[0] == 3.0


@pytest.mark.parametrize("text, match", [
    ("joint_limits:\n  joint1: {has_acceleration_limits: true}", "has no `max_acceleration`"),
    ("joint_limits:\n  joint1: {has_acceleration_limits: true, max_acceleration: 0}",
     "max_acceleration must be > 0"),
    ("joint_limits:\n  joint1: {has_acceleration_limits: 1, max_acceleration: 2}",
     "must be true or false"),
])
def test_bad_acceleration_entries_name_the_joint_and_key(galicki, text, match):
    with pytest.raises(ProblemError, match=match):
        JointLimits.from_model(galicki).narrowed(parse_joint_limits_yaml(text))


def test_acceleration_violation_is_a_fraction_of_the_limit(galicki):
    lim = JointLimits.from_model(galicki).narrowed(parse_joint_limits_yaml(YAML))
    assert lim.acceleration_violation(np.array([[2.9, 50.0, -1.9]])) == 0.0
    assert lim.acceleration_violation(np.array([[3.3, 0.0, -2.0], [0.0, 0.0, -2.5]])) == \
        pytest.approx(0.25)


@pytest.fixture(scope="module")
def panda_runs(panda):
    """The same Panda problem without and with acceleration limits."""
    base = JointLimits.from_model(panda)
    limited = JointLimits(base.names, base.lower, base.upper, base.velocity, 0.0,
                          PANDA_ACCELERATION)
    target = point(panda.point(PANDA_Q1))
    free = plan(Problem(panda, joint_state(PANDA_Q0), target, k=4.0), OPTIONS)
    held = plan(Problem(panda, joint_state(PANDA_Q0), target, k=4.0, limits=limited), OPTIONS)
    return free, held


def test_panda_without_acceleration_limits_exceeds_them(panda_runs):
    """The check below can fail: the motion without the limits breaks them many times."""
    free, _ = panda_runs
    assert free.success, free.message
    fine = free.trajectory.evaluate(np.linspace(0.0, free.T, 4001))
    assert np.max(np.abs(fine.qdd) / PANDA_ACCELERATION) > 5.0
    assert "acceleration_limits" not in free.verification


def test_panda_motion_keeps_its_acceleration_limits_on_the_whole_motion(panda, panda_runs):
    free, held = panda_runs
    assert held.success, held.message
    assert held.certificate is not None and held.certificate.passed
    assert held.verification["acceleration_limits"] == 0.0
    assert held.T > free.T
    fine = held.trajectory.evaluate(np.linspace(0.0, held.T, 8001))
    ratio = np.max(np.abs(fine.qdd), axis=0) / PANDA_ACCELERATION
    assert np.all(ratio <= 1.0 + 1e-9), ratio
    assert np.max(ratio) > 0.99  # they bind: the limits shape the motion
    np.testing.assert_allclose(panda.point(fine.q[-1]), panda.point(PANDA_Q1), atol=1e-4)


def test_panda_reintegrated_accelerations_keep_the_limits(panda, panda_runs):
    """The published torques through the model's dynamics (DOP853, span by span): the
    accelerations the arm would have stay within the limits (to the integration's error)."""
    _, held = panda_runs
    traj, n = held.trajectory, panda.n
    f = panda.function("f")
    scale = held.problem.torque_scale

    def rhs(t, x):
        return np.array(f(x, traj.control(t) * scale)).ravel()

    x = traj.state(0.0)[0, :2 * n]
    worst = 0.0
    for a, b in zip(traj.breaks[:-1] * held.T, traj.breaks[1:] * held.T, strict=True):
        t_eval = np.linspace(a, b, 25)
        sol = solve_ivp(rhs, (a, b), x, method="DOP853", rtol=1e-10, atol=1e-11,
                        t_eval=t_eval)
        assert sol.success
        qdd = np.array([rhs(t, xi)[n:] for t, xi in zip(sol.t, sol.y.T, strict=True)])
        worst = max(worst, float(np.max(np.abs(qdd) / PANDA_ACCELERATION)))
        x = sol.y[:, -1]
    assert worst <= 1.0 + 1e-4, worst
    assert np.max(np.abs(x[:n] - traj.state(held.T)[0, :n])) < 1e-5
    np.testing.assert_allclose(x[n:], 0.0, atol=1e-4)


def test_panda_first_motion_keeps_the_acceleration_limits(panda):
    """The first motion (a seed path timed by TOPP-RA) with the acceleration rows."""
    from tocontrol_ros.core.planning.solver import Planner

    base = JointLimits.from_model(panda)
    limited = JointLimits(base.names, base.lower, base.upper, base.velocity, 0.0,
                          PANDA_ACCELERATION)
    problem = Problem(panda, joint_state(PANDA_Q0), point(panda.point(PANDA_Q1)), k=4.0,
                      limits=limited)
    first = Planner(panda).first(problem, OPTIONS)
    assert first.success, first.message
    assert first.verification["acceleration_limits"] == 0.0
    fine = first.trajectory.evaluate(np.linspace(0.0, first.T, 8001))
    assert np.all(np.max(np.abs(fine.qdd), axis=0) <= PANDA_ACCELERATION * (1 + 1e-9))
