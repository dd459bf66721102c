"""The certificate's open loop of a timed path by explicit steps with an error test (issue 47).

:meth:`ScaledPath.open_loop` first integrates every segment by Heun steps in one compiled call
(:meth:`ScaledPath.open_loop_explicit`) and keeps that when every step's error estimate is
within its bound; CVODES otherwise. Checked here against CVODES (``explicit=False``, the
integration before): the same states to the integrators' accuracy where the test passes,
CVODES's own states where it fails, and the same verdicts on motions the certificate refuses.
"""

from __future__ import annotations

from functools import partialmethod

import numpy as np
import pytest
from first_motion_cases import panda_problem

from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.first_motion import first_motion
from tocontrol_ros.core.direct.scaled_path import ScaledPath
from tocontrol_ros.core.direct.tuning import OPEN_LOOP_ATOL, OPEN_LOOP_RTOL
from tocontrol_ros.core.examples import PAPER_TARGET
from tocontrol_ros.core.types.certificate import CertificateOptions
from tocontrol_ros.core.types.problem import Problem, joint_state, point

TOL = (OPEN_LOOP_RTOL, OPEN_LOOP_ATOL)
OPTIONS = CertificateOptions(rtol=OPEN_LOOP_RTOL, atol=OPEN_LOOP_ATOL)


def _paper_problem(galicki, moving: bool) -> Problem:
    q0 = np.array([0.3, 1.2, -0.9])
    qd0 = np.array([0.0, -0.5, 0.5]) if moving else np.zeros(3)
    return Problem(galicki, joint_state(q0, qd0), point(PAPER_TARGET), k=4.0)


@pytest.fixture(params=["paper-rest", "paper-moving", "panda-rest", "panda-moving"])
def motion(request):
    """A first motion (its path a straight line from rest, a parabola when moving)."""
    robot, start = request.param.split("-")
    model = request.getfixturevalue("galicki" if robot == "paper" else "panda")
    make = _paper_problem if robot == "paper" else panda_problem
    problem = make(model, start == "moving")
    res = first_motion(problem)
    assert res.success, res.message
    return problem, res.trajectory


def test_explicit_steps_meet_their_tolerance_and_agree_with_cvodes(motion):
    """Every step's error estimate within its bound; the states those of CVODES at the same
    tolerances to 1e-12 (measured 1e-14 at most), the end on the path's end; and what
    ``open_loop`` returns is the explicit integration."""
    _, traj = motion
    t, x, ratio = traj.open_loop_explicit(*TOL)
    assert 0.0 < ratio <= 1.0
    t_cv, x_cv, ok = traj.open_loop(*TOL, explicit=False)
    assert ok
    np.testing.assert_array_equal(t, t_cv)
    np.testing.assert_allclose(x, x_cv, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x[-1], traj.state(traj.T)[0, :2 * traj.n], rtol=0, atol=1e-12)
    t_ol, x_ol, ok = traj.open_loop(*TOL)
    assert ok
    np.testing.assert_array_equal(x_ol, x)


def test_a_failed_error_test_falls_back_to_cvodes(panda):
    """From a start 1e-3 off the path the deviation is no longer small: the explicit steps
    fail their test by far, and ``open_loop`` returns CVODES's states, to the bit."""
    traj = first_motion(panda_problem(panda, True)).trajectory
    off = traj.state(0.0) + np.concatenate([np.full(2 * traj.n, 1e-3), np.zeros(2 * traj.n)])
    traj.state = lambda t: off.copy() if np.isscalar(t) and t == 0.0 else \
        ScaledPath.state(traj, t)
    _, x_ex, ratio = traj.open_loop_explicit(*TOL)
    assert ratio > 1e3
    t, x, ok = traj.open_loop(*TOL)
    t_cv, x_cv, ok_cv = traj.open_loop(*TOL, explicit=False)
    assert ok and ok_cv
    np.testing.assert_array_equal(x, x_cv)
    assert np.max(np.abs(x[-1] - traj.state(traj.T)[0, :2 * traj.n])) > 1e-4  # it left


def test_a_non_finite_state_fails_the_test(galicki):
    """A state that is not finite (here the start) makes the ratio NaN: not passed."""
    traj = first_motion(_paper_problem(galicki, False)).trajectory
    bad = traj.state(0.0)
    bad[0, 0] = np.nan
    traj.state = lambda t: bad.copy() if np.isscalar(t) and t == 0.0 else \
        ScaledPath.state(traj, t)
    assert np.isnan(traj.open_loop_explicit(*TOL)[2])


def _verdicts(problem, traj) -> dict:
    cert = certify_open_loop(problem, traj, OPTIONS)
    return {"passed": cert.passed, "failed": sorted(i.name for i in cert.items if not i.passed),
            "end": cert.open_loop_end}


@pytest.mark.parametrize("case", ["as planned", "sped up", "end off target"])
def test_the_certificate_decides_as_with_cvodes(galicki, panda, case, monkeypatch):
    """The certificate with the explicit open loop (now) and with CVODES (before): the same
    verdict and the same failing items on the motions it passes and on those it refuses (a
    motion sped up by 30 %: its torques leave the set; a target 1 mm off the motion's end),
    the open-loop ends within 1e-12."""
    for problem in (_paper_problem(galicki, True), panda_problem(panda, True)):
        traj = first_motion(problem).trajectory
        if case == "sped up":
            traj = ScaledPath(problem.model, traj.path, traj.s, 1.69 * traj.x, problem.k,
                              problem.torque_scale)
        elif case == "end off target":
            problem = Problem(problem.model, problem.start, point(problem.target_point + 1e-3),
                              k=problem.k, limits=problem.limits)
        now = _verdicts(problem, traj)
        with monkeypatch.context() as m:
            m.setattr(ScaledPath, "open_loop",
                      partialmethod(ScaledPath.open_loop, explicit=False))
            before = _verdicts(problem, traj)
        assert now["passed"] == before["passed"] == (case == "as planned")
        assert now["failed"] == before["failed"]
        assert case == "as planned" or now["failed"]
        np.testing.assert_allclose(now["end"], before["end"], rtol=0, atol=1e-12)
