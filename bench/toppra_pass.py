"""One TOPP-RA pass per driver, side by side (issue 47: the compiled sweeps).

The same rows (a straight path between two configurations drawn inside the limits, the
inscribed cube, from rest) timed by each of ``time_scaling.ENGINES`` in turn, ``ROUNDS``
rounds of ``CALLS`` calls each, alternately (so that every driver sees the same load): the
median over the rounds of the processor time per pass (ms; less sensitive than the wall
time to other work on a shared machine, not immune to it), for the paper's arm and the
Panda on the quick replans' 30 segments and the first motion's 100. The squared path speeds
of the drivers are compared too (largest relative difference against the Seidel driver).

Run: ``scripts/dev run python -P bench/toppra_pass.py`` (prints a table).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.common import PANDA_LOCKED, load_text, panda_urdf, table  # noqa: E402

ROUNDS = 15
CALLS = 20


def _rows(model, gridpoints: int):
    """(coefficients, gridpoints s, cube) of one path of ``model``."""
    from tocontrol_ros.core.direct import time_scaling as ts
    from tocontrol_ros.core.direct.scaled_path import PolynomialPath
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    n = model.n
    limits = JointLimits.from_model(model)
    rng = np.random.default_rng(3)
    lo = np.nan_to_num(limits.plan_lower, nan=-2.0)
    hi = np.nan_to_num(limits.plan_upper, nan=2.0)
    q0, q1 = (np.clip(0.5 * (lo + hi) + rng.uniform(-0.3, 0.3, n), lo, hi) for _ in range(2))
    problem = Problem(model, joint_state(q0), point(model.point(q1)), k=4.0, limits=limits)
    s = np.linspace(0.0, 1.0, gridpoints + 1)
    coef = ts._Coefficients(problem, PolynomialPath.straight(q0, q1), s)
    return coef, s, np.full((gridpoints + 1, n), n ** (-1.0 / 8.0))


def measure(model, gridpoints: int) -> dict:
    """Median CPU ms per pass per engine, and the largest difference against Seidel's."""
    from tocontrol_ros.core.direct import time_scaling as ts
    from tocontrol_ros.core.robot import compiled

    coef, s, cube = _rows(model, gridpoints)
    x = {}
    for engine in ts.ENGINES:  # warm-up: builds, imports
        x[engine], why = ts._toppra(coef, s, 0.0, cube, None, engine)
        if x[engine] is None:
            raise RuntimeError(f"{engine}: {why}")
    compiled.wait_for_builds()
    times = {engine: [] for engine in ts.ENGINES}
    for _ in range(ROUNDS):
        for engine in ts.ENGINES:
            c0 = time.process_time()
            for _ in range(CALLS):
                ts._toppra(coef, s, 0.0, cube, None, engine)
            times[engine].append((time.process_time() - c0) / CALLS)
    diff = {e: float(np.max(np.abs(x[e] - x["seidel"]) / np.maximum(np.abs(x["seidel"]),
                                                                   1e-300)))
            for e in ts.ENGINES}
    return {e: (1e3 * statistics.median(t), diff[e]) for e, t in times.items()}


def main() -> None:
    from tocontrol_ros.core.direct.time_scaling import ENGINES
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    models = [("paper", load_robot(default_urdf_path()))]
    urdf = panda_urdf()
    if urdf is not None:
        models.append(("panda", load_robot(str(urdf), tip_link="panda_hand",
                                           locked_joints=PANDA_LOCKED)))
    load0 = load_text()
    rows = []
    for name, model in models:
        for gridpoints in (30, 100):
            out = measure(model, gridpoints)
            rows.append([name, str(gridpoints),
                         *(f"{out[e][0]:.3f} ({out[e][1]:.0e})" for e in ENGINES),
                         f"{out['seidel'][0] / out['compiled'][0]:.2f}x"])
    print(f"TOPP-RA pass, median CPU ms over {ROUNDS} rounds of {CALLS} (largest relative "
          f"difference of x against the Seidel driver). Load before: {load0}; after: "
          f"{load_text()}.")
    print("\n".join(table(["robot", "segments", *ENGINES, "seidel / compiled"], rows)))


if __name__ == "__main__":
    main()
