"""Quick timing of the issue-3 figures (paper's example, k = 4) for one source tree.

Usage (A/B against another commit, interleaved so both see the same machine)::

    git worktree add --detach /tmp/old <commit>
    for i in 1 2; do for tree in /tmp/old .; do
        scripts/dev run python bench/paper_k4.py $tree 20; done; done

The tree given is put first on ``sys.path``, so its ``tocontrol_ros`` and ``bench`` are the
ones imported (the compile cache is shared). Prints cold (one start), warm (target moved by
5 cm, from the multistart result) and multistart medians and minima; ``scripts/dev bench``
is the full, recorded benchmark.
"""

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()))

import numpy as np  # noqa: E402

from bench.common import MOVED_TARGET, MULTI, START, TARGET, paper_model  # noqa: E402
from tocontrol_ros.core.problem import Problem, point  # noqa: E402
from tocontrol_ros.core.solver import SolverOptions, plan  # noqa: E402


def main() -> None:
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    model = paper_model()
    problem = Problem(model, point(START), point(TARGET), k=4.0)
    moved = Problem(model, point(START), point(MOVED_TARGET), k=4.0)
    multi = plan(problem, SolverOptions(verify=False, **MULTI))
    cases = {
        "cold": lambda: plan(problem, SolverOptions(starts=1, candidates=1, verify=False)),
        "warm": lambda: plan(moved, SolverOptions(verify=False), warm_start=multi),
        "multi": lambda: plan(problem, SolverOptions(verify=False, **MULTI)),
    }
    for name, fn in cases.items():
        fn()  # warm-up
        times = []
        for _ in range(runs if name != "multi" else max(5, runs // 3)):
            t0 = time.perf_counter()
            res = fn()
            times.append(time.perf_counter() - t0)
            if not res.success:
                raise SystemExit(f"{name}: {res.message}")
        print(f"{sys.argv[1] if len(sys.argv) > 1 else '.'} {name}: median "
              f"{1e3 * np.median(times):.1f} ms, min {1e3 * min(times):.1f} ms, T {res.T:.6f}, "
              f"{res.iterations} Newton iterations, {res.intervals} intervals")


if __name__ == "__main__":
    main()
