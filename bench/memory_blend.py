"""A hit's warm start from a blend of its stored neighbours against the nearest's (issue 50).

For each request of a requests file (default ``bench/memory_cell/blend_requests.yaml``, the
small cell ``blend_cell.yaml``'s) with a stored motion within the hit radius of a memory
file (serving states on the serving mesh: ``memory build`` stores them, ``memory upgrade``
converts an old file), the nearest basin's hit is re-solved warm through the method contract
(``solve_once``) on the serving mesh from several starts, side by side in one process:

- **nearest**: the nearest stored motion's serving state and its multipliers, as ``recall``
  does today (``warm_far``: IPOPT's barrier from 1e-5 beyond one 2 cm sub-move);
- **lin K**: the local linear fit of the solution (control points, ``T``, multipliers)
  against the requests' parameters over the K nearest stored motions of the nearest's basin
  (``bench/neighbour_blend.py``), then IPOPT as the nearest's (``warm_far``);
- **idw K**: inverse squared distance weights over the same neighbours;
- variants: multipliers from the nearest (``/lam near``), the replans' start (``/dual``:
  barrier from 1e-7, no step), the parametric step from the blend before IPOPT (``/step``),
  the basin widened to 1.5 rad (``b1.5``) or dropped (``all``: across basins);
- **patch lin / patch idw**: the neighbours made to lie in the nearest's basin: each stored
  motion within 10 cm of the nearest (a 10 cm grid's axis neighbours) re-solved warm from
  the nearest's serving state (offline work, not in the hit's time; logged with its
  iterations and its ``T`` against the stored one), then blended with the nearest.

Each column: converged and certified, IPOPT iterations (the load-independent figure),
``T``, the whole call. Before any solve, how far each prediction is from the answer the
nearest's route converged to (``T`` relative, the control points' largest difference in
rad, NLP rows whose activity differs): what a blend buys before IPOPT starts. With
``--cold`` the default cold plan (the full multistart) of each request, the reference of
the issue's 1e-3.

Command: ``scripts/dev run python -P bench/memory_blend.py --memory FILE [--count N]
[--cold] [--requests YAML] [--only NAME ...]`` (FILE is only read; e.g. the small cell's
memory built with ``ros2 run tocontrol_ros memory build bench/memory_cell/blend_cell.yaml
FILE``, 27 motions in about 4 minutes on the two shared cores). Figures of one run are
in docs/memory.md.
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
from bench.neighbour_blend import basin_rows, blend_states, features  # noqa: E402

REQUESTS = Path(__file__).resolve().parent / "memory_cell" / "blend_requests.yaml"
#: A row is active where its multiplier's magnitude is above this (as memory_follow.py).
ACTIVE = 1e-6
#: (name, how, neighbours, multipliers, warm_far, parametric step, basin radius (rad;
#: None: BASIN_RADIUS, inf: every kind-matching neighbour, across basins))
VARIANTS = (
    ("nearest", None, 1, "blend", True, False, None),
    ("lin 8", "linear", 8, "blend", True, False, None),
    ("lin 8/lam near", "linear", 8, "nearest", True, False, None),
    ("lin 8/dual", "linear", 8, "blend", False, False, None),
    ("lin 8/step", "linear", 8, "blend", False, True, None),
    ("lin 4", "linear", 4, "blend", True, False, None),
    ("idw 8", "idw", 8, "blend", True, False, None),
    ("lin 8 b1.5", "linear", 8, "blend", True, False, 1.5),
    ("idw 8 b1.5", "idw", 8, "blend", True, False, 1.5),
    ("lin 8 all", "linear", 8, "blend", True, False, np.inf),
    ("idw 8 all", "idw", 8, "blend", True, False, np.inf),
    ("patch lin", "linear", 7, "blend", True, False, "patch"),
    ("patch lin/lam near", "linear", 7, "nearest", True, False, "patch"),
    ("patch idw", "idw", 7, "blend", True, False, "patch"),
)
#: The patch (``radius`` "patch"): the nearest's stored neighbours at most this far from it
#: (warm units: 1.05 takes a 10 cm grid's axis neighbours), each re-solved warm from the
#: nearest's serving state (offline work: in the nearest's basin by construction).
PATCH_RADIUS = 1.05


def _active(lam) -> np.ndarray:
    return np.abs(np.asarray(lam, dtype=float)) > ACTIVE


def run(memory: Path, requests_file: Path, count: int, cold: bool,
        names: tuple[str, ...] = ()) -> list[dict]:
    """The hits' rows (one dict per hit)."""
    from bench.limits import robots
    from tocontrol_ros.core import Planner, SolverOptions
    from tocontrol_ros.core.memory.codec import warm_result
    from tocontrol_ros.core.memory.recall import (
        BASIN_RADIUS,
        DEFAULT_RADIUS,
        DEFAULT_SPANS,
        choose,
        distances,
        stored_problem,
    )
    from tocontrol_ros.core.memory.store import MotionStore
    from tocontrol_ros.core.planning.solver import solve_once
    from tocontrol_ros.core.types.problem import Problem, point

    variants = [v for v in VARIANTS if not names or v[0] in names]
    model, limits = robots()["Panda"]
    planner = Planner(model)
    requests = yaml.safe_load(requests_file.read_text())
    stations = {k: v["point"] for k, v in requests["stations"].items()}
    base = SolverOptions()
    rows, warmed, states, patches = [], set(), {}, {}
    far_options = replace(base, warm_only=True, replan_spans=DEFAULT_SPANS, warm_far=True,
                          time_limit=600.0)
    with MotionStore(memory) as store:
        keys = store.keys()

        def state(i, problem):
            if i not in states:
                entry = store.get(int(keys["id"][i]))
                states[i] = warm_result(stored_problem(problem, entry.request), "path",
                                        entry.serve, entry.method, f"entry {entry.id}")
            return states[i]

        def patch(i0, problem, served, X):
            """The nearest's neighbours continued from it: ``(rows, states, stats)``."""
            if i0 in patches:
                return patches[i0]
            x0 = X[served.index(i0)]
            got, its, gaps = [i0], [], []
            out = [state(i0, problem).warm_state]
            for j, i in enumerate(served):
                if i == i0 or np.linalg.norm(X[j] - x0) > PATCH_RADIUS:
                    continue
                own = state(i, problem).problem
                res = solve_once(planner, own, far_options, state(i0, problem), None,
                                 time.perf_counter() + 600.0)
                its.append(int(res.iterations))
                if res.success and res.certificate is not None and res.certificate.passed \
                        and res.warm_state is not None and res.warm_state.lam_g is not None:
                    got.append(i)
                    out.append(res.warm_state)
                    gaps.append(float(res.T / keys["T"][i] - 1.0))
            patches[i0] = (got, out, {"tried": len(its), "its": its, "gaps": gaps})
            log(f"patch of entry {int(keys['id'][i0])}: {len(got) - 1}/{len(its)} "
                f"neighbours continued ({sum(its)} iterations), T against their stored: "
                + ", ".join(f"{g:+.1e}" for g in gaps))
            return patches[i0]
        for case, req in enumerate(requests["inside"][:count], start=1):
            problem = Problem(model, point(stations[req["start"]]), point(req["target"]),
                              k=4.0, reserve=0.1, limits=limits)
            dist = distances(keys, problem, base.warm_joint_radius)
            chosen = choose(keys, dist, DEFAULT_RADIUS, 1)
            if not chosen:
                log(f"memory blend {case}: miss (d {float(dist.min()):.3g})")
                continue
            i0 = chosen[0]
            served = [i for i in range(len(keys["id"])) if keys["serve"][i]
                      and np.isfinite(dist[i])]
            X, x = features(keys, served, problem, base.warm_joint_radius)
            orders = {b: basin_rows(keys, dist, i0, X, x, served, 12, b)
                      for b in {v[6] or BASIN_RADIUS for v in variants} if b != "patch"}
            for i in sorted({i for o in orders.values() for i in o}):
                state(i, problem)
            warm0 = state(i0, problem)
            if len(warm0.warm_state.breaks) - 1 != DEFAULT_SPANS:
                log(f"memory blend {case}: the nearest is not on {DEFAULT_SPANS} spans")
                continue
            row = {"case": case, "d": float(dist[i0]),
                   "basin": len(basin_rows(keys, dist, i0, X, x, served, 8, BASIN_RADIUS))}
            for name, how, k, lam, far, step, radius in variants:
                t1 = time.perf_counter()
                if how is None:
                    warm = warm0
                elif radius == "patch":
                    got, sts, stats = patch(i0, problem, served, X)
                    row["patch"] = len(got)
                    st = blend_states(sts[:k], X[[served.index(i) for i in got[:k]]], x, how,
                                      lam)
                    warm = replace(warm0, warm_state=st, T=st.T)
                    t1 = time.perf_counter()
                else:
                    order = orders[radius or BASIN_RADIUS][:k]
                    st = blend_states([states[i].warm_state for i in order],
                                      X[[served.index(i) for i in order]], x, how, lam)
                    warm = replace(warm0, warm_state=st, T=st.T)
                t_blend = time.perf_counter() - t1
                options = replace(base, warm_only=True, replan_spans=DEFAULT_SPANS,
                                  warm_far=far, warm_parametric=step, time_limit=600.0)
                mode = (far, step, lam == "none")
                if mode not in warmed:  # the first call builds this start's transcription
                    solve_once(planner, problem, options, warm, None,
                               time.perf_counter() + 600.0)
                    warmed.add(mode)
                t2 = time.perf_counter()
                res = solve_once(planner, problem, options, warm, None,
                                 time.perf_counter() + 600.0)
                total = time.perf_counter() - t2 + t_blend
                row[name] = {"ok": bool(res.success and res.certificate is not None
                                        and res.certificate.passed),
                             "T": float(res.T), "it": int(res.iterations), "total": total,
                             "blend": t_blend, "pred": warm.warm_state,
                             "state": res.warm_state if res.success else None}
            ans = next((row[name] for name, *_ in variants if row[name]["ok"]), None)
            for name, *_ in variants:  # how far each start is from the converged answer
                pred, got = row[name]["pred"], ans["state"] if ans is not None else None
                if got is None:
                    continue
                row[name]["dT"] = float(pred.T / got.T - 1.0)
                row[name]["dP"] = float(np.max(np.abs(pred.P - got.P)))
                if pred.lam_g is not None and got.lam_g is not None:
                    row[name]["changed"] = int(np.sum(_active(pred.lam_g)
                                                      != _active(got.lam_g)))
            if cold:
                t3 = time.perf_counter()
                cold_res = planner.plan(problem, base)
                row["cold"] = float(cold_res.T) if cold_res.success else np.nan
                row["cold_s"] = time.perf_counter() - t3
            for name, *_ in variants:
                row[name].pop("pred", None)
                row[name].pop("state", None)
            rows.append(row)
            log(f"memory blend {case}: d {row['d']:.3g}, basin {row['basin']} | "
                + " | ".join(f"{name} {row[name]['it']}{'' if row[name]['ok'] else '!'} "
                             f"{row[name]['total'] * 1e3:.0f} ms T {row[name]['T']:.6f}"
                             for name, *_ in variants)
                + (f" | cold T {row['cold']:.6f}" if cold else ""))
    return rows


def neighbours(memory: Path, spacing: float = 0.1) -> str:
    """How alike the stored motions of grid neighbours are (no solve): a line of markdown.

    Pairs of stored motions with the same start whose targets are ``spacing`` (m) apart:
    their end configurations' distance (max-norm, rad; within ``BASIN_RADIUS``: one basin by
    ``recall``'s rule), the NLP rows whose activity differs between their serving states and
    the relative difference of their ``T``.
    """
    from tocontrol_ros.core.memory.codec import decode_warm
    from tocontrol_ros.core.memory.recall import BASIN_RADIUS
    from tocontrol_ros.core.memory.store import MotionStore

    with MotionStore(memory) as store:
        keys = store.keys()
        lam = {i: decode_warm("path", store.get(int(e)).serve)[0].lam_g
               for i, e in enumerate(keys["id"]) if keys["serve"][i]}
    dq, changed, dT = [], [], []
    E = len(keys["id"])
    for i in range(E):
        for j in range(i + 1, E):
            if np.linalg.norm(keys["start_point"][i] - keys["start_point"][j]) > 1e-9 or \
                    abs(np.linalg.norm(keys["target_point"][i] - keys["target_point"][j])
                        - spacing) > 1e-6:
                continue
            dq.append(float(np.max(np.abs(keys["end_q"][i] - keys["end_q"][j]))))
            dT.append(abs(keys["T"][i] / keys["T"][j] - 1.0))
            if i in lam and j in lam:
                changed.append(int(np.sum(_active(lam[i]) != _active(lam[j]))))
    if not dq:
        return f"No stored pairs {spacing} m apart."
    dq, rows = np.array(dq), len(next(iter(lam.values())))
    return (f"{len(dq)} pairs of stored motions {spacing * 100:.0f} cm apart: end "
            f"configurations {np.min(dq):.2f}-{np.max(dq):.2f} rad apart (median "
            f"{np.median(dq):.2f}), within {BASIN_RADIUS} rad (one basin) "
            f"{np.sum(dq <= BASIN_RADIUS)}, within 1.5 rad {np.sum(dq <= 1.5)}; rows of other "
            f"activity median {np.median(changed):.0f} ({min(changed)}-{max(changed)}, of "
            f"{rows}); `T` differs by a median {np.median(dT):.1%}.")


def report(rows: list[dict], load: tuple[str, str], names: list[str]) -> str:
    """The run as markdown: a summary per start and a row per hit."""
    def med(values):
        values = [v for v in values if np.isfinite(v)]
        return float(np.median(values)) if values else np.nan

    lines = [f"Load average {load[0]} at the start, {load[1]} at the end (two cores "
             f"shared); {len(rows)} hits."]
    base = names[0]
    for name in names:
        cols = [r[name] for r in rows]
        ok = [c for c in cols if c["ok"]]
        gap = ""
        if rows and "cold" in rows[0]:
            gaps = [r[name]["T"] / r["cold"] - 1 for r in rows if r[name]["ok"]]
            gap = (f"; `T` within 1e-3 of the cold plan's (or below) "
                   f"{sum(bool(g <= 1e-3) for g in gaps)}/{len(cols)}, worst "
                   f"{max(gaps) if gaps else np.nan:+.1e}")
        same = [r[name]["T"] / r[base]["T"] - 1 for r in rows
                if r[name]["ok"] and r[base]["ok"]]
        lines.append(
            f"- **{name}**: certified {len(ok)}/{len(cols)}; IPOPT iterations median "
            f"{med([c['it'] for c in cols]):.0f}, sum {sum(c['it'] for c in cols)}; whole "
            f"call median {med([c['total'] for c in cols]) * 1e3:.0f} ms (blend "
            f"{med([c['blend'] for c in cols]) * 1e3:.1f} ms); the start against the "
            f"answer: T off by a median {med([abs(c.get('dT', np.nan)) for c in cols]):.1e}"
            f", control points by {med([c.get('dP', np.nan) for c in cols]):.3f} rad, rows "
            f"of other activity {med([c.get('changed', np.nan) for c in cols]):.0f}; `T` against "
            f"{base}'s: worst {max(same) if same else np.nan:+.1e}, best "
            f"{min(same) if same else np.nan:+.1e}{gap}.")
    head = ["case", "d", "basin", "patch"] + [f"{n} it" for n in names] + ["T " + base] + \
        [f"{n} T/{base} - 1" for n in names[1:]]
    if rows and "cold" in rows[0]:
        head += [f"{base}/cold - 1", "cold s"]
    body = []
    for r in rows:
        line = [str(r["case"]), f"{r['d']:.2f}", str(r["basin"]), str(r.get("patch", ""))]
        line += [f"{r[n]['it']}" + ("" if r[n]["ok"] else " (failed)") for n in names]
        line += [f"{r[base]['T']:.6f}"]
        line += [f"{r[n]['T'] / r[base]['T'] - 1:+.1e}" for n in names[1:]]
        if "cold" in r:
            line += [f"{r[base]['T'] / r['cold'] - 1:+.1e}", f"{r['cold_s']:.1f}"]
        body.append(line)
    return "\n".join(lines) + "\n\n" + "\n".join(table(head, body))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--memory", type=Path, required=True)
    parser.add_argument("--requests", type=Path, default=REQUESTS)
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--cold", action="store_true")
    parser.add_argument("--only", nargs="*", default=(),
                        help="the starts to compare (names of VARIANTS; the first is the base)")
    parser.add_argument("--spacing", type=float, default=0.1,
                        help="the memory's grid (m), for the neighbours' figures")
    args = parser.parse_args(argv)
    if not args.memory.is_file():
        parser.error(f"--memory: no file {args.memory}")
    print(neighbours(args.memory, args.spacing))
    if args.count <= 0:
        return 0
    start = load_text()
    names = [v[0] for v in VARIANTS if not args.only or v[0] in args.only]
    rows = run(args.memory, args.requests, args.count, args.cold, tuple(args.only))
    print(report(rows, (start, load_text()), names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
