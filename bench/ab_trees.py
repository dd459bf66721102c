"""Interleaved A/B timing of two source trees on the issue-3 figures (paper's example, k = 4).

Usage::

    git worktree add --detach /tmp/old <commit>
    scripts/dev run python bench/ab_trees.py /tmp/old . [rounds] [cases]

``cases`` is a comma-separated subset of ``cold,warm,multi`` (default ``cold,warm,multi``),
``rounds`` the number of timed runs per case and tree (default 30). One worker process per
tree imports that tree's ``tocontrol_ros`` and ``bench`` (the compile cache is shared), solves
each case once to warm up, then waits for orders: the driver alternates the trees run by run
(A then B, then B then A, ...), so that both see the same phases of a machine whose speed
drifts by tens of percent within minutes. Printed per case: each tree's median and minimum
wall time, the median over runs of the paired ratio B / A (the figure to trust), and the
largest difference between the two trees' final ``T`` over all runs.
``bench/run_all.py`` (``scripts/dev bench``) is the full, recorded benchmark.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CASES = ("cold", "warm", "multi")


def worker(tree: str) -> None:
    """Serve timing orders on stdin: one case name per line, one result line back."""
    sys.path.insert(0, str(Path(tree).resolve()))
    from bench.common import MOVED_TARGET, MULTI, START, TARGET, paper_model

    # The public face, which both sides of a restructuring have (issue 31 onwards).
    from tocontrol_ros.core import Problem, SolverOptions, plan, point

    model = paper_model()
    problem = Problem(model, point(START), point(TARGET), k=4.0)
    moved = Problem(model, point(START), point(MOVED_TARGET), k=4.0)
    multi = plan(problem, SolverOptions(verify=False, **MULTI))
    cases = {
        "cold": lambda: plan(problem, SolverOptions(starts=1, candidates=1, verify=False)),
        "warm": lambda: plan(moved, SolverOptions(verify=False), warm_start=multi),
        "multi": lambda: plan(problem, SolverOptions(verify=False, **MULTI)),
    }
    for fn in cases.values():
        fn()
    print("ready", flush=True)
    for line in sys.stdin:
        t0 = time.perf_counter()
        res = cases[line.strip()]()
        print(f"{time.perf_counter() - t0} {res.success} {res.T}", flush=True)


def main() -> None:
    trees = sys.argv[1:3]
    if len(trees) != 2:
        raise SystemExit(__doc__)
    rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 30
    cases = sys.argv[4].split(",") if len(sys.argv) > 4 else list(CASES)
    if not set(cases) <= set(CASES) or rounds < 1:
        raise SystemExit(f"cases must be among {CASES}, rounds >= 1")
    procs = [subprocess.Popen([sys.executable, __file__, "--worker", tree],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ)) for tree in trees]
    try:
        for proc, tree in zip(procs, trees, strict=True):
            if proc.stdout.readline().strip() != "ready":
                raise SystemExit(f"worker for {tree} did not start")
        times = {(t, c): [] for t in range(2) for c in cases}
        finals = {(t, c): set() for t in range(2) for c in cases}
        for r in range(rounds):
            for case in cases:
                for t in ((0, 1) if r % 2 == 0 else (1, 0)):
                    procs[t].stdin.write(case + "\n")
                    procs[t].stdin.flush()
                    wall, ok, t_final = procs[t].stdout.readline().split()
                    if ok != "True":
                        raise SystemExit(f"{trees[t]}: {case} failed")
                    times[(t, case)].append(1e3 * float(wall))
                    finals[(t, case)].add(float(t_final))
    finally:
        for proc in procs:
            proc.stdin.close()
            proc.wait(timeout=60)
    print(f"A = {trees[0]}, B = {trees[1]}, {rounds} interleaved runs per case")
    for case in cases:
        a, b = np.array(times[(0, case)]), np.array(times[(1, case)])
        t_a, t_b = np.array(sorted(finals[(0, case)])), np.array(sorted(finals[(1, case)]))
        print(f"{case}: A median {np.median(a):.1f} ms (min {a.min():.1f}), B median "
              f"{np.median(b):.1f} ms (min {b.min():.1f}); paired B / A median "
              f"{np.median(b / a):.3f}; T A {t_a[0]:.15f} s, max |T_B - T_A| "
              f"{np.max(np.abs(t_b[:, None] - t_a[None, :])):.1e} s")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        worker(sys.argv[2])
    else:
        main()
