"""The first motion against the full plan on the Panda with its joint limits (issue 32).

Cases drawn like the joint-limits section's (:func:`bench.limits.draw_cases`, their own seed),
in turn point to point, joint state at rest to point, joint state moving (at up to 30 % of
each velocity limit, drawn here) to point; k = 4, the URDF limits. Per case, in this one
process: the first motion (:meth:`Planner.first`, what ``publish: first_then_optimum``
publishes at once: a warm-up call, then ``runs`` timed calls, each from scratch: seed pairs,
TOPP-RA, certificate) and the plan (``plan()`` with the default :class:`SolverOptions`, as
the planner node's defaults but one process, ``workers=1``; timed once). The paper's example
(point to point, no limits) is the first row.

Run alone: ``scripts/dev run python -P bench/first_motion.py [CASES]`` (prints the section).
"""

import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import (  # noqa: E402
    START,
    TARGET,
    Section,
    fmt_ms,
    load_text,
    log,
    measure,
    paper_model,
    table,
    timed,
)
from bench.limits import draw_cases, robots  # noqa: E402
from tocontrol_ros.core.planning.solver import Planner, SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.robot import compiled  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

SEED = 32
K = 4.0
TIME_LIMIT = 600.0
#: Issue 32's target: the first motion well under this on the Panda, after the warm-up (s).
TARGET_TIME = 0.1
KINDS = ("point", "rest", "moving")


def _problems(model, limits, count):
    rng = np.random.default_rng(SEED)
    out = []
    for i, (q0, _, target) in enumerate(draw_cases(model, limits, count, seed=SEED)):
        kind = KINDS[i % len(KINDS)]
        qd0 = rng.uniform(-0.3, 0.3, model.n) * limits.velocity
        if kind == "point":
            start = point(model.point(q0))
        else:
            start = joint_state(q0, qd0 if kind == "moving" else None)
        out.append((f"Panda {i + 1}, {kind}", Problem(model, start, point(target), k=K,
                                                      limits=limits)))
    return out


def _warm(problem, options):
    """A first motion of the model, then the optimised build of its library (the node's
    warm-up: the first call on a machine compiles the open loop's right-hand sides); then a
    plan, so that no timed plan pays for the solver's builds either."""
    t_first, _ = timed(lambda: Planner(problem.model).first(problem, options))
    t_wait, _ = timed(compiled.wait_for_builds)
    log(f"first motion: first call {t_first:.1f} s, optimised build landed {t_wait:.1f} s "
        f"later")
    t_plan, _ = timed(lambda: plan(problem, options))
    compiled.wait_for_builds()
    log(f"first motion: warm-up plan {t_plan:.1f} s (builds included)")
    return t_first, t_wait


def _case(label, problem, runs, options):
    planner = Planner(problem.model)
    # A new problem object per call: the seed pairs of the same object are kept
    # (seeding.seed_pairs), and the node makes a new problem per request.
    fresh = iter([replace(problem) for _ in range(runs + 1)])
    results, cpu = [], []

    def first_motion():
        c0 = time.process_time()
        results.append(planner.first(next(fresh), options))
        cpu.append(time.process_time() - c0)
        return results[-1]

    first_rec, first = measure("first", first_motion, runs, budget=30.0)
    t_plan, res = timed(lambda: plan(problem, options))
    timed_results = results[len(results) - len(first_rec.times):]
    parts = {key: statistics.median(r.timings.get(key, np.nan) for r in timed_results)
             for key in ("guess", "scaling", "verify")}
    split = ", ".join(f"{key} {fmt_ms(value)}" for key, value in parts.items())
    log(f"first motion {label}: {first.status.name} T {first.T:.4f} in "
        f"{fmt_ms(first_rec.median)} ms ({split}); plan {res.status.name} T {res.T:.4f} "
        f"in {t_plan:.2f} s")
    return {"label": label, "first": first, "rec": first_rec, "res": res, "t_plan": t_plan,
            "parts": parts, "cpu": statistics.median(cpu[len(cpu) - len(first_rec.times):])}


def _row(c):
    first, res, rec = c["first"], c["res"], c["rec"]
    ratio = first.T / res.T if first.success and res.success else np.nan
    how = "certified" if first.success else f"**{first.status.name}**"
    return [c["label"], f"{fmt_ms(rec.median)} ({fmt_ms(rec.min)}-{fmt_ms(rec.max)})",
            fmt_ms(c["cpu"]),
            " / ".join(fmt_ms(c["parts"][k]) for k in ("guess", "scaling", "verify")),
            f"{first.T:.3f}" if first.success else "—", how,
            f"{c['t_plan']:.2f}", f"{res.T:.3f}" if res.success else f"**{res.status.name}**",
            f"{ratio:.2f}" if np.isfinite(ratio) else "—",
            f"{c['t_plan'] / rec.median:.0f}"]


def run(runs: int = 10, count: int = 9) -> Section:
    title = "The first motion against the full plan (issue 32)"
    options = SolverOptions(time_limit=TIME_LIMIT)
    load_start = load_text()
    paper = Problem(paper_model(), point(START), point(TARGET), k=K)
    _warm(paper, options)
    cases = [_case("paper's example", paper, runs, options)]
    found = robots().get("Panda")
    notes = []
    if found is None:
        notes = ["example-robot-data is not installed: only the paper's example.", ""]
    else:
        problems = _problems(*found, count)
        t_first, t_wait = _warm(problems[0][1], options)
        notes = [f"First use on the Panda (an empty compile cache): the first call took "
                 f"{t_first:.1f} s (the open loop's right-hand sides compiled, quick build), "
                 f"the optimised build landed {t_wait:.1f} s later; the planner node does "
                 "this in its warm-up. The timings below are after it.", ""]
        for label, problem in problems:
            cases.append(_case(label, problem, runs, options))
    panda = [c for c in cases if c["label"].startswith("Panda")]
    lines = [
        f"Per case: the first motion (`Planner.first`, what `publish: first_then_optimum` "
        f"publishes before the solve) from scratch each time (seed pairs, TOPP-RA, "
        f"certificate), median (min-max) of {runs} calls after a warm-up call, and its parts "
        "(*guess*: the planner's seed pairs, the target followed from the start and the three "
        "candidate paths timed at rest; *scaling*: TOPP-RA passes and the check between "
        "gridpoints; *verify*: the open-loop certificate); the plan with the default "
        f"`SolverOptions()` (`starts={options.starts}, candidates={options.candidates}`, "
        "one process), timed once with seed pairs of its own (in the node the first "
        "motion's are shared with it, which saves it their inverse kinematics, most of the "
        "first motion's *guess*). Panda cases drawn as in the "
        f"joint-limits section (seed {SEED}), k = 4, URDF limits; kinds in turn point to "
        "point, joint state at rest, joint state moving (up to 30 % of each velocity limit). "
        "*CPU*: the median processor time of the same calls (less sensitive than the wall "
        "time to other work on the machine, not immune to it: see the machine speed above). "
        "*T ratio*: the first "
        "motion's T over the plan's; *plan / first*: how many times longer the plan takes. "
        f"Load average (1, 5, 15 min) at the start {load_start}, at "
        f"the end {load_text()}: other work shared the two cores when above 1.",
        "",
    ] + notes
    lines += table(["case", "first motion (ms)", "CPU (ms)", "guess / scaling / verify (ms)",
                    "T first (s)", "certificate", "plan (s)", "T plan (s)", "T ratio",
                    "plan / first"], [_row(c) for c in cases])
    verdict = "not measured (no Panda)"
    if panda:
        medians = [c["rec"].median for c in panda]
        cpus = [c["cpu"] for c in panda]
        ok = [c for c in panda if c["first"].success and c["res"].success]
        ratios = [c["first"].T / c["res"].T for c in ok]
        certified = sum(c["first"].success for c in panda)
        lines += [
            "",
            f"Panda: {certified} of {len(panda)} first motions certified; time to the first "
            f"motion median {fmt_ms(statistics.median(medians))} ms (slowest case "
            f"{fmt_ms(max(medians))} ms; processor time median "
            f"{fmt_ms(statistics.median(cpus))} ms, slowest case {fmt_ms(max(cpus))} ms) "
            f"against the plan's median "
            f"{statistics.median([c['t_plan'] for c in panda]):.2f} s; the first motion's T "
            + (f"{min(ratios):.2f}-{max(ratios):.2f} times the plan's (median "
               f"{statistics.median(ratios):.2f})." if ratios else "not compared."),
        ]
        best = statistics.median(medians)
        verdict = (("**yes**" if max(medians) < TARGET_TIME else
                    "**median yes, slowest no**" if best < TARGET_TIME else "**no**")
                   + f": median {fmt_ms(best)} ms, slowest case {fmt_ms(max(medians))} ms "
                   f"(processor time: median {fmt_ms(statistics.median(cpus))} ms, slowest "
                   f"{fmt_ms(max(cpus))} ms)")
    return Section(title, lines, [(f"the first motion on the Panda well under "
                                   f"{TARGET_TIME * 1e3:.0f} ms after the warm-up", verdict)])


if __name__ == "__main__":
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 9
    sec = run(runs=5, count=count)
    print("\n".join([f"## {sec.title}", ""] + sec.lines))
    for target, verdict in sec.targets:
        print(f"- {target}: {verdict}")
