"""TOPP-RA's sweeps compiled (issue 47, core/direct/sweeps.py) against toppra's Seidel solver.

The same rows go to both: the controllable sets stage by stage, the squared path speeds of
a pass and the timed ``T`` agree to 1e-9 relative, on random paths of the paper's arm and
the Panda, with and without acceleration limits and friction lines; the failures are the
same statuses and messages.
"""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.direct import sweeps
from tocontrol_ros.core.direct import time_scaling as ts
from tocontrol_ros.core.direct.scaled_path import PolynomialPath
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.core.types.result import Status

RTOL = 1e-9
#: Joint acceleration limits (rad/s^2) tight enough to bind on these paths.
ACCELERATION = 2.0


def _limits(model, accelerations: bool) -> JointLimits:
    base = JointLimits.from_model(model)
    acc = np.full(model.n, ACCELERATION) if accelerations else None
    return JointLimits(base.names, base.lower, base.upper, base.velocity, 0.0, acc)


def _case(model, seed: int, accelerations: bool, moving: bool):
    """(problem, path, sd0): a random path inside the limits, from rest or moving."""
    n = model.n
    rng = np.random.default_rng(seed)
    limits = _limits(model, accelerations)
    lo = np.nan_to_num(limits.plan_lower, nan=-2.0)
    hi = np.nan_to_num(limits.plan_upper, nan=2.0)
    q0, q1 = (np.clip(0.5 * (lo + hi) + rng.uniform(-0.4, 0.4, n), lo, hi) for _ in range(2))
    q1[seed % n] = q0[seed % n]  # a joint that does not move: no velocity bound, X_HUGE
    v = rng.uniform(-0.3, 0.3, n) if moving else np.zeros(n)
    path = PolynomialPath.parabola(q0, q1, v) if moving else PolynomialPath.straight(q0, q1)
    problem = Problem(model, joint_state(q0, v), point(model.point(q1)), k=4.0, limits=limits)
    return problem, path, (0.3 if moving else 0.0)


def _seidel_sets(rows: tuple, s: np.ndarray) -> np.ndarray:
    """The controllable sets (N + 1, 2) by toppra's Seidel solver, stage by stage."""
    from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

    a = rows[0]
    wrapper = seidelWrapper([ts._constraint_class()(*rows)], ts._path_class()(a.shape[1]), s,
                            solve_lp1d=True)
    last = len(s) - 1
    K = np.zeros((last + 1, 2))
    for i in range(last - 1, -1, -1):
        hi = wrapper.solve_stagewise_optim(i, None, np.array([1e-9, -1.0]), np.nan, np.nan,
                                           *K[i + 1])[1]
        lo = wrapper.solve_stagewise_optim(i, None, np.array([-1e-9, 1.0]), np.nan, np.nan,
                                           *K[i + 1])[1]
        assert np.isfinite(hi) and np.isfinite(lo), f"Seidel gave no bound at stage {i}"
        K[i] = max(lo, 0.0), hi
    return K


def _compiled_sets(model, rows: tuple, s: np.ndarray, sd0: float):
    """:func:`sweeps.controllable_and_forward` on ``rows`` in the time_scaling layout."""
    a, b, c, x_max = rows
    n, m = model.n, a.shape[1]
    order = np.arange(m) if m == 2 * n else \
        np.r_[0:n, 2 * n:3 * n, n:2 * n, 3 * n:m]
    return sweeps.controllable_and_forward(model, a[:, order], b[:, order], c[:, order],
                                           x_max, s, sd0 ** 2)


CASES = [(robot, seed, acc, moving) for robot in ("galicki", "panda")
         for seed, acc, moving in ((1, False, False), (2, False, True), (3, True, False),
                                   (4, True, True))]


@pytest.mark.parametrize("robot, seed, accelerations, moving", CASES,
                         ids=[f"{r}-{s}-{'acc' if a else 'noacc'}-{'moving' if m else 'rest'}"
                              for r, s, a, m in CASES])
def test_compiled_sweeps_are_seidels(robot, seed, accelerations, moving, request):
    """Controllable sets, a pass's squared speeds (the cube, then friction lines and adapted
    boxes as time_scaling makes them), and the timed path: compiled = Seidel to 1e-9."""
    model = request.getfixturevalue(robot)
    problem, path, sd0 = _case(model, seed, accelerations, moving)
    n, N = model.n, 30
    s = np.linspace(0.0, 1.0, N + 1)
    coef = ts._Coefficients(problem, path, s)
    cube = np.full((N + 1, n), n ** (-1.0 / 8.0))
    x_cube, why = ts._toppra(coef, s, sd0, cube, None, "seidel")
    assert x_cube is not None, why
    # A friction pass and an adapted box pass, as time_scaling's second and third.
    boxes = ts._boxes(coef.torques(x_cube, s), problem.k)
    for box, x_prev in ((cube, None), (cube, x_cube), (boxes, x_cube)):
        rows = ts._rows(coef, sd0, box, x_prev)
        K_seidel = _seidel_sets(rows, s)
        K, _, feasible, paired = _compiled_sets(model, rows, s, sd0)
        np.testing.assert_allclose(K, K_seidel, rtol=RTOL, atol=1e-12)
        assert feasible
        x_new, why_new = ts._toppra(coef, s, sd0, box, x_prev, "compiled")
        x_old, why_old = ts._toppra(coef, s, sd0, box, x_prev, "seidel")
        assert why_new == why_old == ""
        np.testing.assert_allclose(x_new, x_old, rtol=RTOL, atol=1e-12)
    new = ts.time_scaling(problem, path, sd0, N, engine="compiled")
    old = ts.time_scaling(problem, path, sd0, N, engine="seidel")
    assert not isinstance(new[0], Status), new[1]
    assert not isinstance(old[0], Status), old[1]
    assert new[1] == old[1]  # the same passes
    assert new[0].T == pytest.approx(old[0].T, rel=RTOL)
    np.testing.assert_allclose(new[0].x, old[0].x, rtol=RTOL, atol=1e-12)


def test_paired_sweep_is_every_pair(panda):
    """The own rows paired up with down give every pair's sets to the bit; a partner pair
    of one sign (friction lines straddling alpha = 0) is left to every pair, same numbers."""
    problem, path, sd0 = _case(panda, 5, True, True)
    N = 30
    s = np.linspace(0.0, 1.0, N + 1)
    coef = ts._Coefficients(problem, path, s)
    cube = np.full((N + 1, panda.n), panda.n ** (-1.0 / 8.0))
    rows = ts._rows(coef, sd0, cube, None)
    a, b, c, x_max = rows
    m = a.shape[1]
    order = np.r_[0:7, 14:21, 7:14, 21:m]
    A, B, C = a[:, order], b[:, order], c[:, order]
    two_d = 2.0 * np.diff(s)
    args = (np.hstack([A[:-1], A[1:] + two_d[:, None] * B[1:]]).T,
            np.hstack([B[:-1], B[1:]]).T, np.hstack([1.0 - C[:-1], 1.0 - C[1:]]).T,
            x_max[None, :-1], two_d[None, :], sd0 ** 2)
    paired, every = sweeps.sweeps_function(panda, 2 * m, N)
    K_p, x_p, ok_p, exact = paired(*args)
    K_e, x_e, ok_e = every(*args)
    assert np.all(exact == 1.0)
    np.testing.assert_array_equal(K_p, K_e)
    np.testing.assert_array_equal(x_p, x_e)
    # One partner pair of one sign at a gridpoint: its lower row's alpha made positive.
    A2 = A.copy()
    A2[10, 7] = abs(A2[10, 0]) * 0.5 + 1e-3
    rows2 = (A2[:, np.argsort(order)], b, c, x_max)
    K2, x2, _, used = _compiled_sets(panda, rows2, s, sd0)
    assert not used  # every pair served
    np.testing.assert_allclose(K2, _seidel_sets(rows2, s), rtol=RTOL, atol=1e-12)


def test_compiled_failures_are_seidels(galicki, panda):
    """An empty controllable set and an uncontrollable start: the same status and message
    from both drivers; a start a hair above its set (within toppra's SMALL) goes to the
    Seidel driver's retry and gives its numbers."""
    # A start speed no deceleration can stop in time.
    q0, q1 = np.array([0.3, 0.9, 0.6]), np.array([0.32, 0.9, 0.6])
    path = PolynomialPath.straight(q0, q1)
    problem = Problem(galicki, joint_state(q0), point(galicki.point(q1)), k=4.0)
    new = ts.time_scaling(problem, path, 500.0, 30, engine="compiled")
    old = ts.time_scaling(problem, path, 500.0, 30, engine="seidel")
    assert new[0] is old[0] is Status.SCALING_FAILED
    assert new[1] == old[1] and "not controllable" in new[1], (new, old)
    # Gravity beyond the torques somewhere: a stage without any x.
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    weak = Problem(panda, joint_state(q0), point(panda.point(q0 + 0.1)), k=4.0,
                   reserve=0.95, limits=JointLimits.from_model(panda))
    path = PolynomialPath.straight(q0, q0 + np.array([0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
    new = ts.time_scaling(weak, path, 0.0, 30, engine="compiled")
    old = ts.time_scaling(weak, path, 0.0, 30, engine="seidel")
    assert new[0] is old[0] is Status.SCALING_FAILED
    assert new[1] == old[1] and "empty at gridpoint" in new[1], (new, old)
    # A start just above its set (within toppra's SMALL, so not refused as uncontrollable):
    # the compiled forward step is infeasible there, the Seidel driver retries lower.
    problem, path, _ = _case(galicki, 6, False, False)
    s = np.linspace(0.0, 1.0, 31)
    coef = ts._Coefficients(problem, path, s)
    cube = np.full((31, 3), 3 ** (-1.0 / 8.0))
    K, _, _, _ = _compiled_sets(galicki, ts._rows(coef, 0.0, cube, None), s, 0.0)
    sd0 = float(np.sqrt(K[0, 1] + 5e-6))
    _, _, feasible, _ = _compiled_sets(galicki, ts._rows(coef, sd0, cube, None), s, sd0)
    assert not feasible
    x_new, why_new = ts._toppra(coef, s, sd0, cube, None, "compiled")
    x_old, why_old = ts._toppra(coef, s, sd0, cube, None, "seidel")
    assert why_new == why_old == "the forward sweep failed at gridpoint 0 of 30"
    assert x_new is None and x_old is None


@pytest.mark.parametrize("robot, accelerations", [("galicki", False), ("galicki", True),
                                                  ("panda", False), ("panda", True)],
                         ids=["paper", "paper-accel", "panda", "panda-accel"])
def test_first_passes_together_are_each_first_pass_to_the_bit(robot, accelerations, request):
    """A moving start's time scales ranked in one go (``first_passes``: the coefficients by
    one inverse-dynamics call, the sweeps mapped over the paths) give each path's
    ``first_pass`` to the bit: coefficients, squared path speeds, ``T``, failures and their
    messages; a speed cap and a start speed no path can take (uncontrollable) included."""
    model = request.getfixturevalue(robot)
    problem, path, _ = _case(model, 5, accelerations, True)
    q0, q1, v = path.c[0], path.c[0] + path.c[1] + path.c[2], path.c[1]
    taus = [1.0, 2.0, 4.0, 8.0, 16.0]
    paths = [PolynomialPath.parabola(q0, q1, v * tau) for tau in taus]
    sd0s = [1.0 / tau for tau in taus[:-1]] + [500.0]  # the last one not controllable
    cap = np.full(model.n, 0.8)
    for speed_cap in (None, cap):
        together = ts.first_passes(problem, paths, sd0s, 30, speed_cap)
        for got, one_path, sd0 in zip(together, paths, sd0s, strict=True):
            alone = ts.first_pass(problem, one_path, sd0, 30, speed_cap)
            assert got.T == alone.T and got.why == alone.why and got.key == alone.key
            assert (got.x is None) == (alone.x is None)
            if alone.x is not None:
                np.testing.assert_array_equal(got.x, alone.x)
            for name in ("a", "b", "c", "f", "xv"):
                np.testing.assert_array_equal(getattr(got.coef, name),
                                              getattr(alone.coef, name))
        assert any(np.isfinite(p.T) for p in together) and \
            not np.isfinite(together[-1].T)
        assert "not controllable" in together[-1].why
    with pytest.raises(ValueError, match="`sd0s`"):
        ts.first_passes(problem, paths, sd0s[:2], 30)
