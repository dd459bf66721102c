"""The Panda's plan times of one source tree, for comparing two versions on one machine.

Runs the scaling section's Panda task (its URDF limits, k = 4): 5 cold plans after a
warm-up, one start and the default multistart; then bench/optimum_panda.py's 20 cases with
the default options (verified). Run it once per checkout, one after the other:

    scripts/dev run python -P bench/ab_panda.py /path/to/old/checkout
    scripts/dev run python -P bench/ab_panda.py .

The tree given is put first on ``sys.path`` (its ``tocontrol_ros`` and ``bench``), so the
installed package does not mask it.
"""

import sys
import time
from pathlib import Path

ROOT = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import tocontrol_ros  # noqa: E402
from bench.common import PANDA_LOCKED, panda_urdf  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.scaling import PANDA_Q_START, PANDA_Q_TARGET  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.robot import compiled  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

SEED = 20261202  # bench/optimum_panda.py's


def main() -> int:
    if not str(Path(tocontrol_ros.__file__).resolve()).startswith(str(ROOT)):
        print(f"tocontrol_ros imported from {tocontrol_ros.__file__}, not {ROOT}")
        return 2
    model = load_robot(str(panda_urdf()), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    problem = Problem(model, point(model.point(np.array(PANDA_Q_START))),
                      point(model.point(np.array(PANDA_Q_TARGET))), k=4.0)
    for label, opts in (("one start", SolverOptions(verify=False, starts=1, candidates=1)),
                        ("default", SolverOptions(verify=False))):
        plan(problem, opts)
        compiled.wait_for_builds()
        plan(problem, opts)
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            res = plan(problem, opts)
            times.append(time.perf_counter() - t0)
        print(f"Panda task, {label}: median {np.median(times) * 1e3:.0f} ms "
              f"(min {min(times) * 1e3:.0f}), T {res.T:.6f}", flush=True)
    panda, limits = robots()["Panda"]
    rows = []
    for i, (q0, qd0, target) in enumerate(draw_cases(panda, limits, 20, seed=SEED)):
        start = point(panda.point(q0)) if i % 2 == 0 else joint_state(q0, qd0)
        case = Problem(panda, start, point(target), k=4.0, limits=limits)
        t0 = time.perf_counter()
        res = plan(case, SolverOptions(time_limit=600.0))
        rows.append((time.perf_counter() - t0, res.T if res.success else np.nan))
    t, T = np.array(rows).T
    print(f"20 cases, default: median {np.median(t):.2f} s, max {t.max():.2f} s, "
          f"all {t.sum():.1f} s")
    print("T", " ".join(f"{v:.6f}" for v in T))
    print("t", " ".join(f"{v:.1f}" for v in t))
    return 0


if __name__ == "__main__":
    sys.exit(main())
