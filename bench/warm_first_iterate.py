"""Is a parametric step's iterate already a motion to publish? bench/warm_resolve.py's 20 moves.

Issue 47's real-time iterations (docs/limits.md, "Answering at the first feasible iterate"):
the same 20 Panda cases, serving solutions and 2 cm moves as ``bench/warm_resolve.py``
(``bench/warm_pad_rows.py``'s draw; ``--cache FILE`` pickles them on the first run and reads
them back on the next). Each move is answered by ``Planner.plan(moved, replan options,
warm_start=serving)`` (the route: the whole move, a pad round, the sub-moves, IPOPT), and
every Newton iterate of its parametric solves that is not an answer is recorded
(``sensitivity_solve``'s ``on_step``). Per iterate: the largest violation of the NLP's rows
and bounds, ``T``'s gap to IPOPT's converged re-solve of the same NLP (the pads per sample
read off the serving solution), and where the violation is within ``RESIDUAL_TOL`` whether
it is a motion to publish: inside the set between the samples (slowed down by the time
stretch where needed) and certified (``checked.FirstIterate``'s checks, every iterate
tried). And the cheap restorations of a nearly feasible iterate (violation within
``RESTORE_FROM``): one Gauss-Newton step on the violated rows alone at fixed ``T``
(minimum-norm, the control points only), then the same checks.

In the same process, the route with ``on_first`` at each of :data:`TRIES` (values of
``checked.FIRST_TRIES``): the time from the call to the first motion (its checks
included), its ``T`` gap, the time to the answer, and that the answer is the one without
``on_first`` to the bit.

With ``--timed N``, only the timing: main's route (no ``on_first``) and the call with it
under each of :data:`VARIANTS` (``checked.FIRST_TRIES``, ``checked.FIRST_STRETCH``),
alternated ``N`` times per case after one round each (:func:`paired_timing`).

Command: ``scripts/dev run python -P bench/warm_first_iterate.py [--cache FILE] [--timed N]
[cases]``.
"""

from __future__ import annotations

import pickle
import sys
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

#: Iterates whose violation is at most this get the restoration step.
RESTORE_FROM = 1e-2
#: ``checked.FIRST_TRIES`` values tried (the shipped one is also the default of the run).
TRIES = (1, 2, 3, 99)


def load(cache: Path | None, count: int) -> tuple:
    """The planner, replan options and ``(moved, serving)`` cases (bench/warm_pad_rows.py's)."""
    from bench.warm_pad_rows import build
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.types.options import SolverOptions

    if cache is not None and cache.exists():
        with cache.open("rb") as f:
            cases = pickle.load(f)[:count]
        planner = Planner(next(c for c in cases if c is not None)[0].model)
        return planner, replan_options(SolverOptions(), 0.0, 24), cases
    planner, ropts, cases = build(count)
    if cache is not None:
        with cache.open("wb") as f:
            pickle.dump(cases, f)
    return planner, ropts, cases


def recorded(planner, moved, ropts, serving, on_first=None) -> tuple:
    """The plan, and every iterate of its parametric solves: ``(solve, FlatResult, s)``."""
    from tocontrol_ros.core.direct import limited

    seen, calls = [], [0]
    original = limited.sensitivity_solve
    t0 = time.perf_counter()

    def watched(*args, on_step=None, **kwargs):
        calls[0] += 1
        call = calls[0]

        def both(it):
            seen.append((call, it, time.perf_counter() - t0))
            if on_step is not None:
                on_step(it)
        return original(*args, on_step=both, **kwargs)

    limited.sensitivity_solve = watched
    try:
        res = planner.plan(moved, ropts, warm_start=serving, on_first=on_first)
    finally:
        limited.sensitivity_solve = original
    return res, seen


def restored(flat, it, values, bounds, pads):
    """One Gauss-Newton step on the violated rows at fixed ``T``: the iterate (or None)."""
    from dataclasses import replace

    from scipy.sparse import csr_matrix, identity
    from scipy.sparse.linalg import spsolve

    from tocontrol_ros.core.direct.kkt_step import kkt_derivatives
    from tocontrol_ros.core.direct.sensitivity import banded_kkt, iterate

    der = kkt_derivatives(flat)
    par = flat.parameters(*values)
    lbg, ubg, lbx, ubx = flat.bounds(*bounds, pads, (values[0], values[1]))
    w = np.concatenate([it.P.ravel(), [it.T]])
    g, jv = der.rows(w, par)
    banded = banded_kkt(flat, der.jac_sparsity, der.hess_sparsity)
    target = np.clip(g, lbg, ubg)
    rows = np.flatnonzero((g < lbg) | (g > ubg) | (lbg == ubg))
    J = csr_matrix((jv, (banded.jr, banded.jc)), shape=(len(g), len(w)))[rows][:, :-1]
    r = target[rows] - g[rows]
    dw = J.T @ spsolve((J @ J.T + 1e-14 * identity(len(rows))).tocsc(), r)
    w1 = w.copy()
    w1[:-1] += np.asarray(dw).ravel()
    w1 = np.clip(w1, lbx, ubx)
    g1, _ = der.rows(w1, par)
    out = iterate(flat, w1, g1, (lbg, ubg, lbx, ubx), it.iterations, it.solve_time,
                  it.lam_g, it.lam_x)
    return replace(out, message=f"{it.message}, restored")


def checked(planner, moved, ropts, serving, it, pads):
    """Whether the iterate ``it`` is a motion to publish: (passes, why, T after a stretch)."""
    from tocontrol_ros.core.direct import checked as chk
    from tocontrol_ros.core.direct.limited import PAD, state_bounds
    from tocontrol_ros.core.methods.context import SolveContext

    got = []
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    ctx = SolveContext(None, moved, ropts, np.inf, None, on_first=got.append)
    values = (moved.start.value, moved.target.value, moved.k)
    watch = chk.FirstIterate(ctx, flat, state_bounds(moved, PAD), values, "bench", {}, 0.0,
                             time.perf_counter())
    watch(it)
    if got:
        return True, "certified", got[0].T
    if watch.tries == 0:
        return False, f"violation {it.residual:.1e}", np.nan
    return False, "set or certificate", np.nan


#: ``(FIRST_TRIES, FIRST_STRETCH)`` variants timed by :func:`paired_timing` (the shipped
#: one first).
VARIANTS = ((1, True), (1, False), (3, True))


def paired_timing(planner, ropts, cases, rounds: int) -> None:
    """Main's route and the call with ``on_first`` under each of :data:`VARIANTS`,
    alternated call by call ``rounds`` times per case (after one round, not counted).

    Per case (medians of the rounds): main's time to its certified answer; per variant the
    time to the first certified answer within ``BAR_GAP`` (the first motion where it is,
    else the call's answer) and the call's time to its answer. Then the medians over the
    cases.
    """
    from bench.warm_pad_rows import same_nlp
    from bench.warm_resolve import BAR_GAP
    from tocontrol_ros.core.direct import checked as chk

    shipped = chk.FIRST_TRIES, chk.FIRST_STRETCH
    rows = []
    try:
        for i, case in enumerate(cases):
            if case is None:
                continue
            moved, serving = case
            ref = same_nlp(planner, moved, serving)
            main_t, answer_t, with_t = [], {v: [] for v in VARIANTS}, {v: [] for v in VARIANTS}
            firsts_at = {}
            for r in range(rounds + 1):  # the first round warms up, not counted
                t0 = time.perf_counter()
                planner.plan(moved, ropts, warm_start=serving)
                if r:
                    main_t.append(time.perf_counter() - t0)
                for v in VARIANTS:
                    chk.FIRST_TRIES, chk.FIRST_STRETCH = v
                    firsts = []
                    t0 = time.perf_counter()
                    res = planner.plan(moved, ropts, warm_start=serving, on_first=lambda f: (  # noqa: B023
                        firsts.append((f, time.perf_counter() - t0))))  # noqa: B023
                    t_with = time.perf_counter() - t0
                    gap = firsts[0][0].T / ref.T - 1.0 if firsts else np.nan
                    firsts_at[v] = (firsts[0][0].iterations, gap) if firsts else None
                    within = bool(firsts) and abs(gap) <= BAR_GAP
                    if r:
                        with_t[v].append(t_with)
                        answer_t[v].append(firsts[0][1] if within else
                                           t_with if res.success else np.nan)
            row = [1e3 * float(np.median(main_t))] + [
                1e3 * float(np.median(answer_t[v])) for v in VARIANTS]
            rows.append(row)
            print(f"case {i + 1}: main {row[0]:.1f} ms; answer within {BAR_GAP:g}: " + "; ".join(
                f"{v} {a:.1f} ms (first {firsts_at[v]}, to its answer "
                f"{1e3 * float(np.median(with_t[v])):.1f})"
                for v, a in zip(VARIANTS, row[1:], strict=True)), flush=True)
    finally:
        chk.FIRST_TRIES, chk.FIRST_STRETCH = shipped
    med = np.median(np.array(rows), axis=0)
    print(f"medians over {len(rows)} cases ({rounds} rounds, alternated): main {med[0]:.1f} "
          f"ms; answer within {BAR_GAP:g}: " + "; ".join(
              f"{v} {a:.1f} ms" for v, a in zip(VARIANTS, med[1:], strict=True)))


def main(argv: list[str]) -> None:
    from bench.warm_pad_rows import same_nlp
    from tocontrol_ros.core.direct import checked as chk
    from tocontrol_ros.core.direct.limited import PAD, state_bounds
    from tocontrol_ros.core.direct.set_pads import row_pads
    from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL

    cache, rounds = None, 0
    if argv[:1] == ["--cache"]:
        cache, argv = Path(argv[1]), argv[2:]
    if argv[:1] == ["--timed"]:
        rounds, argv = int(argv[1]), argv[2:]
    count = int(argv[0]) if argv else 20
    planner, ropts, cases = load(cache, count)
    if rounds:
        paired_timing(planner, ropts, cases, rounds)
        return
    summary = []
    for i, case in enumerate(cases):
        if case is None:
            print(f"case {i + 1}: not served")
            continue
        moved, serving = case
        ref = same_nlp(planner, moved, serving)
        T_opt = ref.T if ref.success else np.nan
        plain = planner.plan(moved, ropts, warm_start=serving)
        res, seen = recorded(planner, moved, ropts, serving)
        ws = serving.warm_state
        flat = planner.flat(moved, ws.breaks, warm="dual")
        pads = row_pads(serving.trajectory, flat.samples)
        values = (moved.start.value, moved.target.value, moved.k)
        bounds = state_bounds(moved, PAD)
        print(f"case {i + 1}: IPOPT on the same NLP T {T_opt:.7f} ({ref.iterations} it); "
              f"the route's answer T {res.T:.7f} (gap {res.T / T_opt - 1:+.1e}), "
              f"{len(seen)} iterates recorded", flush=True)
        first_any = None
        for call, it, at in seen:
            gap = it.T / T_opt - 1.0
            ok, why, T_pub = checked(planner, moved, ropts, serving, it, pads) \
                if it.residual <= RESIDUAL_TOL else (False, f"violation {it.residual:.1e}",
                                                      np.nan)
            line = (f"    solve {call} step {it.iterations}: viol {it.residual:.1e}, T gap "
                    f"{gap:+.1e}, at {1e3 * at:.1f} ms: {why}")
            if ok and first_any is None:
                first_any = (call, it.iterations, T_pub / T_opt - 1.0, at)
            if not ok and RESIDUAL_TOL < it.residual <= RESTORE_FROM:
                again = restored(flat, it, values, bounds, pads)
                ok2, why2, T2 = checked(planner, moved, ropts, serving, again, pads) \
                    if again.residual <= RESIDUAL_TOL else (False, "", np.nan)
                line += (f"; restored: viol {again.residual:.1e}"
                         + (f", {why2}, T gap {T2 / T_opt - 1:+.1e}" if ok2 else
                            f" {why2}"))
            print(line, flush=True)
        # The route with on_first, at each of TRIES (the shipped FIRST_TRIES first): the
        # first motion's time (its checks included) and gap, the answer's time, its bits.
        shipped, outs = chk.FIRST_TRIES, []
        try:
            for tries in TRIES:
                chk.FIRST_TRIES = tries
                firsts = []
                t0 = time.perf_counter()
                timed = planner.plan(moved, ropts, warm_start=serving, on_first=lambda r: (  # noqa: B023
                    firsts.append((r, time.perf_counter() - t0))))  # noqa: B023
                total = time.perf_counter() - t0
                same = bool(timed.T == plain.T and np.array_equal(
                    timed.trajectory.result.P, plain.trajectory.result.P))
                outs.append((tries, firsts[0] if firsts else None, total, same))
        finally:
            chk.FIRST_TRIES = shipped
        for tries, first, total, same in outs:
            text = (f"first motion at {1e3 * first[1]:.1f} ms, T gap "
                    f"{first[0].T / T_opt - 1:+.1e}, {first[0].iterations} steps"
                    if first else "no first motion")
            print(f"    with on_first (FIRST_TRIES {tries}): {text}; the answer at "
                  f"{1e3 * total:.1f} ms, same bits as without: {same}", flush=True)
        print(f"    first publishable iterate (every one checked): {first_any}")
        summary.append((i + 1, first_any, [(o[0], None if o[1] is None else (
            o[1][0].iterations, f"{o[1][0].T / T_opt - 1:.1e}")) for o in outs],
            all(o[3] for o in outs)))
    print("summary (case, first publishable (solve, step, gap, ms), per FIRST_TRIES the "
          "first motion's (steps, gap), same bits):")
    for row in summary:
        print("   ", row)


if __name__ == "__main__":
    main(sys.argv[1:])
