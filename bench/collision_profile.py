"""Where a collision plan's time goes (issue 51): per stage, per IPOPT solve.

Cases of :mod:`bench.collision` (the Panda, its limits and SRDF, k = 4, margin 1 cm, the
draws of :data:`bench.collision.SEED`, the scenes of ``bench/scenes/`` placed on each
draw's obstacle-free optimum as that module places them), each planned once by ``plan()``
with the bench's options (4 starts, 1 candidate), every piece of work recorded:

- every bounded IPOPT solve (``FlatTranscription.solve``, wrapped): its stage (read off the
  call stack: a seed basin's uniform-mesh solve, its continuation in ``k``, the detour's
  steps, a refinement level, a pad round, a self-row round's warm solve), spans, rows (of
  them clearance rows), IPOPT's iterations and status, ``T``, processor time (the solving
  thread's, ``time.thread_time``) and CasADi's own counters of the time in the rows, their
  Jacobian and the Lagrangian's Hessian; for a basin's first solve, whether its guess
  collides (the spheres, :func:`~tocontrol_ros.core.direct.detour.path_collides`, the check
  the detour uses, timed apart and not counted in the plan's);
- the builds of transcriptions (``FlatTranscription.__init__``: the NLP, its compiled
  libraries), the seeds' coarse direct solves, the detour seed
  (:func:`~tocontrol_ros.core.direct.detour.detour_guess`), the certificates;
- the self-row rounds (each ``solve_once`` after the first).

Then the clearance rows' share of an iteration: the NLP's Jacobian and Hessian evaluated
on the first uniform mesh with the scene and without it (the same spans), alternated.

Run: ``scripts/dev run python -P bench/collision_profile.py 1:table 2:shelf 4:pillar``
(``CASE:SCENE`` pairs). The refinement's active set (:mod:`~tocontrol_ros.core.direct.
active_rows`): ``--full-rows`` plans without it (main before it); ``--paired`` runs each
refinement solve both ways in the plan, alternated (the plan follows the active set's
answer); ``--both`` plans each case with the full rows, then with the active set.
docs/collision.md ("Where a collision plan's time goes") has what these measured.
"""

from __future__ import annotations

import collections
import inspect
import os
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.collision import DRAWS, SEED, K, load_scene_dict  # noqa: E402
from bench.common import PANDA_LOCKED, log, panda_urdf  # noqa: E402
from bench.limits import draw_cases  # noqa: E402
from tocontrol_ros.core.direct import (  # noqa: E402
    active_rows,
    collocation,
    detour,
    flat,
    limited,
)
from tocontrol_ros.core.direct.bspline import basis  # noqa: E402
from tocontrol_ros.core.geometry.collision import collision_model  # noqa: E402
from tocontrol_ros.core.geometry.scene import scene_from_dict  # noqa: E402
from tocontrol_ros.core.planning import solver  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.robot.kinematics import tip_poses  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

#: Function names on the call stack of a bounded solve -> its stage (the innermost wins).
STAGES = {"_detour_solve": "detour steps", "_continued_in_k": "basin: k-continuation",
          "_uniform": "basin: uniform", "_refine_item": "refinement",
          "_inside_set": "pad round", "plan_limited_warm": "self-row warm"}
#: CasADi's per-solve processor-time counters (s).
COUNTERS = {"g": "t_proc_nlp_g", "Jacobian": "t_proc_nlp_jac_g",
            "Hessian": "t_proc_nlp_hess_l"}


def _stage() -> str:
    frame = inspect.currentframe()
    while frame is not None:
        if frame.f_code.co_name in STAGES:
            return STAGES[frame.f_code.co_name]
        frame = frame.f_back
    return "other"


class Recorder:
    """Wraps the solve's pieces (see the module) and keeps what each cost."""

    def __init__(self, collision, paired: bool = False) -> None:
        self.collision, self.paired, self.pairs = collision, paired, []
        self.solves: list[dict] = []
        self.costs: collections.Counter = collections.Counter()
        self.round = 0
        self._undo: list = []

    def _wrap(self, owner, name: str, make) -> None:
        orig = getattr(owner, name)
        self._undo.append((owner, name, orig))
        setattr(owner, name, make(orig))

    def __enter__(self) -> Recorder:
        rec = self

        def timed(key):
            def make(orig):
                def wrapper(*args, **kwargs):
                    t0 = time.thread_time()
                    try:
                        return orig(*args, **kwargs)
                    finally:
                        rec.costs[key] += time.thread_time() - t0
                        rec.costs[key + " (count)"] += 1
                return wrapper
            return make

        self._wrap(flat.FlatTranscription, "solve", self._solve)
        self._wrap(flat.FlatTranscription, "__init__", timed("transcription builds"))
        self._wrap(collocation.DirectCollocation, "solve", timed("seeds' direct solves"))
        self._wrap(limited, "detour_guess", timed("detour seed (IK, OMPL)"))
        self._wrap(limited, "path_collides", timed("guesses' collision check"))
        self._wrap(limited, "verified", timed("certificates"))

        def rounds(orig):
            def wrapper(*args, **kwargs):
                rec.round += 1
                return orig(*args, **kwargs)
            return wrapper

        self._wrap(solver, "solve_once", rounds)
        if self.paired:
            self._wrap(limited, "active_rows_solve", self._paired)
        return self

    def _paired(self, orig):
        """Each refinement solve both ways, alternated: the active set (B) and the full NLP (A).

        B's cost includes the full solve the caller then makes when B returns None; B's
        answer is returned (the plan follows the new code).
        """
        rec = self

        def wrapper(flat_, values, T, P0, bounds, **budget):
            got = {}
            order = ("B", "A") if len(rec.pairs) % 2 == 0 else ("A", "B")
            for which in order:
                t0 = time.thread_time()
                out = orig(flat_, values, T, P0, bounds, **budget) if which == "B" \
                    else flat_.solve(*values, T, P0, *bounds, **budget)
                got[which] = (out, time.thread_time() - t0)
            (a, ca_), (b, cb) = got["A"], got["B"]
            keep = None
            if flat_.clearance is not None:
                slack = np.min(flat_.clearance_slack(*values, T, P0), axis=1)
                keep = int(np.sum(slack < active_rows.ROW_BAND))
            entry = {"spans": flat_.spans, "samples": len(flat_.samples), "kept": keep,
                     "A T": a.T, "A ok": a.success, "A it": a.iterations, "A cpu": ca_,
                     "B T": b.T if b is not None else None,
                     "B ok": None if b is None else b.success,
                     "B it": None if b is None else b.iterations,
                     "B cpu": cb + (ca_ if b is None else 0.0)}
            rec.pairs.append(entry)
            log(f"  paired: {entry}")
            return b
        return wrapper

    def __exit__(self, *exc) -> None:
        for owner, name, orig in reversed(self._undo):
            setattr(owner, name, orig)

    def _solve(self, orig):
        rec = self

        def solve(obj, start, target, k, t_guess, p_guess, *args, **kwargs):
            stage = _stage()
            collides = None
            if stage.startswith("basin") and obj.clearance is not None:
                c0 = time.thread_time()
                s = np.linspace(0.0, 1.0, 8 * obj.spans + 1)
                span, b = basis(obj.breaks, obj.degree, s)
                P = np.asarray(p_guess)
                q = np.einsum("sk,skn->sn", b[:, 0],
                              P[span[:, None] + np.arange(obj.degree + 1)[None, :]])
                collides = detour.path_collides(rec.collision, q)
                rec.costs["(instrument)"] += time.thread_time() - c0
            t0, w0 = time.thread_time(), time.perf_counter()
            out = orig(obj, start, target, k, t_guess, p_guess, *args, **kwargs)
            cpu, wall = time.thread_time() - t0, time.perf_counter() - w0
            st = obj.solver.stats()
            clear = 0 if obj.clearance is None else \
                len(obj.clearance.groups()) * len(obj.samples)
            entry = {"round": rec.round, "stage": stage, "spans": int(obj.spans),
                     "rows": int(obj.rows), "clearance rows": int(clear), "k": float(k),
                     "warm": obj.warm,
                     "iterations": int(out.iterations), "success": out.success,
                     "message": out.message[:40], "T": out.T, "cpu": cpu, "wall": wall,
                     "guess collides": collides}
            for key, name in COUNTERS.items():
                entry[key] = float(st.get(name, 0.0))
            rec.solves.append(entry)
            log(f"  solve: r{rec.round} {stage} L={obj.spans} rows={obj.rows} "
                f"clear={clear} k={float(k):g} warm={obj.warm} it={out.iterations} "
                f"{out.message[:30]} T={out.T:.4f} cpu={cpu:.1f} s "
                f"ms/it={1e3 * cpu / max(out.iterations, 1):.0f} "
                f"jac={entry['Jacobian']:.1f} hess={entry['Hessian']:.1f} "
                f"collides={collides}")
            return out
        return solve


def placed_scene(name: str, free, model):
    """The scene ``name`` placed on the free optimum's path, as :mod:`bench.collision` does."""
    t = np.linspace(0.0, free.T, 401)
    _, tips = tip_poses(model, free.trajectory.evaluate(t).q)
    mid = tips[200]
    data = load_scene_dict(name)
    for ob in data["obstacles"]:
        if ob["name"] in ("shelf", "pillar"):
            z = ob.get("position", [0, 0, 0])[2] if ob["name"] == "pillar" else mid[2]
            ob["position"] = [float(mid[0]), float(mid[1]), float(z)]
    return scene_from_dict(data, f"bench scene {name}")


def row_share(problem: Problem, free_problem: Problem, spans: int = 32, calls: int = 10
              ) -> dict:
    """Processor time (ms) of the NLP's Jacobian and Hessian with the scene and without it.

    The bounded transcription on ``spans`` uniform spans, at a straight joint path from
    the start to its mirror, all multipliers 1; the two alternated, ``calls`` each.
    """
    from tocontrol_ros.core.planning.solver import Planner

    planner = Planner(problem.model)
    out = {}
    flats = {"scene": planner.flat(problem, spans), "none": planner.flat(free_problem, spans)}
    n = problem.model.n
    q0 = problem.start.value[:n]
    P = np.linspace(q0, q0[::-1] * 0.5, flats["scene"].K)
    w = np.concatenate([P.ravel(), [1.0]])
    times = {key: {"jac": [], "hess": []} for key in flats}
    for _ in range(calls):
        for key, tr in flats.items():
            par = tr.parameters(problem.start.value, problem.target.value, problem.k)
            jac, hess = tr.kkt_functions
            t0 = time.thread_time()
            jac(w, par)
            t1 = time.thread_time()
            hess(w, par, 1.0, np.ones(tr.rows))
            t2 = time.thread_time()
            times[key]["jac"].append(t1 - t0)
            times[key]["hess"].append(t2 - t1)
    for key, tr in flats.items():
        out[key] = {"rows": tr.rows, **{f: 1e3 * float(np.median(v))
                                       for f, v in times[key].items()}}
    return out


def run(pairs: list[tuple[int, str]], paired: bool = False, full_rows: bool = False,
        both: bool = False) -> list[dict]:
    """Plan each (draw, scene) once, recorded; print the table; return the records."""
    urdf = panda_urdf()
    srdf = urdf.parent.parent / "srdf" / "panda.srdf"
    model = load_robot(str(urdf), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    limits = JointLimits.from_model(model)
    base = collision_model(model, urdf, srdf)
    options = SolverOptions(starts=4, candidates=1, time_limit=1800.0)
    draws = draw_cases(model, limits, DRAWS * 4, SEED)
    frees, out = {}, []
    # --both: each case with the full rows (main's refinement), then with the active set
    runs = [(c, n, f) for c, n in pairs for f in ((True, False) if both else (full_rows,))]
    for case, name, full in runs:
        q0, _, target = draws[case]
        if case not in frees:
            frees[case] = plan(Problem(model, joint_state(q0), point(target), k=K,
                                       limits=limits), options)
        free = frees[case]
        col = base.with_scene(placed_scene(name, free, model))
        problem = Problem(model, joint_state(q0), point(target), k=K, limits=limits,
                          collision=col)
        active_rows.ACTIVE_ROWS = not full
        with Recorder(col, paired) as rec:
            t0, w0 = time.process_time(), time.perf_counter()
            res = plan(problem, options)
            cpu, wall = time.process_time() - t0, time.perf_counter() - w0
        share = row_share(problem, free.problem)
        out.append({"case": case, "scene": name, "full rows": full,
                    "status": res.status.name, "T": res.T,
                    "cpu": cpu, "wall": wall, "solves": rec.solves, "costs": dict(rec.costs),
                    "timings": dict(res.timings), "share": share, "message": res.message,
                    "pairs": rec.pairs})
        report(out[-1])
    return out


def report(r: dict) -> None:
    """Print one plan's record."""
    log(f"case {r['case']} {r['scene']} full rows {r['full rows']}: {r['status']} T "
        f"{r['T']:.9f} cpu {r['cpu']:.1f} s "
        f"wall {r['wall']:.1f} s: {r['message'][:160]}")
    by = collections.defaultdict(lambda: [0, 0, 0.0])
    for s in r["solves"]:
        key = (s["round"], s["stage"])
        by[key][0] += 1
        by[key][1] += s["iterations"]
        by[key][2] += s["cpu"]
    for (rnd, stage), (count, its, cpu) in sorted(by.items()):
        log(f"  round {rnd} {stage:24s} {count:3} solves {its:5} it {cpu:7.1f} s cpu")
    for key, v in sorted(r["costs"].items()):
        log(f"  {key:32s} {v:8.2f}")
    for s in r["solves"]:
        per = 1e3 * s["cpu"] / max(s["iterations"], 1)
        log(f"    r{s['round']} {s['stage']:22s} L={s['spans']!s:>3} rows={s['rows']!s:>5} "
            f"clear={s['clearance rows']!s:>4} k={s['k']:.0f} warm={s['warm']!s:7s} "
            f"it={s['iterations']!s:>3} {s['message'][:28]:28s} T={s['T']:.4f} "
            f"cpu={s['cpu']:6.1f} ms/it={per:6.1f} jac={s['Jacobian']:.1f} "
            f"hess={s['Hessian']:.1f} collides={s['guess collides']}")
    log(f"  rows' share (32 spans, ms a call): {r['share']}")


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("pairs", nargs="+", help="CASE:SCENE, e.g. 1:table")
    parser.add_argument("--paired", action="store_true",
                        help="each refinement solve with the active set and without, paired")
    parser.add_argument("--full-rows", action="store_true",
                        help="the refinement without the active set (main's)")
    parser.add_argument("--both", action="store_true",
                        help="each case with the full rows, then with the active set")
    args = parser.parse_args()
    run([(int(p.split(":")[0]), p.split(":")[1]) for p in args.pairs], args.paired, args.full_rows,
        args.both)
