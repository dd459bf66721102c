"""Joint limits: seeded random cases planned with the limits enforced (issue 16).

Robots: the paper's arm with velocity limits (0.4, 1, 1) rad/s and joint 1 within
[-2.5, 2.5] rad (its URDF has continuous joints and a 100 rad/s placeholder), and, from
example-robot-data, the UR5 (to ``tool0``), the Panda (to ``panda_hand``, fingers locked)
and the xArm7 (to ``link_eef``) with their URDF limits. Each case: a start joint state drawn
uniformly inside the limits shrunk by 10 % (at rest in even cases; moving at up to 30 % of
each velocity limit in odd ones) and a target point, the end-effector point of another such
configuration, at least 0.1 m away; k = 4, ``starts=4, candidates=1``. Cases per robot:
``--robots Panda:50,UR5:50``.

Reported per robot: successes; successes whose re-integration (the certificate's adaptive
integrator) stays within every limit to 1e-6 of it; the same cases without limits and how
far their optimum violates them; for up to :data:`REFERENCES` successes, ``T`` against
Hermite-Simpson on 192 intervals with the same bounds at its mesh points, started from the
solution (a different transcription of the same problem).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import (  # noqa: E402
    PANDA_LOCKED,
    Section,
    example_robot_data_dir,
    fmt_ms,
    log,
    paper_model,
    table,
    timed,
)
from tocontrol_ros.core.direct.collocation import DirectCollocation  # noqa: E402
from tocontrol_ros.core.direct.limited import PAD, state_bounds  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan, verify  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

SEED = 16
K = 4.0
REFERENCE_INTERVALS = 192
#: Successes per robot compared with the reference.
REFERENCES = 12
TIME_LIMIT = 300.0


def robots() -> dict:
    """Name -> (model, limits) of the robots that are installed."""
    paper = paper_model()
    base = JointLimits.from_model(paper)
    out = {"3R-limited": (paper, JointLimits(
        base.names, np.array([-2.5, -np.inf, -np.inf]), np.array([2.5, np.inf, np.inf]),
        np.array([0.4, 1.0, 1.0])))}
    root = example_robot_data_dir()
    if root is not None:
        for name, rel, tip, locked in (
                ("UR5", "ur_description/urdf/ur5_robot.urdf", "tool0", {}),
                ("Panda", "panda_description/urdf/panda.urdf", "panda_hand", PANDA_LOCKED),
                ("xArm7", "xarm_description/urdf/xarm7.urdf", "link_eef", {})):
            path = root / rel
            if path.is_file():
                model = load_robot(str(path), tip_link=tip, locked_joints=locked)
                out[name] = (model, JointLimits.from_model(model))
    return out


def draw_cases(model, limits: JointLimits, count: int, seed: int = SEED) -> list:
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(limits.lower), limits.lower, -np.pi)
    hi = np.where(np.isfinite(limits.upper), limits.upper, np.pi)
    centre, half = 0.5 * (lo + hi), 0.45 * (hi - lo)
    cases = []
    while len(cases) < count:
        q0 = centre + rng.uniform(-1, 1, model.n) * half
        q1 = centre + rng.uniform(-1, 1, model.n) * half
        qd0 = np.zeros(model.n)
        if len(cases) % 2:
            qd0 = rng.uniform(-0.3, 0.3, model.n) * limits.velocity
        target = model.point(q1)
        if np.linalg.norm(target - model.point(q0)) < 0.1:
            continue
        cases.append((q0, qd0, target))
    return cases


def _reference(model, res) -> float:
    """T of Hermite-Simpson with the bounds at its mesh points, from the solution."""
    problem = res.problem
    dc = DirectCollocation(model, REFERENCE_INTERVALS, problem.start.kind, problem.target.kind)
    tau = np.linspace(0.0, res.T, REFERENCE_INTERVALS + 1)
    s = res.trajectory.evaluate(tau)
    ref = dc.solve(problem.start.value, problem.target.value, problem.k, res.T,
                   np.hstack([s.q, s.qd]), np.clip(s.u, -1, 1),
                   x_bounds=state_bounds(problem, PAD))
    return ref.T if ref.success else float("nan")


def run_robot(name, model, limits, count, free=True) -> dict:
    opts = SolverOptions(starts=4, candidates=1, time_limit=TIME_LIMIT)
    recs, solved = [], []
    for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count)):
        problem = Problem(model, joint_state(q0, qd0), point(target), k=K, limits=limits)
        dt, res = timed(lambda p=problem: plan(p, opts))
        rec = {"success": res.success, "method": res.method, "T": res.T, "time": dt,
               "status": res.status.name, "within": False, "free_violation": float("nan")}
        if res.success:
            solved.append(res)
            v = res.verification
            rec["within"] = max(v["position_limits"], v["velocity_limits"]) <= 1e-6
        if free:
            unlimited = JointLimits(limits.names, np.full(model.n, -np.inf),
                                    np.full(model.n, np.inf), np.full(model.n, np.inf))
            fp = Problem(model, joint_state(q0, qd0), point(target), k=K, limits=unlimited)
            fres = plan(fp, SolverOptions(starts=4, candidates=1, verify=False,
                                          time_limit=TIME_LIMIT))
            if fres.success:
                checks = verify(problem, fres.trajectory)
                rec["free_violation"] = max(checks["position_limit_violation"],
                                            checks["velocity_limit_violation"])
                rec["free_T"] = fres.T
        recs.append(rec)
        log(f"limits {name} case {i}: {res.status.name} ({res.method}) T {res.T:.5f} "
            f"{dt:.1f} s, within {rec['within']}, unconstrained violation "
            f"{rec['free_violation']:.3g}")
    refs = []
    for res in solved:
        if len(refs) < REFERENCES and res.method == "direct":
            ref = _reference(model, res)
            refs.append(abs(res.T - ref) / ref)
    return {"name": name, "n": model.n, "recs": recs, "refs": refs}


def _summary(out: dict) -> list:
    recs, refs = out["recs"], out["refs"]
    ok = [r for r in recs if r["success"]]
    within = [r for r in ok if r["within"]]
    direct = [r for r in ok if r["method"] == "direct"]
    free = [r["free_violation"] for r in recs if np.isfinite(r["free_violation"])]
    agree = sum(1 for e in refs if e <= 1e-3)
    times = [r["time"] for r in ok]
    return [out["name"], out["n"], f"{len(ok)}/{len(recs)} ({100 * len(ok) / len(recs):.0f} %)",
            f"{len(within)}/{len(ok)}", len(direct),
            f"{agree}/{len(refs)} (max {max(refs):.1e})" if refs else "—",
            f"{statistics.median(free):.2f} ({sum(v > 0 for v in free)}/{len(free)} violate)"
            if free else "—",
            fmt_ms(statistics.median(times)) if times else "—"]


def parse_robots(spec: str, count: int) -> dict:
    """``"Panda:50,UR5"`` -> {name: cases} (``count`` where no count is given)."""
    out = {}
    for item in (i.strip() for i in spec.split(",")):
        if item:
            name, _, n = item.partition(":")
            out[name] = int(n) if n else count
    return out


def run(count: int, names=None) -> Section:
    """``names``: robot names, or {name: cases}; ``count`` cases where none is given."""
    counts = names if isinstance(names, dict) else {n: count for n in (names or [])}
    outs = []
    for name, (model, limits) in robots().items():
        if counts and name not in counts:
            continue
        outs.append(run_robot(name, model, limits, counts.get(name, count)))
    sizes = sorted({len(o["recs"]) for o in outs})
    lines = [
        f"{'/'.join(map(str, sizes))} seeded random cases per robot (`bench/limits.py`): a "
        "start joint state inside the limits (at rest, or moving at up to 30 % of the "
        "velocity limits), a target point; k = 4, 4 starts. *Within limits*: the "
        "certificate's re-integration stays inside every position range and velocity limit "
        "to 1e-6 of it. *Direct*: the limits bound, and the bounded B-spline transcription "
        "solved it (docs/limits.md). *Reference*: |T - T_ref| / T_ref <= 1e-3 against "
        f"Hermite-Simpson on {REFERENCE_INTERVALS} intervals with the same bounds at its mesh "
        "points, started from the solution. *Unconstrained*: the same cases without limits, "
        "median of the largest violation (fraction of the range or of the velocity limit). "
        "*Time*: median of the whole plans (a first case pays any compilation not yet "
        "cached).",
        ""]
    lines += table(["robot", "n", "success", "within limits", "direct", "reference",
                    "unconstrained violation", "median time (ms)"],
                   [_summary(o) for o in outs])
    return Section("Joint limits", lines, targets=_targets(outs))


def _targets(outs: list) -> list:
    """Issue 16's bar per 6-7-joint robot: >= 95 % success, every success within the
    limits, T within 1e-3 of the reference on at least 10 cases."""
    rows = []
    for out in outs:
        if out["n"] < 6:
            continue
        recs, refs = out["recs"], out["refs"]
        ok = [r for r in recs if r["success"]]
        within = sum(r["within"] for r in ok)
        agree = sum(e <= 1e-3 for e in refs)
        met = len(ok) >= 0.95 * len(recs) and within == len(ok) and agree >= 10
        rows.append((f"{out['name']} with its URDF limits: >= 95 % of {len(recs)} random cases "
                     "succeed, all within the limits, T within 1e-3 of the reference on >= 10",
                     f"{'**yes**' if met else '**no**'}: {len(ok)}/{len(recs)} succeed, "
                     f"{within}/{len(ok)} within the limits, {agree}/{len(refs)} within 1e-3"))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=50)
    parser.add_argument("--robots", default="",
                        help="comma-separated names, each with an optional :count "
                             "(default all robots, --cases each)")
    args = parser.parse_args(argv)
    sec = run(args.cases, parse_robots(args.robots, args.cases) or None)
    print("\n".join([f"## {sec.title}", ""] + sec.lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
