"""What the certificate costs against the solve, side by side (issue 21).

Per case, in this one process: the cold one-start solve (``starts=1, candidates=1,
verify=False``), then the certificate of its solution (:func:`certify` with the options
:func:`plan` uses, the fine sampling given, as in ``plan``), each timed over several runs.
Cases: the paper's example at k = 1 and 4, a few seeded random pairs of the paper's arm at
k = 4, and the Panda at k = 4 (the scaling section's task, without the joint limits: the
certificate of the maximum principle's solution). On the paper's example at k = 4
the peers run on the same solution: scipy's DOP853 through the trajectory's dense evaluation
(the former ``verify``), and CasADi's CVODES (Adams, JIT-compiled right-hand side, the same
tolerance) mapped over the shooting intervals.
"""

import numpy as np

from bench.common import (
    PANDA_LOCKED,
    START,
    TARGET,
    Section,
    fmt_ms,
    log,
    measure,
    panda_urdf,
    table,
    timed,
)
from bench.random_pairs import draw_pairs
from bench.scaling import PANDA_Q_START, PANDA_Q_TARGET
from tocontrol_ros.core.checks.verification import fine_sample
from tocontrol_ros.core.indirect.certificate import certify
from tocontrol_ros.core.planning.solver import SolverOptions, plan, verify
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, point

#: Issue 21: the certificate may cost at most this fraction of a cold one-start solve.
TARGET_RATIO = 0.2
RANDOM_PAIRS = 5


def _cold_opts():
    return SolverOptions(starts=1, candidates=1, verify=False)


def _case(label, problem, runs, budget):
    solve, res = measure("solve", lambda: plan(problem, _cold_opts()), runs, budget,
                         check=lambda r: r.success)
    if not res.success:
        log(f"verification {label}: solve failed ({res.message})")
        return {"label": label, "solve": solve, "res": res, "cert": None, "c": None}
    traj = res.trajectory
    sample = fine_sample(traj)
    opts = _cold_opts().certificate_options(res.warm_state.steps)
    cert, c = measure("certificate", lambda: certify(problem, traj, opts, sample=sample,
                                                     solver_residual=res.residual),
                      max(runs, 5), budget)
    log(f"verification {label}: solve {fmt_ms(solve.median)} ms, certificate "
        f"{fmt_ms(cert.median)} ms ({cert.median / solve.median:.3f}), {c.summary()}")
    return {"label": label, "solve": solve, "res": res, "cert": cert, "c": c}


def _cvodes(problem, res, rtol, atol):
    """CVODES on the same chain as the certificate: (wall time, end point error)."""
    import casadi as ca

    from tocontrol_ros.core.indirect.adaptive import AdaptiveIntegrator

    traj = res.trajectory
    n = problem.model.n
    rhs = AdaptiveIntegrator(traj.system, rtol, atol)._rhs()
    y, p = ca.SX.sym("y", 6 * n), ca.SX.sym("p", 5)
    dae = {"x": y, "p": p, "ode": p[0] * rhs(y, p[1:])}
    opts = {"reltol": rtol, "abstol": atol, "linear_multistep_method": "adams",
            "nonlinear_solver_iteration": "functional", "max_num_steps": 100000,
            "jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"]}}
    integ = ca.integrator("cert_cvodes", "cvodes", dae, 0.0, 1.0, opts)
    steps = res.warm_state.steps
    idx = np.unique(np.append(np.arange(0, len(traj.t_grid) - 1, steps),
                              len(traj.t_grid) - 1))
    lengths = np.diff(traj.t_grid[idx])
    xo, zj, lj, pj = ca.MX.sym("x", 2 * n), ca.MX.sym("z", 4 * n), ca.MX.sym("L"), \
        ca.MX.sym("par", 4)
    xf = integ(x0=ca.vertcat(zj, xo), p=ca.vertcat(lj, pj))["xf"]
    chain = ca.Function("seg", [xo, zj, lj, pj], [xf[4 * n:], xf[:4 * n]]).mapaccum(
        "chain", len(lengths), 1)
    par = ca.repmat(ca.DM(np.append(traj.law.array(), problem.torque_scale)), 1, len(lengths))

    def run():
        return chain(traj.z_grid[0, :2 * n], traj.z_grid[idx[:-1]].T, lengths[None, :], par)

    run()  # the first call sets the integrator up
    wall, (xs, _) = timed(run)
    x_t = np.array(xs)[:, -1]
    return wall, float(np.linalg.norm(problem.model.point(x_t[:n]) - problem.target_point))


def _row(c):
    res, solve, cert = c["res"], c["solve"], c["cert"]
    if cert is None:
        return [c["label"], fmt_ms(solve.median), "—", "—", "—", "—", "—", "—",
                f"**{res.status.name}**"]
    f = c["c"].figures
    return [c["label"], fmt_ms(solve.median), fmt_ms(cert.median),
            f"{cert.median / solve.median:.3f}", f"{f['point_error']:.1e}",
            f"{f['max_defect']:.1e}", f"{f['max_abs_H']:.1e}",
            f"{f['steps']} / {f['rejected']}",
            "certified" if c["c"].passed else f"**{c['c'].summary()}**"]


def run(model, runs, budget):
    cases = []
    for k in (1.0, 4.0):
        problem = Problem(model, point(START), point(TARGET), k=k)
        cases.append(_case(f"paper's example, k = {k:g}", problem, runs, budget))
    for i, (a, b) in enumerate(draw_pairs(model, RANDOM_PAIRS)):
        cases.append(_case(f"random pair {i}, k = 4", Problem(model, point(a), point(b), k=4.0),
                           min(runs, 3), budget))
    panda = None
    path = panda_urdf()
    if path is not None:
        pmodel = load_robot(str(path), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
        # Without its joint limits: the certificate of the maximum principle's solution is
        # what is measured (with them the problem goes to the bounded solve, which takes
        # minutes on this arm; docs/limits.md).
        unlimited = JointLimits(pmodel.joint_names, np.full(pmodel.n, -np.inf),
                                np.full(pmodel.n, np.inf), np.full(pmodel.n, np.inf))
        problem = Problem(pmodel, point(pmodel.point(np.array(PANDA_Q_START))),
                          point(pmodel.point(np.array(PANDA_Q_TARGET))), k=4.0,
                          limits=unlimited)
        panda = _case("Panda without joint limits, k = 4", problem, 2, budget)
        cases.append(panda)

    header = ["case", "cold solve (ms)", "certificate (ms)", "ratio", "end point error (m)",
              "max defect", "max \\|H\\|", "DP5(4) steps / rejected", "verdict"]
    opts = _cold_opts().certificate_options(12)
    lines = [
        "Cost of the certificate (`core/checks/certificate.py`, on by default: `verify=True`) "
        "against the cold one-start solve of the same problem (`starts=1, candidates=1, "
        "verify=False`), side by side in this process; medians (the certificate of the "
        "solution of the last solve run). The certificate re-integrates, with a compiled "
        f"Dormand-Prince 5(4) pair at rtol {opts.rtol:g} (atol {opts.atol:g}), the canonical "
        "system from each shooting node (max defect: against the next node, relative) and "
        "the model under the nominal torques from x(0) to T (end point error); it checks the "
        "torques in the set, |H| and the boundary conditions on the fine sampling. "
        f"Target: at most {TARGET_RATIO:g} of the solve.",
        "",
    ]
    lines += table(header, [_row(c) for c in cases])

    paper4 = cases[1]
    if paper4["cert"] is not None:
        problem, res = paper4["res"].problem, paper4["res"]
        dop_t, dop = timed(lambda: verify(problem, res.trajectory))
        try:
            cv_t, cv_err = _cvodes(problem, res, opts.rtol, opts.atol)
            cv = [f"CVODES (Adams, JIT), rtol {opts.rtol:g}, per shooting interval",
                  fmt_ms(cv_t), f"{cv_t / paper4['solve'].median:.3f}", f"{cv_err:.3e}"]
        except Exception as exc:  # noqa: BLE001  (a peer that fails is reported, not fatal)
            cv = ["CVODES (Adams, JIT)", "—", "—", f"failed: {exc!r:.80}"]
        f = paper4["c"].figures
        lines += ["", "Peers on the same solution (paper's example, k = 4), end point error "
                  "of the re-integrated nominal torques with each (the closer two independent "
                  "integrators agree, the less their own error counts):", ""]
        lines += table(["integrator", "time (ms)", "ratio to the solve", "end point error (m)"],
                       [["certificate: compiled Dormand-Prince 5(4)",
                         fmt_ms(paper4["cert"].median),
                         f"{paper4['cert'].median / paper4['solve'].median:.3f}",
                         f"{f['point_error']:.3e}"],
                        ["scipy DOP853 (former `verify`), rtol 1e-11, dense RK4 control",
                         fmt_ms(dop_t), f"{dop_t / paper4['solve'].median:.3f}",
                         f"{dop['point_error']:.3e}"], cv])
    targets = []
    for label, c in (("the paper's arm, k = 4", paper4),
                     ("the Panda without joint limits, k = 4", panda)):
        if c is None:
            continue
        if c["cert"] is None:
            verdict = f"**no**: the solve failed ({c['res'].status.name})"
        else:
            ratio = c["cert"].median / c["solve"].median
            ok = ratio <= TARGET_RATIO and c["c"].passed
            verdict = f"**{'yes' if ok else 'no'}**: {ratio:.3f}"
        targets.append((f"certificate at most {TARGET_RATIO:g} x the cold one-start solve, "
                        f"{label}", verdict))
    return Section("Verification: the certificate against the solve", lines, targets)
