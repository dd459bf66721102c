"""Where a warm re-solve's answer spends its time: bench/warm_resolve.py's 20 moves, by parts.

Issue 47's second bar (docs/limits.md, "Cheaper checks and steps"). The same 20 Panda cases,
serving solutions and 2 cm moves as ``bench/warm_resolve.py`` (``bench/warm_pad_rows.py``'s
draw; ``--cache FILE`` pickles them on the first run and reads them back on the next, so
that two versions of the code answer the same moves from the same serving solutions). Each
move is answered by ``Planner.plan(moved, replan options, warm_start=serving)`` ``--calls``
times after one call, and per call the parts' processor times (``time.thread_time``) are
summed by wrappers around them: the Newton steps (``sensitivity_solve``; inside it the
rows and their Jacobian, the Hessians, the banded factorisations and back-substitutions,
and the rest: the loop's NumPy), the pads per sample (``set_pads.warm_row_pads``), the trajectories
(``FlatTrajectory``), the set's check between the samples (``set_values``), the time
stretches (``stretched``), the certificate (``verified``; inside it the fine sample and the
open loop), and the rest of the call. Reported: the medians over the calls of each move,
then the medians over the moves; and the whole call's wall and processor times without the
wrappers (medians of ``--calls`` after one).

``--save FILE`` writes every answer (route, ``T`` and the control points' bytes, the
certificate's figures) to compare two versions to the bit with ``--against FILE``.
``--profile N``: cProfile of the N calls of each move instead (top functions by own time).

``--base DIR`` (a copy of another version's tree, e.g. ``git archive <ref> | tar -x -C DIR``):
paired A/B in this process of the parts that changed, alternated call by call ``--calls``
times after one call each, processor-time medians, and whether both give the same numbers
to the bit: the Newton steps alone (``sensitivity_solve`` of DIR against this tree's, the
route's steps: the whole move, then the sub-moves where it fails).

Command: ``scripts/dev run python -P bench/warm_parts.py --cache /tmp/cases.pkl
[--calls N] [--save FILE] [--against FILE] [--profile N] [--base DIR] [--only 2,3] [cases]``.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import pstats
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import log  # noqa: E402
from bench.warm_first_iterate import load  # noqa: E402

#: Parts timed (name, module path, attribute): wrappers sum each one's processor time.
PARTS = (
    ("steps", "tocontrol_ros.core.direct.limited", "sensitivity_solve"),
    ("rows", "tocontrol_ros.core.direct.kkt_step", "KKTDerivatives.rows"),
    ("hessian", "tocontrol_ros.core.direct.kkt_step", "KKTDerivatives.hessian"),
    ("factor", "tocontrol_ros.core.direct.sensitivity", "BandedKKT.factor"),
    ("backsolve", "tocontrol_ros.core.direct.sensitivity", "BandedKKT.solve"),
    ("row pads", "tocontrol_ros.core.direct.set_pads", "warm_row_pads"),
    ("trajectory", "tocontrol_ros.core.direct.flat_trajectory", "FlatTrajectory._set_result"),
    ("set check", "tocontrol_ros.core.direct.flat_trajectory", "FlatTrajectory.set_values"),
    ("stretch", "tocontrol_ros.core.direct.limited", "stretched"),
    ("certificate", "tocontrol_ros.core.direct.limited", "verified"),
    ("fine sample", "tocontrol_ros.core.direct.checked", "fine_sample"),
    ("open loop", "tocontrol_ros.core.direct.flat_trajectory", "FlatTrajectory.open_loop"),
)


@contextmanager
def timed_parts(sums: dict):
    """Each of :data:`PARTS` wrapped: its processor time (s) added to ``sums[name]``.

    A part called inside another of the same name (a recursion) counts once.
    """
    import importlib

    saved, depth = [], {}
    for name, module, attr in PARTS:
        owner = importlib.import_module(module)
        *path, last = attr.split(".")
        for part in path:
            owner = getattr(owner, part)
        original = owner.__dict__[last] if isinstance(owner, type) else getattr(owner, last)

        def wrapped(*args, _f=original, _n=name, **kwargs):
            depth[_n] = depth.get(_n, 0) + 1
            t0 = time.thread_time()
            try:
                return _f(*args, **kwargs)
            finally:
                depth[_n] -= 1
                if depth[_n] == 0:
                    sums[_n] = sums.get(_n, 0.0) + time.thread_time() - t0

        saved.append((owner, last, original))
        setattr(owner, last, wrapped)
    try:
        yield
    finally:
        for owner, last, original in reversed(saved):
            setattr(owner, last, original)


def answer_of(res) -> dict:
    """What must stay the same to the bit: route, T, control points, certificate figures."""
    text = " ".join(res.warnings)
    route = "parametric" if "(route: parametric)" in text else "ipopt"
    out = {"success": bool(res.success), "route": route, "iterations": int(res.iterations)}
    if res.success:
        P = np.ascontiguousarray(res.trajectory.result.P, dtype=float)
        out.update(T=float(res.T).hex(), P=hashlib.sha256(P.tobytes()).hexdigest(),
                   residual=float(res.residual).hex(),
                   figures={k: (float(v).hex() if isinstance(v, float) else str(v))
                            for k, v in sorted(res.verification.items())})
    return out


def module_from(base: Path, name: str):
    """The module ``name`` (dotted) as it is in the tree ``base``, loaded under another name
    (its own imports resolve to this tree's modules)."""
    import importlib.util

    path = base.joinpath(*name.split(".")).with_suffix(".py")
    spec = importlib.util.spec_from_file_location(f"_base_{name.replace('.', '_')}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def same_bits(a, b) -> bool:
    """Whether two results (dataclasses, arrays, numbers, tuples) are equal to the bit."""
    from dataclasses import fields, is_dataclass

    if is_dataclass(a):
        return type(a).__name__ == type(b).__name__ and all(
            f.name == "solve_time" or same_bits(getattr(a, f.name), getattr(b, f.name))
            for f in fields(a))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, float) and isinstance(b, float):
        return a.hex() == b.hex() or (np.isnan(a) and np.isnan(b))
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(same_bits(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def paired(fns: tuple, calls: int) -> tuple[list[float], list]:
    """Processor-time medians (s) of ``fns`` alternated call by call, and their last outputs."""
    outs = [fn() for fn in fns]
    times = [[] for _ in fns]
    for _ in range(calls):
        for j, fn in enumerate(fns):
            t0 = time.thread_time()
            outs[j] = fn()
            times[j].append(time.thread_time() - t0)
    return [float(np.median(t)) for t in times], outs


def base_module(base: Path):
    """DIR's ``core/direct/sensitivity`` with its KKT orderings kept apart from this tree's
    (both cache them on the transcription under the same key)."""
    old = module_from(base, "tocontrol_ros.core.direct.sensitivity")
    kept = {}

    def banded_kkt(flat, jac, hess):
        key = (id(flat.kkt_cache), hess.size1(), jac.size1())
        if key not in kept:
            kept[key] = (flat.kkt_cache, old.BandedKKT(old._triplets(jac), old._triplets(hess),
                                                       hess.size1(), jac.size1(),
                                                       flat.model.n))
        return kept[key][1]

    old.banded_kkt = banded_kkt
    return old


@contextmanager
def as_base(base_parts: tuple):
    """The warm re-solve as DIR's code makes it, inside this process: its Newton steps
    (``sensitivity_solve``), its open loop and set check (``FlatTrajectory.open_loop`` and
    ``set_values``, evaluated every time), the pads per sample evaluated from the warm
    path (not read off the warm state), the residuals through the row function called
    with ``DM``."""
    from dataclasses import replace

    from tocontrol_ros.core.direct import limited, set_pads
    from tocontrol_ros.core.direct.flat import FlatTranscription, violation
    from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory

    def plain_residual(self, w, par, lbg, ubg, lbx, ubx):
        return violation(w, np.array(self.row_function(w, par)).ravel(), lbg, ubg, lbx, ubx)

    old_sens, old_ft = base_parts
    row_pads = set_pads.warm_row_pads
    saved = (limited.sensitivity_solve, FlatTrajectory.open_loop, FlatTrajectory.set_values,
             FlatTranscription.__dict__["_residual"])
    limited.sensitivity_solve = old_sens.sensitivity_solve
    FlatTrajectory.open_loop = old_ft.FlatTrajectory.open_loop
    FlatTrajectory.set_values = old_ft.FlatTrajectory.set_values
    FlatTranscription._residual = plain_residual
    set_pads.warm_row_pads = lambda flat, warm, k: row_pads(
        flat, replace(warm, set_values=None), k)
    try:
        yield
    finally:
        (limited.sensitivity_solve, FlatTrajectory.open_loop, FlatTrajectory.set_values,
         FlatTranscription._residual) = saved
        set_pads.warm_row_pads = row_pads


def calls_ab(planner, ropts, cases, base: Path, calls: int, only: set) -> None:
    """The whole call, DIR's code (:func:`as_base`) and this tree's alternated call by call:
    processor and wall time medians, the answers compared to the bit."""
    parts = (base_module(base),
             module_from(base, "tocontrol_ros.core.direct.flat_trajectory"))
    rows = []
    for i, case in enumerate(cases):
        if case is None or (only and i + 1 not in only):
            continue
        moved, serving = case

        def call(moved=moved, serving=serving):
            return planner.plan(moved, ropts, warm_start=serving)

        def old_call():
            with as_base(parts):
                return call()

        out, cpu, wall = {}, {"old": [], "new": []}, {"old": [], "new": []}
        for _ in range(calls + 1):
            for name, fn in (("old", old_call), ("new", call)):
                t0, c0 = time.perf_counter(), time.thread_time()
                out[name] = fn()
                cpu[name].append(time.thread_time() - c0)
                wall[name].append(time.perf_counter() - t0)
        med = {f"{kind} {name}": float(np.median(v[name][1:]))
               for kind, v in (("cpu", cpu), ("wall", wall)) for name in ("old", "new")}
        same = answer_of(out["old"]) == answer_of(out["new"])
        route = answer_of(out["new"])["route"]
        rows.append((i + 1, route, med, same))
        log(f"case {i + 1}: {route}, processor {1e3 * med['cpu old']:.2f} -> "
            f"{1e3 * med['cpu new']:.2f} ms ({med['cpu new'] / med['cpu old']:.3f}), wall "
            f"{1e3 * med['wall old']:.2f} -> {1e3 * med['wall new']:.2f} ms; the same "
            f"answer to the bit: {same}")
    for route in ("parametric", "ipopt", None):
        sel = [m for _, r, m, _ in rows if route is None or r == route]
        if not sel:
            continue
        ratio = [m["cpu new"] / m["cpu old"] for m in sel]
        print(f"{route or 'all'} ({len(sel)}): processor median "
              f"{1e3 * np.median([m['cpu old'] for m in sel]):.2f} -> "
              f"{1e3 * np.median([m['cpu new'] for m in sel]):.2f} ms, wall median "
              f"{1e3 * np.median([m['wall old'] for m in sel]):.2f} -> "
              f"{1e3 * np.median([m['wall new'] for m in sel]):.2f} ms; processor ratio "
              f"median {np.median(ratio):.3f} (range {min(ratio):.3f}-{max(ratio):.3f})")
    print(f"the same answers to the bit: {sum(s for *_, s in rows)}/{len(rows)}")


def checks_ab(planner, ropts, cases, base: Path, calls: int, only: set) -> None:
    """The checks' parts, DIR's against this tree's, alternated: the certificate's open loop
    of the answer (DIR's ``FlatTrajectory.open_loop`` on the same trajectory), the pads per
    sample of the serving solution (evaluated from its path, as DIR does, against read off
    its warm state's set values) and the residuals of the answer's six time stretches (the
    row function called with ``DM`` as DIR does, against ``FlatTranscription.residual``)."""
    from dataclasses import replace

    from tocontrol_ros.core.direct import limited, set_pads
    from tocontrol_ros.core.direct.flat import violation
    from tocontrol_ros.core.direct.tuning import PAD, RESIDUAL_TOL, SET_PAD, STRETCHES

    old_ft = module_from(base, "tocontrol_ros.core.direct.flat_trajectory")
    cert = replace(ropts.certificate_options(1), residual_tol=RESIDUAL_TOL)
    rows = []
    for i, case in enumerate(cases):
        if case is None or (only and i + 1 not in only):
            continue
        moved, serving = case
        traj = planner.plan(moved, ropts, warm_start=serving).trajectory
        ws = serving.warm_state
        flat = planner.flat(moved, ws.breaks, warm=True)
        bare = replace(ws, set_values=None)
        (o1, n1), (a, b) = paired((
            lambda traj=traj: old_ft.FlatTrajectory.open_loop(traj, cert.rtol, cert.atol),
            lambda traj=traj: traj.open_loop(cert.rtol, cert.atol)), calls)
        same_ol = all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
        (o2, n2), (c, d) = paired((
            lambda flat=flat, bare=bare, k=moved.k: set_pads.warm_row_pads(flat, bare, k),
            lambda flat=flat, ws=ws, k=moved.k: set_pads.warm_row_pads(flat, ws, k)), calls)
        # The six time stretches' residuals of the answer (checked.stretched): the rows
        # called with DM conversions as DIR does, against flat.residual (buffered).
        res = traj.result
        values = (moved.start.value, moved.target.value, moved.k)
        bounds = limited.state_bounds(moved, PAD)
        durations = [res.T * (1.0 + e) for e in STRETCHES]

        def plain(res=res, values=values, bounds=bounds, durations=durations, flat=flat):
            par = flat.parameters(*values)
            return [violation(np.concatenate([res.P.ravel(), [T]]),
                              np.array(flat.row_function(
                                  np.concatenate([res.P.ravel(), [T]]), par)).ravel(),
                              *flat.bounds(*bounds, SET_PAD, values[:2])) for T in durations]

        def buffered(res=res, values=values, bounds=bounds, durations=durations,
                     flat=flat):
            return [flat.residual(*values, T, res.P, *bounds) for T in durations]

        (o3, n3), (e, f) = paired((plain, buffered), calls)
        rows.append((o1, n1, o2, n2, o3, n3))
        log(f"case {i + 1}: open loop {1e3 * o1:.2f} -> {1e3 * n1:.2f} ms (the same: "
            f"{same_ol}); pads per sample {1e3 * o2:.2f} -> {1e3 * n2:.2f} ms (the same: "
            f"{np.array_equal(c, d)}; read off the warm state: {ws.set_values is not None}); "
            f"six stretches' residuals {1e3 * o3:.2f} -> {1e3 * n3:.2f} ms (the same: "
            f"{[x.hex() for x in e] == [x.hex() for x in f]})")
    med = np.median(np.array(rows), axis=0) * 1e3
    print(f"{len(rows)} moves, medians (processor): open loop {med[0]:.2f} -> {med[1]:.2f} "
          f"ms, pads per sample {med[2]:.2f} -> {med[3]:.2f} ms, six stretches' residuals "
          f"{med[4]:.2f} -> {med[5]:.2f} ms")


def steps_ab(planner, cases, base: Path, calls: int, only: set) -> None:
    """The Newton steps alone, DIR's ``sensitivity_solve`` against this tree's (see module)."""
    from tocontrol_ros.core.direct import limited, sensitivity, set_pads
    from tocontrol_ros.core.direct.tuning import PAD

    old = base_module(base)
    rows = []
    for i, case in enumerate(cases):
        if case is None or (only and i + 1 not in only):
            continue
        moved, serving = case
        ws = serving.warm_state
        flat = planner.flat(moved, ws.breaks, warm="dual")
        pad = set_pads.warm_row_pads(flat, ws, moved.k)
        args = (flat, np.concatenate([ws.P.ravel(), [ws.T]]), ws.lam_g, ws.lam_x,
                moved.start.value, moved.target.value, moved.k,
                *limited.state_bounds(moved, PAD), pad)

        def route(mod, args=args):
            whole = mod.sensitivity_solve(*args)
            if whole[0].success:
                return whole
            return mod.sensitivity_solve(*args, submoves=mod.PATH_SUBMOVES,
                                         max_steps=mod.PATH_STEPS, max_solves=mod.PATH_SOLVES,
                                         sub_budget=mod.PATH_SUB_BUDGET)

        (t_old, t_new), (a, b) = paired((lambda: route(old), lambda: route(sensitivity)),
                                        calls)
        rows.append((t_old, t_new))
        log(f"case {i + 1}: steps {a[1].steps}, solves {a[1].solves}: {1e3 * t_old:.2f} -> "
            f"{1e3 * t_new:.2f} ms ({t_new / t_old:.2f}), the same to the bit: "
            f"{same_bits(a, b)}")
    ratio = [n / o for o, n in rows]
    print(f"steps alone, {len(rows)} moves: median {1e3 * np.median([o for o, _ in rows]):.2f}"
          f" -> {1e3 * np.median([n for _, n in rows]):.2f} ms (processor), ratio median "
          f"{np.median(ratio):.3f} (range {min(ratio):.3f}-{max(ratio):.3f})")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("count", nargs="?", type=int, default=20)
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--calls", type=int, default=5)
    ap.add_argument("--save", type=Path)
    ap.add_argument("--against", type=Path)
    ap.add_argument("--profile", type=int, default=0)
    ap.add_argument("--only", type=str, default="")
    ap.add_argument("--base", type=Path)
    ap.add_argument("--whole", action="store_true")
    ap.add_argument("--checks", action="store_true")
    args = ap.parse_args()
    import tocontrol_ros

    log(f"tocontrol_ros from {Path(tocontrol_ros.__file__).parent}")
    planner, ropts, cases = load(args.cache, args.count)
    only = {int(c) for c in args.only.split(",") if c}
    if args.base is not None:
        if args.whole:
            calls_ab(planner, ropts, cases, args.base, args.calls, only)
        elif args.checks:
            checks_ab(planner, ropts, cases, args.base, args.calls, only)
        else:
            steps_ab(planner, cases, args.base, args.calls, only)
        return
    answers, per_move, wall, cpu = {}, [], [], []
    prof = cProfile.Profile() if args.profile else None
    for i, case in enumerate(cases):
        if case is None or (only and i + 1 not in only):
            continue
        moved, serving = case

        def call(moved=moved, serving=serving):
            return planner.plan(moved, ropts, warm_start=serving)

        res = call()
        answers[str(i + 1)] = answer_of(res)
        if prof is not None:
            prof.enable()
            for _ in range(args.profile):
                call()
            prof.disable()
            continue
        walls, cpus = [], []
        for _ in range(args.calls):
            t0, c0 = time.perf_counter(), time.process_time()
            again = call()
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            if answer_of(again) != answers[str(i + 1)]:
                raise RuntimeError(f"case {i + 1}: the same call gave another answer")
        parts = []
        for _ in range(args.calls):
            sums = {}
            t0 = time.thread_time()
            with timed_parts(sums):
                call()
            sums["call"] = time.thread_time() - t0
            parts.append(sums)
        med = {name: float(np.median([p.get(name, 0.0) for p in parts]))
               for name in ["call"] + [n for n, _, _ in PARTS]}
        per_move.append((i + 1, answers[str(i + 1)]["route"], med))
        wall.append(float(np.median(walls)))
        cpu.append(float(np.median(cpus)))
        log(f"case {i + 1}: {answers[str(i + 1)]['route']} wall {1e3 * wall[-1]:.1f} ms, "
            f"cpu {1e3 * cpu[-1]:.1f} ms; " + ", ".join(
                f"{name} {1e3 * v:.2f}" for name, v in med.items() if v))
    if prof is not None:
        pstats.Stats(prof).sort_stats("tottime").print_stats(40)
    if per_move:
        names = ["call"] + [n for n, _, _ in PARTS]
        print(f"\nmoves: {len(per_move)}; whole call (no wrappers) median wall "
              f"{1e3 * np.median(wall):.1f} ms, processor {1e3 * np.median(cpu):.1f} ms")
        for route in ("parametric", "ipopt", None):
            rows = [m for _, r, m in per_move if route is None or r == route]
            if not rows:
                continue
            print(f"{route or 'all'} ({len(rows)}): " + ", ".join(
                f"{name} {1e3 * np.median([m[name] for m in rows]):.2f}" for name in names))
        print("per move (ms, processor): case route " + " ".join(names))
        for case, route, m in per_move:
            print(f"  {case} {route} " + " ".join(f"{1e3 * m[n]:.2f}" for n in names))
    if args.save is not None:
        args.save.write_text(json.dumps(answers, indent=1, sort_keys=True))
    if args.against is not None:
        other = json.loads(args.against.read_text())
        same = [c for c in answers if other.get(c) == answers[c]]
        differ = [c for c in answers if c in other and other[c] != answers[c]]
        print(f"\nthe same answers to the bit as {args.against}: {len(same)}/{len(answers)}"
              + (f"; differ: {differ}" if differ else ""))
        for c in differ:
            a, b = other[c], answers[c]
            print(f"  case {c}: " + ", ".join(f"{key}: {a.get(key)} -> {b.get(key)}"
                                              for key in sorted(set(a) | set(b))
                                              if a.get(key) != b.get(key)))


if __name__ == "__main__":
    main()
