"""Pose goals on the Panda: the planner's IK route against the joint goal it came from.

For each case (:func:`bench.limits.draw_cases`' configurations with :data:`SEED`: a start at
rest ``q0`` and a configuration ``q1``), the pose of the hand at ``q1`` is planned by the
planning service as a ``~/goal_pose`` request is (:mod:`tocontrol_ros.nodes.pose_goals`:
IK from ``pose_ik_seeds`` seeds, the solutions timed by their first motions,
``pose_candidates`` planned to the optimum, the least ``T`` published after its end pose was
checked), and, as the peer in the same run, the joint goal ``q1`` itself (what a user with
their own IK would send: one configuration, one optimum). Measured: the pose route's time to
its outcome and its parts (IK and first motions, to the ``candidates`` status), the number
of IK solutions, the published ``T`` and the achieved errors; the joint goal's time and
``T``; the ratios pose/joint. Defaults of the planner's parameters (``warm_start`` off, so
that every request is cold), the machine shared as it is.

Run alone: ``scripts/dev run python -P bench/pose_goals.py [CASES]`` (prints the section).
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402

#: The cases' seed (not the best-motion section's: other configurations).
SEED = 52
#: Longest wait for one outcome (s): a hang, not a measurement.
HANG = 600.0


class _Outputs:
    """The planning service's outputs, recorded (no ROS): status events with their times."""

    def __init__(self) -> None:
        self.events: list = []
        self._lock = threading.Lock()

    def status(self, level, message, values, routine=False) -> None:
        with self._lock:
            self.events.append((time.perf_counter(), level, message, dict(values)))

    def log_error(self, message) -> None:
        log(f"planner error: {message}")

    def trajectory(self, sample, stamp_ns):
        return object()

    def path(self, sample, stamp_ns):
        return object()

    def follow(self, request_id, trajectory, config) -> None:
        pass

    def markers(self, result, path, config, start_point, target) -> None:
        pass

    def rest_path(self, point):
        return object()

    def of(self, rid: int, event: str) -> tuple | None:
        with self._lock:
            return next((e for e in self.events if e[3].get("request_id") == rid
                         and e[3].get("event") == event), None)


class _Arm:
    def start(self, config, since_ns, fresh=True):
        raise RuntimeError("every request here has its own start")

    def latest(self, config):
        return 0, None


def run(count: int = 6) -> Section:
    from tocontrol_ros.core.robot.kinematics import tip_pose
    from tocontrol_ros.nodes.planner_config import config_from_values, planner_limits
    from tocontrol_ros.nodes.planning_service import Clock, PlanningService
    from tocontrol_ros.nodes.pose_goals import PoseTarget
    from tocontrol_ros.nodes.requests import PlanRequest

    title = f"Pose goals on the Panda ({count} cases)"
    found = robots().get("Panda")
    if found is None:
        return Section(title, ["example-robot-data is not installed: section skipped."], [])
    model, _ = found
    config = config_from_values({"warm_start": False}, task_dim=model.m)
    limits = planner_limits(config, model)
    out = _Outputs()
    service = PlanningService(model, limits, config, model.base_link, out, _Arm(),
                              Clock(now_ns=time.time_ns))
    service.start()
    if not service.ready.wait(HANG):
        raise RuntimeError("the planning service did not warm up")
    cases = draw_cases(model, limits.with_margin(config.limit_margin), count, seed=SEED)
    rng = np.random.default_rng(SEED + 1)  # not draw_cases' stream: q1 != q0
    rows, ratios_t, ratios_time, ik_parts = [], [], [], []
    try:
        for i, (q0, _qd0, _target) in enumerate(cases):
            lo, hi = limits.lower, limits.upper
            q1 = 0.5 * (lo + hi) + rng.uniform(-0.45, 0.45, model.n) * (hi - lo)
            rotation, position = tip_pose(model, q1)
            start = ("state", np.asarray(q0, dtype=float), np.zeros(model.n))
            pose = PoseTarget(position, rotation, model.base_link)
            outcome = {}
            for kind in ("pose", "joints"):
                rid = service.next_id()
                req = PlanRequest(rid, f"bench_{kind}", start,
                                  position[list(model.task_axes)], config,
                                  target_pose=pose if kind == "pose" else None,
                                  target_q=q1 if kind == "joints" else None)
                t0 = time.perf_counter()
                service.submit(req)
                if not req.done.wait(HANG):
                    raise RuntimeError(f"case {i + 1}: no outcome for the {kind} goal")
                took = time.perf_counter() - t0
                final = out.of(rid, "solved") or out.of(rid, "failed")
                candidates = out.of(rid, "candidates")
                outcome[kind] = (took, req.result, final, candidates, t0)
            took, result, final, candidates, t0 = outcome["pose"]
            j_took, j_result, j_final, _, _ = outcome["joints"]
            if result is None or j_result is None:
                rows.append([str(i + 1), "failed: " + (final[2] if result is None
                                                       else j_final[2]), "", "", "", "", ""])
                continue
            values = final[3]
            ik_time = candidates[0] - t0 if candidates else float("nan")
            ik_parts.append(ik_time)
            ratios_t.append(result.T / j_result.T)
            ratios_time.append(took / j_took)
            rows.append([str(i + 1), f"{values['ik_solutions']}", f"{ik_time:.2f}",
                         f"{took:.2f} / {j_took:.2f}",
                         f"{result.T:.4f} / {j_result.T:.4f} ({result.T / j_result.T:.3f})",
                         f"{values['position_error']:.1e} m, "
                         f"{values['orientation_error']:.1e} rad",
                         values["method_of_published"]])
            log(f"pose goals {i + 1}/{count}: {rows[-1]}")
    finally:
        service.stop()
    lines = [
        f"The Panda of example-robot-data (`tip_link: panda_hand`, its URDF limits, which "
        f"bind), the planner's defaults (`pose_ik_seeds: {config.pose_ik_seeds}`, "
        f"`pose_candidates: {config.pose_candidates}`, `warm_start: false`), through the "
        f"planning service in this process (no ROS transport). Each case: a start at rest and "
        f"the hand's pose at another configuration `q1` (seed {SEED}); the pose goal, then the "
        f"joint goal `q1` (the peer: one configuration, one optimum). IK + first motions: "
        f"from the request to its `candidates` status. Time to outcome: from the submit to "
        f"the final status. Errors: the published motion's last sample against the pose, "
        f"checked before publishing. The machine shared with other work."
        + (f" Median over the cases: T pose/joint {statistics.median(ratios_t):.3f} (the "
           f"pose route may pick a faster configuration than `q1`), time pose/joint "
           f"{statistics.median(ratios_time):.2f}, IK + first motions "
           f"{statistics.median(ik_parts):.2f} s." if ratios_t else "")
        + f" Command: `scripts/dev run python -P bench/pose_goals.py {count}`.",
        "",
        *table(["case", "IK solutions", "IK + first motions (s)",
                "time to outcome, pose / joint (s)", "T pose / joint (s, ratio)",
                "end pose errors", "published"], rows),
    ]
    return Section(title, lines, [])


if __name__ == "__main__":
    run(int(sys.argv[1]) if len(sys.argv) > 1 else 6).print()
