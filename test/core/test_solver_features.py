"""Warm start, moving start, torque reserve, the trajectory object and an enforced limit."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import Planner, SolverOptions, plan
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.core.types.result import WARM_RADIUS

#: One start: these tests do not depend on the basin, and multistart costs time.
SINGLE = SolverOptions(starts=1, candidates=1)

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)
MOVE = np.array([0.03, 0.04])  # 5 cm
RESERVE = 0.2


@pytest.fixture(scope="module")
def base(galicki):
    return plan(Problem(galicki, point(P_START), point(P_TARGET), k=4), SINGLE)


@pytest.fixture(scope="module")
def moved(galicki, base):
    problem = Problem(galicki, point(P_START), point(P_TARGET + MOVE), k=4)
    return {"cold": plan(problem, SINGLE), "warm": plan(problem, SINGLE, warm_start=base)}


@pytest.mark.parametrize("change, fits", [
    ({}, True),
    ({"target": point(P_TARGET + MOVE)}, True),   # a moved target: what warm starts are for
    ({"target": point(P_TARGET + MOVE * 10)}, False),  # 0.5 m away: too far (WARM_RADIUS)
    ({"start": point(P_START - MOVE * 2.1)}, False),   # the start 0.105 m away: too far
    ({"k": 8.0}, True),                           # another exponent: the solve steps k
    ({"reserve": RESERVE}, False),                # another torque bound: another problem
    ({"target": "state"}, False),                 # another target kind: other equations
], ids=["same", "moved", "far", "far-start", "other-k", "other-reserve", "other-kind"])
def test_the_warm_start_rule(galicki, base, change, fits):
    """``PlanResult.can_warm_start`` is the solver's one rule for continuing a result."""
    args = {"start": point(P_START), "target": point(P_TARGET), "k": 4.0, **change}
    if args["target"] == "state":
        args["target"] = joint_state(base.trajectory.state(base.T)[0, :galicki.n])
    assert base.can_warm_start(Problem(galicki, **args)) is fits
    # A result without a solution (here: nothing to move) continues nothing.
    q = base.trajectory.state(0.0)[0, :galicki.n]
    trivial = plan(Problem(galicki, joint_state(q), point(galicki.point(q))))
    assert trivial.success and not trivial.can_warm_start(Problem(galicki, **args))


@pytest.fixture(scope="module")
def reserved(galicki):
    return plan(Problem(galicki, point(P_START), point(P_TARGET), k=4, reserve=RESERVE), SINGLE)


def test_warm_distance_in_radii(galicki, base):
    moved = Problem(galicki, point(P_START), point(P_TARGET + MOVE), k=4)
    assert base.warm_distance(moved) == pytest.approx(0.05 / WARM_RADIUS, rel=1e-12)
    q = base.trajectory.state(base.T)[0, :galicki.n]
    other_kind = Problem(galicki, point(P_START), joint_state(q), k=4)
    assert base.warm_distance(other_kind) == float("inf")


def test_warm_start_is_one_candidate_next_to_the_multistart(base, moved):
    cold, warm = moved["cold"], moved["warm"]
    assert base.success and cold.success and warm.success, (cold.message, warm.message)
    # The warm solution is a candidate (index -1) next to the cold start, not instead of it.
    assert [r.index for r in warm.starts] == [-1, 0]
    warm_record = warm.starts[0]
    print(f"moved target: cold T={cold.T:.10f}, warm candidate T={warm_record.T:.10f} "
          f"({warm.timings['total']:.2f} s for both)")
    assert warm_record.T == pytest.approx(cold.T, rel=1e-7)  # the same basin...
    assert warm.T == cold.T                                   # ...so the cold answer is kept
    assert warm.T != pytest.approx(base.T, rel=1e-3)


def test_the_same_request_gives_the_same_time_whatever_came_before(galicki):
    """A fresh planner and one that has just planned something else answer alike."""
    options = SolverOptions(starts=4, candidates=2)
    # The target 0.5 m from the paper's: continued from the paper's solution, Newton
    # converges, but into a basin 9 % slower than the multistart's (before the rule).
    far = P_TARGET + 0.5 * np.array([np.cos(3.2), np.sin(3.2)])
    request = Problem(galicki, point(P_START), point(far), k=4)
    fresh = Planner(galicki).plan(request, options)
    used = Planner(galicki)
    before = used.plan(Problem(galicki, point(P_START), point(P_TARGET), k=4), options)
    after = used.plan(request, options, warm_start=before)  # as the planner node passes it
    assert fresh.success and before.success and after.success
    assert not before.can_warm_start(request)
    print(f"fresh T={fresh.T!r}, after another request T={after.T!r}")
    assert after.T == fresh.T
    assert [r.index for r in after.starts] == [r.index for r in fresh.starts]


def test_moving_start_to_point(galicki, base):
    q0 = base.trajectory.evaluate(0.0).q[0]
    qd0 = np.array([0.5, -0.3, 1.0])
    res = plan(Problem(galicki, joint_state(q0, qd0), point(P_TARGET), k=4), SINGLE)
    assert res.success, res.message
    start = res.trajectory.evaluate(0.0)
    np.testing.assert_allclose(start.q[0], q0, atol=1e-10)
    np.testing.assert_allclose(start.qd[0], qd0, atol=1e-10)
    end = res.trajectory.evaluate(res.T)
    np.testing.assert_allclose(galicki.point(end.q[0]), P_TARGET, atol=1e-7)
    np.testing.assert_allclose(end.qd[0], 0.0, atol=1e-7)
    assert res.verification["point_error"] < 1e-4
    assert res.T != pytest.approx(base.T, rel=1e-3)


def test_torque_reserve_leaves_headroom_and_costs_time(galicki, base, reserved):
    assert reserved.success, reserved.message
    sample = reserved.trajectory.sample(reserved.T / 1000)
    ratio = np.max(np.abs(sample.tau), axis=0) / galicki.tau_max
    print(f"reserve {RESERVE}: T={reserved.T:.6f} s vs {base.T:.6f} s, "
          f"max |tau| / tau_max = {np.round(ratio, 4)}")
    assert np.all(ratio <= (1 - RESERVE) * (1 + 1e-9))
    assert np.max(ratio) > (1 - RESERVE) * 0.95  # the reduced limits are used
    assert reserved.T > base.T


def test_sample_starts_at_zero_and_ends_at_t_exactly(base):
    traj = base.trajectory
    for dt in (0.01, base.T / 7, 0.3, 10.0):
        s = traj.sample(dt)
        assert s.t[0] == 0.0
        assert s.t[-1] == base.T
        assert np.all(np.diff(s.t) > 0)
        assert np.all(np.diff(s.t)[:-1] == pytest.approx(dt))
        assert s.q.shape == (len(s.t), 3) and s.psi.shape == (len(s.t), 6)
    with pytest.raises(ValueError, match="`dt`"):
        traj.sample(0.0)


def test_evaluate_at_grid_times_matches_the_grid(base):
    traj = base.trajectory
    s = traj.evaluate(traj.t_grid)
    np.testing.assert_array_equal(s.q, traj.z_grid[:, :3])
    np.testing.assert_array_equal(s.qd, traj.z_grid[:, 3:6])
    np.testing.assert_array_equal(s.psi, traj.z_grid[:, 6:])
    # Between grid points: one RK4 step from the grid point before.
    mid = 0.5 * (traj.t_grid[:-1] + traj.t_grid[1:])
    s_mid = traj.evaluate(mid)
    assert np.max(np.abs(np.diff(s_mid.q, axis=0))) < 0.1


def test_trajectory_reaches_the_target_point(galicki, base):
    end = base.trajectory.evaluate(base.T)
    np.testing.assert_allclose(galicki.point(end.q[0]), P_TARGET, atol=1e-8)
    np.testing.assert_allclose(end.qd[0], 0.0, atol=1e-8)
    start = base.trajectory.evaluate(0.0)
    np.testing.assert_allclose(galicki.point(start.q[0]), P_START, atol=1e-8)


@pytest.mark.parametrize("which", ["base", "reserved"])
def test_torques_and_accelerations_are_consistent(galicki, base, reserved, which):
    res = {"base": base, "reserved": reserved}[which]
    r = res.problem.reserve
    s = res.trajectory.sample(res.T / 50)
    np.testing.assert_allclose(s.tau, s.u * galicki.tau_max * (1 - r), rtol=1e-14)
    for i in range(len(s.t)):
        qdd = galicki.forward_dynamics(s.q[i], s.qd[i], s.tau[i])
        np.testing.assert_allclose(s.qdd[i], qdd, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s.H, 0.0, atol=1e-6)


#: The x-y table of test_solver_closed_form with a tight upper limit on joint x.
#: (Its direct guess keeps the limits as bounds: with a limit that no motion can respect,
#: e.g. below the shortest stopping distance, plan() returns NO_GUESS instead of a warned
#: solution.)
TIGHT_URDF = """<?xml version="1.0"?>
<robot name="xy_table">
  <link name="base"/>
  <joint name="x" type="prismatic">
    <parent link="base"/><child link="carriage"/>
    <axis xyz="1 0 0"/>
    <limit effort="10.0" lower="-1" upper="0.265" velocity="100"/>
  </joint>
  <link name="carriage">
    <inertial><mass value="3.0"/>
      <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial>
  </link>
  <joint name="y" type="prismatic">
    <parent link="carriage"/><child link="slide"/>
    <origin xyz="0.1 0.2 0.05"/>
    <axis xyz="0 1 0"/>
    <limit effort="3.0" lower="-5" upper="5" velocity="100"/>
  </joint>
  <link name="slide">
    <inertial><mass value="2.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
</robot>
"""


def test_a_position_limit_the_optimum_overshoots_is_enforced():
    """Moving at 1 m/s towards x's upper limit, the unconstrained optimum overshoots it.

    Braking with all of x's force (a = 2 m/s^2) would stop the carriage at 0.25 m, inside
    the limit 0.265 m; the optimum at k = 1 shares the control with y and reaches 0.2756 m
    (measured with wide limits). With the limit, the best direct guess comes within 2 % of
    it and the solver solves the problem with the limits as hard bounds.
    """
    model = load_robot(TIGHT_URDF, task_axes="xy")
    start, target = joint_state([0.0, 0.0], [1.0, 0.0]), joint_state([-0.5, 0.6])
    wide = JointLimits(model.joint_names, np.full(2, -np.inf), np.full(2, np.inf),
                       model.qd_max)
    free = plan(Problem(model, start, target, k=1, limits=wide))
    assert free.success and free.method == "indirect"
    assert np.max(free.trajectory.sample(1e-3).q[:, 0]) == pytest.approx(0.2756, abs=1e-3)
    res = plan(Problem(model, start, target, k=1))
    assert res.success, res.message
    assert res.method == "direct"
    assert any("joint limits bind" in w for w in res.warnings), res.warnings
    q_max = np.max(res.trajectory.sample(1e-4).q[:, 0])
    assert 0.26 < q_max <= model.q_upper[0]
    assert res.verification["position_limits"] <= 1e-6
    assert res.T > free.T


def test_a_basin_that_fails_its_certificate_gives_way_to_the_next(galicki, monkeypatch):
    """When the best basin's certificate fails, the next best continued basin is finished,
    certified and returned (with a note); with no other basin the failure is returned."""
    import tocontrol_ros.core.indirect.method as solver_module
    from tocontrol_ros.core.types.result import Status

    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4)
    options = SolverOptions(starts=16, candidates=4)
    honest = plan(problem, options)
    assert honest.success, honest.message
    real = solver_module.verdict
    calls = []

    def first_fails(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            return Status.VERIFICATION_FAILED, "verification failed: (forced by the test)"
        return real(*args, **kwargs)

    monkeypatch.setattr(solver_module, "verdict", first_fails)
    res = plan(problem, options)
    assert res.success, res.message
    assert len(calls) == 2
    assert res.T > honest.T * (1 + 1e-6)  # the next basin, not the best one again
    returned = [r for r in res.starts if r.status == "returned"]
    assert len(returned) == 1 and returned[0].T == pytest.approx(res.T)
    assert any("forced by the test" in r.status for r in res.starts)
    assert any("failed its certificate" in w for w in res.warnings)
    calls.clear()
    alone = plan(problem, SolverOptions(starts=1, candidates=1))
    assert alone.status is Status.VERIFICATION_FAILED and len(calls) == 1


def test_limits_that_never_bind_leave_the_multistart_unchanged(galicki):
    """The paper's arm's URDF gives 100 rad/s velocity placeholders, which count as limits
    but never bind: its plans equal those with no limits at all (bounds in the guesses'
    NLP, even inactive, moved this pair of bench/optimum.py, its 43rd, to a basin 1.1 %
    slower)."""
    a = [-0.8480411940448495, 0.22229667693812885]
    b = [-0.3085992164990332, -3.749588203891952]
    n = galicki.n
    none = JointLimits(galicki.joint_names, np.full(n, -np.inf), np.full(n, np.inf),
                       np.full(n, np.inf))
    default = Problem(galicki, point(a), point(b), k=4)
    assert default.limits.active
    free = Problem(galicki, point(a), point(b), k=4, limits=none)
    res, ref = plan(default), plan(free)
    assert res.success and ref.success, (res.message, ref.message)
    assert res.T == pytest.approx(ref.T, rel=1e-9)


def test_the_slow_solver_hook_slows_a_nested_solve_once(monkeypatch):
    """``TOCONTROL_SLOW_SOLVER=f`` makes a plan f times as long, not f squared (issue 53).

    ``Planner.plan`` runs ``solve_once``, both slowed: only the outermost call sleeps, for
    ``f - 1`` times the whole call's duration. A fake clock and a recording sleep: no time
    passes in this test.
    """
    from tocontrol_ros.core.planning import solver

    now = [0.0]
    sleeps = []
    monkeypatch.setattr(solver, "SLOW_SOLVER", 5.0)
    monkeypatch.setattr(solver, "_REAL_CLOCK", lambda: now[0])
    monkeypatch.setattr(solver, "_SLEEP", sleeps.append)

    @solver._slowed
    def inner():
        now[0] += 1.0
        return "inner"

    @solver._slowed
    def outer():
        now[0] += 2.0
        return inner()

    assert outer() == "inner"
    assert sleeps == [4.0 * 3.0]  # the whole call's 3 s, once; not 4 * 1 s inside as well
    assert inner() == "inner"
    assert sleeps == [12.0, 4.0]  # called alone, the inner solve is slowed itself
