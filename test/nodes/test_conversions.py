"""Message conversions and the planner's parameter table, without a node or spinning."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from geometry_msgs.msg import Point
from sensor_msgs.msg import JointState

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes import conversions as conv
from tocontrol_ros.nodes.params import descriptor
from tocontrol_ros.nodes.planner_config import (
    PARAMETERS,
    ConfigError,
    config_from_values,
    default_values,
    solver_options,
)

JOINTS = ("joint1", "joint2", "joint3")


@pytest.fixture(scope="module")
def model():
    return load_robot(default_urdf_path())


@pytest.fixture(scope="module")
def frame(model):
    return conv.task_frame(model, "base_link")


def test_task_frame_of_planar_arm(frame):
    assert frame.task_axes == (0, 1)
    assert frame.fixed == ((2, pytest.approx(0.0, abs=1e-12)),)


def test_forward_kinematics_matches_model(model):
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-3, 3, model.n)
        links = conv.link_positions(model, q)
        assert links.shape == (model.n + 2, 3)
        np.testing.assert_allclose(links[-1, :2], model.point(q), atol=1e-12)
        rot, pos = conv.tip_pose(model, q)
        np.testing.assert_allclose(pos, links[-1], atol=1e-12)
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        # Planar arm: the tip's heading is the sum of the joint angles.
        assert math.atan2(rot[1, 0], rot[0, 0]) == pytest.approx(
            math.atan2(math.sin(q.sum()), math.cos(q.sum())), abs=1e-12)
    # Link lengths of the paper's arm: 2.5, 2.0, 1.0 m.
    links = conv.link_positions(model, np.zeros(3))
    np.testing.assert_allclose(links[:, 0], [0.0, 0.0, 2.5, 4.5, 5.5], atol=1e-12)


def test_quaternion_of_rotation():
    for angle in (0.0, 0.7, math.pi - 1e-9, -2.0):
        c, s = math.cos(angle), math.sin(angle)
        quat = conv._quaternion(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]))
        assert abs(quat.z) == pytest.approx(abs(math.sin(angle / 2)), abs=1e-9)
        assert abs(quat.w) == pytest.approx(abs(math.cos(angle / 2)), abs=1e-9)


def test_point_from_msg(frame):
    p = conv.point_from_msg(Point(x=2.2, y=1.5, z=0.0005), "base_link", frame, "goal")
    np.testing.assert_array_equal(p, [2.2, 1.5])
    np.testing.assert_array_equal(conv.embed_point(frame, p), [2.2, 1.5, 0.0])


@pytest.mark.parametrize("xyz, frame_id, match", [
    ((float("nan"), 1.0, 0.0), "base_link", r"`goal\.x` must be finite, got nan"),
    ((1.0, float("inf"), 0.0), "base_link", r"`goal\.y` must be finite"),
    ((1.0, 1.0, float("-inf")), "base_link", r"`goal\.z` must be finite"),
    ((1.0, 1.0, 0.01), "base_link", r"`goal\.z` = 0\.01 m is off the arm's reachable set"),
    ((1.0, 1.0, 0.0), "map", r"frame_id 'map' is not the planner's frame 'base_link'"),
    ((1.0, 1.0, 0.0), "", r"frame_id '' is not"),
])
def test_point_from_msg_rejects(frame, xyz, frame_id, match):
    with pytest.raises(conv.ConversionError, match=match):
        conv.point_from_msg(Point(x=xyz[0], y=xyz[1], z=xyz[2]), frame_id, frame, "goal")


def test_joint_state_by_name_extra_joints_ignored():
    msg = JointState(name=["finger", "joint3", "joint1", "joint2"],
                     position=[9.0, 0.3, 0.1, 0.2], velocity=[9.0, 3.0, 1.0, 2.0])
    q, qd = conv.joint_state_from_msg(msg, JOINTS)
    np.testing.assert_array_equal(q, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(qd, [1.0, 2.0, 3.0])
    q, qd = conv.joint_state_from_msg(JointState(name=list(JOINTS), position=[1.0, 2.0, 3.0]),
                                      JOINTS)
    np.testing.assert_array_equal(qd, 0.0)


@pytest.mark.parametrize("names, position, velocity, match", [
    (["a", "b", "c"], [0, 0, 0], [], r"lacks the planner's joint\(s\) \['joint1', 'joint2', "),
    (["joint1", "joint2"], [0, 0], [], r"lacks the planner's joint\(s\) \['joint3'\]"),
    (list(JOINTS), [0, 0], [], r"`joint_states.position` has 2 entries for 3 names"),
    (list(JOINTS), [0, 0, 0], [0], r"`joint_states.velocity` has 1 entries"),
    (list(JOINTS) + ["joint1"], [0, 0, 0, 0], [], r"duplicates"),
    (list(JOINTS), [0, float("nan"), 0], [], r"position` of joint 'joint2' must be finite"),
    (list(JOINTS), [0, 0, 0], [0, 0, float("inf")], r"velocity` of joint 'joint3'"),
])
def test_joint_state_rejects(names, position, velocity, match):
    msg = JointState(name=names, position=[float(v) for v in position],
                     velocity=[float(v) for v in velocity])
    with pytest.raises(conv.ConversionError, match=match):
        conv.joint_state_from_msg(msg, JOINTS)


def test_time_conversions():
    assert conv.seconds(conv.duration_from_seconds(1.25)) == 1.25
    d = conv.duration_from_seconds(0.9999999999)
    assert (d.sec, d.nanosec) == (1, 0)
    stamp = conv.time_from_seconds(10.6)
    later = conv.add_seconds(stamp, 0.5)
    assert (later.sec, later.nanosec) == (11, 100_000_000)


def _fake_sample(model, count=5):
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 0.5, count)
    q = rng.uniform(-1, 1, (count, model.n))
    return SimpleNamespace(t=t, q=q, qd=q * 2, qdd=q * 3, tau=q * 4)


def test_trajectory_msg(model):
    sample = _fake_sample(model)
    stamp = conv.time_from_seconds(100.0)
    msg = conv.trajectory_msg(sample, model.joint_names, "base_link", stamp)
    assert list(msg.joint_names) == list(JOINTS)
    assert msg.header.stamp == stamp
    assert len(msg.points) == 5
    for i, point in enumerate(msg.points):
        assert conv.seconds(point.time_from_start) == pytest.approx(sample.t[i], abs=1e-9)
        np.testing.assert_array_equal(point.positions, sample.q[i])
        np.testing.assert_array_equal(point.velocities, sample.qd[i])
        np.testing.assert_array_equal(point.accelerations, sample.qdd[i])
        np.testing.assert_array_equal(point.effort, sample.tau[i])


def test_trajectory_msg_times_are_duration_from_seconds_to_the_nanosecond(model):
    """The vectorised message: each point's time as duration_from_seconds gives it (whole
    nanoseconds, rounded half to even), over seconds and at values that round."""
    t = np.array([0.0, 1e-9, 0.4999999995, 0.9999999996, 1.0, 1.0000000005, 2.345678901,
                  12.5, 3600.0000000015])
    sample = SimpleNamespace(t=t, q=np.zeros((t.size, model.n)), qd=np.zeros((t.size, model.n)),
                             qdd=np.zeros((t.size, model.n)), tau=np.zeros((t.size, model.n)))
    msg = conv.trajectory_msg(sample, model.joint_names, "base_link", conv.time_from_seconds(1.0))
    for ti, point in zip(t, msg.points, strict=True):
        expect = conv.duration_from_seconds(float(ti))
        assert (point.time_from_start.sec, point.time_from_start.nanosec) == \
            (expect.sec, expect.nanosec), ti


def test_path_and_markers(model):
    sample = _fake_sample(model)
    stamp = conv.time_from_seconds(100.0)
    path = conv.path_msg(model, sample, "base_link", stamp)
    assert len(path.poses) == 5 and path.header.frame_id == "base_link"
    for t, q, pose in zip(sample.t, sample.q, path.poses, strict=True):
        p = pose.pose.position
        np.testing.assert_allclose([p.x, p.y], model.point(q), atol=1e-12)
        assert conv.seconds(pose.header.stamp) == pytest.approx(100.0 + t, abs=1e-9)
    assert len(conv.empty_path("base_link", stamp).poses) == 0
    markers = conv.markers_msg(model, sample.q[:3], np.zeros((4, 3)), [1, 1, 0], [2, 1, 0],
                               "base_link", stamp).markers
    assert markers[0].action == markers[0].DELETEALL
    arms = [m for m in markers if m.ns == "arm"]
    assert [m.id for m in arms] == [0, 1, 2]
    assert all(len(m.points) == model.n + 2 for m in arms)
    assert {m.ns for m in markers} == {"", "arm", "joints", "ee_path", "endpoints"}


def test_status_msg():
    msg = conv.status_msg("WARN", "/planner", "superseded", "galicki_3r",
                          {"request_id": 3, "T": 0.5390477218, "start": np.array([1.0, 1.0]),
                           "warm_start": True, "skip": None})
    assert msg.level == conv.LEVELS["WARN"]
    values = {kv.key: kv.value for kv in msg.values}
    assert values == {"request_id": "3", "T": "0.539047722", "start": "[1, 1]",
                      "warm_start": "true"}
    with pytest.raises(ValueError, match="`level` must be one of"):
        conv.status_msg("FATAL", "", "", "", {})


def test_certificate_values(model):
    """The certificate's figures as ~/status values: one per item, failures and tolerances."""
    from tocontrol_ros.core.planning.solver import SolverOptions, plan
    from tocontrol_ros.core.types.problem import Problem, point

    res = plan(Problem(model, point([1.0, 1.0]), point([2.2, 1.5]), k=1),
               SolverOptions(starts=1, candidates=1))
    values = conv.certificate_values(res.certificate)
    assert values["certified"] is True and values["cert_failed"] == ""
    assert values["cert_end_point"] == res.certificate.item("end_point").value
    assert "end_point=0.0001" in values["cert_tolerances"]
    kv = {k.key: k.value for k in conv.status_values(values)}
    assert kv["certified"] == "true" and float(kv["cert_max_abs_H"]) < 1e-5
    assert conv.certificate_values(None) == {"certified": False}


def test_a_stamp_in_the_status_keeps_its_nanoseconds():
    # "%.9g" of a stamp since the epoch keeps whole seconds; the text is exact.
    ns = 1_796_411_759_578_123_456
    kv = {k.key: k.value for k in conv.status_values({"handoff": conv.stamp_text(ns),
                                                       "plain": ns * 1e-9})}
    assert kv["handoff"] == "1796411759.578123456"
    assert kv["plain"] == "1.79641176e+09"  # why stamps are not passed as floats
    assert conv.stamp_text(-1_500_000_000) == "-1.500000000"
    assert conv.stamp_text(7) == "0.000000007"


# ------------------------------------------------------------------ parameters
def test_parameter_table_defaults_are_valid():
    config = config_from_values(default_values(), task_dim=2)
    assert config.k == 4.0 and config.default_start == (1.0, 1.0)
    assert config.sample_period == 0.01 and config.verify is True
    options = solver_options(config)
    assert (options.starts, options.candidates, options.verify) == (16, 6, True)


def test_descriptors_carry_ranges_and_read_only():
    by_name = {spec.name: descriptor(spec) for spec in PARAMETERS}
    assert by_name["k"].floating_point_range[0].from_value == 1.0
    assert by_name["starts"].integer_range[0].from_value == 1
    assert by_name["robot_description"].read_only and not by_name["k"].read_only
    for d in by_name.values():
        assert d.description


@pytest.mark.parametrize("values, match", [
    ({"k": 0.5}, r"`k` must be in \[1, 64\]"),
    ({"k": "4"}, r"`k` must be a number"),
    ({"starts": 2.0}, r"`starts` must be an integer"),
    ({"verify": 1}, r"`verify` must be true or false"),
    ({"sample_period": float("nan")}, r"`sample_period` must be finite"),
    ({"starts": 2}, r"`candidates` \(6\) must not exceed `starts` \(2\)"),
    ({"default_start": [1.0]}, r"`default_start` must have 2 entries"),
    ({"default_start": [1.0, float("nan")]}, r"`default_start` must be finite"),
    ({"gravity": [0.0, -9.8]}, r"`gravity` must have 3 entries"),
    ({"nonsense": 1}, r"unknown parameter"),
    ({"replan_spans": 2}, r"`replan_spans` must be 0 or at least 4, got 2"),
    ({"publish": "first"}, r"`publish` must be one of optimum, first_then_optimum, got 'first'"),
])
def test_config_rejects(values, match):
    with pytest.raises(ConfigError, match=match):
        config_from_values({**default_values(), **values}, task_dim=2)


def test_the_paper_default_start_does_not_apply_to_a_spatial_arm():
    """The Panda (task space xyz): the default start (the paper's planar point) is dropped
    rather than refused, so the planner starts; a start the user gives is still checked."""
    config = config_from_values(default_values(), task_dim=3)
    assert config.default_start == ()
    assert config_from_values({**default_values(), "default_start": [0.4, 0.0, 0.5]},
                              task_dim=3).default_start == (0.4, 0.0, 0.5)
    with pytest.raises(ConfigError, match=r"`default_start` must have 3 entries"):
        config_from_values({**default_values(), "default_start": [0.4, 0.0]}, task_dim=3)


def test_the_node_multistart_defaults_are_the_solvers():
    from tocontrol_ros.core.types.options import SolverOptions

    values = default_values()
    assert (values["starts"], values["candidates"]) == (SolverOptions.starts,
                                                        SolverOptions.candidates)


def test_yaml_and_docs_list_every_parameter():
    import pathlib

    import yaml

    repo = pathlib.Path(__file__).resolve().parents[2]
    values = yaml.safe_load((repo / "config" / "planner.yaml").read_text())
    assert values["/**"]["ros__parameters"] == default_values()
    doc = (repo / "msg_docs" / "parameters.md").read_text()
    for spec in PARAMETERS:
        assert f"| `{spec.name}` |" in doc, spec.name


def _result(method="indirect", warnings=(), certificate=None):
    status = SimpleNamespace(name="SUCCESS")
    return SimpleNamespace(T=0.73, k=4.0, iterations=3, timings={"total": 0.03, "verify": 0.01},
                           residual=0.0, max_abs_u=0.99, warnings=warnings, method=method,
                           certificate=certificate, status=status)


@pytest.mark.parametrize("method, steps", [("first", "3 TOPP-RA passes"),
                                           ("indirect", "3 Newton iterations")])
def test_result_message_names_the_steps_of_the_method(method, steps):
    level, message = conv.result_message(_result(method))
    assert level == "OK" and steps in message and message.startswith("T = 0.73 s at k = 4")
    assert conv.result_values(_result(method))["method"] == method


def test_result_message_warns_on_warnings_but_not_on_routine_notes():
    level, message = conv.result_message(_result(warnings=(conv.ROUTINE_NOTE + " (x)",)))
    assert level == "OK" and conv.ROUTINE_NOTE in message
    level, message = conv.result_message(_result(warnings=("joint 'j' violates ...",)))
    assert level == "WARN" and message.endswith("warnings: joint 'j' violates ...")
