"""The parametric step's work on bench/warm_resolve.py's 20 moves: two variants counted.

Issue 47's one-replan bar (docs/limits.md, "Warm re-solves by the parametric step"): the
same 20 Panda cases, serving solutions and 2 cm moves as ``bench/warm_resolve.py`` (the
same draw), then, in process, the parametric steps alone (``sensitivity_solve``: the whole
move, then the sub-moves where it fails) counted by work, not timed:

- **refresh policy**: the Hessian re-evaluated when a step cuts the residual by less than
  ``CONTRACTION`` (default 0.1), at most ``REFRESHES`` times (default 4): the converged
  moves, their Newton steps and Hessians for a few pairs;
- **fallback start**: on the moves whose steps fail, IPOPT's first solve (within
  ``NEAR_MAX_ITER``) from the serving solution (``warm="dual"``, the route's fallback), and
  with ``warm="dual"`` or ``"dual_tight"`` from the failed whole move's or the failed
  sub-moves' last iterate and multipliers: iterations and ``T``.

Command: ``scripts/dev run python -P bench/warm_step_work.py`` (about 8 minutes on two
loaded cores, most of it the 20 default plans).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import log, panda_urdf  # noqa: E402

#: (CONTRACTION, REFRESHES) pairs: the default first.
POLICIES = ((0.1, 4), (0.01, 4), (0.01, 8), (1e-3, 8))


def serving_cases(count: int = 20, results: bool = False, label: str = "warm_step_work"
                  ) -> list:
    """``(moved problem, serving warm state)`` of bench/warm_resolve.py's draw (the same
    random directions), and the planner: ``(planner, cases)``; with ``results`` the serving
    plan itself (its ``PlanResult``) in place of its warm state."""
    from bench.limits import draw_cases
    from tocontrol_ros.core.errors import ProblemError
    from tocontrol_ros.core.planning.replan import replan_options, warm_replan
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.robot.model import load_robot
    from tocontrol_ros.core.types.options import SolverOptions
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    model = load_robot(str(panda_urdf()), tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    limits = JointLimits.from_model(model)
    planner = Planner(model)
    options = SolverOptions()
    ropts = replan_options(options, 0.0, 24)
    rng = np.random.default_rng(47)  # bench/warm_resolve.py's seed and order of draws
    cases = []
    for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count)):
        problem = Problem(model, joint_state(q0, qd0), point(target), k=4.0, limits=limits)
        base = planner.plan(problem, options)
        serving = warm_replan(planner, problem, [base], ropts) if base.success else base
        moved = None
        for _ in range(10):
            d = rng.normal(size=3)
            try:
                moved = Problem(model, problem.start, point(target + 0.02 * d / np.linalg.norm(d)),
                                k=4.0, limits=limits)
                break
            except ProblemError:
                continue
        ok = serving.success and serving.warm_state is not None and moved is not None
        cases.append((moved, serving if results else serving.warm_state) if ok else None)
        log(f"{label}: case {i + 1} served: {ok}")
    return planner, cases


def _args(planner, moved, ws) -> tuple:
    from tocontrol_ros.core.direct.limited import state_bounds
    from tocontrol_ros.core.direct.tuning import PAD, SET_PAD

    flat = planner.flat(moved, ws.breaks, warm="dual")
    return (flat, np.concatenate([ws.P.ravel(), [ws.T]]), ws.lam_g, ws.lam_x,
            moved.start.value, moved.target.value, moved.k, *state_bounds(moved, PAD), SET_PAD)


def _steps(args):
    """The route's steps: the whole move, then the sub-moves; (whole, last, pre-steps)."""
    import tocontrol_ros.core.direct.sensitivity as sens

    whole, out = sens.sensitivity_solve(*args)
    if whole.success:
        return whole, whole, out, 0
    again, out2 = sens.sensitivity_solve(*args, submoves=sens.PATH_SUBMOVES,
                                         max_steps=sens.PATH_STEPS, max_solves=sens.PATH_SOLVES,
                                         sub_budget=sens.PATH_SUB_BUDGET)
    return whole, again, out2, out.steps


def main(count: int = 20) -> None:
    import tocontrol_ros.core.direct.sensitivity as sens
    from tocontrol_ros.core.direct.limited import state_bounds
    from tocontrol_ros.core.direct.tuning import NEAR_MAX_ITER, PAD

    planner, cases = serving_cases(count)
    saved = sens.CONTRACTION, sens.REFRESHES
    rows = {}
    try:
        for policy in POLICIES:
            sens.CONTRACTION, sens.REFRESHES = policy
            rows[policy] = [None if c is None else _steps(_args(planner, *c)) for c in cases]
    finally:
        sens.CONTRACTION, sens.REFRESHES = saved
    base = rows[POLICIES[0]]
    for policy, out in rows.items():
        ok = [i for i, r in enumerate(out) if r is not None and r[1].success]
        steps = {i + 1: out[i][2].steps + out[i][3] for i in ok}
        hess = {i + 1: out[i][2].hessians for i in ok}
        gap = max((abs(out[i][1].T / base[i][1].T - 1.0) for i in ok
                   if base[i] is not None and base[i][1].success), default=float("nan"))
        print(f"CONTRACTION, REFRESHES = {policy}: converged on {len(ok)} ({sorted(steps)}); "
              f"Newton steps {steps} (sum {sum(steps.values())}), Hessians {hess} (sum "
              f"{sum(hess.values())}); |T - default's T| / T at most {gap:.1e}")
    print("Fallback start (IPOPT's first solve; iterations, T):")
    for i, c in enumerate(cases):
        if c is None or base[i][1].success:
            continue
        moved, ws = c
        whole, last = base[i][0], base[i][1]
        values = (moved.start.value, moved.target.value, moved.k)
        bounds = state_bounds(moved, PAD)
        parts = []
        for name, warm, start in (
                ("dual, serving", "dual", (ws.T, ws.P, ws.lam_g, ws.lam_x)),
                ("dual, whole move's iterate", "dual", (whole.T, whole.P, whole.lam_g,
                                                        whole.lam_x)),
                ("dual, sub-moves' iterate", "dual", (last.T, last.P, last.lam_g, last.lam_x)),
                ("dual_tight, whole move's iterate", "dual_tight",
                 (whole.T, whole.P, whole.lam_g, whole.lam_x)),
                ("dual_tight, sub-moves' iterate", "dual_tight",
                 (last.T, last.P, last.lam_g, last.lam_x))):
            flat = planner.flat(moved, ws.breaks, warm=warm)
            T, P, lam_g, lam_x = start
            res = flat.solve(*values, T, P, *bounds, lam_g0=lam_g, lam_x0=lam_x,
                             max_iter=NEAR_MAX_ITER)
            parts.append(f"{name}: {res.iterations}{'' if res.success else ' (failed)'}, "
                         f"T {res.T:.9f}")
        print(f"  case {i + 1}: " + "; ".join(parts))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
