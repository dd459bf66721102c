"""The refinement's solves started from the coarser level's multipliers (issue 47, third bar).

A default Panda plan spends about a third of its two-core path in the refinement levels
(BENCHMARKS.md, "Where a Panda plan's time goes"): each level solves the finer mesh from the
coarser solution's path (knot insertion: the same path exactly) with IPOPT's barrier from
``WARM_MU`` (``warm=True``), 20-50 iterations a level. A warm start that also carries the
multipliers (IPOPT's ``warm_start_init_point``, as the replans' ``warm="dual"`` does on one
mesh) needs them on the finer mesh's rows: here they are mapped as densities (each row's
multiplier over its share of ``s``: the set's samples by their spacing, the velocity rows
and the control points' bounds by their Greville abscissae and knot spans; the boundary
rows and ``T``'s bound copied), which is the coarse problem's stationarity spread over the
finer rows.

Each refinement level of the cases' default plans (captured as the plan makes them: the
coarser trajectory, its mesh and its multipliers) is solved again in this process on the
level's finer mesh under every variant:

- ``today``: ``warm=True`` (the planner's route);
- ``dual``: the mapped multipliers, ``warm="dual"`` (barrier from ``WARM_MU``);
- ``dualmu<mu>``: the same from another barrier (``1e-8``, ``1e-6``);
- ``pushmu<mu>``: the same with the warm start's pushes at ``mu`` too (``dual_tight``'s
  form);
- ``floor``: the finer mesh's own converged solution and its own multipliers, ``warm="dual"``
  (what an exact warm start of the same NLP costs IPOPT);
- ``newton``: the parametric Newton steps (:func:`~tocontrol_ros.core.direct.sensitivity.
  sensitivity_solve`, one sub-move) from the mapped point.

Iterations (Newton steps for ``newton``), CPU time (``time.process_time``), success and
``T`` against ``today``'s. Command: ``scripts/dev run python -P bench/refine_warm.py
[CASES] [VARIANTS]``, e.g. ``bench/refine_warm.py 6 today,dual,dualmu1e-8,dualmu1e-6,
pushmu1e-7,floor,newton``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import log, panda_urdf  # noqa: E402


def _density(xc: np.ndarray, wc: np.ndarray, lc: np.ndarray, xf: np.ndarray,
             wf: np.ndarray) -> np.ndarray:
    """Multipliers ``lc`` at ``xc`` with shares ``wc`` carried to ``xf`` with shares ``wf``."""
    return np.interp(xf, xc, lc / wc) * wf


def _samples(breaks: np.ndarray, per_span: int) -> tuple[np.ndarray, np.ndarray]:
    """The set's samples' ``s`` (S,) and their shares of ``s`` (S,)."""
    frac = np.arange(per_span) / per_span
    s = np.concatenate([(breaks[:-1, None] + frac[None, :] * np.diff(breaks)[:, None])
                        .ravel(), [1.0]])
    w = np.repeat(np.diff(breaks) / per_span, per_span)
    return s, np.concatenate([w, [w[-1]]])


def _greville(breaks: np.ndarray, degree: int, derivative: bool
              ) -> tuple[np.ndarray, np.ndarray]:
    """Greville abscissae and knot-span shares of the control points (K,) or of the
    derivative's (K - 1,)."""
    from tocontrol_ros.core.direct.bspline import knots

    t, p = knots(breaks, degree), degree
    K = len(breaks) - 1 + p
    if derivative:
        xi = np.array([t[j + 2:j + p + 1].mean() for j in range(K - 1)])
        share = np.array([(t[j + p + 1] - t[j + 1]) / p for j in range(K - 1)])
    else:
        xi = np.array([t[j + 1:j + p + 1].mean() for j in range(K)])
        share = np.array([(t[j + p + 1] - t[j]) / (p + 1) for j in range(K)])
    return xi, np.maximum(share, 1e-12)


def map_multipliers(coarse, fine, lam_g: np.ndarray, lam_x: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The coarse solution's multipliers on the finer transcription's rows and bounds.

    Parameters
    ----------
    coarse, fine : FlatTranscription
        Without acceleration or clearance rows (the Panda's default plan).
    lam_g : ndarray, shape (coarse rows,)
    lam_x : ndarray, shape (coarse K n + 1,)

    Returns
    -------
    tuple of ndarray
        ``(lam_g, lam_x)`` for ``fine``.
    """
    n, p, ps = coarse.model.n, coarse.degree, coarse.per_span
    Kc, Kf = coarse.K, fine.K
    Sc, Sf = coarse.spans * ps + 1, fine.spans * ps + 1
    vc, vf = n * (Kc - 1), n * (Kf - 1)
    nb = coarse.rows - Sc - vc
    if nb != fine.rows - Sf - vf:
        raise ValueError("only the set, velocity and boundary rows are mapped")
    out_g = np.zeros(fine.rows)
    out_g[:Sf] = _density(*_samples(coarse.breaks, ps), lam_g[:Sc], *_samples(fine.breaks, ps))
    xc, sc = _greville(coarse.breaks, p, True)
    xf, sf = _greville(fine.breaks, p, True)
    for i in range(n):  # the velocity rows joint by joint
        out_g[Sf + i * (Kf - 1):Sf + (i + 1) * (Kf - 1)] = _density(
            xc, sc, lam_g[Sc + i * (Kc - 1):Sc + (i + 1) * (Kc - 1)], xf, sf)
    out_g[Sf + vf:] = lam_g[Sc + vc:]
    xc, sc = _greville(coarse.breaks, p, False)
    xf, sf = _greville(fine.breaks, p, False)
    out_x = np.zeros(Kf * n + 1)
    lc = lam_x[:-1].reshape(Kc, n)
    for i in range(n):  # the control points' bounds, point by point (K, n) row-major
        out_x[i:Kf * n:n] = _density(xc, sc, lc[:, i], xf, sf)
    out_x[-1] = lam_x[-1]
    return out_g, out_x


def _warm_options_with_mu(original):
    """``flat._warm_options`` that also knows ``dualmu<mu>`` and ``pushmu<mu>``."""
    def options(warm):
        if isinstance(warm, str) and warm[:6] in ("dualmu", "pushmu"):
            mu = float(warm[6:])
            opts = {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": mu,
                    "ipopt.warm_start_init_point": "yes"}
            if warm.startswith("pushmu"):
                opts.update({f"ipopt.warm_start_{key}": mu for key in (
                    "bound_push", "bound_frac", "slack_bound_push", "slack_bound_frac",
                    "mult_bound_push")})
            return opts
        return original(warm)
    return options


def run(count: int, variants: list[str]) -> dict:
    from bench.limits import draw_cases
    from tocontrol_ros.core.direct import flat as flat_module
    from tocontrol_ros.core.direct import limited
    from tocontrol_ros.core.direct.sensitivity import sensitivity_solve
    from tocontrol_ros.core.direct.tuning import NEAR_MAX_ITER, PAD, SET_PAD
    from tocontrol_ros.core.planning.solver import Planner
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.robot.model import load_robot
    from tocontrol_ros.core.types.options import SolverOptions
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    flat_module._warm_options = _warm_options_with_mu(flat_module._warm_options)
    model = load_robot(str(panda_urdf()), tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    limits = JointLimits.from_model(model)
    planner = Planner(model)
    captured = []
    refined_breaks = limited.refined_breaks

    def capture(traj, *args, **kwargs):
        captured.append(traj)
        return refined_breaks(traj, *args, **kwargs)

    limited.refined_breaks = capture
    totals = {v: [0, 0.0, 0, 0] for v in variants}  # iterations, CPU s, successes, same T
    for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count)):
        problem = Problem(model, joint_state(q0, qd0), point(target), k=4.0, limits=limits)
        captured.clear()
        planner.plan(problem, SolverOptions())
        bounds = limited.state_bounds(problem, PAD)
        values = (problem.start.value, problem.target.value, problem.k)
        for level, traj in enumerate(list(captured)):
            breaks = refined_breaks(traj)
            if len(breaks) == len(traj.breaks) or traj.result.lam_g is None:
                continue
            breaks = limited._bucketed(breaks)
            P0 = traj.control_points_on(breaks)
            coarse = planner.flat(problem, traj.breaks)
            line, Ts = [f"case {i + 1} level {level} spans {len(traj.breaks) - 1}->"
                        f"{len(breaks) - 1}"], {}
            for v in variants:
                fine = planner.flat(problem, breaks, warm=None if v == "today" else
                                    "dual" if v in ("floor", "newton") else v)
                kw, T0, Pg = {}, traj.T, P0
                if v == "floor":
                    own = planner.flat(problem, breaks).solve(*values, traj.T, P0, *bounds,
                                                              max_iter=NEAR_MAX_ITER)
                    kw, T0, Pg = {"lam_g0": own.lam_g, "lam_x0": own.lam_x}, own.T, own.P
                elif v != "today":
                    lg, lx = map_multipliers(coarse, fine, traj.result.lam_g,
                                             traj.result.lam_x)
                    kw = {"lam_g0": lg, "lam_x0": lx}
                t0 = time.process_time()
                if v == "newton":
                    out, outcome = sensitivity_solve(
                        fine, np.concatenate([P0.ravel(), [traj.T]]), kw["lam_g0"],
                        kw["lam_x0"], *values, *bounds, SET_PAD)
                    its = outcome.steps
                else:
                    out = fine.solve(*values, T0, Pg, *bounds, max_iter=NEAR_MAX_ITER, **kw)
                    its = out.iterations
                dt = time.process_time() - t0
                Ts[v] = out.T if out.success else np.nan
                tot = totals[v]
                tot[0] += its
                tot[1] += dt
                tot[2] += int(out.success)
                same = "today" in Ts and abs(Ts[v] / Ts["today"] - 1) < 1e-9
                tot[3] += int(same)
                result = f"T {out.T:.9f}" if out.success else "FAILED"
                line.append(f"{v}: {its} it {dt * 1e3:.0f} ms {result}")
            log(" | ".join(line))
    limited.refined_breaks = refined_breaks
    return totals


def main() -> None:
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 6
    variants = sys.argv[2].split(",") if len(sys.argv) > 2 else [
        "today", "dual", "dualmu1e-8", "dualmu1e-6", "pushmu1e-7", "floor", "newton"]
    totals = run(count, variants)
    print("| variant | iterations (steps) | CPU (s) | converged | same T (1e-9) |")
    print("|---|---|---|---|---|")
    for v, (its, cpu, ok, same) in totals.items():
        print(f"| {v} | {its} | {cpu:.2f} | {ok} | {same} |")


if __name__ == "__main__":
    main()
