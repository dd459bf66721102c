"""A trajectory's bytes into arrays: rclpy's deserialization against the package's reader.

The tracker subscribes to ``~/trajectory`` raw and reads the bytes in its parser thread
(:func:`tocontrol_ros.nodes.trajectory_cdr.read_trajectory_cdr`); before, rclpy deserialized
every message into a ``JointTrajectoryPoint`` per point on the executor's thread, before
the callback, where the control loop's timer runs too. Both timed here on the planner's own
bytes (:func:`~tocontrol_ros.nodes.trajectory_cdr.trajectory_cdr`) of the sizes the nodes
publish (the paper's arm at the default 10 ms sample period, the Panda at the README's 2 ms),
alternated, the least and the median of 50 calls each (ms), in one process.

Command: ``scripts/dev run python -P bench/trajectory_read.py``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import table  # noqa: E402

#: (points, joints): the paper's arm's replans (30-100 points), the Panda's (150-500).
SIZES = ((30, 3), (100, 3), (150, 7), (250, 7), (500, 7))
CALLS = 50


def run() -> list[str]:
    from rclpy.serialization import deserialize_message
    from trajectory_msgs.msg import JointTrajectory

    from tocontrol_ros.nodes.trajectory_cdr import read_trajectory_cdr, trajectory_cdr

    rng = np.random.default_rng(0)
    rows = []
    for count, n in SIZES:
        sample = SimpleNamespace(t=np.arange(count) * 0.002, q=rng.normal(size=(count, n)),
                                 qd=rng.normal(size=(count, n)),
                                 qdd=rng.normal(size=(count, n)),
                                 tau=rng.normal(size=(count, n)))
        data = trajectory_cdr(sample, [f"joint_{i}" for i in range(n)], "base_link", 1)
        times = {"rclpy": [], "reader": []}
        for _ in range(CALLS):
            for name, fn in (("rclpy", lambda b=data: deserialize_message(b, JointTrajectory)),
                             ("reader", lambda b=data: read_trajectory_cdr(b))):
                t0 = time.perf_counter()
                fn()
                times[name].append(1e3 * (time.perf_counter() - t0))
        rows.append([f"{count} x {n}", f"{len(data)}",
                     *(f"{min(times[k]):.3f} / {np.median(times[k]):.3f}"
                       for k in ("rclpy", "reader")),
                     f"{np.median(times['rclpy']) / np.median(times['reader']):.1f}"])
    return table(["points x joints", "bytes", "rclpy ms (least / median)",
                  "reader ms (least / median)", "median ratio"], rows)


if __name__ == "__main__":
    print("\n".join(run()))
