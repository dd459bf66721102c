"""Report: ``ros2 run tocontrol_ros report FILE`` draws every motion of a recorded run.

From a recording alone (messages decoded with ``rclpy.serialization.deserialize_message``,
an independent path from the raw recorder) it writes into ``--out`` (default: a folder
named after the file, next to it):

- ``motion_<i>.png``, one figure per motion (each ``/planner/trajectory`` in the file, with
  its execution on the tracker if there was one): the planned controls
  ``u_i = tau_i / tau_max_i`` against ``time_from_start`` (the paper's Figures 2 and 3), the
  applied controls from ``/joint_states`` effort with the planned ones dashed, the arm at
  snapshots with the executed and planned end-effector paths (Figure 4; for a spatial arm,
  one whose task has three axes, a 3-D view of the executed and planned end-effector paths
  against the goal of the motion, the last ``/planner/goal`` before its plan, with the arm at
  the start and the end), and the tracking error ``/tracker/tracking_error`` against time;
- ``summary.txt``: the run (k, joints, torque limits), the clearance of each executed motion
  (below) and a table, one row per motion: T, planned and applied max ``|u_i|``, final
  end-effector error, time saturated, outcome;
- ``clearance_<i>.png`` for a recording with a scene: the executed motion's least distance
  (Coal, the URDF's collision geometry) against time, the closest pairs, the planned motion's
  and the margin (:mod:`tocontrol_ros.recording.clearance`: where the scene, margin, allowed
  and disabled pairs come from; ``--margin``, ``--scene``, ``--srdf``); without a scene one
  line says the clearance was not checked;
- ``index.html``: the table and every figure, one page to open in a browser.

An execution is the tracker's "executing trajectory" status (its ``start_time`` and the
trajectory's size) up to its completed or preempted summary, whose figures (final
end-effector error, saturated fraction) the table shows; its joint states are those stamped
from its start to the next execution's start (or 0.3 s after its end). A recording without
tracker status (another tracker) gets one execution, all joint states, for the last plan.
The torque limits come from the URDF (``--urdf``; default the recording's
``/robot_description``, else the bundled arm; ``--tip-link`` for an arm with several leaf
links); the joint order from the messages' names.
"""

import argparse
import html
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tocontrol_ros.core.robot.kinematics import link_positions
from tocontrol_ros.recording import clearance, mcap_io, target_path

TRAJECTORY = "/planner/trajectory"
PLANNER_STATUS = "/planner/status"
GOAL = "/planner/goal"
JOINT_STATES = "/joint_states"
TRACKING_ERROR = "/tracker/tracking_error"
TRACKER_STATUS = "/tracker/status"
ROBOT_DESCRIPTION = "/robot_description"
TOPICS = (TRAJECTORY, PLANNER_STATUS, GOAL, JOINT_STATES, TRACKING_ERROR, TRACKER_STATUS)
#: |u_i| at or above this counts as saturated (the tracker clips to |u_i| <= 1).
SATURATION = 0.999
#: Arm snapshots per motion.
SNAPSHOTS = 12
#: Joint states drawn after an execution's end (s), unless the next one starts earlier.
HOLD_SHOWN = 0.3
#: Size (inches) and resolution of a motion's figure: 990 x 720 pixels.
FIGSIZE, DPI = (11, 8), 90


@dataclass
class Run:
    """What a recording holds of one run (arrays in joint order of `joint_names`)."""

    joint_names: list = field(default_factory=list)
    trajectories: list = field(default_factory=list)  # (log time ns, JointTrajectory)
    planner_status: list = field(default_factory=list)  # DiagnosticStatus messages
    tracker_status: list = field(default_factory=list)  # (log time ns, DiagnosticStatus)
    goal: object = None  # the last PointStamped
    goals: list = field(default_factory=list)  # every goal point (x, y, z), in order
    goal_times: list = field(default_factory=list)  # their log times (ns)
    js_t: list = field(default_factory=list)  # stamp (s)
    js_q: list = field(default_factory=list)
    js_effort: list = field(default_factory=list)
    js_qd: list = field(default_factory=list)  # None where a joint state has no velocity
    err_t: list = field(default_factory=list)
    err_q: list = field(default_factory=list)

    @property
    def trajectory(self):
        """The last planned trajectory (None without one)."""
        return self.trajectories[-1][1] if self.trajectories else None


@dataclass
class Motion:
    """One planned trajectory and its execution (either may be missing)."""

    index: int
    trajectory: object = None
    start: float | None = None  # execution start, stamp time (s)
    end: float | None = None  # last joint-state time shown (s)
    summary: dict = field(default_factory=dict)  # the tracker's completed/preempted values
    outcome: str = ""


def _stamp(header):
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def _ordered(names, values, joint_names):
    if not values:
        return None
    index = {n: i for i, n in enumerate(names)}
    if names and all(n in index for n in joint_names):
        return [values[index[n]] for n in joint_names]
    return list(values)


def _values(status):
    return {kv.key: kv.value for kv in status.values}


def load_run(path, joint_names=None):
    """Decode the report's topics from a finished recording.

    Parameters
    ----------
    path : str or os.PathLike
    joint_names : sequence of str, optional
        Joint order; default: the first trajectory's, else the first joint state's.

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
            run.trajectories.append((record.log_time, msg))
            if not run.joint_names:
                run.joint_names = list(msg.joint_names)
        elif record.topic == PLANNER_STATUS:
            run.planner_status.append(msg)
        elif record.topic == TRACKER_STATUS:
            run.tracker_status.append((record.log_time, msg))
        elif record.topic == GOAL:
            run.goal = msg
            run.goals.append((msg.point.x, msg.point.y, msg.point.z))
            run.goal_times.append(record.log_time)
        elif record.topic == JOINT_STATES:
            if not run.joint_names:
                run.joint_names = list(msg.name)
            q = _ordered(msg.name, list(msg.position), run.joint_names)
            if q is None:
                continue
            run.js_t.append(_stamp(msg.header) or record.log_time * 1e-9)
            run.js_q.append(q)
            run.js_effort.append(_ordered(msg.name, list(msg.effort), run.joint_names))
            run.js_qd.append(_ordered(msg.name, list(msg.velocity), run.joint_names))
        elif record.topic == TRACKING_ERROR:
            e = _ordered(msg.name, list(msg.position), run.joint_names or list(msg.name))
            if e is not None:
                run.err_t.append(_stamp(msg.header) or record.log_time * 1e-9)
                run.err_q.append(e)
    return run


def _duration(traj):
    last = traj.points[-1].time_from_start
    return last.sec + 1e-9 * last.nanosec


def _fits(traj, values):
    """Whether `traj` is the one a tracker start event (`values`) describes."""
    return bool(traj.points) and str(len(traj.points)) == values.get("points") and abs(
        _duration(traj) - float(values.get("duration", "nan"))) < 1e-6


def motions(run):
    """The run's motions: each planned trajectory, paired with its execution if recorded.

    Each "executing trajectory" event of the tracker goes to the latest trajectory received
    before it with the same number of points and duration (else the first such one not yet
    paired); a trajectory never executed is a motion without execution.

    Returns
    -------
    list of Motion
        In the order of the trajectories.
    """
    out = [Motion(index=i + 1, trajectory=traj) for i, (_, traj) in enumerate(run.trajectories)]
    executions = []
    for i, (log_time, status) in enumerate(run.tracker_status):
        values = _values(status)
        if not status.message.startswith("executing trajectory") or "start_time" not in values:
            continue
        summary = next((_values(s) for _, s in run.tracker_status[i + 1:]
                        if "outcome" in _values(s)), {})
        executions.append((log_time, values, summary))
    for log_time, values, summary in executions:
        free = [i for i, (_, traj) in enumerate(run.trajectories)
                if out[i].start is None and _fits(traj, values)]
        if not free:
            continue
        before = [i for i in free if run.trajectories[i][0] <= log_time]
        motion = out[before[-1] if before else free[0]]
        motion.start = float(values["start_time"])
        motion.summary = summary
        motion.outcome = summary.get("outcome", "running when the recording ended")
        motion.end = motion.start + float(summary.get("elapsed", values.get("duration", 0)))
    if not executions and run.js_t and out:
        # No tracker status: the joint states all belong to the last plan (the old layout).
        t0 = _stamp(out[-1].trajectory.header)
        out[-1].start = t0 if t0 > 0 and run.js_t[-1] >= t0 else run.js_t[0]
        out[-1].end = run.js_t[-1]
        out[-1].outcome = "no tracker status recorded"
    starts = sorted(m.start for m in out if m.start is not None)
    for m in out:
        if m.start is None:
            continue
        later = [s for s in starts if s > m.start]
        limit = later[0] if later else math.inf
        m.end = min(max(m.end, m.start) + HOLD_SHOWN, limit)
    return out


def _window(times, start, end):
    t = np.asarray(times, dtype=float)
    return np.flatnonzero((t >= start - 1e-9) & (t < end - 1e-9))


def nominal(traj, tau_max):
    """Planned times (s), positions (rad) and normalised controls from a trajectory."""
    points = traj.points
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in points])
    q = np.array([list(p.positions) for p in points], dtype=float)
    u = np.array([list(p.effort) for p in points], dtype=float) / tau_max
    return t, q, u


@dataclass(frozen=True)
class MotionRow:
    """One row of the summary table (NaN where the recording does not say)."""

    index: int
    T: float
    planned_max_u: float
    applied_max_u: float
    final_error: float
    saturated: float
    outcome: str


def motion_row(run, motion, model, tau_max):
    """The table row of `motion`: the tracker's own figures where it reported them."""
    nan = float("nan")
    T = planned = nan
    if motion.trajectory is not None and motion.trajectory.points:
        t_nom, q_nom, u_nom = nominal(motion.trajectory, tau_max)
        T, planned = float(t_nom[-1]), float(np.max(np.abs(u_nom)))
    applied = final = saturated = nan
    if motion.start is not None:
        rows = _window(run.js_t, motion.start, motion.end)
        efforts = [run.js_effort[i] for i in rows if run.js_effort[i] is not None]
        u = np.abs(np.array(efforts, dtype=float) / tau_max) if efforts else None
        s = motion.summary
        applied = float(s["max_abs_u"]) if "max_abs_u" in s else (
            float(u.max()) if u is not None else nan)
        saturated = float(s["saturated_fraction"]) if "saturated_fraction" in s else (
            float(np.mean(np.any(u >= SATURATION, axis=1))) if u is not None else nan)
        if "final_point_error" in s:
            final = float(s["final_point_error"])
        elif rows.size and not math.isnan(T):
            axes = list(model.task_axes)
            p_end = link_positions(model, np.array(run.js_q[rows[-1]], dtype=float))[-1]
            p_plan = link_positions(model, q_nom[-1])[-1]
            final = float(np.linalg.norm((p_end - p_plan)[axes]))
    return MotionRow(motion.index, T, planned, applied, final, saturated,
                     motion.outcome or "not executed")


TABLE_HEADER = ("motion", "T (s)", "planned max |u|", "applied max |u|",
                "final EE error (m)", "saturated (%)", "outcome")


def _cells(row):
    def fmt(value, spec):
        return "-" if math.isnan(value) else format(value, spec)

    return (str(row.index), fmt(row.T, ".4f"), fmt(row.planned_max_u, ".4f"),
            fmt(row.applied_max_u, ".4f"), fmt(row.final_error, ".3g"),
            fmt(100 * row.saturated, ".1f"), row.outcome)


def table_text(rows):
    """The motions table as aligned text."""
    lines = [list(TABLE_HEADER)] + [list(_cells(r)) for r in rows]
    widths = [max(len(line[i]) for line in lines) for i in range(len(TABLE_HEADER))]
    return "\n".join("  ".join(c.rjust(w) if i < 6 else c for i, (c, w) in
                               enumerate(zip(line, widths, strict=True)))
                     for line in lines)


def summarise(run, model, tau_max, rows, extra=()):
    """The summary's lines (run, overall errors, ``extra``, then the motions table)."""
    planner = {}
    for status in run.planner_status:
        planner.update(_values(status))
    lines = [f"k = {planner.get('k', 'unknown')}",
             f"joints = {', '.join(run.joint_names)}",
             f"tau_max = {np.array2string(tau_max, precision=4)} N m",
             f"motions = {len(rows)} planned, "
             f"{sum(r.outcome != 'not executed' for r in rows)} executed"]
    if run.err_q:
        err = np.abs(np.array(run.err_q, dtype=float))
        lines.append("max |tracking error| per joint = "
                     + np.array2string(err.max(axis=0), precision=6) + " rad")
        lines.append("RMS tracking error per joint = "
                     + np.array2string(np.sqrt(np.mean(err**2, axis=0)), precision=6)
                     + " rad")
    if run.js_q and run.goal is not None:
        p_end = link_positions(model, np.array(run.js_q[-1], dtype=float))[-1]
        goal = np.array([run.goal.point.x, run.goal.point.y, run.goal.point.z])
        axes = list(model.task_axes)
        lines.append(f"final end-effector error v. last goal = "
                     f"{np.linalg.norm((p_end - goal)[axes]):.6f} m")
    if run.js_t:
        lines.append(f"joint states = {len(run.js_q)} over "
                     f"{run.js_t[-1] - run.js_t[0]:.3f} s")
    lines += [*extra, "", table_text(rows)]
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


def _plot_motion(ax, model, q, q_nom):
    axes = list(model.task_axes)[:2] if model.m >= 2 else [0, 1]
    if len(q):
        picks = np.unique(np.linspace(0, len(q) - 1, SNAPSHOTS).round().astype(int))
        for j, k in enumerate(picks):
            pts = link_positions(model, q[k])[:, axes]
            shade = 0.8 - 0.7 * j / max(len(picks) - 1, 1)
            ax.plot(pts[:, 0], pts[:, 1], "-o", color=str(shade), ms=3, lw=1.5)
        tip = np.array([link_positions(model, qk)[-1] for qk in q])[:, axes]
        ax.plot(tip[:, 0], tip[:, 1], color="C3", lw=1.5, label="executed")
    if q_nom is not None:
        tip_nom = np.array([link_positions(model, qk)[-1] for qk in q_nom])[:, axes]
        ax.plot(tip_nom[:, 0], tip_nom[:, 1], "--", color="C0", lw=1.2, label="planned")
        ax.plot(tip_nom[-1, 0], tip_nom[-1, 1], "x", color="C2", ms=9, label="target")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("xyz"[axes[0]] + " (m)")
    ax.set_ylabel("xyz"[axes[1]] + " (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")


def motion_goal(run, motion):
    """The goal point (3,) (m) of a motion: the last goal logged before its plan, or None.

    Plans served on the service (no goal message) have none unless an earlier goal was sent.
    """
    if motion.trajectory is None or not run.goals:
        return None
    planned = run.trajectories[motion.index - 1][0]
    before = [g for g, t in zip(run.goals, run.goal_times, strict=True) if t <= planned]
    return np.array(before[-1], dtype=float) if before else None


def _plot_motion_3d(ax, model, q, q_nom, goal):
    """The end effector's executed and planned paths against the goal, in 3-D (m)."""
    points = []
    for k, shade, label in ((0, "0.7", "arm at start"), (-1, "0.3", "arm at end")):
        if len(q):
            pts = link_positions(model, q[k])
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], "-o", color=shade, ms=2, lw=1.2,
                    label=label)
            points.append(pts)
    if len(q):
        tip = np.array([link_positions(model, qk)[-1] for qk in q])
        ax.plot(tip[:, 0], tip[:, 1], tip[:, 2], color="C3", lw=1.8, label="executed")
        points.append(tip)
    if q_nom is not None:
        tip_nom = np.array([link_positions(model, qk)[-1] for qk in q_nom])
        ax.plot(tip_nom[:, 0], tip_nom[:, 1], tip_nom[:, 2], "--", color="C0", lw=1.2,
                label="planned")
        points.append(tip_nom)
    if goal is not None:
        ax.scatter([goal[0]], [goal[1]], [goal[2]], marker="x", s=80, color="C2",
                   label="goal")
        points.append(goal[None, :])
    if points:
        allp = np.vstack(points)
        centre = 0.5 * (allp.max(axis=0) + allp.min(axis=0))
        half = max(0.5 * float(np.max(allp.max(axis=0) - allp.min(axis=0))), 1e-3)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend(fontsize="x-small", loc="upper left")


def plot_motion(plt, run, motion, row, model, tau_max, names, path):
    """The four panels of one motion, saved to `path`."""
    fig, axs = plt.subplots(2, 2, figsize=FIGSIZE)
    have_plan = motion.trajectory is not None and bool(motion.trajectory.points)
    t_nom = q_nom = u_nom = None
    if have_plan:
        t_nom, q_nom, u_nom = nominal(motion.trajectory, tau_max)
        _plot_controls(axs[0, 0], t_nom, u_nom, names)
        axs[0, 0].legend(loc="lower right", fontsize="small")
    axs[0, 0].set_title("Planned controls" if have_plan else "No plan recorded")
    q = np.empty((0, len(names)))
    if motion.start is not None:
        rows = _window(run.js_t, motion.start, motion.end)
        q = np.array([run.js_q[i] for i in rows], dtype=float).reshape(-1, len(names))
        efforts = [run.js_effort[i] for i in rows]
        if rows.size and all(e is not None for e in efforts):
            t = np.array(run.js_t)[rows] - motion.start
            _plot_controls(axs[0, 1], t, np.array(efforts, dtype=float) / tau_max, names,
                           label="applied ")
        if have_plan:
            _plot_controls(axs[0, 1], t_nom, u_nom, names, style="--", label="planned ")
        axs[0, 1].legend(loc="lower right", fontsize="x-small", ncol=2)
        axs[0, 1].set_title("Applied controls (joint_states effort), planned dashed")
        err_rows = _window(run.err_t, motion.start, motion.end)
        if err_rows.size:
            err = np.array([run.err_q[i] for i in err_rows], dtype=float)
            t = np.array(run.err_t)[err_rows] - motion.start
            for i, name in enumerate(names[:err.shape[1]]):
                axs[1, 1].plot(t, err[:, i], color=f"C{i}", label=name)
            axs[1, 1].legend(fontsize="small")
        axs[1, 1].set_xlabel("t (s)")
        axs[1, 1].set_ylabel("position error (rad)")
        axs[1, 1].grid(alpha=0.3)
        axs[1, 1].set_title("Tracking error")
    else:
        for ax in (axs[0, 1], axs[1, 1]):
            ax.set_title("Not executed in this recording")
            ax.axis("off")
    if model.m == 3:
        axs[1, 0].remove()
        ax3d = fig.add_subplot(2, 2, 3, projection="3d")
        _plot_motion_3d(ax3d, model, q, q_nom, motion_goal(run, motion))
        ax3d.set_title("End effector against the goal (3-D)")
    else:
        _plot_motion(axs[1, 0], model, q, q_nom)
        axs[1, 0].set_title("Motion of the arm")
    cells = dict(zip(TABLE_HEADER, _cells(row), strict=True))
    fig.suptitle(f"Motion {motion.index}: T = {cells['T (s)']} s, final end-effector error "
                 f"{cells['final EE error (m)']} m, saturated {cells['saturated (%)']} %, "
                 f"{row.outcome}")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def write_html(path, recording, figures, rows, summary_lines, extra=(), after=None):
    """``index.html``: the table, then every figure (relative links, no script).

    ``extra``: figures shown before the motions' (the moving target's path); ``after``:
    motion index -> a figure shown after that motion's (its clearance).
    """
    after = after or {}
    head = "".join(f"<th>{html.escape(h)}</th>" for h in TABLE_HEADER)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in _cells(r))
                   + "</tr>\n" for r in rows)
    images = "".join(
        f'<figure id="motion-{r.index}"><img src="{html.escape(f.name)}" '
        f'alt="Motion {r.index}: planned and applied controls, arm, tracking error" '
        f'width="{FIGSIZE[0] * DPI}" height="{FIGSIZE[1] * DPI}">'
        f'<figcaption>Motion {r.index}</figcaption></figure>\n'
        + (f'<figure id="clearance-{r.index}"><img src="{html.escape(after[r.index].name)}" '
           f'alt="Motion {r.index}: clearance of the executed motion"><figcaption>Motion '
           f'{r.index}: clearance</figcaption></figure>\n' if r.index in after else "")
        for f, r in zip(figures, rows, strict=True))
    images = "".join(f'<figure id="{html.escape(f.stem)}"><img src="{html.escape(f.name)}" '
                     f'alt="{html.escape(f.stem)}"><figcaption>the goals and the end '
                     f'effector</figcaption></figure>\n' for f in extra) + images
    details = html.escape("\n".join(summary_lines[:summary_lines.index("")]
                                    if "" in summary_lines else summary_lines))
    title = html.escape(f"Report: {Path(recording).name}")
    path.write_text(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{title}</title>\n<style>body{{font-family:sans-serif;margin:2em}}"
        "table{border-collapse:collapse}td,th{border:1px solid #999;padding:3px 8px;"
        "text-align:right}img{max-width:100%;height:auto}</style></head>\n<body>\n"
        f"<h1>{title}</h1>\n<pre>{details}</pre>\n"
        f"<table id=\"motions\"><thead><tr>{head}</tr></thead><tbody>\n{body}</tbody></table>\n"
        f"{images}</body></html>\n", encoding="utf-8")
    return path


def write_report(path, out_dir, model, urdf=None, clearance_options=None):
    """Write one PNG per motion, ``summary.txt`` and ``index.html`` into `out_dir`.

    Parameters
    ----------
    path : str or os.PathLike
        The recording.
    out_dir : str or os.PathLike
    model : RobotModel
    urdf : str or os.PathLike, optional
        The model's URDF (XML or file) for the clearance check; default the recording's
        ``/robot_description`` (none: the clearance is not checked).
    clearance_options : ClearanceOptions, optional
        Margin, scene file, SRDF (:mod:`tocontrol_ros.recording.clearance`).

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    ValueError
        If the recording's joints are not the URDF's.
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
    found = motions(run)
    rows = [motion_row(run, m, model, tau_max) for m in found]
    figures = [plot_motion(plt, run, m, r, model, tau_max, names,
                           out_dir / f"motion_{m.index}.png")
               for m, r in zip(found, rows, strict=True)]
    cleared, clearance_lines = executed_clearances(
        plt, path, run, found, model, names, urdf if urdf is not None else recorded_urdf(path),
        clearance_options or clearance.ClearanceOptions(), out_dir)
    lines = summarise(run, model, tau_max, rows, clearance_lines)
    extra = []
    if len(run.goals) >= target_path.MIN_GOALS and len(names) == model.n:
        order = [names.index(n) for n in model.joint_names] if set(names) == \
            set(model.joint_names) else list(range(model.n))
        js = np.asarray(run.js_q, dtype=float)[:, order] if run.js_q else []
        extra.append(target_path.plot_target_path(plt, model, run.goals, js,
                                                  out_dir / "moving_target.png"))
    summary = out_dir / "summary.txt"
    summary.write_text(f"recording: {path}\n" + "\n".join(lines) + "\n")
    page = write_html(out_dir / "index.html", path, figures, rows, lines, extra, cleared)
    return [*extra, *figures, *cleared.values(), summary, page]


def executed_clearances(plt, path, run: Run, found: list, model, names: list, urdf,
                        options: clearance.ClearanceOptions, out_dir: Path
                        ) -> tuple[dict, list]:
    """Each executed motion's clearance (:mod:`~tocontrol_ros.recording.clearance`).

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    path : str or os.PathLike
        The recording (its ``/planner/markers``).
    run : Run
    found : list of Motion
        :func:`motions`.
    model : RobotModel
    names : list of str
        The recording's joint order (``run``'s arrays).
    urdf : str or os.PathLike or None
        The model's URDF (XML or file); None: nothing is checked (one line says so).
    options : ClearanceOptions
    out_dir : pathlib.Path

    Returns
    -------
    figures : dict
        Motion index -> its ``clearance_<i>.png``.
    lines : list of str
        The summary's lines: the check's inputs and one per executed motion, or one line
        saying why nothing was checked.
    """
    from tocontrol_ros.core.errors import ProblemError

    reported = any("min_clearance" in _values(s) for s in run.planner_status)
    try:
        scenes = clearance.recorded_scenes(path)
    except ProblemError as exc:
        return {}, [f"clearance: not checked (the recorded scene: {exc})"]
    check = clearance.ClearanceCheck(model, urdf, options, scenes, reported)
    if check.reason:
        return {}, [check.reason]
    order = [names.index(n) for n in model.joint_names] if set(names) == \
        set(model.joint_names) else list(range(model.n))
    figures, lines = {}, [check.header()]
    for motion in found:
        if motion.start is None:
            continue
        rows = _window(run.js_t, motion.start, motion.end)
        if not rows.size:
            continue
        q = np.array([run.js_q[i] for i in rows], dtype=float)[:, order]
        qd = [run.js_qd[i] for i in rows]
        qd = np.array(qd, dtype=float)[:, order] if all(v is not None and len(v) == len(names)
                                                        for v in qd) else None
        t = np.array(run.js_t)[rows] - motion.start
        planned_ns = run.trajectories[motion.index - 1][0]
        next_ns = run.trajectories[motion.index][0] if motion.index < len(run.trajectories) \
            else None
        try:
            col = check.model_for(planned_ns, next_ns)
            found_clearance = clearance.executed_clearance(col, t, q, qd)
        except ProblemError as exc:
            lines.append(f"motion {motion.index} clearance: not checked ({exc})")
            continue
        planned = None
        if motion.trajectory is not None and motion.trajectory.points:
            t_nom, q_nom, _ = nominal(motion.trajectory, np.ones(len(names)))
            planned = clearance.planned_clearance(col, t_nom, q_nom[:, order])
        lines.append(found_clearance.line(motion.index))
        figures[motion.index] = clearance.plot_clearance(
            plt, motion.index, found_clearance, planned,
            out_dir / f"clearance_{motion.index}.png")
    return figures, lines


def build_parser():
    """Return the report's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="report", description="Figures of every motion, a table and an HTML page of a "
        "recorded run (from the file alone).")
    parser.add_argument("file", type=Path, metavar="FILE", help="recording (.mcap)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="output folder (default: FILE without .mcap, plus _report)")
    parser.add_argument("--urdf", type=Path, default=None, metavar="PATH",
                        help="URDF of the arm, for torque limits and drawing (default: the "
                        "recording's /robot_description, else the bundled arm)")
    parser.add_argument("--tip-link", default=None, metavar="LINK",
                        help="the arm's tip link, as the planner's tip_link (default: the "
                        "URDF's only leaf link)")
    parser.add_argument("--margin", type=float, default=None, metavar="M",
                        help="collision margin (m) the executed motion is checked against, "
                        "the planner's `margin` (default: its default, 0.01)")
    parser.add_argument("--scene", default=None, metavar="FILE",
                        help="the planner's scene_file: its allowed pairs, and its obstacles "
                        "where the recording has no scene markers")
    parser.add_argument("--srdf", default=None, metavar="FILE",
                        help="the planner's robot_description_semantic (SRDF): its disabled "
                        "pairs are not checked")
    return parser


def recorded_urdf(path):
    """The URDF XML of a recording's first ``/robot_description`` message, or None."""
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    if ROBOT_DESCRIPTION not in mcap_io.read_channels(path):
        return None
    for record in mcap_io.iter_records(path, topics=[ROBOT_DESCRIPTION]):
        return deserialize_message(record.data, String).data
    return None


def main(argv=None):
    """Write the report; returns the exit status."""
    args = build_parser().parse_args(argv)
    if not args.file.is_file():
        print(f"report: no such file: {args.file}", file=sys.stderr)
        return 2
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    out = args.out or args.file.with_name(args.file.stem + "_report")
    try:
        source = args.urdf or recorded_urdf(args.file) or default_urdf_path()
        model = load_robot(source, **({"tip_link": args.tip_link} if args.tip_link else {}))
        written = write_report(args.file, out, model, source, clearance.ClearanceOptions(
            args.margin, args.scene, args.srdf))
    except (ValueError, OSError) as err:
        print(f"report: {err}", file=sys.stderr)
        return 2
    for path in written:
        print(path)
    print((out / "summary.txt").read_text(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
