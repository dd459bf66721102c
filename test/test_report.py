"""The report from a recorded file: PNGs and a summary with T, k, errors and saturation."""

import cdr_exact
import numpy as np
import pytest
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tocontrol_ros import mcap_io, report
from tocontrol_ros.core.model import default_urdf_path, load_robot

T = 1.5
T0 = 100.0  # trajectory start stamp (s)


def _time(t):
    return Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))


def write_run(path, model):
    """A synthetic run: plan, goal, status, 100 Hz joint states (one saturated joint)."""
    names = list(model.joint_names)
    tau_max = np.asarray(model.tau_max)
    ts = np.linspace(0.0, T, 31)
    q = np.outer(ts / T, [0.8, -0.5, 0.3])
    tau = np.outer(np.cos(np.pi * ts / T), 0.7 * tau_max)
    traj = JointTrajectory(header=Header(stamp=_time(T0)), joint_names=names, points=[
        JointTrajectoryPoint(positions=q[i].tolist(), effort=tau[i].tolist(),
                             time_from_start=Duration(sec=int(t), nanosec=int((t % 1) * 1e9)))
        for i, t in enumerate(ts)])
    status = DiagnosticStatus(name="planner", values=[KeyValue(key="T", value=str(T)),
                                                      KeyValue(key="k", value="4")])
    goal = PointStamped(point=model_point(model, q[-1]))
    with mcap_io.RecordingWriter(path) as writer:
        for topic, msg in [("/planner/goal", goal), ("/planner/trajectory", traj),
                           ("/planner/status", status)]:
            writer.add_topic(topic, f"{type(msg).__module__.split('.')[0]}/msg/"
                             f"{type(msg).__name__}", [QoSProfile(depth=1)])
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=int(T0 * 1e9) - 1000)
        writer.add_topic("/joint_states", "sensor_msgs/msg/JointState", [QoSProfile(depth=10)])
        writer.add_topic("/tracker/tracking_error", "sensor_msgs/msg/JointState",
                         [QoSProfile(depth=10)])
        for t in np.arange(0.0, T + 1e-9, 0.01):
            qi = np.array([np.interp(t, ts, q[:, j]) for j in range(3)])
            u = np.array([np.interp(t, ts, tau[:, j]) for j in range(3)]) / tau_max
            u[2] = 1.0  # joint 3 saturated throughout
            err = 1e-3 * np.sin([t, 2 * t, 3 * t])
            stamp = int((T0 + t) * 1e9)
            js = JointState(header=Header(stamp=_time(T0 + t)), name=names,
                            position=(qi + err).tolist(), effort=(u * tau_max).tolist())
            writer.write("/joint_states", cdr_exact.serialize_exact(js), log_time=stamp)
            e = JointState(header=Header(stamp=_time(T0 + t)), name=names,
                           position=err.tolist(), velocity=[0.0] * 3)
            writer.write("/tracker/tracking_error", cdr_exact.serialize_exact(e), log_time=stamp)


def model_point(model, q):
    from geometry_msgs.msg import Point

    p = model.point(q)
    return Point(x=float(p[0]), y=float(p[1]), z=0.0)


@pytest.fixture(scope="module")
def model():
    return load_robot(default_urdf_path())


def test_report_from_recording(tmp_path, model):
    path = tmp_path / "run.mcap"
    write_run(path, model)
    out = tmp_path / "report"
    assert report.main([str(path), "--out", str(out)]) == 0
    for name in ("controls_nominal.png", "controls_applied.png", "motion.png",
                 "tracking_error.png"):
        png = out / name
        assert png.stat().st_size > 5000, name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (out / "summary.txt").read_text()
    assert f"T = {T:.4f} s" in summary
    assert "k = 4" in summary
    assert "nominal max |u_i| = 0.7000" in summary
    assert "saturated fraction per joint" in summary and "1." in summary
    line = next(s for s in summary.splitlines() if s.startswith("max |tracking error|"))
    assert "0.00" in line
    assert "final end-effector error v. goal" in summary


def test_report_default_out_next_to_file(tmp_path, model):
    path = tmp_path / "run.mcap"
    write_run(path, model)
    assert report.main([str(path)]) == 0
    assert (tmp_path / "run_report" / "summary.txt").is_file()


def test_report_missing_file(tmp_path, capsys):
    assert report.main([str(tmp_path / "nope.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err
