"""A seeded set of random start/target pairs of the paper's arm at k = 4.

Points are drawn uniformly in area over the annulus 0.5 <= |p| <= 5.3 m (the arm reaches
5.5 m and every point inside), pairs at least 0.2 m apart, from ``numpy.random.default_rng``
with a fixed seed. Each pair is solved twice: one start (``starts=1, candidates=1``) and the
multistart; both ``verify=False`` and a 30 s time limit, then the multistart's solution is
verified (re-integration) apart from the timing.
"""

import statistics

import numpy as np

from bench.common import Section, fmt_ms, log, table, timed
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.planning.solver import SolverOptions, plan, verify
from tocontrol_ros.core.types.problem import Problem, point

SEED = 20240607
K = 4.0
R_MIN, R_MAX = 0.5, 5.3
MIN_DISTANCE = 0.2
TIME_LIMIT = 30.0


def draw_pairs(model, count, seed=SEED):
    rng = np.random.default_rng(seed)
    pairs = []
    while len(pairs) < count:
        r = np.sqrt(rng.uniform(R_MIN ** 2, R_MAX ** 2, 2))
        a = rng.uniform(-np.pi, np.pi, 2)
        p = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
        if np.linalg.norm(p[0] - p[1]) <= MIN_DISTANCE:
            continue
        try:
            Problem(model, point(p[0]), point(p[1]), k=K)
        except ProblemError:  # not expected inside the disc of reach; skip if it happens
            continue
        pairs.append((p[0], p[1]))
    return pairs


def _pct(values, q):
    return float(np.percentile(values, q)) if values else float("nan")


def run(model, count, starts, candidates):
    pairs = draw_pairs(model, count)
    one_opts = SolverOptions(starts=1, candidates=1, verify=False, time_limit=TIME_LIMIT)
    multi_opts = SolverOptions(starts=starts, candidates=candidates, verify=False,
                               time_limit=TIME_LIMIT)
    recs = []
    for i, (a, b) in enumerate(pairs):
        problem = Problem(model, point(a), point(b), k=K)
        t1, one = timed(lambda p=problem: plan(p, one_opts))
        tm, multi = timed(lambda p=problem: plan(p, multi_opts))
        checks, tv = {}, float("nan")
        if multi.success:
            tv, checks = timed(lambda p=problem, r=multi: verify(p, r.trajectory))
        verified = bool(multi.success and checks.get("point_error", 1) <= 1e-4
                        and checks.get("velocity_error", 1) <= 1e-3)
        from_first = any(s.index == 0 and s.status == "returned" for s in multi.starts)
        recs.append({"a": a, "b": b, "one": one, "multi": multi, "t_one": t1, "t_multi": tm,
                     "t_verify": tv, "verified": verified, "from_first": from_first,
                     "checks": checks})
        log(f"random {i + 1}/{len(pairs)}: {np.round(a, 3)} -> {np.round(b, 3)}: one "
            f"{one.status.name} {one.T:.4f} ({t1:.2f} s), multi {multi.status.name} "
            f"{multi.T:.4f} ({tm:.2f} s), verified {verified}")
    return _section(recs, starts, candidates, count)


def _section(recs, starts, candidates, count):
    n = len(recs)
    ok_multi = [r for r in recs if r["multi"].success]
    ok_one = [r for r in recs if r["one"].success]
    verified = [r for r in recs if r["verified"]]
    both = [r for r in recs if r["one"].success and r["multi"].success]
    gains = [(r["one"].T - r["multi"].T) / r["one"].T for r in both]
    better = [g for g in gains if g > 1e-6]
    worse = [g for g in gains if g < -1e-6]
    first = [r for r in ok_multi if r["from_first"]]
    fails = {}
    for label, key in (("one start", "one"), ("multistart", "multi")):
        for r in recs:
            res = r[key]
            if not res.success:
                fails.setdefault((label, res.message.split(":")[0]), []).append(r)

    def dist(key, subset):
        v = [r[key] for r in subset]
        if not v:
            return ["—"] * 4
        return [fmt_ms(statistics.median(v)), fmt_ms(_pct(v, 90)), fmt_ms(max(v)),
                fmt_ms(min(v))]

    lines = [
        f"{n} pairs (seed {SEED}), k = {K:g}, points uniform in area over "
        f"{R_MIN} <= |p| <= {R_MAX} m, at least {MIN_DISTANCE} m apart. Multistart here: "
        f"`starts={starts}, candidates={candidates}`"
        + (" (the solver's default)" if (starts, candidates) == (16, 3) else
           " (cheaper than the default 16x3, to fit the run's time budget)")
        + f"; time limit {TIME_LIMIT:g} s per solve; `verify=False` in the timed solve, the "
        "re-integration check afterwards.",
        "",
    ]
    lines += table(["", "one start", "multistart"], [
        ["success (converged)", f"{len(ok_one)}/{n}", f"{len(ok_multi)}/{n}"],
        ["verified (re-integration within 1e-4 m, 1e-3 rad/s)", "—",
         f"{len(verified)}/{n}"],
        ["solve time median / p90 / max / min (ms), successes", " / ".join(dist("t_one",
                                                                                 ok_one)),
         " / ".join(dist("t_multi", ok_multi))],
        ["solve time median / p90 / max (ms), all", " / ".join(dist("t_one", recs)[:3]),
         " / ".join(dist("t_multi", recs)[:3])],
        ["Newton iterations median / max",
         _it(ok_one, "one"), _it(ok_multi, "multi")],
    ])
    lines += [
        "",
        f"Multistart against the first start (both solved: {len(both)} pairs): it returned "
        f"the first seed pair's solution in {len(first)} of {len(ok_multi)} successes; it "
        f"found a shorter T than the single start in {len(better)} pairs "
        + (f"(by {100 * statistics.median(better):.1f} % median, "
           f"{100 * max(better):.1f} % at most)" if better else "")
        + (f"; a longer one in {len(worse)} (by {100 * max(-g for g in worse):.2g} % at "
           "most: the single start continued a seed the multistart ranked out)"
           if worse else "")
        + f". Mean T gain over all {len(both)}: "
        + (f"{100 * statistics.mean(gains):.2f} %." if gains else "—."),
        "",
    ]
    if fails:
        lines += ["Failures (the message of the first pair of each kind in the last column):",
                  ""]
        lines += table(["solve", "status", "count", "pairs (start -> target, m)", "message"], [
            [label, status, len(rs), "; ".join(
                f"{np.round(r['a'], 4).tolist()} -> {np.round(r['b'], 4).tolist()}"
                for r in rs[:4]) + (" ..." if len(rs) > 4 else ""),
             rs[0]["one" if label == "one start" else "multi"].message]
            for (label, status), rs in sorted(fails.items())])
    else:
        lines.append("No failures.")
    unverified = [r for r in ok_multi if not r["verified"]]
    if unverified:
        lines += ["", f"Converged but not verified: {len(unverified)} (" + "; ".join(
            f"{np.round(r['a'], 4).tolist()} -> {np.round(r['b'], 4).tolist()}: T "
            f"{r['multi'].T:.6f} s, re-integrated end point off by "
            f"{r['checks'].get('point_error', float('nan')):.2g} m, end velocity "
            f"{r['checks'].get('velocity_error', float('nan')):.2g}, max |H| "
            f"{r['checks'].get('max_abs_H', float('nan')):.2g}, {r['multi'].intervals} "
            f"intervals" for r in unverified[:4]) + ")."]
    tv = [r["t_verify"] for r in ok_multi]
    if tv:
        lines += ["", f"Verification alone (DOP853 re-integration): median "
                  f"{fmt_ms(statistics.median(tv))} ms per solution."]
    target = ("random pairs: success rate (multistart, verified)",
              f"{len(verified)}/{n} ({100 * len(verified) / max(n, 1):.0f} %)")
    return Section(f"Random start/target pairs of the paper's arm ({count})", lines, [target])


def _it(rs, key):
    v = [r[key].iterations for r in rs]
    return f"{statistics.median(v):g} / {max(v)}" if v else "—"
