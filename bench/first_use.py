"""First use of a model: the Panda's compile routes, each in a new process with an empty cache.

The Panda (``panda.urdf`` of example-robot-data to ``panda_hand``, fingers locked) without
its joint limits (with them the problem goes to the bounded solve, whose own library is
built on first use too), the scaling section's task at k = 4, one start, verified. Routes:

- *two tiers* (the default): long sources built at ``-O0`` first, optimised in the
  background (:mod:`tocontrol_ros.core.compiled`);
- *optimised at once* (``TOCONTROL_COMPILE_TIERS=0``): what every first plan paid before;
- *-O0 only*: every library unoptimised, to measure what the quick builds cost a solve.

Per route: the first plan (compilation included), the time until the background builds
landed, then the median of cold solves on the code the route ends with (a new planner, as
``plan()`` makes one once optimised libraries landed).
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import PANDA_LOCKED, Section, fmt_ms, fmt_s, log, panda_urdf, table

#: The Panda's first-ever plan, compilation included (issue 18).
TARGET_FIRST = 20.0

CODE = r"""
import json, os, sys, time
import numpy as np
t0 = time.perf_counter()
from tocontrol_ros.core import compiled
if os.environ.get("BENCH_O0_ONLY"):
    compiled.CFLAGS = compiled.LARGE_CFLAGS = compiled.QUICK_CFLAGS
from tocontrol_ros.core.limits import JointLimits
from tocontrol_ros.core.model import load_robot
from tocontrol_ros.core.problem import Problem, point
from tocontrol_ros.core.solver import SolverOptions, plan
path, locked, qa, qb, runs = json.loads(sys.argv[1])
builds = []
compiled.add_listener(lambda e, name, info: builds.append((e, name, info.get("seconds"))))
model = load_robot(path, tip_link="panda_hand", locked_joints=locked)
free = JointLimits(model.joint_names, np.full(model.n, -np.inf), np.full(model.n, np.inf),
                   np.full(model.n, np.inf))
pr = Problem(model, point(model.point(np.array(qa))), point(model.point(np.array(qb))),
             k=4.0, limits=free)
opts = SolverOptions(starts=1, candidates=1)
t1 = time.perf_counter()
r1 = plan(pr, opts)
t2 = time.perf_counter()
compiled.wait_for_builds()
t3 = time.perf_counter()
plan(pr, opts)  # the planner on the final libraries (a new one when optimised ones landed)
times = []
for _ in range(runs):
    ts = time.perf_counter()
    r = plan(pr, opts)
    times.append(time.perf_counter() - ts)
print(json.dumps({"first": t2 - t1, "setup": t1 - t0, "background": t3 - t2,
                  "ok": bool(r1.success), "message": r1.message, "T": r1.T,
                  "times": times, "ok_after": bool(r.success),
                  "compiled": [b for b in builds if b[0] in ("compiled", "optimised")]}))
"""

PANDA_Q_START = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
PANDA_Q_TARGET = (0.8, 0.2, 0.3, -1.6, 0.2, 1.8, 0.5)
ROUTES = (("two tiers (default)", {}),
          ("optimised at once", {"TOCONTROL_COMPILE_TIERS": "0"}),
          ("-O0 only", {"BENCH_O0_ONLY": "1", "TOCONTROL_COMPILE_TIERS": "0"}))


def _route(env_extra, runs):
    import tocontrol_ros

    env = dict(os.environ)
    pkg_parent = str(Path(tocontrol_ros.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([pkg_parent] + ([env["PYTHONPATH"]]
                                                        if env.get("PYTHONPATH") else []))
    env.update(env_extra)
    arg = json.dumps([str(panda_urdf()), PANDA_LOCKED, PANDA_Q_START, PANDA_Q_TARGET, runs])
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


def run(runs=3):
    if panda_urdf() is None:
        return Section("First use of a model: compile routes (Panda)",
                       ["example-robot-data is not installed: section skipped."])
    results = []
    for label, env in ROUTES:
        out = _route(env, runs)
        log(f"first use, {label}: {json.dumps({k: v for k, v in out.items() if k != 'compiled'})}")
        results.append((label, out))
    ref = dict(results).get("optimised at once", {})
    ref_med = sorted(ref["times"])[len(ref["times"]) // 2] if ref.get("times") else None
    rows = []
    for label, out in results:
        if "error" in out:
            rows.append([label, "—", "—", "—", "—", f"**failed: {out['error']}**"])
            continue
        med = sorted(out["times"])[len(out["times"]) // 2]
        built = [b for b in out["compiled"] if b[0] == "compiled"]
        rows.append([label, fmt_s(out["first"]),
                     fmt_s(sum(b[2] or 0.0 for b in built)) + f" ({len(built)} libraries)",
                     fmt_s(out["background"]) if out["background"] > 0.05 else "—",
                     f"{fmt_ms(med)}" + (f" ({med / ref_med:.2f}x)" if ref_med else ""),
                     "ok" if out["ok"] and out["ok_after"] else f"**{out['message']}**"])
    lines = [
        "The Panda without joint limits (the scaling section's task, k = 4, one start, "
        "verified), each route in a new process with an empty `TOCONTROL_CACHE`. *First "
        "plan*: its wall time, compilation included; *gcc before solving*: the summed gcc "
        "time of the builds it waited for (on both cores at once: more than their wall "
        "time); *background*: after the first plan, until the optimised libraries "
        "landed (two tiers only); *cold afterwards*: median of "
        f"{runs} cold solves on the route's final code (ratio to the optimised libraries).",
        "",
    ]
    lines += table(["route", "first plan (s)", "gcc before solving (s)",
                    "background (s)", "cold afterwards (ms)", "status"], rows)
    tiers = dict(results).get(ROUTES[0][0], {})
    targets = []
    if "first" in tiers:
        verdict = ("**yes**" if tiers["first"] <= TARGET_FIRST else "**no**") + \
            f": {tiers['first']:.1f} s (optimised at once: " + \
            (f"{ref['first']:.1f} s)" if "first" in ref else "failed)")
        targets.append((f"Panda first-ever plan (empty cache) <= {TARGET_FIRST:g} s, "
                        "without joint limits", verdict))
    return Section("First use of a model: compile routes (Panda)", lines, targets)
