"""The certificate (core/checks/certificate.py): passes on good solutions, fails on corrupted ones.

Every corruption is small (a costate off by 1 %, one torque sample a hair over the limit,
torques 1 % short) and each is caught by the check that is meant to catch it, while the
other checks still pass: the items are independent, and the tolerances are tight enough to
matter and loose enough for the solver's own accuracy.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tocontrol_ros.core.checks.verification import fine_sample
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.indirect.certificate import certify
from tocontrol_ros.core.indirect.trajectory import Trajectory
from tocontrol_ros.core.planning.solver import SolverOptions, Status, plan
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.certificate import Certificate, CertificateOptions
from tocontrol_ros.core.types.problem import Problem, point

SINGLE = SolverOptions(starts=1, candidates=1)


@pytest.fixture(scope="module")
def solved(galicki):
    """The paper's example, one start, k = 1 and 4 (certified by plan itself)."""
    out = {}
    for k in (1, 4):
        res = plan(Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=k), SINGLE)
        assert res.success, res.message
        out[k] = res
    return out


def _recheck(res, z_grid=None, sample=None, problem=None, **options) -> Certificate:
    """Certify ``res``'s solution again, with a corrupted grid, sample or problem."""
    traj = res.trajectory
    if z_grid is not None:
        traj = Trajectory(traj.system, traj.t_grid, z_grid, traj.law)
    opts = CertificateOptions(segment_steps=res.warm_state.steps, **options)
    return certify(problem or res.problem, traj, opts,
                   sample=sample if sample is not None else fine_sample(traj),
                   solver_residual=res.residual)


@pytest.mark.parametrize("k", [1, 4])
def test_certificate_passes_on_the_papers_example(solved, k):
    res = solved[k]
    cert = res.certificate
    assert res.status is Status.SUCCESS
    assert cert is not None and cert.passed, cert.summary()
    assert cert.summary() == "certified"
    names = {i.name for i in cert.items}
    assert {"end_point", "end_velocity", "max_defect", "boundary", "transversality",
            "control_set", "max_abs_u", "max_abs_H", "solver_residual",
            "integrator_finished"} <= names
    # Far inside the tolerances, not just inside: the solver's accuracy is about 1e-7.
    assert cert.figures["point_error"] < 1e-6
    assert cert.figures["velocity_error"] < 1e-5
    assert cert.figures["max_defect"] < 1e-6
    assert res.verification["point_error"] == cert.figures["point_error"]
    print(f"k={k}: " + "; ".join(str(i) for i in cert.items))


def test_certificate_is_independent_of_segment_choice(solved):
    """Per RK4 step or per shooting interval, the open loop lands on the same point."""
    res = solved[4]
    a = _recheck(res)
    b = certify(res.problem, res.trajectory, CertificateOptions(segment_steps=1),
                sample=fine_sample(res.trajectory))
    assert a.passed and b.passed
    assert abs(a.figures["point_error"] - b.figures["point_error"]) < 1e-8
    assert b.figures["segments"] == len(res.trajectory.t_grid) - 1


def test_a_costate_off_by_one_percent_at_one_node_fails(solved):
    res = solved[4]
    z = res.trajectory.z_grid.copy()
    n = res.problem.model.n
    node = 5 * res.warm_state.steps  # a shooting node inside the motion
    z[node, 2 * n:] *= 1.01
    cert = _recheck(res, z_grid=z)
    assert not cert.passed
    failed = {i.name for i in cert.failures}
    assert "max_defect" in failed
    assert "max_abs_H" in failed
    assert "max_defect" in cert.summary()


def test_all_costates_off_by_one_percent_fail_on_the_hamiltonian(solved):
    """psi scaled everywhere is again a solution of (16) (homogeneous), but H = 0.01."""
    res = solved[1]
    z = res.trajectory.z_grid.copy()
    n = res.problem.model.n
    z[:, 2 * n:] *= 1.01
    cert = _recheck(res, z_grid=z)
    assert {i.name for i in cert.failures} == {"max_abs_H"}
    assert cert.item("max_abs_H").value == pytest.approx(0.01, rel=1e-3)


def test_a_costate_along_the_self_motion_manifold_fails_transversality(solved, galicki):
    """At a point end, psi_q must have no component along null(J) (eq. 21)."""
    res = solved[4]
    z = res.trajectory.z_grid.copy()
    n = galicki.n
    _, _, vt = np.linalg.svd(galicki.jacobian(z[0, :n]))
    z[0, 2 * n:3 * n] += 1e-3 * vt[-1] * np.max(np.abs(z[0, 2 * n:3 * n]))
    cert = _recheck(res, z_grid=z)
    assert "transversality" in {i.name for i in cert.failures}
    assert cert.item("transversality").value > 1e-4  # tolerance 1e-6


def test_a_state_off_at_one_node_fails(solved):
    res = solved[4]
    z = res.trajectory.z_grid.copy()
    z[3 * res.warm_state.steps, 0] += 1e-4  # q_1 at a node, 0.1 mrad
    cert = _recheck(res, z_grid=z)
    assert "max_defect" in {i.name for i in cert.failures}


def test_a_torque_sample_over_the_limit_fails(solved):
    res = solved[4]
    sample = fine_sample(res.trajectory)
    u = sample.u.copy()
    j = int(np.argmax(np.abs(u[:, 2])))
    u[j, 2] = np.sign(u[j, 2]) * 1.0001
    cert = _recheck(res, sample=dataclasses.replace(sample, u=u))
    assert {i.name for i in cert.failures} == {"control_set", "max_abs_u"}
    assert not cert.item("max_abs_u").passed


def test_a_torque_inside_the_box_but_outside_the_set_fails(solved):
    """|u_i| <= 1 is not enough: sum u^2k <= 1 is the planned limit."""
    res = solved[4]
    sample = fine_sample(res.trajectory)
    u = sample.u.copy()
    u[len(u) // 2] = 0.95  # every joint at 95 %: sum 3 * 0.95^8 = 1.99
    cert = _recheck(res, sample=dataclasses.replace(sample, u=u))
    assert {i.name for i in cert.failures} == {"control_set"}


def test_torques_one_percent_short_miss_the_target(solved, galicki):
    """The open loop applies the problem's torques: a plan solved for other limits fails."""
    res = solved[4]
    short = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4, reserve=0.01)
    cert = _recheck(res, problem=short)
    failed = {i.name for i in cert.failures}
    assert "end_point" in failed
    assert cert.figures["point_error"] > 1e-3


def test_a_blown_up_state_fails_fast(solved):
    """A non-finite state: the integrator gives up on it and says so (no endless halving)."""
    res = solved[1]
    z = res.trajectory.z_grid.copy()
    z[5 * res.warm_state.steps, 3] = np.inf
    cert = _recheck(res, z_grid=z)
    failed = {i.name for i in cert.failures}
    assert {"integrator_finished", "max_defect", "end_point"} <= failed


def test_a_residual_above_tolerance_fails(solved):
    res = solved[1]
    traj = res.trajectory
    cert = certify(res.problem, traj, CertificateOptions(residual_tol=1e-12),
                   solver_residual=1e-9)
    assert {i.name for i in cert.failures} == {"solver_residual"}


def test_a_failed_certificate_is_not_a_success(galicki):
    """plan() reports a solution that fails its certificate as VERIFICATION_FAILED."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=1)
    strict = SolverOptions(starts=1, candidates=1,
                           certificate=CertificateOptions(hamiltonian_tol=1e-14))
    res = plan(problem, strict)
    assert not res.success
    assert res.status is Status.VERIFICATION_FAILED
    assert "max_abs_H" in res.message and "tol 1e-14" in res.message
    assert res.certificate is not None and not res.certificate.passed


def test_verify_false_leaves_the_solution_uncertified(galicki):
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=1)
    assert SolverOptions().verify is True
    res = plan(problem, dataclasses.replace(SINGLE, verify=False))
    assert res.success and res.certificate is None and res.verification == {}
    assert "not certified" in res.message


def test_limits_are_items(solved):
    """The problem's joint limits are items (on by default); the 3R arm's never bind."""
    res = solved[4]
    cert = _recheck(res)
    assert cert.passed
    assert cert.item("position_limits").value == 0.0
    assert cert.item("velocity_limits").value == 0.0


def test_a_velocity_limit_crossed_fails_the_certificate(galicki, solved):
    """The unconstrained optimum, certified against a 2 rad/s velocity limit, fails it."""
    res = solved[4]
    base = JointLimits.from_model(galicki)
    tight = JointLimits(base.names, base.lower, base.upper, np.full(3, 2.0))
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4, limits=tight)
    cert = _recheck(res, problem=problem)
    assert {i.name for i in cert.failures} == {"velocity_limits"}
    assert cert.item("velocity_limits").value > 1.0  # 6.3 rad/s: more than twice the limit


@pytest.mark.parametrize("kwargs, match", [
    ({"point_tol": 0.0}, "`point_tol` must be a positive number"),
    ({"rtol": float("nan")}, "`rtol` must be a positive number"),
    ({"segment_steps": 0}, "`segment_steps` must be an integer >= 1"),
    ({"rtol": 1e-6}, "`rtol` .* must be at least 1000 times below"),
])
def test_options_are_validated(kwargs, match):
    with pytest.raises(ProblemError, match=match):
        CertificateOptions(**kwargs)


def test_solver_options_validate_the_certificate_tolerances():
    with pytest.raises(ProblemError, match="`certificate` must be a CertificateOptions"):
        SolverOptions(certificate={"rtol": 1e-10})
    with pytest.raises(ProblemError, match="1000 times below"):
        SolverOptions(verify_point_tol=1e-9)


def test_a_trajectory_of_another_model_is_rejected(solved):
    res = solved[1]
    other = load_robot(default_urdf_path())
    problem = Problem(other, point(PAPER_START), point(PAPER_TARGET), k=1)
    with pytest.raises(ProblemError, match="`trajectory` was not computed for"):
        certify(problem, res.trajectory)
