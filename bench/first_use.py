"""First use of a model: the Panda's compile routes, each in a new process with an empty cache.

The Panda (``panda.urdf`` of example-robot-data to ``panda_hand``, fingers locked), the
scaling section's task at k = 4, one start, verified, planned as a user's first ``plan()``
does: with its URDF joint limits, which bind (the bounded solve: Hermite-Simpson guesses,
then the B-spline transcription of :mod:`tocontrol_ros.core.direct.flat`), and without them (the
maximum principle's multiple shooting). Routes:

- *two tiers* (the default): long sources built at ``-O0`` first, optimised in the
  background (:mod:`tocontrol_ros.core.robot.compiled`);
- *optimised at once* (``TOCONTROL_COMPILE_TIERS=0``): every library optimised before use;
- *-O0 only*: every library unoptimised, to measure what the quick builds cost a solve.

Per route: the first plan (compilation included) and the CPU time of its process and its
compilers, the time until the background builds landed, then the median of cold solves on
the code the route ends with (a new planner, as ``plan()`` makes one once optimised
libraries landed); and for the default route, every library built (C source, build time).
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import (  # noqa: E402
    PANDA_LOCKED,
    Section,
    fmt_ms,
    fmt_s,
    log,
    panda_urdf,
    table,
)

#: The Panda's first-ever plan, compilation included (issue 18).
TARGET_FIRST = 20.0

CODE = r"""
import json, os, resource, sys, time
import numpy as np
t0 = time.perf_counter()
from tocontrol_ros.core.robot import compiled
if os.environ.get("BENCH_O0_ONLY"):
    compiled.CFLAGS = compiled.LARGE_CFLAGS = compiled.QUICK_CFLAGS
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, point
from tocontrol_ros.core.planning.solver import SolverOptions, plan
path, locked, qa, qb, runs, limited = json.loads(sys.argv[1])
builds = []
compiled.add_listener(lambda e, name, info: builds.append(
    (e, name, info.get("seconds"), info.get("bytes"), info.get("flags"))))
model = load_robot(path, tip_link="panda_hand", locked_joints=locked)
limits = None if limited else JointLimits(
    model.joint_names, np.full(model.n, -np.inf), np.full(model.n, np.inf),
    np.full(model.n, np.inf))
pr = Problem(model, point(model.point(np.array(qa))), point(model.point(np.array(qb))),
             k=4.0, limits=limits)
opts = SolverOptions(starts=1, candidates=1)
def cpu():
    own, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF,
                                                  resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime
t1 = time.perf_counter()
c1 = cpu()
r1 = plan(pr, opts)
t2 = time.perf_counter()
c2 = cpu()
compiled.wait_for_builds()
t3 = time.perf_counter()
plan(pr, opts)  # the planner on the final libraries (a new one when optimised ones landed)
times = []
for _ in range(runs):
    ts = time.perf_counter()
    r = plan(pr, opts)
    times.append(time.perf_counter() - ts)
print(json.dumps({"first": t2 - t1, "setup": t1 - t0, "background": t3 - t2,
                  "cpu_python": c2[0] - c1[0], "cpu_compiler": c2[1] - c1[1],
                  "ok": bool(r1.success), "message": r1.message, "T": r1.T,
                  "method": r1.method, "times": times, "ok_after": bool(r.success),
                  "compiled": [b for b in builds if b[0] in ("compiled", "optimised")]}))
"""

PANDA_Q_START = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
PANDA_Q_TARGET = (0.8, 0.2, 0.3, -1.6, 0.2, 1.8, 0.5)
ROUTES = (("two tiers (default)", {}),
          ("optimised at once", {"TOCONTROL_COMPILE_TIERS": "0"}),
          ("-O0 only", {"BENCH_O0_ONLY": "1", "TOCONTROL_COMPILE_TIERS": "0"}))
#: (label, with the URDF limits, routes)
CASES = (("URDF limits", True, ROUTES), ("no limits", False, ROUTES[:1]))


def _route(env_extra, runs, limited):
    import tocontrol_ros

    env = dict(os.environ)
    pkg_parent = str(Path(tocontrol_ros.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([pkg_parent] + ([env["PYTHONPATH"]]
                                                        if env.get("PYTHONPATH") else []))
    env.update(env_extra)
    arg = json.dumps([str(panda_urdf()), PANDA_LOCKED, PANDA_Q_START, PANDA_Q_TARGET, runs,
                      limited])
    with tempfile.TemporaryDirectory(prefix="tocontrol-first-use-") as cache:
        env["TOCONTROL_CACHE"] = cache
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", CODE, arg], env=env,
                              capture_output=True, text=True, timeout=1800)
        wall = time.perf_counter() - t0
    if proc.returncode != 0:
        return {"error": " ".join(proc.stderr.strip().splitlines()[-1:]), "process": wall}
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process"] = wall
    return out


def _libraries(out):
    """Rows per library of one route: C source, quick build, optimised build."""
    libs: dict = {}
    for event, name, seconds, size, flags in out["compiled"]:
        row = libs.setdefault(name, {"bytes": size, "quick": None, "optimised": None})
        # The default route: an -O0 build the solve waited for is a quick build.
        tier = "quick" if event == "compiled" and flags.startswith("-O0") else "optimised"
        row[tier] = (seconds, flags.split()[0])
    return [[name, f"{row['bytes'] / 1e3:.0f}",
             f"{fmt_s(row['quick'][0])} ({row['quick'][1]})" if row["quick"] else "—",
             f"{fmt_s(row['optimised'][0])} ({row['optimised'][1]})" if row["optimised"]
             else "—"] for name, row in libs.items()]


def run(runs=3):
    title = "First use of a model: compile routes (Panda)"
    if panda_urdf() is None:
        return Section(title, ["example-robot-data is not installed: section skipped."])
    results = []
    for case, limited, routes in CASES:
        for label, env in routes:
            out = _route(env, runs, limited)
            log(f"first use, {case}, {label}: "
                f"{json.dumps({k: v for k, v in out.items() if k != 'compiled'})}")
            results.append((case, label, out))
    ref = {case: out for case, label, out in results if label == "optimised at once"}
    rows = []
    for case, label, out in results:
        if "error" in out:
            rows.append([case, label] + ["—"] * 5 + [f"**failed: {out['error']}**"])
            continue
        med = sorted(out["times"])[len(out["times"]) // 2]
        times = ref.get(case, {}).get("times")
        ref_med = sorted(times)[len(times) // 2] if times else None
        built = [b for b in out["compiled"] if b[0] == "compiled"]
        rows.append([case, label, fmt_s(out["first"]),
                     f"{fmt_s(out['cpu_python'], 1)} + {fmt_s(out['cpu_compiler'], 1)}",
                     fmt_s(sum(b[2] or 0.0 for b in built)) + f" ({len(built)} libraries)",
                     fmt_s(out["background"]) if out["background"] > 0.05 else "—",
                     f"{fmt_ms(med)}" + (f" ({med / ref_med:.2f}x)" if ref_med else ""),
                     f"ok ({out['method']})" if out["ok"] and out["ok_after"]
                     else f"**{out['message']}**"])
    lines = [
        "The Panda (the scaling section's task, k = 4, one start, verified) with its URDF "
        "limits, which bind (the bounded solve), and without them (the multiple shooting); "
        "each route in a new process with an empty `TOCONTROL_CACHE`. *First plan*: its "
        "wall time, compilation included; *CPU*: the process's own CPU time during it, plus "
        "its compilers' (on a loaded machine the wall time grows, these less); *gcc before "
        "solving*: the summed time of the builds it waited for (on both cores at once: more "
        "than their wall time); *background*: after the first plan, until the optimised "
        "libraries landed (two tiers only); *cold afterwards*: median of "
        f"{runs} cold solves on the route's final code (ratio to the optimised libraries).",
        "",
    ]
    lines += table(["limits", "route", "first plan (s)", "CPU: Python + gcc (s)",
                    "gcc before solving (s)", "background (s)", "cold afterwards (ms)",
                    "status"], rows)
    default = [out for case, label, out in results
               if case == CASES[0][0] and label == ROUTES[0][0] and "error" not in out]
    if default:
        lines += ["", "Libraries of the default route with the URDF limits (the shooting's "
                  "are built on the first solve that reaches it: none here):", ""]
        lines += table(["library", "C source (kB)", "quick build (s)", "optimised build (s)"],
                       _libraries(default[0]))
    targets = []
    for case, label, out in results:
        if label != ROUTES[0][0] or "first" not in out:
            continue
        verdict = ("**yes**" if out["first"] <= TARGET_FIRST else "**no**") + \
            f": {out['first']:.1f} s" + (f" (optimised at once: {ref[case]['first']:.1f} s)"
                                         if "first" in ref.get(case, {}) else "")
        targets.append((f"Panda first-ever plan (empty cache) <= {TARGET_FIRST:g} s, "
                        f"{case}", verdict))
    return Section(title, lines, targets)


if __name__ == "__main__":
    section = run(runs=int(sys.argv[1]) if len(sys.argv) > 1 else 3)
    section.print()
