"""The stage-wise transcription and its solvers on Panda cases, side by side (issue 47).

The NLP of :mod:`tocontrol_ros.core.direct.stagewise` (piecewise-constant accelerations,
``order 1``, unless said; start joint state, target point at rest, the URDF limits padded as
the planner pads them, k = 4) solved by IPOPT (MUMPS), Fatrop and the own SQP with HPIPM
(:mod:`~tocontrol_ros.core.direct.stagewise_sqp`), from the same guesses:

- *cold*: the planner's first seed pair joined by ``initial_path`` (its start velocity is the
  case's only through the bounds);
- *plan*: the planner's own bounded plan (``plan(problem, SolverOptions())``), sampled at the
  nodes.

Sections: cold solves; warm re-solves after a 2 cm move of the target (primal + duals of the
converged solution; the reference is IPOPT converged on the moved problem); replans from the
motion's state 50 and 100 ms in (the rest of the motion as guess; SQP real-time iterations
1-3); meshes (``N``, order and a free mesh, each interval's length a control, against the planner's
``T``); and the evaluation cost of one
iteration's functions compiled (the solvers here evaluate CasADi's SX virtual machine, which
dominates their times: the tables give the solvers' own time per iteration apart).

Fatrop runs in a forked child with a timeout (it has hung inside an iteration before). Every
loop is bounded in count, and the run in time (``--budget``, s). Times wobble on a shared
machine: compare within a table.

Usage: ``scripts/dev run python -P bench/stagewise.py [CASES] [--budget S] [--skip-compiled]``.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench.common import Section, log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED, K  # noqa: E402
from tocontrol_ros.core.direct.collocation import initial_path  # noqa: E402
from tocontrol_ros.core.direct.limited import state_bounds  # noqa: E402
from tocontrol_ros.core.direct.stagewise import StagewiseTranscription  # noqa: E402
from tocontrol_ros.core.direct.stagewise_solve import StagewiseSolver  # noqa: E402
from tocontrol_ros.core.direct.tuning import PAD  # noqa: E402
from tocontrol_ros.core.methods.seeding import seed_pairs  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

#: The default mesh of the comparison, the meshes of the mesh section.
N_MAIN = 30
MESHES = ((20, 1, False), (30, 1, False), (50, 1, False), (20, 2, False), (30, 2, False),
          (20, 1, True), (30, 1, True), (20, 2, True))
#: Target moves (m) and shifts (s).
MOVE = 0.02
SHIFTS = (0.05, 0.10)
#: Fatrop's time limit per solve (s).
FATROP_TIMEOUT = 60.0
SQP_COLD_ITER = 30


def _guarded(fn, timeout: float) -> dict:
    """``fn()`` (returning a dict) in a forked child; ``{"hung": True}`` after ``timeout``."""
    ctx = multiprocessing.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)

    def run():
        try:
            child.send(fn())
        except Exception as e:  # noqa: BLE001  (reported as a failure)
            child.send({"error": repr(e)[:200]})

    proc = ctx.Process(target=run)
    proc.start()
    ready = parent.poll(timeout)
    out = parent.recv() if ready else {"hung": True}
    if proc.is_alive():
        proc.kill()
    proc.join()
    return out


def _summary(r, S=None) -> dict:
    qp = sum(f["qp_s"] for f in S.sqp_log) if S is not None and S.sqp_log else np.nan
    return {"ok": r.success, "status": r.status, "T": r.T, "it": r.iterations,
            "s": r.seconds, "eval": r.eval_seconds, "res": r.residual, "w": r.w,
            "lam_g": r.warm.lam_g, "lam_x": r.warm.lam_x, "qp": qp}


def _solve(S: StagewiseSolver, solver: str, args: tuple, **kw) -> dict:
    """One solve (Fatrop guarded); the summary dict."""
    if solver == "fatrop":
        S.solver("fatrop", kw.get("warm") is not None, kw.get("max_iter"))  # built here
        out = _guarded(lambda: _summary(S.solve(*args, solver=solver, **kw)), FATROP_TIMEOUT)
        if "hung" in out or "error" in out:
            return {"ok": False, "status": "hung" if "hung" in out else out["error"],
                    "T": np.nan, "it": -1, "s": np.nan, "eval": np.nan, "res": np.nan}
        return out
    S.sqp_log = []
    r = S.solve(*args, solver=solver, **kw)
    return _summary(r, S if solver == "sqp" else None)


class Case:
    """One Panda case: problem, bounds, the planner's plan."""

    def __init__(self, model, limits, q0, qd0, target) -> None:
        self.model, self.q0, self.qd0, self.target = model, q0, qd0, target
        self.problem = Problem(model, joint_state(q0, qd0), point(target), k=K, limits=limits)
        self.lo, self.hi = state_bounds(self.problem, PAD)
        self.scale = model.tau_max * self.problem.torque_scale
        self.x0 = np.concatenate([q0, qd0])
        t0 = time.perf_counter()
        self.plan = plan(self.problem, SolverOptions())
        self.plan_s = time.perf_counter() - t0
        self.pair = seed_pairs(self.problem, SolverOptions())[0]

    def args(self, target=None, x0=None) -> tuple:
        return (self.x0 if x0 is None else x0, self.target if target is None else target, K,
                self.scale, self.lo, self.hi)

    def cold_guess(self, tr: StagewiseTranscription) -> np.ndarray:
        from scipy.interpolate import CubicHermiteSpline

        n = self.model.n
        T, x, _ = initial_path(self.model, self.pair[0], self.pair[1], 4 * tr.N,
                               self.problem.torque_scale, self.problem.limits.plan_velocity)
        t = np.linspace(0.0, T, 4 * tr.N + 1)
        acc = np.gradient(x[:, n:], t, axis=0)
        return tr.guess(T, CubicHermiteSpline(t, x[:, :n], x[:, n:]),
                        CubicHermiteSpline(t, x[:, n:], acc))

    def plan_guess(self, tr: StagewiseTranscription) -> np.ndarray:
        tj = self.plan.trajectory
        return tr.guess(self.plan.T, lambda t: tj.evaluate(t).q, lambda t: tj.evaluate(t).qd,
                        lambda t: tj.evaluate(t).qdd)


def _med(v) -> str:
    v = [x for x in v if np.isfinite(x)]
    return f"{statistics.median(v):.3g}" if v else "—"


def _max(v) -> str:
    v = [x for x in v if np.isfinite(x)]
    return f"{max(v):.3g}" if v else "—"


def _row(name: str, recs: list[dict], ref: list[float], every: bool = False) -> list:
    """A table row; ``every``: times and T gaps of every run (real-time iterations), not
    only of the converged ones."""
    ok = [r for r in recs if r["ok"]]
    use = [r for r in recs if np.isfinite(r["T"])] if every else ok
    it = [r["it"] for r in use]
    own = [(r["s"] - r["eval"]) / max(r["it"], 1) * 1e3 for r in use]
    qp = [r.get("qp", np.nan) / max(r["it"], 1) * 1e3 for r in use]
    ev = [r["eval"] / max(r["it"], 1) * 1e3 for r in use]
    gap = [(r["T"] - t) / t for r, t in zip(recs, ref, strict=True)
           if (r["ok"] or every) and np.isfinite(r["T"])]
    return [name, f"{len(ok)}/{len(recs)}", _med(it), _max(it), _med(own), _med(qp),
            _med(ev), _med([r["s"] * 1e3 for r in use]), _med(gap),
            _max(np.abs(gap)) if gap else "—"]


HEAD = ["solver / start", "converged", "iter median", "iter max", "own ms/iter",
        "of which QP ms/iter", "eval ms/iter (VM)", "total ms median", "T gap median",
        "abs T gap max"]


def cold_section(cases, S, budget_end, fatrop=None) -> tuple[list, dict]:
    """Cold solves; returns the lines and the converged IPOPT-from-plan solutions.

    ``fatrop``: the solver (another tolerance) of Fatrop's solves, default ``S``.
    """
    recs = {f"{s} / {g}": [] for s in ("ipopt", "fatrop", "sqp") for g in ("cold", "plan")}
    ref, base = [], {}
    for i, c in enumerate(cases):
        if time.perf_counter() > budget_end:
            break
        ref.append(c.plan.T)
        for g, w0 in (("cold", c.cold_guess(S.tr)), ("plan", c.plan_guess(S.tr))):
            for s in ("ipopt", "fatrop", "sqp"):
                kw = {"max_iter": SQP_COLD_ITER} if s == "sqp" else {}
                r = _solve(fatrop if (s == "fatrop" and fatrop) else S, s, c.args(),
                           guess=w0, **kw)
                recs[f"{s} / {g}"].append(r)
                if s == "ipopt" and g == "plan" and r["ok"]:
                    base[i] = r
        log(f"stagewise: cold case {i}: plan T {c.plan.T:.5f} ({c.plan_s:.2f} s); " + ", ".join(
            f"{k} {v[-1]['T']:.5f} {v[-1]['it']} it {'ok' if v[-1]['ok'] else 'FAIL'}"
            for k, v in recs.items()))
    lines = [f"Cold solves, N = {S.tr.N}, order {S.tr.order}; T gap against the planner's own "
             f"bounded plan (median planner time {_med([c.plan_s for c in cases])} s):", ""]
    lines += table(HEAD, [_row(k, v, ref[:len(v)]) for k, v in recs.items()])
    return lines, base


def warm_section(cases, S, base, rng, budget_end) -> list:
    """2 cm moves from the converged solution; reference: IPOPT converged on the move."""
    recs = {k: [] for k in ("ipopt warm", "fatrop warm (primal)", "sqp 1 it", "sqp 2 it",
                            "sqp 3 it", "sqp to convergence")}
    ref, viol = [], {k: [] for k in recs}
    for i, b in base.items():
        c = cases[i]
        for _ in range(2):
            if time.perf_counter() > budget_end:
                break
            d = rng.normal(size=3)
            tgt = c.target + MOVE * d / np.linalg.norm(d)
            from tocontrol_ros.core.direct.stagewise_solve import StageWarm

            warm = StageWarm(b["w"], b["lam_g"], b["lam_x"])
            r_ref = _solve(S, "ipopt", c.args(tgt), guess=b["w"], warm=warm)
            if not r_ref["ok"]:
                log(f"stagewise: warm case {i}: reference failed ({r_ref['status']})")
                continue
            ref.append(r_ref["T"])
            runs = {"ipopt warm": ("ipopt", None), "fatrop warm (primal)": ("fatrop", None),
                    "sqp 1 it": ("sqp", 1), "sqp 2 it": ("sqp", 2), "sqp 3 it": ("sqp", 3),
                    "sqp to convergence": ("sqp", SQP_COLD_ITER)}
            for k, (s, mi) in runs.items():
                kw = {"max_iter": mi} if mi else {}
                r = _solve(S, s, c.args(tgt), guess=b["w"], warm=warm, **kw)
                if s == "sqp" and mi and mi <= 3:
                    r["ok"] = r["it"] == mi and not r["status"].startswith("QP failed")
                recs[k].append(r)
                viol[k].append(r["res"])
            log(f"stagewise: warm case {i}: ref T {r_ref['T']:.5f} ({r_ref['it']} it); " +
                ", ".join(f"{k} {v[-1]['T']:.5f} res {v[-1]['res']:.1e}"
                          for k, v in recs.items()))
    lines = [f"Warm re-solves after a {MOVE * 100:.0f} cm move (primal and multipliers of the "
             "converged solution; Fatrop 1.1.8 takes no multipliers), T gap against IPOPT "
             "converged on the moved problem:", ""]
    rows = [_row(k, v, ref, every=k.startswith("sqp")) + [_med(viol[k]), _max(viol[k])]
            for k, v in recs.items()]
    lines += table(HEAD + ["residual median", "residual max"], rows)
    return lines


def replan_section(cases, S, base, budget_end) -> list:
    """Replans from the motion's state at 50 and 100 ms; reference: IPOPT converged."""
    recs = {k: [] for k in ("ipopt (duals of the last)", "fatrop (primal)", "sqp 1 it",
                            "sqp 2 it", "sqp 3 it", "sqp to convergence")}
    ref, viol = [], {k: [] for k in recs}
    from tocontrol_ros.core.direct.stagewise_solve import StageWarm

    for i, b in base.items():
        c = cases[i]
        for dt in SHIFTS:
            if time.perf_counter() > budget_end:
                break
            x0, w0 = S.tr.shifted(b["w"], dt)
            warm = StageWarm(w0, b["lam_g"], b["lam_x"])
            r_ref = _solve(S, "ipopt", c.args(x0=x0), guess=w0)
            if not r_ref["ok"]:
                log(f"stagewise: replan case {i}: reference failed ({r_ref['status']})")
                continue
            ref.append(r_ref["T"])
            runs = {"ipopt (duals of the last)": ("ipopt", None), "fatrop (primal)":
                    ("fatrop", None), "sqp 1 it": ("sqp", 1), "sqp 2 it": ("sqp", 2),
                    "sqp 3 it": ("sqp", 3), "sqp to convergence": ("sqp", SQP_COLD_ITER)}
            for k, (s, mi) in runs.items():
                kw = {"max_iter": mi} if mi else {}
                r = _solve(S, s, c.args(x0=x0), guess=w0, warm=warm, **kw)
                if s == "sqp" and mi and mi <= 3:
                    r["ok"] = r["it"] == mi and not r["status"].startswith("QP failed")
                recs[k].append(r)
                viol[k].append(r["res"])
            log(f"stagewise: replan case {i} dt {dt}: ref T {r_ref['T']:.5f}; " +
                ", ".join(f"{k} {v[-1]['T']:.5f} res {v[-1]['res']:.1e}"
                          for k, v in recs.items()))
    lines = ["Replans from the motion's own state 50 and 100 ms in (the rest of the motion as "
             "the guess, the last solve's multipliers), T gap against IPOPT converged:", ""]
    rows = [_row(k, v, ref, every=k.startswith("sqp")) + [_med(viol[k]), _max(viol[k])]
            for k, v in recs.items()]
    lines += table(HEAD + ["residual median", "residual max"], rows)
    return lines


def mesh_section(cases, model, budget_end) -> list:
    """T per mesh (IPOPT from the plan), against the planner's T; the set on a fine sampling."""
    rows = []
    for N, order, free in MESHES:
        S = StagewiseSolver(StagewiseTranscription(model, N, "state", order, free))
        gaps, sets, ok, its, tried = [], [], 0, [], 0
        for c in cases:
            if time.perf_counter() > budget_end:
                break
            tried += 1
            r = S.solve(*c.args(), guess=c.plan_guess(S.tr))
            if r.success:
                ok += 1
                gaps.append((r.T - c.plan.T) / c.plan.T)
                sets.append(float(S.tr.set_values(r.w, K, c.scale).max()))
                its.append(r.iterations)
        rows.append([N, order, "free" if free else "uniform", f"{ok}/{tried}", _med(gaps),
                     _max(gaps), f"{min(gaps):.3g}" if gaps else "—", _max(sets), _med(its)])
        log(f"stagewise: mesh {rows[-1]}")
    return ["Meshes (IPOPT from the plan), T against the planner's bounded plan; the torque "
            "set's largest value on 32 samples per interval:", ""] + table(
        ["N", "order", "mesh", "converged", "T gap median", "T gap max", "T gap min",
         "set max (fine)", "iter median"], rows)


def compiled_section(S: StagewiseSolver, cases) -> list:
    """One iteration's stage functions compiled: their time against the VM's."""
    from tocontrol_ros.core.robot.compiled import compile_function

    f = S.tr.stage_derivatives()
    t0 = time.perf_counter()
    fc, how = compile_function(f)
    build = time.perf_counter() - t0
    N, n = S.tr.N, S.tr.model.n
    _, X, U = S.tr.unpack(cases[0].plan_guess(S.tr))
    args = (X[:N].T, U.T, K, cases[0].scale, np.ones((f.size1_in(4), N)))
    out = []
    for name, fun in (("VM", f), ("compiled", fc)):
        mapped = fun.map(N)
        mapped(*args)
        t0 = time.perf_counter()
        reps = 20
        for _ in range(reps):
            mapped(*args)
        out.append([name, f"{(time.perf_counter() - t0) / reps * 1e3:.2f}"])
    return [f"One iteration's stage functions (rows, Jacobian, Hessian of {N} stages, "
            f"n = {n}), compiled by gcc ({how}, {build:.0f} s):", ""] + table(
        ["evaluation", "ms per iteration"], out)


def run(count: int = 10, budget: float = 2400.0, sections: str = "cold,warm,replan,mesh,compiled",
        fatrop_tol: float | None = 1e-6) -> Section:
    """The tables on ``count`` Panda cases, as a section of BENCHMARKS.md (issue 47)."""
    end = time.perf_counter() + budget
    model, limits = robots()["Panda"]
    raw = draw_cases(model, limits, count, seed=SEED)
    log(f"stagewise: planning {len(raw)} Panda cases")
    cases = [Case(model, limits, *c) for c in raw]
    S = StagewiseSolver(StagewiseTranscription(model, N_MAIN, "state", 1))
    secs = sections.split(",")
    out = [f"Command: `scripts/dev run python -P bench/stagewise.py {count}"
           + (f" --fatrop-tol {fatrop_tol:g}" if fatrop_tol is not None else "") + "`; "
           f"{len(cases)} Panda cases (draw_cases, seed {SEED}; odd ones start moving), "
           f"k = {K:g}. The solvers tried on the same NLPs from the same guesses "
           f"(docs/limits.md, \"Stage-wise transcription\": measured, not adopted).", ""]
    fat = None if fatrop_tol is None else StagewiseSolver(S.tr, tol=fatrop_tol)
    lines, base = cold_section(cases, S, end, fat)
    if fat is not None:
        lines[0] += f" (Fatrop's tolerance {fatrop_tol:g})"
    out += lines + [""]
    if "warm" in secs:
        out += warm_section(cases, S, base, np.random.default_rng(47), end) + [""]
    if "replan" in secs:
        out += replan_section(cases, S, base, end) + [""]
    if "mesh" in secs:
        out += mesh_section(cases, model, end) + [""]
    if "compiled" in secs:
        out += compiled_section(S, cases) + [""]
    return Section("Stage-wise transcription: IPOPT, Fatrop and an SQP with HPIPM on the "
                   "same NLPs (issue 47)", out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="?", type=int, default=10)
    ap.add_argument("--budget", type=float, default=2400.0)
    ap.add_argument("--skip-compiled", action="store_true")
    ap.add_argument("--sections", default="cold,warm,replan,mesh,compiled")
    ap.add_argument("--fatrop-tol", type=float, default=None,
                    help="Fatrop's tolerance in the cold section (default: the others', 1e-8)")
    a = ap.parse_args()
    sections = a.sections if not a.skip_compiled else ",".join(
        x for x in a.sections.split(",") if x != "compiled")
    run(a.cases, a.budget, sections, a.fatrop_tol).print()


if __name__ == "__main__":
    main()
