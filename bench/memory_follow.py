"""A memory's hits re-solved in process: IPOPT warm, its distant start, the walk (issue 50).

For each inside request of ``bench/memory_cell/requests.yaml`` with a stored motion within
the hit radius of a memory file (its serving states converted: ``memory upgrade``), the
nearest stored motion (one basin, as ``memory_first_success``) is re-solved warm through
the method contract (``solve_once``) on its serving mesh, side by side in one process:

- **today**: as a replan's warm start (``warm_far`` and ``warm_follow`` off: what a hit
  did before): one parametric step from the stored solution and its multipliers
  (core/direct/sensitivity.py), IPOPT warm (``warm="dual"``) where it does not converge;
- **far**: ``warm_far=True`` (what ``recall`` now asks): IPOPT warm from the stored
  solution and its multipliers with its barrier from 1e-5 and the start pushed as far into
  its bounds (``warm="dual_far"``), without the single parametric step;
- **walk**: ``warm_follow=True``: the stored request's parameters walked to the new ones in
  sub-moves of at most 2 cm, the parametric step per sub-move
  (core/direct/path_following.py), IPOPT warm from the stored state where the walk does not
  arrive.

Then the node's core call, ``recall`` with its defaults (two basins, the solution alone
after a failure from the multipliers), as before (``far=False``) and now. Each column: the
route (``parametric`` or ``ipopt``, read from the result's warnings),
success and certificate, ``T``, the work (IPOPT iterations or Newton steps), the solve
(``timings["shooting"]``), the certificate (``timings["verify"]``) and the whole call. Also
the lookup (distances and the choice over the file's keys), the decoding of the entry's
serving state, and how many NLP rows changed activity between the stored serving solution
and today's answer (multiplier above 1e-6 in one and not the other: why a 2-8 cm move is
not a small perturbation). With ``--cold`` the default cold plan of each request too (the
full multistart: 15-60 s each on two shared cores), the reference of the issue's 1e-3.

Command: ``scripts/dev run python -P bench/memory_follow.py --memory FILE [--count N]
[--cold] [--spans N]`` (FILE: a copy; it is only read). Figures from one run are in
docs/memory.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import load_text, log, table  # noqa: E402

REQUESTS = Path(__file__).resolve().parent / "memory_cell" / "requests.yaml"
#: A row is active where its multiplier's magnitude is above this.
ACTIVE = 1e-6


def _route(result) -> str:
    text = " ".join(result.warnings)
    return "parametric" if "(route: parametric)" in text else \
        "ipopt" if "(route: ipopt)" in text else "none"


def _active(lam) -> np.ndarray:
    return np.abs(np.asarray(lam, dtype=float)) > ACTIVE


def run(memory: Path, count: int, cold: bool, spans: int = 0) -> list[dict]:
    """The hits' rows (one dict per hit)."""
    from bench.limits import robots
    from tocontrol_ros.core import Planner, SolverOptions
    from tocontrol_ros.core.memory.codec import warm_result
    from tocontrol_ros.core.memory.recall import (
        DEFAULT_RADIUS,
        DEFAULT_SPANS,
        choose,
        distances,
        recall,
        stored_problem,
    )
    from tocontrol_ros.core.memory.serve import serve_spans
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.planning.solver import solve_once
    from tocontrol_ros.core.types.problem import Problem, point

    model, limits = robots()["Panda"]
    planner = Planner(model)
    requests = yaml.safe_load(REQUESTS.read_text())
    stations = {k: v["point"] for k, v in requests["stations"].items()}
    base = SolverOptions()
    spans = spans or DEFAULT_SPANS
    rows, warmed = [], False
    with MotionStore(memory) as store:
        for case, req in enumerate(requests["inside"][:count], start=1):
            problem = Problem(model, point(stations[req["start"]]), point(req["target"]),
                              k=4.0, reserve=0.1, limits=limits)
            t0 = time.perf_counter()
            keys = store.keys()
            dist = distances(keys, problem, base.warm_joint_radius)
            chosen = choose(keys, dist, DEFAULT_RADIUS, 1)
            t_lookup = time.perf_counter() - t0
            if not chosen:
                log(f"memory follow {case}: miss (d {float(dist.min()):.3g})")
                continue
            i = chosen[0]
            t1 = time.perf_counter()
            entry = store.get(int(keys["id"][i]))
            if entry.serve is None:
                log(f"memory follow {case}: entry {entry.id} has no serving state")
                continue
            if serve_spans(entry.serve) != spans:
                log(f"memory follow {case}: entry {entry.id} served on "
                    f"{serve_spans(entry.serve)} spans, not {spans}")
                continue
            warm = warm_result(stored_problem(problem, entry.request), "path", entry.serve,
                               entry.method, f"entry {entry.id}")
            t_decode = time.perf_counter() - t1
            row = {"case": case, "d": float(dist[i]), "lookup": t_lookup, "decode": t_decode}
            for name, follow, far in (("today", False, False), ("far", False, True),
                                      ("walk", True, False)):
                options = replace(base, warm_only=True, replan_spans=spans,
                                  warm_follow=follow, warm_far=far, time_limit=600.0)
                if not warmed:  # the first call builds the serving mesh's transcription
                    solve_once(planner, problem, options, warm, None,
                               time.perf_counter() + 600.0)
                    warmed = True
                t2 = time.perf_counter()
                res = solve_once(planner, problem, options, warm, None,
                                 time.perf_counter() + 600.0)
                total = time.perf_counter() - t2
                row[name] = {"ok": bool(res.success and res.certificate is not None
                                        and res.certificate.passed),
                             "route": _route(res), "T": float(res.T),
                             "work": int(res.iterations),
                             "solve": float(res.timings.get("shooting", np.nan)),
                             "verify": float(res.timings.get("verify", np.nan)),
                             "total": total}
                if name == "today" and res.success and res.warm_state is not None \
                        and res.warm_state.lam_g is not None:
                    row["changed"] = int(np.sum(_active(res.warm_state.lam_g)
                                                != _active(warm.warm_state.lam_g)))
                    row["rows"] = len(res.warm_state.lam_g)
            for name, far in (("recall before", False), ("recall", True)):
                # The node's core call (two basins, the solution alone after a failure).
                t2 = time.perf_counter()
                found = recall(planner, problem, replace(base, time_limit=600.0), store,
                               spans=spans, far=far)
                total = time.perf_counter() - t2
                res = found.result
                row[name] = {"ok": bool(res is not None and res.success),
                             "T": float(res.T) if res is not None else np.nan,
                             "work": int(found.iterations), "total": total}
            if cold:
                ref = planner.plan(problem, base)
                row["cold"] = float(ref.T) if ref.success else np.nan
            rows.append(row)
            log(f"memory follow {case}: d {row['d']:.3g} "
                + " | ".join(f"{k} {row[k].get('route', '')} {row[k]['total']:.3f} s T "
                             f"{row[k]['T']:.6f}" for k in ("today", "far", "walk",
                                                            "recall before", "recall")))
    return rows


def report(rows: list[dict], load: tuple[str, str]) -> str:
    """The run as markdown: a summary and a row per hit."""
    def med(values):
        values = [v for v in values if np.isfinite(v)]
        return float(np.median(values)) if values else np.nan

    lines = [f"Load average {load[0]} at the start, {load[1]} at the end (two cores "
             f"shared); {len(rows)} hits."]
    for name in ("today", "far", "walk"):
        cols = [r[name] for r in rows]
        para = sum(c["route"] == "parametric" for c in cols)
        lines.append(f"- **{name}**: certified {sum(c['ok'] for c in cols)}/{len(cols)}, "
                     f"parametric route {para}/{len(cols)}; work median "
                     f"{med([c['work'] for c in cols]):.0f}, sum "
                     f"{sum(c['work'] for c in cols)}; whole call median "
                     f"{med([c['total'] for c in cols]) * 1e3:.0f} ms, solve "
                     f"{med([c['solve'] for c in cols]) * 1e3:.0f} ms, certificate "
                     f"{med([c['verify'] for c in cols]) * 1e3:.1f} ms.")
    for name in ("recall before", "recall"):
        cols = [r[name] for r in rows]
        within = ""
        if any("cold" in r for r in rows):
            gaps = [r[name]["T"] / r["cold"] - 1 for r in rows if "cold" in r]
            within = (f"; `T` within 1e-3 of the cold plan's (or below) "
                      f"{sum(bool(g <= 1e-3) for g in gaps)}/{len(gaps)}, worst "
                      f"{np.nanmax(gaps):+.1e}")
        lines.append(f"- **{name}** (two basins): answered {sum(c['ok'] for c in cols)}/"
                     f"{len(cols)}; IPOPT iterations median {med([c['work'] for c in cols]):.0f}"
                     f"; whole call median {med([c['total'] for c in cols]) * 1e3:.0f} ms, "
                     f"p95 {np.nanpercentile([c['total'] for c in cols], 95) * 1e3:.0f} ms"
                     f"{within}.")
    lines.append(f"- lookup median {med([r['lookup'] for r in rows]) * 1e3:.1f} ms, decoding "
                 f"{med([r['decode'] for r in rows]) * 1e3:.1f} ms; rows that changed "
                 f"activity (of {rows[0].get('rows', 0) if rows else 0}) median "
                 f"{med([r.get('changed', np.nan) for r in rows]):.0f}.")
    head = ["case", "d", "changed", "today route", "it", "today ms", "far it", "far ms",
            "walk route", "steps", "walk ms", "T today", "far/today - 1", "walk/today - 1",
            "recall before ms", "recall ms", "recall T"]
    if any("cold" in r for r in rows):
        head += ["recall before/cold - 1", "recall/cold - 1"]
    body = []
    for r in rows:
        a, f, b = r["today"], r["far"], r["walk"]
        rb, rn = r["recall before"], r["recall"]
        line = [str(r["case"]), f"{r['d']:.2f}", str(r.get("changed", "")),
                a["route"] + ("" if a["ok"] else " (failed)"), str(a["work"]),
                f"{a['total'] * 1e3:.0f}", str(f["work"]) + ("" if f["ok"] else " (failed)"),
                f"{f['total'] * 1e3:.0f}", b["route"] + ("" if b["ok"] else " (failed)"),
                str(b["work"]), f"{b['total'] * 1e3:.0f}", f"{a['T']:.6f}",
                f"{f['T'] / a['T'] - 1:+.1e}", f"{b['T'] / a['T'] - 1:+.1e}",
                f"{rb['total'] * 1e3:.0f}", f"{rn['total'] * 1e3:.0f}", f"{rn['T']:.6f}"]
        if "cold" in r:
            line += [f"{rb['T'] / r['cold'] - 1:+.1e}", f"{rn['T'] / r['cold'] - 1:+.1e}"]
        body.append(line)
    return "\n".join(lines) + "\n\n" + "\n".join(table(head, body))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--memory", type=Path, required=True)
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--cold", action="store_true")
    parser.add_argument("--spans", type=int, default=0,
                        help="the serving mesh (default: memory_spans' 64); the file's "
                             "serving states must be on it (memory upgrade --spans N)")
    args = parser.parse_args(argv)
    if not args.memory.is_file():
        parser.error(f"--memory: no file {args.memory}")
    start = load_text()
    rows = run(args.memory, args.count, args.cold, args.spans)
    print(report(rows, (start, load_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
