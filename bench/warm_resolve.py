"""One replan after a 2 cm target move on the Panda with its limits (issue 47's second bar).

20 Panda cases (bench/limits.py's draw, the URDF limits, k = 4; odd ones start moving): the
default plan of each, then its target moved by 2 cm (a fixed direction per case) and the
moved problem answered three ways, each timed after a warm-up of the same call:

- **warm**: the planner's warm re-solve of a replan (``warm_replan`` from the plan with
  ``replan_options``: warm alone, ``replan_spans`` 24), what ``replan_quick: false`` does;
- **quick**: the quick motion (``first_motion.quick_motion``: Newton from the plan's end,
  the path timed by TOPP-RA, the certificate), what a replan publishes first by default;
- **converged**: the warm re-solve's ``T`` is the reference (the optimum of the moved
  problem in the plan's basin); the quick motion's ``T`` gap is against it.

The issue's bar: median <= 10 ms with ``T`` within 1e-3 of the converged optimum. Command:
``scripts/dev run python -P bench/warm_resolve.py [cases]``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, log, panda_urdf, table  # noqa: E402

#: Cases, the move (m) and the bar (s; relative T gap).
CASES, MOVE, BAR_TIME, BAR_GAP = 20, 0.02, 0.010, 1e-3


def _timed(fn, repeats: int = 3):
    """``fn()``'s result and its median wall time (s) over ``repeats`` calls after one."""
    fn()
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times))


def run(count: int = CASES) -> Section:
    from bench.limits import draw_cases
    from tocontrol_ros.core.direct.first_motion import quick_motion
    from tocontrol_ros.core.planning.replan import replan_options, warm_replan
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.robot.model import load_robot
    from tocontrol_ros.core.types.options import SolverOptions
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    title = "One replan after a 2 cm move on the Panda: warm re-solve and quick motion (issue 47)"
    urdf = panda_urdf()
    if urdf is None:
        return Section(title, ["example-robot-data is not installed: skipped."])
    model = load_robot(str(urdf), tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    limits = JointLimits.from_model(model)
    planner = Planner(model)
    options = SolverOptions()
    rng = np.random.default_rng(47)
    rows, warm_t, quick_t, gaps, warm_ok, quick_ok = [], [], [], [], 0, 0
    for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count)):
        problem = Problem(model, joint_state(q0, qd0), point(target), k=4.0, limits=limits)
        base = planner.plan(problem, options)
        if not base.success:
            rows.append([str(i + 1), "plan failed", "", "", "", "", ""])
            continue
        d = rng.normal(size=3)
        moved = Problem(model, problem.start, point(target + MOVE * d / np.linalg.norm(d)),
                        k=4.0, limits=limits)
        q_end = base.trajectory.state(base.T)[0][:model.n]
        warm, tw = _timed(lambda: warm_replan(  # noqa: B023
            planner, moved, [base], replan_options(options, 0.0, 24)))  # noqa: B023
        quick, tq = _timed(lambda: quick_motion(moved, q_end, None, options))  # noqa: B023
        warm_ok += bool(warm.success)
        quick_ok += bool(quick.success)
        gap = (quick.T / warm.T - 1.0) if warm.success and quick.success else float("nan")
        if warm.success:
            warm_t.append(tw)
        if quick.success:
            quick_t.append(tq)
        gaps.append(gap)
        rows.append([str(i + 1), "moving" if np.any(qd0) else "rest",
                     f"{warm.T:.5f}" if warm.success else "failed",
                     f"{1e3 * tw:.1f} ({warm.iterations})",
                     f"{quick.T:.5f}" if quick.success else "failed",
                     f"{1e3 * tq:.1f}", f"{gap:.2e}"])
        log(f"warm_resolve {i + 1}: warm {1e3 * tw:.1f} ms T {warm.T:.5f}, quick "
            f"{1e3 * tq:.1f} ms T {quick.T:.5f}")
    finite = [g for g in gaps if np.isfinite(g)]

    def med(v: list) -> float:
        return float(np.median(v)) if v else float("nan")

    lines = [
        f"{count} Panda cases (bench/limits.py's draw, URDF limits, k = 4; odd ones start "
        f"moving): the default plan, then the target moved {100 * MOVE:g} cm in a random "
        f"direction, answered by the planner's warm re-solve of a replan (`warm_replan`, "
        f"`replan_options`, 24 spans: what `replan_quick: false` publishes) and by the quick "
        f"motion (what a replan publishes first); median wall time of 3 calls after one, "
        f"IPOPT iterations in parentheses; *gap*: the quick motion's T over the warm "
        f"re-solve's, minus 1. Command: `scripts/dev run python -P bench/warm_resolve.py`.",
        "",
        *table(["case", "start", "warm T (s)", "warm ms (it)", "quick T (s)", "quick ms",
                "gap"], rows),
        "",
        f"Warm re-solve: {warm_ok}/{len(rows)} converged, median {1e3 * med(warm_t):.1f} ms; "
        f"quick motion: {quick_ok}/{len(rows)} certified, median {1e3 * med(quick_t):.1f} ms, "
        f"T gap median {med(finite):.3g} (max {max(finite, default=float('nan')):.3g}).",
    ]
    targets = [
        ("warm re-solve after a 2 cm move: median <= 10 ms (T converged)",
         ("**yes**" if med(warm_t) <= BAR_TIME else "**no**")
         + f": {1e3 * med(warm_t):.1f} ms"),
        ("quick motion after a 2 cm move: median <= 10 ms with T within 1e-3",
         ("**yes**" if med(quick_t) <= BAR_TIME and finite and max(finite) <= BAR_GAP
          else "**no**") + f": {1e3 * med(quick_t):.1f} ms, T gap median {med(finite):.3g}"),
    ]
    return Section(title, lines, targets)


if __name__ == "__main__":
    section = run(int(sys.argv[1]) if len(sys.argv) > 1 else CASES)
    section.print()
