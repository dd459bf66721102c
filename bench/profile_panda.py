"""Where a default Panda plan's time goes (issue 32: measure first).

The best-motion section's Panda cases (:func:`bench.limits.draw_cases`, seed of
:mod:`bench.optimum_panda`: even cases point to point, odd ones from a joint state, k = 4,
the URDF limits enforced, so every plan takes the bounded B-spline path of docs/limits.md),
each planned once with the default :class:`SolverOptions` after one warm-up plan (compile
cache filled). Every IPOPT solve is recorded by wrapping ``DirectCollocation.solve`` (the
multistart's guesses, at the requested k within the limits) and
``FlatTranscription.solve`` (the bounded solves), with CasADi's own counters of that
solve (``solver.stats()``): wall time in each kind of function evaluation (constraints,
their Jacobian, the Lagrangian's Hessian, objective), in the Python iteration callback,
and the rest (IPOPT's own work: the linear solves with MUMPS, the barrier update, the line
search's bookkeeping). The builds of transcriptions
(``FlatTranscription.__init__``, ``DirectCollocation.__init__``) are timed the same way,
and the plan's own ``timings`` give the certificate; what is left of a plan's wall time is
the orchestration in Python (seeding, inverse kinematics, fits, trajectories).

Bounded solves are grouped by stage: *uniform* (the first solve of each candidate on
:data:`~tocontrol_ros.core.direct.tuning.SPANS` spans, IPOPT's default start), *refined*
(each refinement level, warm), *re-solves* (the pad's widening and the continuations in
``k``, ``warm="resume"``/``"restart"``/``"dual"``).

:func:`run_cores` then plans the same cases with one process and with two (``workers=2``,
:mod:`tocontrol_ros.core.planning.pool`), paired, and checks that both give the same plan.

Run alone: ``scripts/dev run python -P bench/profile_panda.py [CASES] [--cores]`` (prints
the section).
"""

from __future__ import annotations

import collections
import hashlib
import os
import statistics
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import Section, log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED, K  # noqa: E402
from tocontrol_ros.core import Problem, SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.direct import collocation, flat  # noqa: E402
from tocontrol_ros.core.direct.tuning import REFINEMENTS, SPANS, T_SETTLED  # noqa: E402
from tocontrol_ros.core.planning.prepared import PreparedModel  # noqa: E402
from tocontrol_ros.core.types.problem import joint_state, point  # noqa: E402

#: CasADi's per-solve wall-time counters (s), by what they time.
EVALUATIONS = {"constraints": "t_wall_nlp_g", "Jacobian": "t_wall_nlp_jac_g",
               "Hessian": "t_wall_nlp_hess_l", "objective": ("t_wall_nlp_f", "t_wall_nlp_grad_f"),
               "callback": "t_wall_callback_fun"}
STAGES = ("guesses (Hermite-Simpson, k = 4)", "bounded: uniform", "bounded: refined",
          "bounded: re-solves")


class Recorder:
    """Wraps the transcriptions' ``solve`` and ``__init__`` and keeps what they cost.

    Also the planner's shared pieces (``PreparedModel.map``, one process): each call's
    pieces' wall times and the solves they made (``groups``), for :func:`two_core_path`.
    """

    def __init__(self) -> None:
        self.solves: list[dict] = []
        self.builds: collections.Counter = collections.Counter()
        self.groups: list[dict] = []
        self._undo = []

    def __enter__(self) -> Recorder:
        for cls, tag in ((collocation.DirectCollocation, "guess"),
                         (flat.FlatTranscription, "flat")):
            self._wrap_solve(cls, tag)
            self._wrap_init(cls, tag)
        self._wrap_map()
        return self

    def _wrap_map(self) -> None:
        orig = PreparedModel.map
        recorder = self

        def map_(obj, fn, ctx, items):
            if (ctx.options.workers or 2) > 1:  # pieces in other processes: not timed here
                yield from orig(obj, fn, ctx, items)
                return
            group = {"items": [], "first_solve": len(recorder.solves)}
            if fn.__name__ == "_refine_item":  # a refinement level: (T in, T out, success)
                group["links"] = []
            recorder.groups.append(group)
            for item in items:
                t0 = time.perf_counter()
                out = fn(obj, ctx, *item)
                group["items"].append(time.perf_counter() - t0)
                if "links" in group:
                    group["links"].append((float(item[2]), float(out.T), bool(out.success)))
                yield out

        self._undo.append((PreparedModel, "map", orig))
        PreparedModel.map = map_

    def __exit__(self, *exc) -> None:
        for cls, name, orig in self._undo:
            setattr(cls, name, orig)

    def _wrap_solve(self, cls, tag) -> None:
        orig = cls.solve

        def solve(obj, *args, **kwargs):
            t0 = time.perf_counter()
            out = orig(obj, *args, **kwargs)
            wall = time.perf_counter() - t0
            st = obj.solver.stats()
            rec = {"stage": _stage(tag, obj), "wall": wall, "iterations": out.iterations,
                   "spans": getattr(obj, "spans", None)}
            for name, keys in EVALUATIONS.items():
                keys = keys if isinstance(keys, tuple) else (keys,)
                rec[name] = sum(float(st.get(k, 0.0)) for k in keys)
            self.solves.append(rec)
            return out

        self._undo.append((cls, "solve", orig))
        cls.solve = solve

    def _wrap_init(self, cls, tag) -> None:
        orig = cls.__init__

        def init(obj, *args, **kwargs):
            t0 = time.perf_counter()
            orig(obj, *args, **kwargs)
            self.builds[tag] += time.perf_counter() - t0
            self.builds[tag + " count"] += 1

        self._undo.append((cls, "__init__", orig))
        cls.__init__ = init


def makespan(pieces: list[float], processes: int = 2) -> float:
    """Wall time of ``pieces`` (s, in order) taken from one queue by ``processes`` processes.

    Each piece goes to the process that is free first, as
    :class:`~tocontrol_ros.core.planning.pool.WorkerPool` shares them out (the caller's
    process takes pieces too); no start-up or transfer costs.
    """
    free = [0.0] * processes
    for piece in pieces:
        i = free.index(min(free))
        free[i] += piece
    return max(free)


def chained_makespan(levels: list[list[tuple]], processes: int = 2,
                     speculative: bool = False) -> float:
    """Wall time of a refinement's levels without the barrier between levels.

    ``levels``: each level's pieces in order, ``(wall, T in, T out, success)``; a piece
    continues the candidate whose last piece ended with its ``T in`` (:func:`_race` starts a
    level from each candidate's last ``T``). A piece is ready when its predecessor ends (the
    first level's at once) and goes to the process free first; among the pieces that could
    start earliest, the lower level, then the earlier in its level. With ``speculative``, a
    candidate whose chain stops while neither settled (``T`` moved by more than
    :data:`T_SETTLED`) nor failed nor at the last level nor the best so far (it was left
    behind by a level's window, a decision that needs the other candidates' results) starts
    one more piece as long as its last one: the solve that a refinement without the barrier
    starts at once and discards later. Without: those solves are left out (a lower bound).
    """
    pieces: list[dict] = []
    last: dict[float, list[int]] = {}  # T -> the pieces that ended with it, not yet followed
    for level, items in enumerate(levels):
        ended: dict[float, list[int]] = {}
        for order, (wall, t_in, t_out, ok) in enumerate(items):
            pred = last[t_in].pop(0) if level and last.get(t_in) else None
            pieces.append({"wall": wall, "pred": pred, "key": (level, order)})
            ended.setdefault(t_out, []).append(len(pieces) - 1)
            pieces[-1].update(level=level, settled=abs(t_out - t_in) <= T_SETTLED * t_out,
                              ok=ok, T=t_out)
        for t_out, ids in ended.items():  # a candidate not refined at a level keeps its T
            last.setdefault(t_out, []).extend(ids)
    if speculative:
        followed = {p["pred"] for p in pieces if p["pred"] is not None}
        discarded = []
        for i, p in enumerate(pieces):
            best = min(q["T"] for q in pieces if q["level"] <= p["level"])
            if i not in followed and p["ok"] and not p["settled"] and p["T"] > best \
                    and p["level"] < REFINEMENTS - 1:
                discarded.append({"wall": p["wall"], "pred": i,
                                  "key": (p["level"] + 1, len(pieces) + len(discarded))})
        pieces += discarded
    end: list[float | None] = [None] * len(pieces)
    free = [0.0] * processes
    while any(e is None for e in end):
        best = None
        for i, p in enumerate(pieces):
            if end[i] is not None or (p["pred"] is not None and end[p["pred"]] is None):
                continue
            ready = 0.0 if p["pred"] is None else end[p["pred"]]
            start = max(ready, min(free))
            if best is None or (start, p["key"]) < best[0]:
                best = ((start, p["key"]), i)
        (start, _), i = best
        j = free.index(min(free))
        end[i] = start + pieces[i]["wall"]
        free[j] = end[i]
    return max(end, default=0.0)


def unbarred_refinement(groups: list[dict], processes: int = 2,
                        speculative: bool = False) -> tuple[float, float]:
    """A plan's refinement levels on ``processes``: with the level barrier, and without.

    ``groups``: the plan's shared pieces (:class:`Recorder`); each run of consecutive
    refinement levels (groups with ``links``) is one race. Returns (with the barrier, as
    :func:`makespan` per level; without it, :func:`chained_makespan`), in seconds.
    """
    races: list[list[list[tuple]]] = []
    previous = False
    for group in groups:
        links = group.get("links")
        if links is None:
            previous = False
            continue
        if not previous:
            races.append([])
        races[-1].append([(wall, *link) for wall, link in zip(group["items"], links,
                                                              strict=True)])
        previous = True
    barred = sum(makespan([p[0] for p in level], processes) for race in races for level in race)
    free = sum(chained_makespan(race, processes, speculative) for race in races)
    return barred, free


def two_core_path(wall: float, groups: list[dict], solves: list[dict],
                  processes: int = 2) -> dict:
    """One plan's time (one process) split by what ``processes`` cores could share.

    ``groups``: the plan's shared pieces (:class:`Recorder`), each attributed to the stage
    of its first solve. Returns, by stage, ``(one process, estimate on processes)`` in
    seconds, and under ``"not shared"`` the rest of the plan (the first guess, the pad's
    re-solves, seeding, fits, certificate), the same on any number of cores.
    """
    out: dict = {}
    shared = 0.0
    for group in groups:
        if not group["items"]:
            continue
        first = group["first_solve"]
        stage = solves[first]["stage"] if first < len(solves) else "other"
        one, many = sum(group["items"]), makespan(group["items"], processes)
        shared += one
        a, b = out.get(stage, (0.0, 0.0))
        out[stage] = (a + one, b + many)
    out["not shared"] = (wall - shared, wall - shared)
    return out


def _stage(tag: str, obj) -> str:
    if tag == "guess":
        return STAGES[0]
    if obj.warm is False and obj.spans == SPANS:
        return STAGES[1]
    if obj.warm is True and obj.spans != SPANS:
        return STAGES[2]
    return STAGES[3]


def run(count: int) -> Section:
    found = robots().get("Panda")
    if found is None:
        return Section("Where a Panda plan's time goes", [
            "example-robot-data is not installed: section skipped."], [])
    model, limits = found
    options = SolverOptions(time_limit=600.0)
    cases = draw_cases(model, limits, count, seed=SEED)
    problems = [Problem(model, point(model.point(q0)) if i % 2 == 0 else joint_state(q0, qd0),
                        point(target), k=K, limits=limits)
                for i, (q0, qd0, target) in enumerate(cases)]
    plan(problems[0], options)  # warm-up: compile cache, optimised libraries loaded
    plans = []
    with Recorder() as rec:
        for i, problem in enumerate(problems):
            first, builds = len(rec.solves), dict(rec.builds)
            groups = len(rec.groups)
            t0 = time.perf_counter()
            res = plan(problem, options)
            wall = time.perf_counter() - t0
            solves = rec.solves[first:]
            build = sum(rec.builds[k] - builds.get(k, 0.0) for k in ("guess", "flat"))
            groups = [dict(g, first_solve=g["first_solve"] - first)
                      for g in rec.groups[groups:]]
            plans.append({"wall": wall, "solves": solves, "build": build,
                          "path": two_core_path(wall, groups, solves),
                          "unbarred": (unbarred_refinement(groups),
                                       unbarred_refinement(groups, speculative=True)),
                          "verify": res.timings.get("verify", 0.0), "ok": res.success})
            log(f"profile Panda {i + 1}/{count}: {res.status.name} T {res.T:.6f} in "
                f"{wall:.2f} s, {len(solves)} IPOPT solves")
    return _section(plans, options)


def _section(plans: list, options: SolverOptions) -> Section:
    total = sum(p["wall"] for p in plans)
    solves = [s for p in plans for s in p["solves"]]
    rows = []
    for stage in STAGES:
        group = [s for s in solves if s["stage"] == stage]
        if not group:
            continue
        wall = sum(s["wall"] for s in group)
        its = sum(s["iterations"] for s in group)
        evals = {name: sum(s[name] for s in group) for name in EVALUATIONS}
        own = wall - sum(evals.values())
        other = evals["constraints"] + evals["Jacobian"] + evals["objective"]
        spans = sorted({s["spans"] for s in group if s["spans"] is not None})
        rows.append([stage, f"{len(group) / len(plans):.1f}", f"{its / len(group):.0f}",
                     f"{spans[0]}-{spans[-1]}" if spans else "—",
                     f"{100 * wall / total:.0f} %",
                     f"{1e3 * wall / max(its, 1):.2f}",
                     f"{100 * evals['Hessian'] / wall:.0f} %",
                     f"{100 * other / wall:.0f} %",
                     f"{100 * evals['callback'] / wall:.0f} %",
                     f"{100 * own / wall:.0f} %"])
    in_solves = sum(s["wall"] for s in solves)
    build = sum(p["build"] for p in plans)
    verify = sum(p["verify"] for p in plans)
    rest = total - in_solves - build - verify
    walls = [p["wall"] for p in plans]
    lines = [
        f"{len(plans)} Panda cases of the best-motion section (seed {SEED}; even ones point to "
        f"point, odd ones from a joint state; k = {K:g}, URDF limits enforced), each planned "
        f"once with the default `SolverOptions` (`starts={options.starts}, "
        f"candidates={options.candidates}`, verified) after a warm-up plan. "
        f"Plan time median {statistics.median(walls):.2f} s, min {min(walls):.2f} s, "
        f"max {max(walls):.2f} s, {sum(p['ok'] for p in plans)}/{len(plans)} succeeded. "
        "Per stage: IPOPT solves per plan, iterations per solve, the mesh's spans, the share "
        "of all plan time, wall time per IPOPT iteration, and within the stage's solves the "
        "shares of the Lagrangian's Hessian, of the other evaluations (constraints, their "
        "Jacobian, objective), of the Python iteration callback and of IPOPT's own work "
        "(MUMPS factorisations and solves, the adaptive barrier's extra solves, line search). "
        "Command: `scripts/dev run python -P bench/profile_panda.py 20`.",
        "",
    ]
    lines += table(["stage", "solves / plan", "iterations / solve", "spans", "of plan time",
                    "ms / iteration", "Hessian", "other evaluations", "callback", "IPOPT own"],
                   rows)
    lines += ["", *table(["where", "of plan time"], [
        ["all IPOPT solves", f"{100 * in_solves / total:.0f} %"],
        ["building transcriptions (new span counts)", f"{100 * build / total:.0f} %"],
        ["certificate (re-integration, checks)", f"{100 * verify / total:.0f} %"],
        ["the rest (Python: seeding, IK, fits, trajectories)", f"{100 * rest / total:.0f} %"],
    ])]
    lines += ["", *_path_lines(plans)]
    return Section("Where a Panda plan's time goes", lines, [])


def _path_lines(plans: list) -> list[str]:
    """The table of what two cores could share (:func:`two_core_path`), per plan medians."""
    stages = [*STAGES, "other", "not shared"]
    path_total = sum(sum(v[1] for v in p["path"].values()) for p in plans)
    rows = []
    for stage in stages:
        ones = [p["path"].get(stage, (0.0, 0.0))[0] for p in plans]
        twos = [p["path"].get(stage, (0.0, 0.0))[1] for p in plans]
        if not any(ones):
            continue
        rows.append([stage if stage != "not shared" else
                     "not shared (first guess, pad re-solves, seeding, fits, certificate)",
                     f"{sum(ones) / len(plans):.2f}", f"{sum(twos) / len(plans):.2f}",
                     f"{100 * sum(twos) / path_total:.0f} %"])
    ratios = [p["wall"] / sum(v[1] for v in p["path"].values()) for p in plans]
    # The refinement without its level barrier (chained_makespan): the plan's two-core path
    # with the refinement's estimate replaced, lower bound and with the speculative solves.
    free = [[p["wall"] / (sum(v[1] for v in p["path"].values()) - p["unbarred"][k][0]
                          + p["unbarred"][k][1]) for p in plans] for k in (0, 1)]
    refine = [[sum(p["unbarred"][k][j] for p in plans) / len(plans) for j in (0, 1)]
              for k in (0, 1)]
    return [
        "The same plans on two cores, estimated from these one-process timings: the pieces "
        "the planner shares out (`Compiled.map`: the guesses after the first, the "
        "candidates' uniform solves, each refinement level's solves) taken from one queue "
        "by two processes, each piece to the one free first (as `core/planning/pool.py` "
        "does, without its start-up and transfer costs), the rest of the plan in one "
        "process. Seconds per plan (means), and each stage's share of the two-core path. "
        f"Estimated speed-up on two cores: median {statistics.median(ratios):.2f} "
        f"(min {min(ratios):.2f}, max {max(ratios):.2f}); what the planner reaches is "
        "measured in the next section. Without the barrier between refinement levels (each "
        "candidate's next level ready as soon as its own level ends, the pieces still taken "
        "by the process free first; `chained_makespan`): the refinement "
        f"{refine[0][1]:.2f} s per plan instead of {refine[0][0]:.2f} s with the barrier, "
        f"{refine[1][1]:.2f} s counting the solves such a race would start and then discard "
        "(a candidate left behind by a level's window runs one more level, as long as its "
        f"last); estimated speed-up on two cores median {statistics.median(free[0]):.2f} "
        f"(with the discarded solves {statistics.median(free[1]):.2f}).",
        "",
        *table(["stage", "one process (s)", "two cores, estimate (s)", "of the two-core path"],
               rows),
    ]


def _fingerprint(res) -> tuple:
    """Status, every digit of T, the start records and the trajectory's bits."""
    digest = None
    if res.trajectory is not None:
        s = res.trajectory.evaluate(np.linspace(0.0, res.T, 101))
        digest = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes()
                                         for a in (s.q, s.qd, s.u))).hexdigest()
    return (res.status, repr(res.T), digest,
            tuple((r.index, repr(r.guess_T), repr(r.T), r.status) for r in res.starts))


def run_cores(count: int, workers: int = 2) -> Section:
    """The default plan with ``workers`` processes against one, paired, same answer."""
    found = robots().get("Panda")
    if found is None:
        return Section("The Panda on several cores", [
            "example-robot-data is not installed: section skipped."], [])
    model, limits = found
    cases = draw_cases(model, limits, count, seed=SEED)
    problems = [Problem(model, point(model.point(q0)) if i % 2 == 0 else joint_state(q0, qd0),
                        point(target), k=K, limits=limits)
                for i, (q0, qd0, target) in enumerate(cases)]
    one, many = SolverOptions(time_limit=600.0), SolverOptions(time_limit=600.0,
                                                               workers=workers)
    plan(problems[0], many)  # warm-up: compile cache, the workers started and loaded
    rows, ratios, same = [], [], 0
    for i, problem in enumerate(problems):
        order = (one, many) if i % 2 == 0 else (many, one)  # alternate who goes first
        out = {}
        for options in order:
            t0 = time.perf_counter()
            res = plan(problem, options)
            out[options.workers] = (time.perf_counter() - t0, res)
        (t1, r1), (tw, rw) = out[1], out[workers]
        f1, fw = _fingerprint(r1), _fingerprint(rw)
        equal = f1 == fw
        same += equal
        if not equal:  # which part differs, for the log
            parts = [name for name, a, b in zip(("status", "T", "trajectory", "starts"), f1, fw,
                                                strict=True) if a != b]
            log(f"cores Panda {i + 1}: not the same plan: {', '.join(parts)} differ "
                f"(T {r1.T!r} / {rw.T!r}); start records that differ: " + "; ".join(
                    f"{a} / {b}" for a, b in zip(f1[3], fw[3], strict=False) if a != b))
        ratios.append(t1 / tw)
        rows.append([str(i + 1), problem.start.kind, r1.status.name, f"{r1.T:.6f}",
                     f"{t1:.2f}", f"{tw:.2f}", f"{t1 / tw:.2f}", "yes" if equal else "NO"])
        log(f"cores Panda {i + 1}/{count}: 1 worker {t1:.2f} s, {workers} workers {tw:.2f} s, "
            f"same plan: {equal}")
    lines = [
        f"The same {count} Panda cases as the profile above, each planned with the default "
        f"`SolverOptions()` (one process) and with `workers={workers}` (this process and "
        f"{workers - 1} worker process(es): the multistart's guesses after the first, the "
        "bounded solve's candidates and each refinement level shared out, "
        "`core/planning/pool.py`), in alternating order, after a warm-up plan that started the "
        "workers. *Same plan*: status, every digit of T, every start record and the "
        "trajectory's bits at 101 times equal. Ratio: one process's time over the "
        f"workers'. Median ratio {statistics.median(ratios):.2f} (min {min(ratios):.2f}, max "
        f"{max(ratios):.2f}); the same plan in {same}/{count}. "
        f"Command: `scripts/dev run python -P bench/profile_panda.py {count} --cores`.",
        "",
        *table(["case", "start", "status", "T (s)", "1 process (s)",
                f"{workers} processes (s)", "ratio", "same plan"], rows),
    ]
    return Section("The Panda on several cores", lines, [])


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    count = int(argv[0]) if argv and argv[0].isdigit() else 4
    section = run_cores(count) if "--cores" in argv else run(count)
    section.print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
