"""Scaling with the number of joints: planar arms of 2 to 8 links and a 7-joint Panda.

Planar arms (generated in code, ``bench.common.planar_arm_urdf``): equal uniform rods of
1 m and 1 kg, horizontal plane (gravity does no work), viscous friction 0.1 N m s/rad,
continuous joints, torque limit ``10 (n - i + 1)`` N m at joint i (the number of links it
carries); task space (x, y), so the redundancy is n - 2. One fixed pair of points, reachable
by every arm: (1.2, 0.4) -> (0.4, 1.3) m.

The Panda: ``panda.urdf`` of example-robot-data to ``panda_hand``, fingers locked, standard
gravity, position task (m = 3); two points computed from two joint configurations within the
limits, which are enforced (the plans take the bounded path of ``docs/limits.md``).

Per model: the first plan in this process (symbolic functions built and compiled to C into a
fresh cache: the first-run cost), then cold single-start solves (``starts=1, candidates=1,
verify=False``) with their phase breakdown.
"""

import numpy as np

from bench.common import (
    PANDA_LOCKED,
    Section,
    fmt_ms,
    fmt_s,
    fmt_t,
    log,
    panda_urdf,
    planar_arm_urdf,
    table,
    timed,
)
from tocontrol_ros.core.planning.solver import _PLANNERS, SolverOptions, plan
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, point

PLANAR_NS = (2, 3, 4, 5, 6, 7, 8)
PLANAR_START = (1.2, 0.4)
PLANAR_TARGET = (0.4, 1.3)
K = 4.0
#: k = 1 is Newton on the smooth law alone; k = 4 adds the continuation and the refinement.
PLANAR_KS = (4.0, 1.0)
PANDA_Q_START = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
PANDA_Q_TARGET = (0.8, 0.2, 0.3, -1.6, 0.2, 1.8, 0.5)
PANDA_KS = (4.0, 1.0)
TARGET_PANDA = 1.0
_COMPILED = set()


#: Seed settings: the single start, and a small multistart for when the first seed pair's
#: guess does not converge (redundant arms: the first-ranked pair is not always the best).
SETTINGS = {"1": {"starts": 1, "candidates": 1}, "4x2": {"starts": 4, "candidates": 2}}


def _case(label, model, start, target, k, runs, setting="1"):
    problem = Problem(model, point(start), point(target), k=k)
    opts = SolverOptions(verify=False, **SETTINGS[setting])
    t_first, first = timed(lambda: plan(problem, opts))
    # Optimised builds of the quick-built libraries (core/compiled.py), then the planner that
    # loads them (plan() makes it): the timed runs measure the optimised code.
    t_background, _ = timed(compiled.wait_for_builds)
    if t_background > 0.05:
        plan(problem, opts)
    times, res = [], first
    # A failing solve is repeated once only: its time is that of giving up.
    for _ in range(runs if first.success else 1):
        dt, res = timed(lambda: plan(problem, opts))
        times.append(dt)
    compiled_before = id(model) in _COMPILED
    _COMPILED.add(id(model))
    planner = _PLANNERS.get(id(model))
    stagewise = bool(planner.system.stagewise) if planner is not None else None
    med = float(np.median(times)) if times else float("nan")
    log(f"scaling {label} k = {k:g}, starts {setting}: first {t_first:.2f} s (then "
        f"{t_background:.1f} s of background builds), cold "
        f"{fmt_ms(med)} ms, {res.status.name}, T {res.T:.6f}, {res.iterations} it, "
        f"{res.intervals} intervals")
    return {"label": label, "n": model.n, "m": model.m, "k": k, "setting": setting,
            "first": t_first,
            "first_res": first, "times": times, "median": med, "res": res,
            "stagewise": stagewise, "compiled_before": compiled_before}


def _row(c):
    res = c["res"]
    ph = res.timings
    status = f"ok ({res.method})" if res.success else f"**{res.message}**"
    t = c["times"]
    if c["compiled_before"]:
        first, compile_cost = f"{fmt_s(c['first'])} (compiled above)", "—"
    else:
        first = fmt_s(c["first"])
        compile_cost = fmt_s(c["first"] - c["median"]) if np.isfinite(c["median"]) else "—"
    return [c["label"], c["n"], c["n"] - c["m"], f"{c['k']:g}", c["setting"], first,
            compile_cost,
            f"{fmt_ms(c['median'])} ({fmt_ms(min(t))}-{fmt_ms(max(t))})" if t else "—",
            " / ".join(fmt_ms(ph.get(key, float("nan")))
                       for key in ("guess", "shooting", "refine")),
            res.iterations, res.intervals, fmt_t(res.T),
            "stage-wise" if c["stagewise"] else "whole step", status]


def _exponents(cases) -> list[str]:
    """Cold time against n on the planar arms: least-squares ``log t = a + p log n``."""
    out = []
    for k in PLANAR_KS:
        for setting in SETTINGS:
            pts = [(c["n"], c["median"]) for c in cases if c["k"] == k and
                   c["setting"] == setting and c["res"].success and np.isfinite(c["median"])]
            if len(pts) < 3:
                continue
            n, t = np.log(np.array(pts, dtype=float)).T
            p, a = np.polyfit(n, t, 1)
            out.append(f"- k = {k:g}, starts {setting}: cold time ~ n^{p:.2f} over n = "
                       f"{', '.join(str(int(round(np.exp(v)))) for v in n)} (the rows that "
                       f"succeeded; {np.exp(a) * 1e3:.2f} ms x n^{p:.2f})")
    if out:
        out.insert(0, "Fitted exponent of the cold time against the number of joints "
                      "(planar arms, least squares in log-log):")
    return out


def run(runs, panda_runs):
    cases = []
    for n in PLANAR_NS:
        model = load_robot(planar_arm_urdf(n))
        for k in PLANAR_KS:
            for setting in SETTINGS:
                cases.append(_case(f"planar {n}R", model, PLANAR_START, PLANAR_TARGET, k,
                                   runs, setting))
    path = panda_urdf()
    panda_cases = []
    if path is not None:
        model = load_robot(str(path), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
        a = model.point(np.array(PANDA_Q_START))
        b = model.point(np.array(PANDA_Q_TARGET))
        for k in PANDA_KS:
            for setting in SETTINGS:
                panda_cases.append(_case("Panda", model, a, b, k, panda_runs, setting))
    header = ["arm", "n", "n - m", "k", "starts", "first plan (s)", "compile etc. (s)",
              "cold (ms)", "guess / shooting / refine (ms)", "Newton it.", "intervals",
              "T (s)", "RK4 Jacobian", "status"]
    lines = [
        f"Cold single-start solves, `verify=False`; planar arms {PLANAR_START} -> "
        f"{PLANAR_TARGET} m at k = {K:g} and k = 1 (Newton on the smooth law, no "
        "continuation), the Panda likewise. *First plan*: the first solve of the model in "
        "this process, with a fresh compile cache (builds the symbolic functions and "
        "compiles them to C); *compile etc.* = first plan minus the steady cold median. "
        f"*Cold*: median (min-max) of {runs} further solves ({panda_runs} for the Panda); "
        "phases of the last one; a failing solve is repeated once only. *Starts*: `1` = "
        "`starts=1, candidates=1`, `4x2` = `starts=4, candidates=2` (a small multistart: "
        "on the redundant arms the first-ranked seed pair's guess does not always "
        "converge). Large models use the stage-wise RK4 Jacobian. *Status*: the method "
        "of the plan, `indirect` (the maximum principle's shooting) or `direct` (the "
        "B-spline path of docs/limits.md: the Panda's limits bind, or the shooting failed "
        "and `direct_fallback` solved it; the other columns then have the bounded solve's "
        "figures: IPOPT iterations, spans).",
        "",
    ]
    lines += table(header, [_row(c) for c in cases + panda_cases])
    lines += ["", *_exponents(cases)]
    if panda_cases:
        a = panda_cases[0]["res"].problem
        lines += ["", f"Panda task: q = {list(PANDA_Q_START)} -> {list(PANDA_Q_TARGET)} rad, "
                  f"i.e. P = {np.round(a.start.value, 4).tolist()} -> "
                  f"{np.round(a.target.value, 4).tolist()} m (configurations then free), "
                  "with its URDF limits enforced (docs/limits.md): `method` "
                  f"{', '.join(sorted({c['res'].method for c in panda_cases}))}."]
        warn = [w for c in panda_cases for w in c["res"].warnings if "limit" in w]
        if warn:
            lines += ["", f"Panda notes about the limits: {warn[0]}"
                      + (f" (+{len(warn) - 1} more)" if len(warn) > 1 else "")]
    targets = []
    if panda_cases:
        c = panda_cases[0]  # k = 4, one start
        ok = c["res"].success
        med = c["median"]
        if ok and med < TARGET_PANDA:
            verdict = f"**yes**: {fmt_ms(med)} ms"
        elif ok:
            verdict = f"**no**: {fmt_ms(med)} ms, {med / TARGET_PANDA:.1f}x over"
        else:
            alts = [p for p in panda_cases[1:] if p["res"].success]
            verdict = (f"**no**: at k = {c['k']:g} the cold single-start solve fails "
                       f"({c['res'].message}) after {fmt_ms(med)} ms"
                       + "".join(f"; k = {alt['k']:g}, starts {alt['setting']}: solved in "
                                 f"{fmt_ms(alt['median'])} ms "
                                 f"({alt['median'] / TARGET_PANDA:.1f}x the target), "
                                 f"T = {alt['res'].T:.6f} s" for alt in alts))
        targets.append((f"7-joint arm (Panda) planned cold in < {TARGET_PANDA:g} s "
                        "(steady state, compile cache filled)", verdict))
        targets.append(("7-joint arm, first-ever plan (compilation included)",
                        f"{c['first']:.1f} s at k = {c['k']:g}"))
    return Section("Scaling with the number of joints", lines, targets)
