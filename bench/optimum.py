"""The default multistart against the exhaustive reference, on seeded random pairs.

Each pair of the paper's arm (k = 4, drawn as in :mod:`bench.random_pairs` but from its own
seed) is solved with the default :class:`SolverOptions` (as a user calls ``plan``) and with
``SolverOptions(exhaustive=True)``: a dense self-motion grid, every full-turn branch, 216
direct solves and every distinct basin continued (``docs/seeding.md``). The exhaustive best
``T`` is the reference; the gap of the default and the local optima per pair (the distinct
final ``T`` of the continued basins) are reported.

Run alone: ``scripts/dev run python bench/optimum.py [PAIRS]`` (prints the section);
``... bench/optimum.py PAIRS --times`` only times the default, the peer and the default with
the guess settings before (``BEFORE``) on the same pairs,
side by side (minutes instead of the reference's quarter hour: for a quiet machine).
"""

import os
import statistics
import sys
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import Section, fmt_ms, log, table, timed  # noqa: E402
from bench.random_pairs import draw_pairs  # noqa: E402
from tocontrol_ros.core.indirect.method import SKIPPED  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, point  # noqa: E402

SEED = 20261201
K = 4.0
#: The default reaches the reference when its T is within this of the exhaustive best.
GAP_TOL = 1e-3
#: Two continued basins are one local optimum when their T agree to this (relative).
SAME_T = 1e-6
TARGET_HITS = 0.97
#: The peer: the default before the best-motion work (16 starts, 3 candidates), same seeding.
PEER = SolverOptions(starts=16, candidates=3)
#: The default's guess settings before the guess-phase work (12 intervals, IPOPT tol 1e-8).
BEFORE = SolverOptions(guess_intervals=12, guess_tol=1e-8)
TARGET_MEDIAN = 0.5


def _optima(result, key: str = "T") -> list[float]:
    """Distinct final T of the continued basins of a result (``key="guess_T"``: distinct
    direct solutions at k = 1), ascending."""
    ts = sorted(getattr(r, key) for r in result.starts if np.isfinite(getattr(r, key)))
    out: list[float] = []
    for t in ts:
        if not out or t > out[-1] * (1 + SAME_T):
            out.append(t)
    return out


def run(model, count: int) -> Section:
    default = SolverOptions()
    reference = SolverOptions(exhaustive=True, verify=False, time_limit=600.0)
    recs = []
    pairs = draw_pairs(model, count, seed=SEED)
    plan(Problem(model, point(pairs[0][0]), point(pairs[0][1]), k=K), default)  # warm-up
    for i, (a, b) in enumerate(pairs):
        problem = Problem(model, point(a), point(b), k=K)
        t_def, res = timed(lambda p=problem: plan(p, default))
        t_old, old = timed(lambda p=problem: plan(p, PEER))
        t_before, before = timed(lambda p=problem: plan(p, BEFORE))
        t_ref, ref = timed(lambda p=problem: plan(p, reference))
        best = min([t for t in (res.T, ref.T) if np.isfinite(t)], default=np.nan)
        gap = (res.T - best) / best if res.success else np.inf
        gap_old = (old.T - best) / best if old.success else np.inf
        gap_before = (before.T - best) / best if before.success else np.inf
        recs.append({"a": a, "b": b, "res": res, "ref": ref, "t_def": t_def, "t_ref": t_ref,
                     "t_before": t_before, "gap_before": gap_before,
                     "gap_old": gap_old, "t_old": t_old,
                     "gap": gap, "optima": _optima(ref), "direct": _optima(ref, "guess_T"),
                     "below": res.T < ref.T * (1 - SAME_T)})
        log(f"optimum {i + 1}/{count}: default {res.status.name} {res.T:.6f} ({t_def:.2f} s), "
            f"exhaustive {ref.status.name} {ref.T:.6f} ({t_ref:.1f} s, "
            f"{len(recs[-1]['direct'])} direct optima), gap {gap:.2e}")
    return _section(recs, default)


def _section(recs, default) -> Section:
    n = len(recs)
    hits = [r for r in recs if r["gap"] <= GAP_TOL]
    gaps = sorted((r["gap"] for r in recs if r["gap"] > GAP_TOL), reverse=True)
    t_def = [r["t_def"] for r in recs]
    t_ref = [r["t_ref"] for r in recs]
    optima = [len(r["direct"]) for r in recs if r["direct"]]
    final = [len(r["optima"]) for r in recs if r["optima"]]
    direct = [len(r["res"].starts) for r in recs]
    continued = [sum(np.isfinite(s.T) for s in r["res"].starts) for r in recs]
    skipped = [sum(s.status == SKIPPED for s in r["res"].starts) for r in recs]
    iters = [r["res"].iterations for r in recs if r["res"].success]
    ref_ok = sum(r["ref"].success for r in recs)
    below = [r for r in recs if r["below"]]
    long_way = sum(bool(np.any(np.abs(r["res"].trajectory.state(r["res"].T)[0, :3]
                                      - r["res"].trajectory.state(0.0)[0, :3]) > np.pi))
                   for r in recs if r["res"].success)
    hist = np.bincount(optima) if optima else np.zeros(1, int)
    lines = [
        f"{n} pairs (seed {SEED}), k = {K:g}, drawn as in the random-pairs section. Default: "
        f"`SolverOptions()` (`starts={default.starts}, candidates={default.candidates}, "
        f"ik_count={default.ik_count}`, verified), as a user calls `plan`. Reference: "
        "`SolverOptions(exhaustive=True)` (24 self-motion angles and both elbows per end, "
        "-1/0/+1 turns of every joint, 216 direct solves spread over the 27 branches, the 12 "
        "best distinct direct solutions continued; `verify=False`). Gap: (T_default - "
        "T_best) / T_best, T_best the lower of the two.",
        "",
    ]
    lines += table(["", "value"], [
        [f"default within {GAP_TOL:g} of the best", f"{len(hits)}/{n} "
         f"({100 * len(hits) / max(n, 1):.0f} %)"],
        [f"peer `starts=16, candidates=3` within {GAP_TOL:g} of the best",
         f"{sum(r['gap_old'] <= GAP_TOL for r in recs)}/{n}"],
        ["peer plan time median (ms)", fmt_ms(statistics.median([r["t_old"] for r in recs]))],
        [f"default with the guess settings before (12 intervals, tol 1e-8) within "
         f"{GAP_TOL:g} of the best", f"{sum(r['gap_before'] <= GAP_TOL for r in recs)}/{n}"],
        ["default plan time / the same with the guess settings before: median of the "
         "per-pair ratios", f"{statistics.median(r['t_def'] / r['t_before'] for r in recs):.3f}"],
        [f"default gaps above {GAP_TOL:g} (largest first)",
         ", ".join(f"{100 * g:.2f} %" for g in gaps[:10]) or "none"],
        ["default below the exhaustive reference (by > 1e-6)", f"{len(below)}"],
        ["reference solved", f"{ref_ok}/{n}"],
        ["default plan time median / p90 / max (ms)",
         " / ".join(fmt_ms(v) for v in (statistics.median(t_def), np.percentile(t_def, 90),
                                        max(t_def)))],
        ["reference time median / max (s)",
         f"{statistics.median(t_ref):.1f} / {max(t_ref):.1f}"],
        ["default: direct solves per plan median / max",
         f"{statistics.median(direct):g} / {max(direct)}"],
        ["default: basins continued per plan median / max",
         f"{statistics.median(continued):g} / {max(continued)}"],
        ["default: candidates not continued (direct T x bound above the best) median / max",
         f"{statistics.median(skipped):g} / {max(skipped)}"],
        ["default: Newton iterations of the returned start median / max",
         f"{statistics.median(iters):g} / {max(iters)}" if iters else "—"],
        ["default motions turning a joint by more than pi", f"{long_way}/{n}"],
        ["local optima per pair at k = 1 (distinct T of the reference's 216 direct "
         "solutions) median / min / max",
         f"{statistics.median(optima):g} / {min(optima)} / {max(optima)}" if optima else "—"],
        ["distinct final T among the reference's 12 continued, median / min / max",
         f"{statistics.median(final):g} / {min(final)} / {max(final)}" if final else "—"],
    ])
    lines += ["", "Local optima per pair at k = 1 (distinct direct solutions of the reference; "
              "how many pairs have that many):", ""]
    edges = [(1, 10), (11, 20), (21, 30), (31, 40), (41, 60), (61, 100), (101, 1000)]
    lines += table(["optima", *[f"{lo}-{hi}" if hi < 1000 else f">{lo - 1}"
                                for lo, hi in edges]],
                   [["pairs", *[int(hist[lo:hi + 1].sum()) for lo, hi in edges]]])
    misses = [r for r in recs if r["gap"] > GAP_TOL]
    if misses:
        lines += ["", "Misses (start -> target, m: default T, best T):", ""]
        lines += [f"- {np.round(r['a'], 4).tolist()} -> {np.round(r['b'], 4).tolist()}: "
                  f"{r['res'].T:.6f} s ({r['res'].status.name}), {r['ref'].T:.6f} s"
                  for r in misses[:10]]
    targets = [
        (f"default multistart within {GAP_TOL:g} of the exhaustive best "
         f"(>= {100 * TARGET_HITS:.0f} %)", f"{len(hits)}/{n} "
         f"({100 * len(hits) / max(n, 1):.0f} %)"),
        (f"median default plan time (<= {TARGET_MEDIAN} s, under the run's load)",
         f"{statistics.median(t_def):.2f} s"),
    ]
    return Section(f"The best motion: default multistart against the exhaustive reference "
                   f"({n} pairs)", lines, targets)


def times(model, count: int) -> None:
    """Median plan time of the default and of the peer on the same pairs (printed)."""
    default = SolverOptions()
    pairs = draw_pairs(model, count, seed=SEED)
    plan(Problem(model, point(pairs[0][0]), point(pairs[0][1]), k=K), default)  # warm-up
    t_def, t_old, t_before = [], [], []
    for a, b in pairs:
        problem = Problem(model, point(a), point(b), k=K)
        t_def.append(timed(lambda p=problem: plan(p, default))[0])
        t_old.append(timed(lambda p=problem: plan(p, PEER))[0])
        t_before.append(timed(lambda p=problem: plan(p, BEFORE))[0])
    ratio = statistics.median(d / b for d, b in zip(t_def, t_before, strict=True))
    print(f"default plan time median {fmt_ms(statistics.median(t_def))} ms, p90 "
          f"{fmt_ms(float(np.percentile(t_def, 90)))} ms; peer (16x3) median "
          f"{fmt_ms(statistics.median(t_old))} ms; guess settings before (12 intervals, "
          f"tol 1e-8) median {fmt_ms(statistics.median(t_before))} ms, default / before "
          f"{ratio:.3f} (median of per-pair ratios); {count} pairs, load {os.getloadavg()}")


if __name__ == "__main__":
    from bench.common import paper_model

    if "--times" in sys.argv:
        times(paper_model(), int(sys.argv[1]))
        sys.exit(0)
    sec = run(paper_model(), int(sys.argv[1]) if len(sys.argv) > 1 else 100)
    print(f"## {sec.title}\n")
    print("\n".join(sec.lines))
    for target, verdict in sec.targets:
        print(f"- {target}: {verdict}")
