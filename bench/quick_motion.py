"""A replan's quick motion in process, its parts, against TOPP-RA's drivers before issue 47's
cuts, in the same run.

The cases are the replans of ``bench/replan.py --moving``, made here in one process: the
paper's arm after goals on its 0.3 m circle, the Panda in the README's set-up (start
configuration, limit margin 0.05) after goals twice around its 0.25 m circle, 10 Hz; each
replan starts from the last quick motion's state 0.1 s after it was published (at rest when
it was over by then), ``q_near`` its end (what the planner node passes), k = 4, reserve 0.1
(the node's defaults). Per case, alternately (so that both see the same load):

- *now*: :func:`~tocontrol_ros.core.direct.first_motion.quick_motion` as the planner calls
  it (TOPP-RA's two sweeps in one compiled call, ``engine="compiled"``; the ranking pass
  handed on, the certificate's open loop in one call, the compiled inverse dynamics);
- *seidel*: ``engine="seidel"`` (toppra's compiled Seidel solver driven stage by stage from
  Python: the TOPP-RA of main before the compiled sweeps);
- *before*: ``engine="toppra"`` (toppra's algorithm object per pass, the time scales ranked
  in the full cube and timed again from scratch: the TOPP-RA of main before issue 47); the
  rest is the present code's;
- the certificate's open loop of the same motion: the state by CVODES segment by segment
  from Python (``ScaledPath.open_loop(..., one_call=False, deviation=False)``, main's before
  issue 47), the state in one ``mapaccum`` call
  (:func:`~tocontrol_ros.core.direct.flat_trajectory.open_loop_sweep`), the deviation from
  each segment's path by CVODES in one call (``explicit=False``), and the deviation by
  explicit steps with an error test in one compiled call (the default since), the states
  compared.

Figures: medians over the cases (ms), before -> seidel -> now and the ratio seidel / now of
the medians, ``T`` now / before per case (median, min, max), the largest relative difference
of ``T`` now against seidel, successes. Run alone:
``scripts/dev run python -P bench/quick_motion.py [paper|panda|both]`` (prints the section).
"""

from __future__ import annotations

import importlib
import math
import statistics
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.common import PANDA_LOCKED, Section, load_text, log, panda_urdf, table  # noqa: E402
from bench.replan import (  # noqa: E402  (the node benchmark's moving targets)
    DURATION,
    MOVING_PANDA_LAPS,
    MOVING_PANDA_RADIUS,
    MOVING_PAPER_RADIUS,
    RATE,
    README_PANDA_Q0,
)

#: TOPP-RA's drivers compared, the default first.
ENGINES = ("compiled", "seidel", "toppra")
#: Goals per robot, as bench/replan.py sends them.
GOALS = int(RATE * DURATION)
PAPER_RADIUS, PANDA_RADIUS, PANDA_LAPS = MOVING_PAPER_RADIUS, MOVING_PANDA_RADIUS, \
    MOVING_PANDA_LAPS
#: The pause before each case of the paused run (s): one goal period of the stream.
PAUSE = 1.0 / RATE
#: The paper's arm's start (bench/replan.py's).
PAPER_Q0 = (0.3, 0.9, 0.6)


def _robot(name: str, pkg: str = "tocontrol_ros"):
    """(model, start configuration, circle radius, laps, limits) or None, of package ``pkg``."""
    JointLimits = importlib.import_module(f"{pkg}.core.robot.limits").JointLimits
    robot = importlib.import_module(f"{pkg}.core.robot.model")

    if name == "paper":
        model = robot.load_robot(robot.default_urdf_path())
        return model, np.array(PAPER_Q0), PAPER_RADIUS, 1, JointLimits.from_model(model)
    urdf = panda_urdf()
    if urdf is None:
        return None
    model = robot.load_robot(str(urdf), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    return (model, np.array(README_PANDA_Q0), PANDA_RADIUS, PANDA_LAPS,
            JointLimits.from_model(model).with_margin(0.05))


def replans(name: str, pkg: str = "tocontrol_ros") -> list | None:
    """The chain's ``(problem, q_near)``, each from the last quick motion (see the module).

    ``pkg``: the package whose types and quick motion make it (``bench/quick_motion_pair.py``
    builds another commit's package under another name).
    """
    fm = importlib.import_module(f"{pkg}.core.direct.first_motion")
    first_motion, quick_motion = fm.first_motion, fm.quick_motion
    types = importlib.import_module(f"{pkg}.core.types.problem")
    Problem, joint_state, point = types.Problem, types.joint_state, types.point

    found = _robot(name, pkg)
    if found is None:
        return None
    model, q0, radius, laps, limits = found
    n, centre = model.n, model.point(q0)
    goals = []
    for a in np.linspace(0.0, 2.0 * math.pi * laps, GOALS + 1)[:-1]:
        p = np.array(centre, dtype=float)
        p[:2] += radius * np.array([math.cos(a), math.sin(a)])
        goals.append(p)
    running = first_motion(Problem(model, joint_state(q0), point(goals[0]), k=4.0,
                                   reserve=0.1, limits=limits))
    if not running.success:
        raise RuntimeError(f"{name}: the first motion onto the circle failed: "
                           f"{running.message}")
    out = []
    for goal in goals[1:]:
        t = min(1.0 / RATE, running.T)
        z = running.trajectory.state(t)[0]
        qd = limits.admissible_velocity(z[n:2 * n]) if t < running.T else np.zeros(n)
        problem = Problem(model, joint_state(z[:n], qd), point(goal), k=4.0, reserve=0.1,
                          limits=limits)
        q_near = running.trajectory.state(running.T)[0][:n]
        out.append((problem, q_near))
        quick = quick_motion(problem, q_near)
        if quick.success:
            running = quick
    return out


def _open_loops(traj) -> tuple[float, ...]:
    """The open loop of ``traj``: the state segment by segment (main's before issue 47), the
    state in one call, the deviation from the path by CVODES in one call, the deviation by
    explicit steps in one call (now): times (s), and the largest differences of the one-call
    state's, of the CVODES deviation's and of the explicit steps' states from the first."""
    from tocontrol_ros.core.direct.tuning import OPEN_LOOP_ATOL, OPEN_LOOP_RTOL

    tol = (OPEN_LOOP_RTOL, OPEN_LOOP_ATOL)
    t0 = time.perf_counter()
    _, x_old, ok_old = traj.open_loop(*tol, one_call=False, deviation=False)
    t1 = time.perf_counter()
    _, x_one, ok_one = traj.open_loop(*tol, deviation=False)
    t2 = time.perf_counter()
    _, x_dev, ok_dev = traj.open_loop(*tol, explicit=False)
    t3 = time.perf_counter()
    _, x_new, ok_new = traj.open_loop(*tol)
    t4 = time.perf_counter()
    ok = ok_old and ok_one and ok_dev and ok_new
    diffs = [float(np.max(np.abs(x - x_old))) if ok else float("nan")
             for x in (x_one, x_dev, x_new)]
    return (t1 - t0, t2 - t1, t3 - t2, t4 - t3, *diffs)


def measure(name: str) -> dict | None:
    """One robot's paired figures (see the module), or None without the robot."""
    from tocontrol_ros.core.direct.first_motion import quick_motion
    from tocontrol_ros.core.robot import compiled

    cases = replans(name)
    if cases is None:
        return None
    for problem, q_near in cases[:3]:  # warm-up: builds, mappings
        for engine in ENGINES:
            quick_motion(problem, q_near, engine=engine)
    compiled.wait_for_builds()
    rows = {engine: [] for engine in ENGINES}
    loops = []
    for problem, q_near in cases:
        for engine in ENGINES:
            rows[engine].append(quick_motion(problem, q_near, engine=engine))
        now = rows["compiled"][-1]
        if now.success:
            loops.append(_open_loops(now.trajectory))
    # As the planner node meets them: one replan per goal period, the worker asleep between
    # them (its caches cold by then on a machine with other work), the same motions again.
    paused = []
    for problem, q_near in cases:
        time.sleep(PAUSE)
        paused.append(quick_motion(problem, q_near))
    moving = sum(bool(np.any(p.start.value[p.model.n:])) for p, _ in cases)

    def med(engine: str, key: str) -> float:
        return statistics.median(r.timings[key] for r in rows[engine])

    def both(a: str, b: str) -> list:
        return [(x, y) for x, y in zip(rows[a], rows[b], strict=True)
                if x.success and y.success]

    ratios = [a.T / b.T for a, b in both("compiled", "toppra")]
    seidel = max((abs(a.T / b.T - 1.0) for a, b in both("compiled", "seidel")), default=0.0)
    return {
        "robot": name, "cases": len(cases), "moving": moving,
        "ok": {e: sum(r.success for r in rs) for e, rs in rows.items()},
        "parts": {e: {k: med(e, k) for k in ("guess", "scaling", "verify", "total")}
                  for e in rows},
        "paused": {k: statistics.median(r.timings[k] for r in paused)
                   for k in ("guess", "scaling", "verify", "total")},
        "passes": {e: statistics.median(r.iterations for r in rs) for e, rs in rows.items()},
        "T_ratio": (statistics.median(ratios), min(ratios), max(ratios)),
        "T_seidel": seidel,
        "loop": tuple(statistics.median(v[i] for v in loops) for i in range(4))
        + tuple(max(v[i] for v in loops) for i in range(4, 7)),
    }


def run(which: str = "both") -> Section:
    names = ("paper", "panda") if which == "both" else (which,)
    load0 = load_text()
    results = []
    for name in names:
        log(f"quick motion: {name} ...")
        out = measure(name)
        if out is None:
            log(f"quick motion: {name} skipped (example-robot-data is not installed)")
            continue
        results.append(out)
        log(f"quick motion {name}: {out}")
    rows = []
    for r in results:
        now, seidel, before = (r["parts"][e] for e in ("compiled", "seidel", "toppra"))
        rows.append([
            f"{r['robot']} ({r['moving']}/{r['cases']} moving)",
            "{} / {} / {}".format(*(r["ok"][e] for e in ("compiled", "seidel", "toppra"))),
            *(f"{1e3 * before[k]:.2f} -> {1e3 * seidel[k]:.2f} -> {1e3 * now[k]:.2f} "
              f"({seidel[k] / now[k]:.2f}x)" for k in ("scaling", "verify", "total")),
            f"{r['passes']['toppra']:.0f} -> {r['passes']['compiled']:.0f}",
            "{:.4f} [{:.4f}, {:.4f}]".format(*r["T_ratio"]),
            f"{r['T_seidel']:.1e}",
            f"{1e3 * r['loop'][0]:.2f} -> {1e3 * r['loop'][1]:.2f} -> "
            f"{1e3 * r['loop'][2]:.2f} -> {1e3 * r['loop'][3]:.2f} "
            f"({r['loop'][2] / r['loop'][3]:.2f}x; max diff {r['loop'][4]:.1e} / "
            f"{r['loop'][5]:.1e} / {r['loop'][6]:.1e})",
            " / ".join(f"{1e3 * r['paused'][k]:.2f}" for k in ("guess", "scaling", "verify",
                                                                "total"))])
    lines = [
        "A replan's quick motion in one process (`first_motion.quick_motion`), the replans "
        "of `bench/replan.py --moving` (each from the last quick motion's state 0.1 s "
        "after it, k = 4, reserve 0.1), per case with each TOPP-RA driver in turn: "
        "*before* (`engine=\"toppra\"`: toppra's algorithm object per pass, the time "
        "scales ranked in the full cube and timed again from scratch: main before issue "
        "47's cuts), *seidel* (`engine=\"seidel\"`: toppra's Seidel solver driven stage by "
        "stage from Python) and *now* (`engine=\"compiled\"`, the default: both sweeps in "
        "one compiled call, each stage's LP in closed form). Medians in ms, before -> "
        "seidel -> now (seidel / now); scaling: TOPP-RA and the check between gridpoints; "
        "verify: the certificate (the present one in every column); open loop: the "
        "certificate's re-integration of the same motion, the state segment by segment from "
        "Python (main's before issue 47) -> the state in one `mapaccum` call -> the "
        "deviation from each segment's path by CVODES in one call (`ScaledPath.open_loop`'s "
        "`deviation`, `explicit=False`) -> the deviation by explicit Heun steps with their "
        "error test in one compiled call (now), (CVODES deviation / explicit), the largest "
        "differences of the one-call state's, the CVODES deviation's and the explicit "
        "steps' states from the first. T now / "
        "before per case: median [min, max]; T vs seidel: the largest relative difference. "
        f"*Paused*: the same quick motions (now) again, each after a pause of {PAUSE:g} s, "
        "as the planner node's worker meets them (asleep between goals, its caches cold "
        "on a machine with other work): guess / scaling / verify / total, medians in ms. "
        f"Load before: {load0}; after: {load_text()}. Command: `scripts/dev run python -P "
        f"bench/quick_motion.py {which}`.",
        "",
        *table(["robot", "certified now / seidel / before", "scaling ms", "verify ms",
                "total ms", "passes", "T now / before", "T vs seidel", "open loop ms",
                "paused ms"],
               rows),
    ]
    return Section("Replanning: the quick motion's parts in process (issue 47)", lines, [])


if __name__ == "__main__":
    which = sys.argv[1] if len(sys.argv) > 1 else "both"
    if which not in ("paper", "panda", "both"):
        raise SystemExit(f"usage: bench/quick_motion.py [paper|panda|both], got {which!r}")
    section = run(which)
    print("\n".join(section.lines))
