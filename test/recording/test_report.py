"""The report from a recorded file: a figure per motion, a summary with a table (T, max |u|,
final error, saturation per motion) and an HTML page that shows them all."""

import numpy as np
import pytest
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from skip_policy import panda_urdf
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.recording import cdr as cdr_exact
from tocontrol_ros.recording import mcap_io, report

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
    """A recording without tracker status (another tracker): one motion, all joint states."""
    path = tmp_path / "run.mcap"
    write_run(path, model)
    out = tmp_path / "report"
    assert report.main([str(path), "--out", str(out)]) == 0
    png = out / "motion_1.png"
    assert png.stat().st_size > 20000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "motion_1.png",
                                                     "summary.txt"]
    summary = (out / "summary.txt").read_text()
    assert "k = 4" in summary
    line = next(s for s in summary.splitlines() if s.startswith("max |tracking error|"))
    assert "0.00" in line
    assert "final end-effector error v. last goal" in summary
    (row,) = _table(summary)
    # T, planned max |u| (0.7 tau_max), applied (joint 3 saturated throughout), final error
    # against the plan's end (the synthetic error at T: 1e-3 sin(t, 2t, 3t) rad), time
    # saturated (all of it).
    assert row[:3] == ["1", f"{T:.4f}", "0.7000"] and row[3] == "1.0000"
    q_end = np.array([0.8, -0.5, 0.3]) + 1e-3 * np.sin([T, 2 * T, 3 * T])
    want = np.linalg.norm((model.point(q_end) - model.point([0.8, -0.5, 0.3]))[:2])
    assert float(row[4]) == pytest.approx(want, rel=1e-2)
    assert row[5] == "100.0" and row[6] == "no tracker status recorded"


def _table(summary):
    lines = summary.splitlines()
    start = next(i for i, s in enumerate(lines) if s.startswith("motion "))
    return [s.split(None, 6) for s in lines[start + 1:] if s.strip()]


def write_two_motions(path, model):
    """Three plans, the first two executed (the tracker's events, 100 Hz joint states for
    0.5 s past each end), the third never."""
    names = list(model.joint_names)
    tau_max = np.asarray(model.tau_max)
    plans, q0 = [], np.zeros(3)
    for i, (dq, T_i) in enumerate([([0.5, -0.3, 0.2], 0.5), ([-0.2, 0.4, 0.1], 0.8),
                                   ([0.1, 0.1, 0.1], 0.3)]):
        ts = np.linspace(0.0, T_i, 11)
        q = q0 + np.outer(ts / T_i, dq)
        tau = np.outer(np.cos(np.pi * ts / T_i), (0.5 + 0.2 * i) * tau_max)
        plans.append((T_i, q, JointTrajectory(joint_names=names, points=[
            JointTrajectoryPoint(positions=q[j].tolist(), effort=tau[j].tolist(),
                                 time_from_start=Duration(sec=int(t),
                                                          nanosec=int(round((t % 1) * 1e9))))
            for j, t in enumerate(ts)])))
        q0 = q[-1]
    events = []  # (time s, topic, message)
    for i, start in enumerate([T0, T0 + 2.0]):
        T_i, q, traj = plans[i]
        events.append((start - 0.5, "/planner/trajectory", traj))
        events.append((start + 0.001, "/tracker/status", DiagnosticStatus(
            message="executing trajectory: 11 points", values=[
                KeyValue(key="points", value="11"), KeyValue(key="duration", value=f"{T_i}"),
                KeyValue(key="start_time", value=f"{start:.9f}")])))
        events.append((start + T_i + 0.001, "/tracker/status", DiagnosticStatus(
            message="trajectory completed", values=[
                KeyValue(key="outcome", value="completed"),
                KeyValue(key="elapsed", value=f"{T_i}"),
                KeyValue(key="final_point_error", value=f"{(i + 1) * 1e-4}"),
                KeyValue(key="saturated_fraction", value=f"{0.25 * i}"),
                KeyValue(key="max_abs_u", value=f"{0.9 + 0.1 * i}")])))
        for t in np.arange(0.0, T_i + 0.5, 0.01):
            qi = np.array([np.interp(t, np.linspace(0, T_i, 11), q[:, j]) for j in range(3)])
            events.append((start + t, "/joint_states", JointState(
                header=Header(stamp=_time(start + t)), name=names, position=qi.tolist(),
                effort=(0.5 * tau_max).tolist())))
    events.append((T0 + 4.0, "/planner/trajectory", plans[2][2]))
    with mcap_io.RecordingWriter(path) as writer:
        for topic, kind in [("/planner/trajectory", "trajectory_msgs/msg/JointTrajectory"),
                            ("/tracker/status", "diagnostic_msgs/msg/DiagnosticStatus"),
                            ("/joint_states", "sensor_msgs/msg/JointState")]:
            writer.add_topic(topic, kind, [QoSProfile(depth=10)])
        for t, topic, msg in sorted(events, key=lambda e: e[0]):
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=int(round(t * 1e9)))


def test_report_draws_every_motion_and_writes_the_page(tmp_path, model):
    path = tmp_path / "run.mcap"
    write_two_motions(path, model)
    out = tmp_path / "report"
    assert report.main([str(path), "--out", str(out)]) == 0
    summary = (out / "summary.txt").read_text()
    rows = _table(summary)
    assert [r[0] for r in rows] == ["1", "2", "3"]
    # The tracker's own figures for executed motions; none for the one never executed.
    assert rows[0][1:] == ["0.5000", "0.5000", "0.9000", "0.0001", "0.0", "completed"]
    assert rows[1][1:] == ["0.8000", "0.7000", "1.0000", "0.0002", "25.0", "completed"]
    assert rows[2][1:4] == ["0.3000", "0.9000", "-"] and rows[2][6] == "not executed"
    assert "motions = 3 planned, 2 executed" in summary
    motions = report.motions(report.load_run(path))
    # Each execution sees only its own joint states: up to 0.3 s after its end.
    assert [m.start for m in motions] == [T0, T0 + 2.0, None]
    assert motions[0].end == pytest.approx(T0 + 0.8) and motions[1].end == pytest.approx(
        T0 + 3.1)
    page = (out / "index.html").read_text()
    for i in (1, 2, 3):
        assert (out / f"motion_{i}.png").stat().st_size > 20000
        assert f'src="motion_{i}.png"' in page
    assert page.count("<tr>") == 4 and "not executed" in page


def test_report_default_out_next_to_file(tmp_path, model):
    path = tmp_path / "run.mcap"
    write_run(path, model)
    assert report.main([str(path)]) == 0
    assert (tmp_path / "run_report" / "summary.txt").is_file()


def test_report_missing_file(tmp_path, capsys):
    assert report.main([str(tmp_path / "nope.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_spatial_arm_gets_its_end_effector_path_in_3d_against_the_goal(tmp_path, monkeypatch):
    """The Panda (three task axes): the motion's arm panel is a 3-D axes with the executed and
    planned end-effector paths and the goal; the URDF comes from the recording itself."""
    import matplotlib.pyplot as plt
    from std_msgs.msg import String

    from tocontrol_ros.core.robot.kinematics import link_positions

    urdf = panda_urdf()
    model = load_robot(urdf, tip_link="panda_hand")
    assert model.m == 3
    names = list(model.joint_names)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    q1 = np.array([0.9, 0.6, -0.4, -1.5, 0.5, 1.5, -0.2])
    ts = np.linspace(0.0, T, 21)
    q = q0 + np.outer(ts / T, q1 - q0)
    traj = JointTrajectory(header=Header(stamp=_time(T0)), joint_names=names, points=[
        JointTrajectoryPoint(positions=q[i].tolist(), effort=[0.0] * 7,
                             time_from_start=Duration(sec=int(t), nanosec=int((t % 1) * 1e9)))
        for i, t in enumerate(ts)])
    p_goal = model.point(q1)
    goal = PointStamped(point=Point(x=float(p_goal[0]), y=float(p_goal[1]),
                                    z=float(p_goal[2])))
    path = tmp_path / "panda.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        writer.add_topic("/robot_description", "std_msgs/msg/String", [QoSProfile(depth=1)])
        writer.write("/robot_description", cdr_exact.serialize_exact(
            String(data=urdf.read_text())), log_time=int(T0 * 1e9) - 5000)
        for topic, msg in [("/planner/goal", goal), ("/planner/trajectory", traj)]:
            writer.add_topic(topic, f"{type(msg).__module__.split('.')[0]}/msg/"
                             f"{type(msg).__name__}", [QoSProfile(depth=1)])
            writer.write(topic, cdr_exact.serialize_exact(msg), log_time=int(T0 * 1e9) - 1000)
        writer.add_topic("/joint_states", "sensor_msgs/msg/JointState", [QoSProfile(depth=10)])
        for t in np.arange(0.0, T + 1e-9, 0.01):
            qi = np.array([np.interp(t, ts, q[:, j]) for j in range(7)])
            js = JointState(header=Header(stamp=_time(T0 + t)), name=names,
                            position=qi.tolist(), effort=[0.0] * 7)
            writer.write("/joint_states", cdr_exact.serialize_exact(js),
                         log_time=int((T0 + t) * 1e9))
    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig) or close(fig))
    out = tmp_path / "report"
    # No --urdf: the recording's /robot_description is the arm.
    assert report.main([str(path), "--out", str(out), "--tip-link", "panda_hand"]) == 0
    assert (out / "motion_1.png").stat().st_size > 20000
    (fig,) = [f for f in figures if f is not None]
    (ax3d,) = [ax for ax in fig.axes if ax.name == "3d"]
    lines = {line.get_label(): line for line in ax3d.get_lines()}
    executed = np.array(lines["executed"].get_data_3d()).T
    want = np.array([link_positions(model, row)[-1] for row in q])
    np.testing.assert_allclose(executed[0], want[0], atol=1e-9)
    np.testing.assert_allclose(executed[-1], want[-1], atol=1e-9)
    assert "planned" in lines
    (goal_marker,) = [c for c in ax3d.collections if c.get_label() == "goal"]
    np.testing.assert_allclose(np.array(goal_marker._offsets3d).ravel(), p_goal, atol=1e-12)


def test_planar_arm_keeps_its_2d_motion_panel(tmp_path, model, monkeypatch):
    import matplotlib.pyplot as plt

    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig) or close(fig))
    path = tmp_path / "run.mcap"
    write_run(path, model)
    assert report.main([str(path), "--out", str(tmp_path / "r")]) == 0
    (fig,) = [f for f in figures if f is not None]
    assert not [ax for ax in fig.axes if ax.name == "3d"]
