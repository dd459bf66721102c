"""The moving-target figure of a report: the goals' path against the end effector's.

A recording with more than one goal on ``/planner/goal`` (``demo --moving-target``) gets one
more figure: the goals in the order they were sent and the end effector's path computed from
the recorded joint states (the planning model's kinematics), in the task plane (the first two
task axes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["MIN_GOALS", "plot_target_path", "end_effector_path"]

#: Fewer goals than this is no moving target (the demo's usual single goal).
MIN_GOALS = 3


def end_effector_path(model, joint_positions) -> np.ndarray:
    """End-effector points, shape (K, m) (m), of joint positions of shape (K, n)."""
    q = np.asarray(joint_positions, dtype=float)
    return np.array([np.asarray(model.point(row), dtype=float) for row in q])


def plot_target_path(plt, model, goals, js_q, path: Path,
                     figsize=(8, 8), dpi=90) -> Path:
    """Draw the goals' path and the end effector's; write ``path`` (PNG).

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot`` (Agg backend).
    model : RobotModel
    goals : array_like, shape (G, 3)
        Goal points as sent (m, base frame).
    js_q : array_like, shape (K, n)
        Recorded joint positions (rad, m), in the model's joint order.
    path : pathlib.Path
    """
    goals = np.asarray(goals, dtype=float)
    axes = list(model.task_axes)[:2]
    ee = end_effector_path(model, js_q) if len(js_q) else np.zeros((0, len(axes)))
    fig, ax = plt.subplots(figsize=figsize)
    label = "xyz"
    if len(ee):
        ax.plot(ee[:, 0], ee[:, 1], "-", color="tab:blue", lw=1.5, label="end effector")
    ax.plot(goals[:, axes[0]], goals[:, axes[1]], "o--", color="tab:red", ms=3, lw=0.8,
            label=f"target ({len(goals)} goals)")
    ax.plot(goals[-1, axes[0]], goals[-1, axes[1]], "x", color="k", ms=10,
            label="last goal")
    ax.set_xlabel(f"{label[axes[0]]} (m)")
    ax.set_ylabel(f"{label[axes[1]]} (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    ax.set_title("Moving target: the goals and the end effector")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
