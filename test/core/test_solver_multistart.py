"""Multistart on the paper's arm: the best basin, and robustness over random problems."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.types.problem import Problem, point

pytestmark = pytest.mark.slow

P_START, P_TARGET = np.array(PAPER_START), np.array(PAPER_TARGET)
K = 4
MULTI = SolverOptions(starts=16, candidates=4)
EXHAUSTIVE = SolverOptions(starts=64, candidates=16, ik_count=16, time_limit=600.0)
SEED = 20240611
PAIRS = 20
#: Measured (seed above, k = 4, starts=8, candidates=3): 17/20 solved, the 3 others
#: VERIFICATION_FAILED; the first seed pair's continued T was the best in only 2 of 17
#: (a lower bound: the first pair is not always among the continued candidates).
#: Multistart on the paper's example: T = 0.5070396 s, 6 % below the single start's 0.539048.
MIN_SUCCESS_RATE = 0.8


def test_multistart_finds_the_exhaustive_optimum(galicki):
    problem = Problem(galicki, point(P_START), point(P_TARGET), k=K)
    multi = plan(problem, MULTI)
    full = plan(problem, EXHAUSTIVE)
    assert multi.success, multi.message
    assert full.success, full.message
    continued = [r for r in full.starts if np.isfinite(r.T)]
    print(f"multistart T={multi.T:.10f} ({multi.timings['total']:.1f} s); exhaustive "
          f"T={full.T:.10f} ({full.timings['total']:.1f} s, {len(continued)} basins continued: "
          + ", ".join(f"{r.T:.6f}" for r in sorted(continued, key=lambda r: r.T)) + ")")
    assert multi.T == pytest.approx(full.T, rel=1e-7)
    assert multi.T <= min(r.T for r in continued) * (1 + 1e-7)


def _random_pairs(rng: np.random.Generator, count: int) -> list[tuple[np.ndarray, ...]]:
    pairs = []
    while len(pairs) < count:
        radius = rng.uniform(0.5, 5.3, size=2)
        angle = rng.uniform(-np.pi, np.pi, size=2)
        pts = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
        if np.linalg.norm(pts[0] - pts[1]) > 0.2:
            pairs.append((pts[0], pts[1]))
    return pairs


def test_random_problems_success_rate(galicki):
    pairs = _random_pairs(np.random.default_rng(SEED), PAIRS)
    options = SolverOptions(starts=8, candidates=3, time_limit=120.0)
    solved = first_best = 0
    lines = []
    for a, b in pairs:
        res = plan(Problem(galicki, point(a), point(b), k=K), options)
        first = [r for r in res.starts if r.index == 0]
        is_first = bool(res.success and first and np.isfinite(first[0].T)
                        and first[0].T <= res.T * (1 + 1e-7))
        solved += res.success
        first_best += is_first
        lines.append(f"  {np.round(a, 3)} -> {np.round(b, 3)}: {res.status.name} "
                     f"T={res.T:.6f} first-start-best={is_first} "
                     f"{res.timings['total']:.1f} s")
    rate = solved / len(pairs)
    print("\n".join(lines))
    print(f"success {solved}/{len(pairs)} = {rate:.0%}; first start alone best in "
          f"{first_best}/{solved} solved")
    assert rate >= MIN_SUCCESS_RATE
