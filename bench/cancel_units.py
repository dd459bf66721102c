"""Which units of a Panda plan see a cancel late: the solver's own stop, in this process.

For the cancel benchmark's cases (:mod:`bench.cancel`: :func:`bench.limits.draw_cases` with
:mod:`bench.optimum_panda`'s seed, a joint-state start at rest to a point, ``warm_start``
off), ``Planner.plan`` runs with a ``should_stop`` that turns true ``d`` s after the call
(``DELAYS``); measured: the time from then to the plan's return (the solver's stop latency),
how late the first true poll came (the unit running at ``d`` did not poll), and where in
the solver that poll and the one before it were (function:line). The first motion
(``Planner.first``, not interruptible) is timed too. No ROS: the planner node adds its queue
and the action's messages on top (:mod:`bench.cancel`).

Run alone: ``scripts/dev run python -P bench/cancel_units.py [CASES]`` (prints one line per
case). Docs: docs/speed.md, "Cancel".
"""

from __future__ import annotations

import sys
import time
import traceback
from pathlib import Path

#: When the cancel comes after the call (s).
DELAYS = (0.05, 0.3, 1.0, 2.5)


def _where() -> str:
    """Where the poll came from: the solver's function that checked (function:line).

    ``SolveContext.check`` names its caller; a poll from the worker pool's watcher thread
    (``watch``) means items ran in the worker processes (their polls are not seen here).
    """
    frames = [f for f in traceback.extract_stack(limit=10)[:-2]
              if f.name not in ("check", "should_stop", "_where")]
    if frames and frames[-1].name == "watch":
        return "the pool's watcher (items in worker processes)"
    return f"{frames[-1].name}:{frames[-1].lineno}" if frames else "unknown"


def main(count: int) -> None:
    sys.path.append(str(Path(__file__).resolve().parents[1]))
    from bench.limits import draw_cases, robots
    from bench.optimum_panda import SEED
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.types.problem import Problem, joint_state, point
    from tocontrol_ros.nodes.planner_config import config_from_values, solver_options

    model, limits = robots()["Panda"]
    config = config_from_values({"warm_start": False}, task_dim=3)
    options = solver_options(config)
    planner = Planner(model)

    def problem_of(q0, target):
        return Problem(model, joint_state(q0), point(target), k=config.k,
                       reserve=config.reserve, limits=limits)

    cases = draw_cases(model, limits, count, seed=SEED)
    planner.plan(problem_of(cases[0][0], cases[0][2]), options)  # compiled, pool started
    for i, (q0, _qd0, target) in enumerate(cases):
        problem = problem_of(q0, target)
        t = time.perf_counter()
        planner.first(problem, options)
        first = time.perf_counter() - t
        cells = []
        for delay in DELAYS:
            seen: dict = {}
            t0 = time.perf_counter()

            def should_stop(delay=delay, seen=seen, t0=t0):
                now = time.perf_counter()
                if now - t0 < delay:
                    seen["before"] = _where()
                    return False
                seen.setdefault("at", (now, _where()))
                return True

            result = planner.plan(problem, options, should_stop=should_stop)
            t1 = time.perf_counter()
            if result.status.name != "CANCELLED":
                cells.append(f"{delay:g} s: done before ({t1 - t0:.2f} s)")
                continue
            at, where = seen["at"]
            cells.append(f"{delay:g} s: stop {(t1 - t0 - delay) * 1e3:.0f} ms, poll "
                         f"{(at - t0 - delay) * 1e3:.0f} ms late (before: "
                         f"{seen.get('before', 'none')}; at: {where})")
        print(f"case {i + 1}: first motion {first * 1e3:.0f} ms; " + " | ".join(cells),
              flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8)
