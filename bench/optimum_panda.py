"""The best motion on the Panda with its joint limits: the default against a denser multistart.

Cases drawn like the joint-limits section's (:func:`bench.limits.draw_cases`, their own
seed): even cases from a point (the end-effector point of the drawn start configuration)
to a point, odd ones from the drawn joint state (at rest or moving) to a point; k = 4, the
URDF limits enforced (the limit-bound path of ``docs/limits.md`` in every case). Each is
planned with the default :class:`SolverOptions` (as a user calls ``plan``, with a longer
``time_limit``) and with :data:`REFERENCE` (four times the seed pairs over twice the
self-motion angles, twice the candidates; the exhaustive mode's 216 bounded guesses cost
over 10 minutes a case). The lower ``T`` is
the best; the gap of the default and the distinct local optima (bounded guesses and the
basins solved, both at k = 4) are reported.

Run alone: ``scripts/dev run python bench/optimum_panda.py [CASES]`` (prints the section).
"""

import os
import statistics
import sys
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import Section, log, table, timed  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum import GAP_TOL, _optima  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

SEED = 20261202
K = 4.0
TIME_LIMIT = 600.0
#: The reference: four times the default's seed pairs over twice its self-motion angles,
#: twice its candidates (the exhaustive mode's 216 bounded guesses took over 600 s a case
#: under load).
REFERENCE = {"starts": 64, "candidates": 12, "ik_count": 16}


def run(count: int) -> Section:
    found = robots().get("Panda")
    if found is None:
        return Section("The best motion on the Panda with its limits", [
            "example-robot-data is not installed: section skipped."], [])
    model, limits = found
    default = SolverOptions(time_limit=TIME_LIMIT)
    reference = SolverOptions(**REFERENCE, verify=False, time_limit=TIME_LIMIT)
    recs = []
    for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count, seed=SEED)):
        start = point(model.point(q0)) if i % 2 == 0 else joint_state(q0, qd0)
        problem = Problem(model, start, point(target), k=K, limits=limits)
        t_def, res = timed(lambda p=problem: plan(p, default))
        t_ref, ref = timed(lambda p=problem: plan(p, reference))
        best = min([r.T for r in (res, ref) if r.success], default=np.nan)
        gap = (res.T - best) / best if res.success else np.inf
        recs.append({"res": res, "ref": ref, "t_def": t_def, "t_ref": t_ref, "gap": gap,
                     "kind": start.kind, "optima": _optima(ref),
                     "direct": _optima(ref, "guess_T")})
        log(f"optimum Panda {i + 1}/{count} ({start.kind}): default {res.status.name} "
            f"{res.T:.6f} ({t_def:.1f} s), reference {ref.status.name} {ref.T:.6f} "
            f"({t_ref:.1f} s), gap {gap:.2e}")
    return _section(recs, default)


def _section(recs, default) -> Section:
    n = len(recs)
    ok = [r for r in recs if r["res"].success]
    hits = [r for r in recs if r["gap"] <= GAP_TOL]
    gaps = sorted((r["gap"] for r in recs if np.isfinite(r["gap"]) and r["gap"] > GAP_TOL),
                  reverse=True)
    t_def = [r["t_def"] for r in recs]
    t_ref = [r["t_ref"] for r in recs]
    direct = [len(r["direct"]) for r in recs if r["direct"]]
    final = [len(r["optima"]) for r in recs if r["optima"]]
    below = sum(r["ref"].success and r["res"].success and r["ref"].T < r["res"].T *
                (1 - GAP_TOL) for r in recs)
    lines = [
        f"{n} cases (seed {SEED}) drawn as in the joint-limits section: even cases point to "
        "point, odd ones joint state (at rest or moving) to point; k = 4, the URDF limits "
        f"enforced. Default: `SolverOptions()` (`starts={default.starts}, "
        f"candidates={default.candidates}, ik_count={default.ik_count}`, verified; "
        f"`time_limit={TIME_LIMIT:g}`; on the Panda `starts + starts // 2` seed pairs are "
        "solved, `seeding.starts_solved`). Reference: `SolverOptions(starts=64, "
        "candidates=12, ik_count=16, verify=False)` (96 bounded direct solves at k = 4 from 16 "
        "self-motion angles per end point, the 12 best distinct ones solved as bounded "
        "B-spline paths at k = 4). "
        "Gap: (T_default - T_best) / T_best, T_best the lower of the two.",
        "",
    ]
    lines += table(["", "value"], [
        ["default succeeded", f"{len(ok)}/{n}"],
        [f"default within {GAP_TOL:g} of the best", f"{len(hits)}/{n}"],
        [f"default gaps above {GAP_TOL:g} (largest first)",
         ", ".join(f"{100 * g:.2f} %" for g in gaps[:10]) or "none"],
        ["reference better than the default by more than the tolerance", f"{below}"],
        ["reference solved", f"{sum(r['ref'].success for r in recs)}/{n}"],
        ["default plan time median / max (s)",
         f"{statistics.median(t_def):.1f} / {max(t_def):.1f}"],
        ["reference plan time median / max (s)",
         f"{statistics.median(t_ref):.1f} / {max(t_ref):.1f}"],
        ["distinct bounded guesses at k = 4 per case (reference) median / min / max",
         f"{statistics.median(direct):g} / {min(direct)} / {max(direct)}" if direct else "—"],
        ["distinct final T of the reference's solved basins median / min / max",
         f"{statistics.median(final):g} / {min(final)} / {max(final)}" if final else "—"],
    ])
    targets = [(f"Panda with its limits: default multistart within {GAP_TOL:g} of the "
                "reference's best (reported, issue 17)", f"{len(hits)}/{n}")]
    return Section(f"The best motion on the Panda with its limits ({n} cases)", lines, targets)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    sec = run(int(argv[0]) if argv else 20)
    print("\n".join([f"## {sec.title}", ""] + sec.lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
