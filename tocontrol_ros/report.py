"""Report: ``ros2 run tocontrol_ros report FILE`` draws a recorded run and summarises it.

From a recording alone (messages decoded with ``rclpy.serialization.deserialize_message``,
an independent path from the raw recorder) it writes into ``--out`` (default: a folder
named after the file, next to it):

- ``controls_nominal.png``: the planned controls ``u_i = tau_i / tau_max_i`` from the last
  ``/planner/trajectory`` against ``time_from_start`` (the paper's Figures 2 and 3);
- ``controls_applied.png``: the applied controls from ``/joint_states`` effort, with the
  nominal ones dashed;
- ``motion.png``: the arm at snapshots of ``/joint_states`` positions, the end-effector path
  and the planned one (Figure 4);
- ``tracking_error.png``: ``/tracker/tracking_error`` positions (rad) against time;
- ``summary.txt``: T, k, tracking errors, final end-effector error, saturation.

The torque limits come from the URDF (``--urdf``; default the bundled arm); the joint
order from the messages' names.
"""

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tocontrol_ros import mcap_io

TRAJECTORY = "/planner/trajectory"
PLANNER_STATUS = "/planner/status"
GOAL = "/planner/goal"
JOINT_STATES = "/joint_states"
TRACKING_ERROR = "/tracker/tracking_error"
TRACKER_STATUS = "/tracker/status"
TOPICS = (TRAJECTORY, PLANNER_STATUS, GOAL, JOINT_STATES, TRACKING_ERROR, TRACKER_STATUS)
#: |u_i| at or above this counts as saturated (the tracker clips to |u_i| <= 1).
SATURATION = 0.999
#: Arm snapshots in motion.png.
SNAPSHOTS = 12


@dataclass
class Run:
    """What a recording holds of one run (arrays in joint order of `joint_names`)."""

    joint_names: list = field(default_factory=list)
    trajectory: object = None  # the last JointTrajectory
    planner_status: list = field(default_factory=list)  # DiagnosticStatus messages
    tracker_status: list = field(default_factory=list)
    goal: object = None  # the last PointStamped
    js_t: list = field(default_factory=list)  # stamp (s)
    js_q: list = field(default_factory=list)
    js_effort: list = field(default_factory=list)
    err_t: list = field(default_factory=list)
    err_q: list = field(default_factory=list)


def _stamp(header):
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def _ordered(names, values, joint_names):
    if not values:
        return None
    index = {n: i for i, n in enumerate(names)}
    if names and all(n in index for n in joint_names):
        return [values[index[n]] for n in joint_names]
    return list(values)


def load_run(path, joint_names=None):
    """Decode the report's topics from a finished recording.

    Parameters
    ----------
    path : str or os.PathLike
    joint_names : sequence of str, optional
        Joint order; default: the trajectory's, else the first joint state's.

    Returns
    -------
    Run
    """
    from rclpy.serialization import deserialize_message

    channels = mcap_io.read_channels(path)
    classes = {t: mcap_io.message_class(c.type) for t, c in channels.items() if t in TOPICS}
    run = Run(joint_names=list(joint_names or []))
    for record in mcap_io.iter_records(path, topics=list(classes)):
        msg = deserialize_message(record.data, classes[record.topic])
        if record.topic == TRAJECTORY:
            run.trajectory = msg
            if not joint_names:
                run.joint_names = list(msg.joint_names)
        elif record.topic == PLANNER_STATUS:
            run.planner_status.append(msg)
        elif record.topic == TRACKER_STATUS:
            run.tracker_status.append(msg)
        elif record.topic == GOAL:
            run.goal = msg
        elif record.topic == JOINT_STATES:
            if not run.joint_names:
                run.joint_names = list(msg.name)
            q = _ordered(msg.name, list(msg.position), run.joint_names)
            if q is None:
                continue
            t = _stamp(msg.header) or record.log_time * 1e-9
            run.js_t.append(t)
            run.js_q.append(q)
            run.js_effort.append(_ordered(msg.name, list(msg.effort), run.joint_names))
        elif record.topic == TRACKING_ERROR:
            e = _ordered(msg.name, list(msg.position), run.joint_names or list(msg.name))
            if e is not None:
                run.err_t.append(_stamp(msg.header) or record.log_time * 1e-9)
                run.err_q.append(e)
    return run


def _values(statuses):
    out = {}
    for status in statuses:
        out.update({kv.key: kv.value for kv in status.values})
    return out


def _origin(run):
    """Time origin (s): the trajectory's start stamp if the joint states fall after it."""
    if run.trajectory is not None:
        t0 = _stamp(run.trajectory.header)
        if t0 > 0 and run.js_t and run.js_t[-1] >= t0:
            return t0
    if run.js_t:
        return run.js_t[0]
    return run.err_t[0] if run.err_t else 0.0


def nominal(run, tau_max):
    """Planned times (s), positions (rad) and normalised controls from the trajectory."""
    points = run.trajectory.points
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in points])
    q = np.array([list(p.positions) for p in points], dtype=float)
    u = np.array([list(p.effort) for p in points], dtype=float) / tau_max
    return t, q, u


def _joint_points(model, q):
    """Base, joint origins and tip (m) at `q`, shape (n + 2, 3)."""
    rot, pos, out = np.eye(3), np.zeros(3), [np.zeros(3)]
    for body, qi in zip(model.bodies, q, strict=True):
        if body.kind == "prismatic":
            r, p = body.rotation, body.translation + body.rotation @ body.axis * qi
        else:
            k = np.array([[0.0, -body.axis[2], body.axis[1]],
                          [body.axis[2], 0.0, -body.axis[0]],
                          [-body.axis[1], body.axis[0], 0.0]])
            r = body.rotation @ (np.eye(3) + math.sin(qi) * k + (1 - math.cos(qi)) * k @ k)
            p = body.translation
        pos = pos + rot @ p
        rot = rot @ r
        out.append(pos)
    out.append(pos + rot @ model.tip_translation)
    return np.array(out)


def summarise(run, model, tau_max):
    """The summary's lines (T, k, errors, saturation) as a list of str."""
    planner = _values(run.planner_status)
    tracker = _values(run.tracker_status)
    lines = []
    if run.trajectory is not None and run.trajectory.points:
        t_nom, q_nom, u_nom = nominal(run, tau_max)
        lines.append(f"T = {t_nom[-1]:.4f} s (planned motion time)")
        lines.append(f"nominal max |u_i| = {np.max(np.abs(u_nom)):.4f}")
    elif "T" in planner:
        lines.append(f"T = {planner['T']} s (planner status)")
    else:
        lines.append("T = unknown (no /planner/trajectory recorded)")
    lines.append(f"k = {planner.get('k', 'unknown')}")
    lines.append(f"joints = {', '.join(run.joint_names)}")
    lines.append(f"tau_max = {np.array2string(tau_max, precision=4)} N m")
    if run.err_q:
        err = np.abs(np.array(run.err_q, dtype=float))
        lines.append("max |tracking error| per joint = "
                     + np.array2string(err.max(axis=0), precision=6) + " rad")
        lines.append("RMS tracking error per joint = "
                     + np.array2string(np.sqrt(np.mean(err**2, axis=0)), precision=6)
                     + " rad")
    if run.js_q:
        q_end = np.array(run.js_q[-1], dtype=float)
        p_end = _joint_points(model, q_end)[-1]
        axes = list(model.task_axes)
        if run.trajectory is not None and run.trajectory.points:
            p_plan = _joint_points(model, q_nom[-1])[-1]
            lines.append(f"final end-effector error v. plan = "
                         f"{np.linalg.norm((p_end - p_plan)[axes]):.6f} m")
        if run.goal is not None:
            goal = np.array([run.goal.point.x, run.goal.point.y, run.goal.point.z])
            lines.append(f"final end-effector error v. goal = "
                         f"{np.linalg.norm((p_end - goal)[axes]):.6f} m")
        effort = [e for e in run.js_effort if e is not None]
        if effort:
            u = np.abs(np.array(effort, dtype=float) / tau_max)
            lines.append(f"applied max |u_i| = {u.max():.4f}")
            saturated = np.mean(u >= SATURATION, axis=0)
            lines.append(f"saturated fraction per joint (|u_i| >= {SATURATION}) = "
                         + np.array2string(saturated, precision=4))
        lines.append(f"joint states = {len(run.js_q)} over "
                     f"{run.js_t[-1] - run.js_t[0]:.3f} s")
    for key, value in tracker.items():
        lines.append(f"tracker {key} = {value}")
    for key, value in planner.items():
        if key not in ("T", "k"):
            lines.append(f"planner {key} = {value}")
    return lines


def _plot_controls(ax, t, u, names, style="-", label=""):
    for i, name in enumerate(names):
        ax.plot(t, u[:, i], style, color=f"C{i}", label=f"{label}{name}")
    ax.set_ylim(-1.1, 1.1)
    ax.axhline(1.0, color="0.6", lw=0.6)
    ax.axhline(-1.0, color="0.6", lw=0.6)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("u = tau / tau_max")
    ax.grid(alpha=0.3)


def write_report(path, out_dir, model):
    """Write the PNGs and ``summary.txt`` for the recording at `path` into `out_dir`.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = load_run(path, joint_names=None)
    names = run.joint_names or list(model.joint_names)
    index = {n: i for i, n in enumerate(model.joint_names)}
    if all(n in index for n in names) and len(names) == model.n:
        tau_max = np.array([model.tau_max[index[n]] for n in names], dtype=float)
    elif len(names) == model.n:
        tau_max = np.asarray(model.tau_max, dtype=float)
    else:
        raise ValueError(f"the recording's joints {names} do not match the URDF's "
                         f"{list(model.joint_names)} (pass --urdf)")
    written = []
    t0 = _origin(run)
    have_plan = run.trajectory is not None and bool(run.trajectory.points)
    if have_plan:
        t_nom, q_nom, u_nom = nominal(run, tau_max)
        fig, ax = plt.subplots(figsize=(7, 4))
        _plot_controls(ax, t_nom, u_nom, names)
        ax.set_title(f"Nominal controls, T = {t_nom[-1]:.3f} s")
        ax.legend(loc="lower right", fontsize="small")
        written.append(_save(fig, out_dir / "controls_nominal.png"))
    efforts = [e for e in run.js_effort if e is not None]
    if run.js_q and len(efforts) == len(run.js_q):
        t = np.array(run.js_t) - t0
        u = np.array(efforts, dtype=float) / tau_max
        fig, ax = plt.subplots(figsize=(7, 4))
        _plot_controls(ax, t, u, names, label="applied ")
        if have_plan:
            _plot_controls(ax, t_nom, u_nom, names, style="--", label="nominal ")
        ax.set_title("Applied controls (joint_states effort)")
        ax.legend(loc="lower right", fontsize="x-small", ncol=2)
        written.append(_save(fig, out_dir / "controls_applied.png"))
    if run.js_q:
        written.append(_plot_motion(plt, model, run, q_nom if have_plan else None,
                                    out_dir / "motion.png"))
    if run.err_q:
        t = np.array(run.err_t) - t0
        err = np.array(run.err_q, dtype=float)
        fig, ax = plt.subplots(figsize=(7, 4))
        for i, name in enumerate(names[:err.shape[1]]):
            ax.plot(t, err[:, i], color=f"C{i}", label=name)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("position error (rad)")
        ax.set_title("Tracking error")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
        written.append(_save(fig, out_dir / "tracking_error.png"))
    summary = out_dir / "summary.txt"
    summary.write_text(f"recording: {path}\n" + "\n".join(summarise(run, model, tau_max))
                       + "\n")
    written.append(summary)
    return written


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _plot_motion(plt, model, run, q_nom, path):
    axes = list(model.task_axes)[:2] if model.m >= 2 else [0, 1]
    q = np.array(run.js_q, dtype=float)
    fig, ax = plt.subplots(figsize=(6, 5))
    picks = np.unique(np.linspace(0, len(q) - 1, SNAPSHOTS).round().astype(int))
    for j, k in enumerate(picks):
        pts = _joint_points(model, q[k])[:, axes]
        shade = 0.8 - 0.7 * j / max(len(picks) - 1, 1)
        ax.plot(pts[:, 0], pts[:, 1], "-o", color=str(shade), ms=3, lw=1.5)
    tip = np.array([_joint_points(model, qk)[-1] for qk in q])[:, axes]
    ax.plot(tip[:, 0], tip[:, 1], color="C3", lw=1.5, label="end effector (joint_states)")
    if q_nom is not None:
        tip_nom = np.array([_joint_points(model, qk)[-1] for qk in q_nom])[:, axes]
        ax.plot(tip_nom[:, 0], tip_nom[:, 1], "--", color="C0", lw=1.2, label="planned")
    if run.goal is not None:
        goal = np.array([run.goal.point.x, run.goal.point.y, run.goal.point.z])[axes]
        ax.plot(goal[0], goal[1], "x", color="C2", ms=9, label="goal")
    ax.set_aspect("equal")
    ax.set_xlabel("xyz"[axes[0]] + " (m)")
    ax.set_ylabel("xyz"[axes[1]] + " (m)")
    ax.set_title("Motion of the arm")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    return _save(fig, path)


def build_parser():
    """Return the report's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="report", description="Plots and a summary of a recorded run (from the file "
        "alone).")
    parser.add_argument("file", type=Path, metavar="FILE", help="recording (.mcap)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="output folder (default: FILE without .mcap, plus _report)")
    parser.add_argument("--urdf", type=Path, default=None, metavar="PATH",
                        help="URDF of the arm, for torque limits and drawing (default: the "
                        "bundled arm)")
    return parser


def main(argv=None):
    """Write the report; returns the exit status."""
    args = build_parser().parse_args(argv)
    if not args.file.is_file():
        print(f"report: no such file: {args.file}", file=sys.stderr)
        return 2
    from tocontrol_ros.core.model import default_urdf_path, load_robot

    out = args.out or args.file.with_name(args.file.stem + "_report")
    try:
        model = load_robot(args.urdf or default_urdf_path())
        written = write_report(args.file, out, model)
    except (ValueError, OSError) as err:
        print(f"report: {err}", file=sys.stderr)
        return 2
    for path in written:
        print(path)
    print((out / "summary.txt").read_text(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
