"""The method contract (core/methods/contract.py): the package's methods implement it, and a
third method plugs in through it without touching the orchestration."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tocontrol_ros.core import PlanResult, Problem, SolverOptions, Status, plan, point
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.checks.verification import fine_sample, verdict
from tocontrol_ros.core.direct.scaled_path import PolynomialPath
from tocontrol_ros.core.direct.time_scaling import time_scaling
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.methods.contract import (
    Method,
    method_named,
    method_names,
    method_owning,
    register,
)
from tocontrol_ros.core.methods.seeding import seed_pairs


class StraightJointPath(Method):
    """A toy method: the best-ranked seed pair's straight joint path, timed by TOPP-RA."""

    name = "test_straight_joint_path"

    def __init__(self) -> None:
        self.solves = 0

    def solve(self, compiled, ctx, timings, t_start):
        self.solves += 1
        problem = ctx.problem
        qa, qb = seed_pairs(problem, ctx.options)[0]
        out = time_scaling(problem, PolynomialPath.straight(qa, qb), 0.0)
        if isinstance(out[0], Status):
            return PlanResult.failure(problem, out[0], out[1], timings, k=problem.k,
                                      method=self.name)
        traj, passes = out
        sample = fine_sample(traj)
        cert = self.certify(problem, traj, ctx.options.certificate_options(1))
        status, message = verdict(ctx.options, cert, 0.0)
        timings["total"] = time.perf_counter() - t_start
        return PlanResult(
            success=status is Status.SUCCESS, status=status, message=message, T=traj.T,
            k=problem.k, trajectory=traj, residual=0.0, iterations=passes, timings=timings,
            continuation=(), max_abs_u=float(np.max(np.abs(sample.u))), delta=0.0,
            intervals=1, verification=dict(cert.figures), certificate=cert, warnings=(),
            problem=problem, method=self.name)

    def certify(self, problem, motion, options):
        return certify_open_loop(problem, motion, options)


@pytest.fixture(scope="module")
def straight():
    return register(StraightJointPath(), replace=True)


def test_the_package_methods_are_registered():
    names = method_names()
    assert {"auto", "indirect", "direct", "first"} <= set(names)
    assert method_named("auto") is method_named("indirect")


def test_an_unknown_method_is_refused_naming_the_known_ones(galicki):
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4)
    with pytest.raises(ProblemError, match=r"`method` must be one of 'auto', .*'direct'"):
        plan(problem, SolverOptions(method="no such method"))
    with pytest.raises(ProblemError, match="`method`"):
        SolverOptions(method="")


@pytest.mark.parametrize("bad, match", [
    (object(), "must be a Method"),
    (type("Nameless", (StraightJointPath,), {"name": ""})(), "non-empty string"),
    (type("Auto", (StraightJointPath,), {"name": "auto"})(), "other than 'auto'"),
])
def test_register_refuses_what_is_not_a_method(bad, match):
    with pytest.raises(ProblemError, match=match):
        register(bad)


def test_a_name_is_registered_once(straight):
    with pytest.raises(ProblemError, match="already registered"):
        register(StraightJointPath())


def test_a_third_method_plugs_in_through_the_contract(galicki, straight):
    """plan() runs the toy method by its name: certified open loop, slower than the optimum
    (a path fixed in advance cannot beat the maximum principle's), and its result's method
    names it; the warm start of its result is no method's."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4)
    before = straight.solves
    res = plan(problem, SolverOptions(method=straight.name))
    assert straight.solves == before + 1
    assert res.success, res.message
    assert res.method == straight.name and res.certificate.passed
    assert res.certificate.figures["point_error"] < 1e-4
    optimum = plan(problem, SolverOptions(starts=4, candidates=2))
    assert optimum.success and optimum.method == "indirect"
    assert optimum.T < res.T
    assert method_owning(res.warm_state) is None
    assert method_owning(optimum.warm_state) is method_named("indirect")


def test_each_method_certifies_its_own_motions(galicki):
    """The maximum principle's certificate re-integrates its canonical system (a defect
    item); the first motion's is open loop (none)."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4)
    options = SolverOptions(starts=4, candidates=2)
    for name, has_defect in (("indirect", True), ("first", False)):
        res = plan(problem, replace_method(options, name))
        assert res.success and res.method == name, res.message
        cert = method_named(name).certify(problem, res.trajectory,
                                          options.certificate_options(12))
        assert ("max_defect" in cert.figures) is has_defect
        assert cert.figures["point_error"] < 1e-4


def replace_method(options: SolverOptions, name: str) -> SolverOptions:
    from dataclasses import replace

    return replace(options, method=name)
