"""The bounded solves' Newton matrix without the inverse dynamics' second derivatives.

Issue 47 (the Panda's cold plan in 1 s): each IPOPT iteration of the bounded B-spline NLP
(:mod:`tocontrol_ros.core.direct.flat`) evaluates the Lagrangian's Hessian through the
per-sample library ``flat_set_hess``,

    mu Hess_z c = Juz^T diag(mu c'') Juz + Jy^T Hess_y(w^T u) Jy + sum_j (Ju^T w)_j Hess_z y_j,

whose middle term (the inverse dynamics' second derivatives) is about half of the library's
instructions. Leaving it out (``hessian="id_linear"``), or everything but the first term
(``"ggn"``, the generalised Gauss-Newton matrix: positive semi-definite, the set being
convex in ``u``), changes only the matrix IPOPT's Newton steps use, not the NLP nor its KKT
conditions. This measures whether IPOPT's iterations rise more than their cost falls.

The bounded solves of the default plans of ``bench/profile_panda.py``'s first cases (seed of
:mod:`bench.optimum_panda`; even cases point to point, odd ones from a joint state; k = 4,
the URDF limits; ``workers=1``) are captured (the transcription's arguments, its
breakpoints, the solve's start, bounds and pad) and solved again, in this one process, on a
new transcription of each Hessian kind (the same breakpoints), the kinds alternated solve by
solve. Per stage (the uniform mesh's cold solves, the refined meshes' warm ones, the set
pad's re-solves) and kind: converged solves, IPOPT iterations, CPU time
(``time.process_time``, summed over the solves), CPU per iteration, the share of the
Hessian's evaluations (CasADi's ``t_proc_nlp_hess_l``), and ``T`` against the exact
Hessian's re-solve (the same to 1e-6, worse or better by more than 1e-4).

A kind may name IPOPT's linear solver and its options after the Hessian, joined by ``+``:
``exact+spral`` (SPRAL, in the CasADi wheel's IPOPT; it wants ``OMP_CANCELLATION=TRUE
OMP_PROC_BIND=TRUE`` in the environment), ``exact+mumps+mumps_mem_percent=100``.

Run alone: ``scripts/dev run python -P bench/hessian_gn.py [CASES] [KIND ...]`` (default 6
cases, kinds ``id_linear ggn``); ``--library`` instead times the three per-sample Hessian
libraries alone on the same inputs (what a cheaper middle term could save at most).
"""

from __future__ import annotations

import collections
import os
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED, K  # noqa: E402
from tocontrol_ros.core import Problem, SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.direct import flat  # noqa: E402
from tocontrol_ros.core.direct.bspline import basis  # noqa: E402
from tocontrol_ros.core.robot import compiled  # noqa: E402
from tocontrol_ros.core.types.problem import joint_state, point  # noqa: E402

#: The solve's keyword arguments replayed (the rest are the caller's clock and callbacks).
REPLAYED = ("set_pad", "max_iter", "lam_g0", "lam_x0")


def problems(count: int) -> list[Problem]:
    """``bench/profile_panda.py``'s cases: even ones point to point, odd from a state."""
    model, limits = robots()["Panda"]
    return [Problem(model, point(model.point(q0)) if i % 2 == 0 else joint_state(q0, qd0),
                    point(target), k=K, limits=limits)
            for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count, seed=SEED))]


def stage(spec: dict, kwargs: dict) -> str:
    """Which stage of a plan a bounded solve belongs to."""
    if spec.get("warm") in ("resume", "restart") or "set_pad" in kwargs:
        return "pad re-solves"
    if spec.get("warm") is True:
        return "refined"
    if spec.get("warm") is False:
        return "uniform"
    return f"warm={spec.get('warm')}"


def keep_specs() -> None:
    """Each transcription built from now on keeps its arguments (``bench_spec``)."""
    init = flat.FlatTranscription.__init__

    def init_(obj, model, spans, *args, **kwargs):
        names = ("start_kind", "target_kind", "degree", "per_span", "torque_scale", "tol",
                 "max_iter", "warm", "clearance", "acceleration")
        obj.bench_spec = {**dict(zip(names, args, strict=False)), **kwargs,
                          "spans": int(spans) if np.ndim(spans) == 0 else len(spans) - 1}
        init(obj, model, spans, *args, **kwargs)

    flat.FlatTranscription.__init__ = init_


def capture(cases: list[Problem]) -> list[dict]:
    """The bounded solves of the cases' default plans: what it takes to make them again."""
    solves = []
    solve = flat.FlatTranscription.solve

    def solve_(obj, *args, **kwargs):
        out = solve(obj, *args, **kwargs)
        kept = {k: v for k, v in kwargs.items() if k in REPLAYED}
        solves.append({"spec": obj.bench_spec, "breaks": obj.breaks.copy(), "args": args,
                       "kwargs": kept, "stage": stage(obj.bench_spec, kept),
                       "T": out.T, "iterations": out.iterations, "success": out.success})
        return out

    flat.FlatTranscription.solve = solve_
    try:
        for i, problem in enumerate(cases):
            res = plan(problem, SolverOptions(time_limit=600.0))
            log(f"hessian_gn capture {i + 1}/{len(cases)}: {res.status.name} T {res.T:.6f}, "
                f"{len(solves)} bounded solves so far")
    finally:
        flat.FlatTranscription.solve = solve
    return solves


def _number(text: str) -> int | float | str:
    """An option's value: an integer, a float, else the text."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


class Replayer:
    """New transcriptions of each Hessian kind, one per captured constructor's arguments."""

    def __init__(self, model) -> None:
        self.model = model
        self.built: dict = {}

    def transcription(self, spec: dict, breaks: np.ndarray, kind: str
                      ) -> flat.FlatTranscription:
        spec = {k: v for k, v in spec.items() if k != "hessian"}
        key = (repr(sorted((k, repr(v)) for k, v in spec.items())), kind)
        base = self.built.get(key)
        if base is None:
            hessian, _, linear = kind.partition("+")
            kwargs = {k: v for k, v in spec.items() if k != "spans"}
            options_of = flat.ipopt_options
            if linear:  # IPOPT's linear solver, and its options (name=value, joined by +)
                extra = {"ipopt.linear_solver": linear.split("+")[0]}
                for part in linear.split("+")[1:]:
                    name, _, value = part.partition("=")
                    extra[f"ipopt.{name}"] = _number(value)
                flat.ipopt_options = lambda *args: {**options_of(*args), **extra}
            try:
                base = self.built[key] = flat.FlatTranscription(
                    self.model, spec["spans"], hessian=hessian, **kwargs)
            finally:
                flat.ipopt_options = options_of
        return base if np.array_equal(breaks, base.breaks) else base.on(breaks)

    def solve(self, item: dict, hessian: str) -> dict:
        nlp = self.transcription(item["spec"], item["breaks"], hessian)
        c0 = time.process_time()
        out = nlp.solve(*item["args"], **item["kwargs"])
        cpu = time.process_time() - c0
        stats = nlp.solver.stats()
        evaluations = sum(float(v) for name, v in stats.items()
                          if name.startswith("t_proc_nlp_") or name == "t_proc_callback_fun")
        total = float(stats.get("t_proc_total", cpu))
        return {"T": out.T, "success": out.success, "iterations": out.iterations, "cpu": cpu,
                "hess": float(stats.get("t_proc_nlp_hess_l", 0.0)), "total": total,
                "own": total - evaluations}


def replay(solves: list[dict], kinds: list[str], model) -> dict:
    """Every captured solve again with each kind (``"exact"`` first in the list), alternated."""
    rep = Replayer(model)
    per = {kind: [] for kind in kinds}
    for i, item in enumerate(solves):
        order = kinds if i % 2 == 0 else kinds[::-1]
        got = {kind: rep.solve(item, kind) for kind in order}
        for kind in kinds:
            per[kind].append({**got[kind], "stage": item["stage"]})
        if i % 10 == 0:
            log(f"hessian_gn replay {i + 1}/{len(solves)} ({item['stage']}): " + ", ".join(
                f"{kind} {got[kind]['iterations']} it {got[kind]['cpu']:.2f} s "
                f"T {got[kind]['T']:.7f}" for kind in kinds))
    return per


def rows(per: dict, kinds: list[str]) -> list[list[str]]:
    base = per["exact"]
    out = []
    stages = sorted({r["stage"] for r in base}, key=["uniform", "refined", "pad re-solves"].index
                    if all(r["stage"] in ("uniform", "refined", "pad re-solves") for r in base)
                    else str)
    for name in [*stages, "all"]:
        pick = [j for j, r in enumerate(base) if name in ("all", r["stage"])]
        for kind in kinds:
            got = [per[kind][j] for j in pick]
            ref = [base[j] for j in pick]
            its = sum(g["iterations"] for g in got)
            cpu = sum(g["cpu"] for g in got)
            gap = np.array([(g["T"] - b["T"]) / b["T"] if g["success"] and b["success"]
                            else np.nan for g, b in zip(got, ref, strict=True)])
            out.append([name, kind, f"{len(pick)}", f"{sum(g['success'] for g in got)}",
                        f"{its}", f"{cpu:.2f}",
                        f"{cpu / sum(b['cpu'] for b in ref):.2f}",
                        f"{1e3 * cpu / max(its, 1):.2f}",
                        f"{sum(g['hess'] for g in got) / sum(g['total'] for g in got):.2f}",
                        f"{1e3 * sum(g['own'] for g in got) / max(its, 1):.2f}",
                        f"{int(np.sum(np.abs(gap) <= 1e-6))}",
                        f"{int(np.sum(gap > 1e-4))} / {int(np.sum(gap < -1e-4))}",
                        f"{np.nanmax(np.abs(gap)) if np.any(np.isfinite(gap)) else np.nan:.1e}"])
    return out


def run(count: int, kinds: list[str]) -> list[str]:
    model = robots()["Panda"][0]
    kinds = ["exact", *[k for k in kinds if k != "exact"]]
    hessians = sorted({kind.partition("+")[0] for kind in kinds})
    for hessian in hessians:  # the libraries built and their optimised builds landed first
        flat.compile_flat(model, 3, hessian)
    compiled.wait_for_builds()
    for hessian in hessians:
        log(f"hessian_gn library {hessian}: {flat.compile_flat(model, 3, hessian)[1]}")
    keep_specs()
    cases = problems(count)
    plan(cases[0], SolverOptions(time_limit=600.0))  # warm-up: compile cache
    solves = capture(cases)
    log(f"hessian_gn: {len(solves)} bounded solves, "
        f"{dict(collections.Counter(s['stage'] for s in solves))}")
    per = replay(solves, kinds, model)
    return [f"The bounded solves of {count} default Panda plans (bench/profile_panda.py's "
            f"cases, {len(solves)} solves) solved again from their captured starts with "
            "each Hessian kind, paired solve by solve in one process. CPU: process time "
            "summed over the solves; ratio: to the exact Hessian's on the same solves; "
            "Hessian share: CasADi's t_proc_nlp_hess_l over IPOPT's t_proc_total; IPOPT's own: "
            "t_proc_total less the function evaluations (its linear algebra and the rest). "
            f"Command: `scripts/dev run python -P bench/hessian_gn.py {count} "
            f"{' '.join(kinds[1:])}`.", "",
            *table(["stage", "Hessian", "solves", "converged", "iterations", "CPU (s)",
                    "CPU / exact's", "CPU per iteration (ms)", "Hessian share",
                    "IPOPT's own per iteration (ms)",
                    "same T (1e-6)", "T worse / better by > 1e-4", "largest |T gap|"],
                   rows(per, kinds))]


def library(rounds: int = 40, calls: int = 5) -> list[str]:
    """The per-sample library of each Hessian kind alone, mapped over a 32-span mesh's samples.

    The same inputs for the three (a straight joint path of the Panda at T = 0.6 s, k = 4,
    multipliers in [0, 1]); the kinds alternated within each round, process time; medians
    over the rounds of each kind's time and of its ratio to the exact one's in that round.
    """
    model = robots()["Panda"][0]
    for hessian in flat.HESSIANS:
        flat.compile_flat(model, 3, hessian)
    compiled.wait_for_builds()
    nlp = flat.FlatTranscription(model, 32, "point", "point")
    S, d1 = len(nlp.samples), nlp.degree + 1
    span, b = basis(nlp.breaks, nlp.degree, nlp.samples)
    rng = np.random.default_rng(0)
    q0, q1 = rng.uniform(-0.8, 0.8, model.n), rng.uniform(-0.8, 0.8, model.n)
    P = q0 + (q1 - q0) * np.linspace(0.0, 1.0, nlp.K)[:, None]
    cols = (span[:, None] + np.arange(d1)[None, :]).ravel()
    args = (P[cols].T, 0.6, np.concatenate(list(b), axis=1), 4.0, nlp.scale,
            rng.uniform(0.0, 1.0, S))
    maps = {h: flat.compile_flat(model, 3, h)[0][2].map(S) for h in flat.HESSIANS}
    times = {h: [] for h in flat.HESSIANS}
    for r in range(rounds):
        for h in (flat.HESSIANS if r % 2 == 0 else flat.HESSIANS[::-1]):
            c0 = time.process_time()
            for _ in range(calls):
                maps[h](*args)
            times[h].append((time.process_time() - c0) / calls)
    exact = np.array(times["exact"])
    rows = [[h, f"{1e6 * np.median(times[h]) / S:.1f}",
             f"{np.median(np.array(times[h]) / exact):.2f}"] for h in flat.HESSIANS]
    return [f"The per-sample Hessian library of each kind, mapped over the {S} samples of a "
            f"32-span Panda mesh, {rounds} rounds of {calls} calls, alternated, process time "
            "(load {:.1f}). Command: `scripts/dev run python -P bench/hessian_gn.py "
            "--library`.".format(os.getloadavg()[0]), "",
            *table(["Hessian", "per sample (us)", "to the exact one's (paired)"], rows)]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--library"]:
        print("\n".join(library()))
        return 0
    count = int(argv[0]) if argv and argv[0].isdigit() else 6
    kinds = (argv[1:] if argv and argv[0].isdigit() else argv) or ["id_linear", "ggn"]
    for kind in kinds:
        if kind.partition("+")[0] not in flat.HESSIANS:
            raise SystemExit(f"unknown Hessian kind {kind!r} (one of {flat.HESSIANS})")
    print("\n".join(run(count, kinds)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
