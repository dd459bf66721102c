"""The planner's ``joint_limits`` file as a MoveIt user writes it (issue 52): positions,
velocities, accelerations, jerks and efforts of the bundled arm, no ROS."""

import numpy as np
import pytest

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.nodes.planner_config import (
    config_from_values,
    plan_problem,
    planner_limits,
    planner_model,
)

LIMITS = """
joint_limits:
  joint1: {has_effort_limits: true, max_effort: 20.0, has_acceleration_limits: true,
           max_acceleration: 40.0}
  joint2: {has_effort_limits: true, max_effort: 1000000.0, has_jerk_limits: true, max_jerk: 5.0}
  joint3: {has_effort_limits: false, max_effort: 0.5}
"""


def _config(tmp_path, text=LIMITS):
    path = tmp_path / "joint_limits.yaml"
    path.write_text(text)
    return config_from_values({"joint_limits": str(path)})


def test_efforts_narrow_the_urdf_torque_limits(tmp_path):
    urdf = planner_model(config_from_values({}))
    model = planner_model(_config(tmp_path))
    assert model.tau_max[0] == 20.0 < urdf.tau_max[0]
    assert model.tau_max[1] == urdf.tau_max[1]  # a wider effort leaves the URDF's
    assert model.tau_max[2] == urdf.tau_max[2]  # has_effort_limits false: not used
    limits = planner_limits(_config(tmp_path), model)
    assert limits.acceleration[0] == 40.0 and np.all(np.isinf(limits.acceleration[1:]))


@pytest.mark.parametrize("text, match", [
    ("joint_limits:\n  joint1: {has_effort_limits: true}", "has no `max_effort`"),
    ("joint_limits:\n  joint1: {has_effort_limits: true, max_effort: -1}",
     "max_effort must be > 0"),
    ("joint_limits:\n  wrist: {has_effort_limits: true, max_effort: 1}",
     "'wrist' is not a moving joint"),
])
def test_bad_effort_entries_are_named(tmp_path, text, match):
    with pytest.raises(TocontrolError, match=match):
        planner_model(_config(tmp_path, text))


def _plan(config):
    model = planner_model(config)
    problem = plan_problem(config, model, planner_limits(config, model),
                           ("point", np.array(PAPER_START)), np.array(PAPER_TARGET))
    result = plan(problem, SolverOptions(time_limit=600.0))
    assert result.success, result.message
    return result, result.trajectory.evaluate(np.linspace(0.0, result.T, 4001))


def test_a_plan_keeps_the_narrowed_efforts(tmp_path):
    _, free = _plan(config_from_values({}))
    assert np.max(np.abs(free.tau[:, 0])) > 20.0  # the check below can fail
    result, fine = _plan(_config(tmp_path, "joint_limits:\n  joint1: {has_effort_limits: "
                                           "true, max_effort: 20.0}"))
    assert np.max(np.abs(fine.tau[:, 0])) <= 20.0 * (1 + 1e-6)
    assert result.certificate.passed


def test_a_plan_keeps_the_file_s_accelerations(tmp_path):
    _, free = _plan(config_from_values({}))
    assert np.max(np.abs(free.qdd[:, 0])) > 2.0  # the check below can fail
    result, fine = _plan(_config(tmp_path, "joint_limits:\n  joint1: "
                                           "{has_acceleration_limits: true, "
                                           "max_acceleration: 2.0}"))
    assert np.max(np.abs(fine.qdd[:, 0])) <= 2.0 * (1 + 1e-9)
    assert np.max(np.abs(fine.qdd[:, 0])) > 0.99 * 2.0  # it binds
    assert result.verification["acceleration_limits"] == 0.0
