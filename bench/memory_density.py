"""How dense a memory must be for a hit to cost a few iterations (issue 50).

A hit re-solves the nearest stored motion warm (``core/memory/recall.py``); its work is set
by how far the request is from the stored one. The design proposed when 5 cm hits stayed at
30-100 IPOPT iterations was a denser memory (about 2 cm), built by continuation from the
coarse entries. This bench measures what such a memory would give before building it: for
``--count`` stored motions of a memory file (spread over its entries in id order), the
stored request's target moved by each of :data:`DISTANCES` in ``--directions`` random
directions (seeded), and the move re-solved from the entry's serving state exactly as
``recall`` re-solves a hit (``solve_once`` with ``warm_only``, the serving mesh,
``warm_far``: IPOPT from its distant start, the single parametric step first where the move
is at most ``FAR_STEP_MOVE`` sub-moves, 0.6 cm), and again from IPOPT's distant start
without the step (the warm state without its own problem: the move is not known). Before
session 39 a hit of one 2 cm sub-move or less kept the replans' start (the step, then
IPOPT's barrier from 1e-7): this bench measured that route at its *as recall* rows. Per
distance and start: how many converged and were certified, the route (``parametric`` or
``ipopt``), IPOPT iterations or Newton steps, the solve's time and its time per iteration,
how many NLP rows changed activity (multiplier above 1e-6 in one and not the other), and
``T``'s change against the stored motion's.

The 2 cm row is also what a continuation build pays per new entry (each new grid point
solved warm from a neighbour 2 cm away).

Command: ``scripts/dev run python -P bench/memory_density.py --memory FILE [--count N]
[--directions N] [--seed S]`` (FILE: a memory with serving states on 64 spans, e.g. the
memory benchmark's, ``bench/memory.py``; it is only read). Figures from one run are in
docs/memory.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import load_text, log, table  # noqa: E402

#: Target moves (m) measured.
DISTANCES = (0.005, 0.01, 0.02, 0.03, 0.05)
#: The report's names of the two starts.
START = {"recall": "as recall", "far": "distant, no step"}
#: A row is active where its multiplier's magnitude is above this.
ACTIVE = 1e-6


def _route(result) -> str:
    text = " ".join(result.warnings)
    return "parametric" if "(route: parametric)" in text else "ipopt"


def run(memory: Path, count: int, directions: int, seed: int) -> list[dict]:
    """One dict per (entry, distance, direction)."""
    from bench.limits import robots
    from tocontrol_ros.core import Planner, SolverOptions
    from tocontrol_ros.core.memory.codec import warm_result
    from tocontrol_ros.core.memory.recall import DEFAULT_SPANS, stored_problem
    from tocontrol_ros.core.memory.serve import serve_spans
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.planning.solver import solve_once
    from tocontrol_ros.core.types.problem import Problem, point

    model, limits = robots()["Panda"]
    planner = Planner(model)
    template = Problem(model, point([0.3, 0.0, 0.65]), point([0.5, 0.0, 0.35]), k=4.0,
                       reserve=0.1, limits=limits)
    options = replace(SolverOptions(), warm_only=True, replan_spans=DEFAULT_SPANS,
                      warm_far=True, time_limit=600.0)
    rng = np.random.default_rng(seed)
    rows, warmed = [], False
    with MotionStore(memory) as store:
        keys = store.keys()
        ids = sorted(int(i) for i in keys["id"])
        picked = [ids[int(j)] for j in np.linspace(0, len(ids) - 1, min(count, len(ids)))]
        for entry_id in picked:
            entry = store.get(entry_id)
            if entry.request.target_kind != "point" or \
                    serve_spans(entry.serve) != DEFAULT_SPANS:
                log(f"memory density: entry {entry_id} skipped (no serving state on "
                    f"{DEFAULT_SPANS} spans, or not a point target)")
                continue
            own = stored_problem(template, entry.request)
            warm = warm_result(own, "path", entry.serve, entry.method, f"entry {entry_id}")
            for d in DISTANCES:
                for _ in range(directions):
                    u = rng.normal(size=3)
                    target = np.asarray(entry.request.target, float) + d * u / np.linalg.norm(u)
                    problem = Problem(model, own.start, point(target), k=own.k,
                                      reserve=own.reserve, limits=own.limits)
                    if not warmed:  # the first call builds the serving mesh's transcription
                        solve_once(planner, problem, options, warm, None,
                                   time.perf_counter() + 600.0)
                        warmed = True
                    row = {"entry": entry_id, "d": d}
                    # As recall re-solves a hit; then from the distant start whatever the
                    # move (the warm state without its problem: the move is not known).
                    for name, start in (("recall", warm), ("far", replace(warm, problem=None))):
                        t0 = time.perf_counter()
                        res = solve_once(planner, problem, options, start, None,
                                         time.perf_counter() + 600.0)
                        total = time.perf_counter() - t0
                        col = {"total": total,
                               "ok": bool(res.success and res.certificate is not None
                                          and res.certificate.passed),
                               "route": _route(res), "work": int(res.iterations),
                               "solve": float(res.timings.get("shooting", np.nan)),
                               "dT": float(res.T) / float(entry.T) - 1.0 if res.success
                               else np.nan}
                        state = res.warm_state
                        if res.success and state is not None and \
                                getattr(state, "lam_g", None) is not None:
                            col["changed"] = int(np.sum(
                                (np.abs(state.lam_g) > ACTIVE)
                                != (np.abs(warm.warm_state.lam_g) > ACTIVE)))
                        row[name] = col
                    rows.append(row)
                    log(f"memory density: entry {entry_id} d {d * 100:.1f} cm: " + "; ".join(
                        f"{n} {'ok' if c['ok'] else 'failed'} {c['route']} {c['work']} in "
                        f"{c['total'] * 1e3:.0f} ms, changed {c.get('changed', '-')}"
                        for n, c in ((n, row[n]) for n in ("recall", "far"))))
    return rows


def report(rows: list[dict], load: tuple[str, str]) -> str:
    """The run as markdown: one row per distance."""
    def med(values, q=50):
        values = [v for v in values if np.isfinite(v)]
        return float(np.percentile(values, q)) if values else np.nan

    head = ["move (cm)", "start", "solves", "certified", "parametric route",
            "work median (min-max)", "solve median (ms)", "p95 (ms)", "ms per iteration",
            "rows changed median", "`T` change median |.|"]
    body = []
    for d, name in ((d, n) for d in DISTANCES for n in ("recall", "far")):
        sel = [r[name] for r in rows if r["d"] == d]
        if not sel:
            continue
        work = [r["work"] for r in sel]
        per = [r["solve"] / r["work"] * 1e3 for r in sel if r["work"] > 0]
        body.append([f"{d * 100:g}", START[name], str(len(sel)), f"{sum(r['ok'] for r in sel)}",
                     f"{sum(r['route'] == 'parametric' for r in sel)}",
                     f"{med(work):.0f} ({min(work)}-{max(work)})",
                     f"{med([r['solve'] for r in sel]) * 1e3:.0f}",
                     f"{med([r['solve'] for r in sel], 95) * 1e3:.0f}",
                     f"{med(per):.1f}",
                     f"{med([r.get('changed', np.nan) for r in sel]):.0f}",
                     f"{med([abs(r['dT']) for r in sel]):.1e}"])
    entries = len({r["entry"] for r in rows})
    return (f"{entries} stored motions, {len(rows)} moves; load average {load[0]} at the "
            f"start, {load[1]} at the end (two cores).\n\n" + "\n".join(table(head, body)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--memory", type=Path, required=True)
    parser.add_argument("--count", type=int, default=8, help="stored motions moved")
    parser.add_argument("--directions", type=int, default=3, help="moves per distance")
    parser.add_argument("--seed", type=int, default=50)
    args = parser.parse_args(argv)
    if not args.memory.is_file():
        parser.error(f"--memory: no file {args.memory}")
    start = load_text()
    rows = run(args.memory, args.count, args.directions, args.seed)
    print(report(rows, (start, load_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
