"""Independent checks of a solution: re-integration, ``H``, the control set, URDF limits.

The checks sample the solution once (:func:`fine_sample`); the solver certifies it on that
sampling (:func:`~tocontrol_ros.core.indirect.certificate.certify`, a compiled adaptive integrator
independent of the solver's RK4) and :func:`verdict` turns the certificate into the result's
status. :func:`verify` is a second, slower re-integration of the nominal torques by scipy's
DOP853, against which the certificate is tested.
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.types.certificate import Certificate
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import Status
from tocontrol_ros.core.types.trajectory import Motion, TrajectorySample

__all__ = ["SAMPLE_GAPS", "fine_sample", "limit_warnings", "verdict", "verify"]


def verify(problem: Problem, trajectory: Motion, rtol: float = 1e-11,
           sample: TrajectorySample | None = None) -> dict:
    """Independent checks of a solution.

    Re-integrates the model under the nominal torques ``tau(t)`` of the trajectory with an
    adaptive integrator (scipy's DOP853) from the trajectory's initial state, and evaluates
    ``H`` and the control-set equation on a fine sampling.

    Parameters
    ----------
    problem : Problem
    trajectory : Motion
    rtol : float
        Relative tolerance of the integrator (absolute: ``rtol / 10``).
    sample : TrajectorySample, optional
        The sampling on which ``H`` and the control set are checked; default: the one
        :func:`~tocontrol_ros.core.planning.solver.plan` uses (the RK4 step points, filled in where
        they are more than ``T / SAMPLE_GAPS`` apart).

    Returns
    -------
    dict
        ``point_error`` (m): distance of the re-integrated end point to the target point;
        ``state_error``: max-norm of the re-integrated final state minus the trajectory's;
        ``velocity_error``: max |qd(T)| of the re-integration (rad/s); ``max_abs_H``;
        ``max_set_error``: max |sum u^2k - 1|; ``nfev``; ``position_limit_violation`` and
        ``velocity_limit_violation``: the largest excess of the re-integrated motion (at the
        sampling's times) over the problem's joint limits, as a fraction of the position
        range or of the velocity limit (0 within them).
    """
    from scipy.integrate import solve_ivp

    model = problem.model
    n = model.n
    f = model.function("f")
    scale = problem.torque_scale

    def rhs(t, x):
        u = trajectory.control(t)
        return np.array(f(x, u * scale)).ravel()

    x0 = trajectory.state(0.0)[0, :2 * n]
    if sample is None:
        sample = fine_sample(trajectory)
    sol = solve_ivp(rhs, (0.0, trajectory.T), x0, method="DOP853", rtol=rtol,
                    atol=rtol / 10, t_eval=sample.t)
    x_end = sol.y[:, -1]
    planned_end = trajectory.state(trajectory.T)[0, :2 * n]
    pos_viol, vel_viol = problem.limits.violations(sol.y[:n].T, sol.y[n:2 * n].T)
    k = trajectory.law.k
    set_err = np.abs(np.sum(np.abs(sample.u) ** (2 * k), axis=1) - 1)
    return {
        "point_error": float(np.linalg.norm(model.point(x_end[:n]) - problem.target_point)),
        "state_error": float(np.max(np.abs(x_end - planned_end))),
        "velocity_error": float(np.max(np.abs(x_end[n:]))),
        "max_abs_H": float(np.max(np.abs(sample.H))),
        "max_set_error": float(np.max(set_err)),
        "max_abs_u": float(np.max(np.abs(sample.u))),
        "nfev": int(sol.nfev),
        "integrator_success": bool(sol.success),
        "position_limit_violation": pos_viol,
        "velocity_limit_violation": vel_viol,
    }


#: The checks of a result (max |u|, URDF limits, H) sample the solution at its RK4 step
#: points, which crowd at the switches, plus equally spaced times wherever two step points
#: are more than T / SAMPLE_GAPS apart.
SAMPLE_GAPS = 250


def fine_sample(trajectory: Motion) -> TrajectorySample:
    """One sampling for every check of a result (see :data:`SAMPLE_GAPS`).

    It finds the extremes of a much finer equally spaced sampling at a fraction of its cost,
    since most step points need no integration.

    Parameters
    ----------
    trajectory : Motion

    Returns
    -------
    TrajectorySample
        At the RK4 step points and the filled-in times, in increasing order.
    """
    t_grid = trajectory.t_grid
    widths = np.diff(t_grid)
    parts = np.ceil(widths / (trajectory.T / SAMPLE_GAPS)).astype(int)  # per step, >= 1
    wide = np.flatnonzero(parts > 1)
    extra = np.repeat(wide, parts[wide] - 1)  # the step each extra time falls in
    rank = np.arange(len(extra)) - np.repeat(np.cumsum(parts[wide] - 1) - (parts[wide] - 1),
                                             parts[wide] - 1) + 1
    fill = t_grid[extra] + widths[extra] * rank / parts[extra]
    return trajectory.evaluate(np.sort(np.concatenate([t_grid, fill])))


def limit_warnings(problem: Problem, sample: TrajectorySample) -> tuple[str, ...]:
    """One warning per joint and limit (position, velocity) that ``sample`` violates.

    Each names the first time it does (the problem's limits, margin not applied).
    """
    lim = problem.limits
    out = []
    if not (np.any((sample.q < lim.lower) | (sample.q > lim.upper))
            or np.any((sample.qd < -lim.velocity) | (sample.qd > lim.velocity))):
        return ()  # the usual case, in one test (what the loop below would find)
    for i, name in enumerate(lim.names):
        for label, values, lo, hi in (
                ("position", sample.q[:, i], lim.lower[i], lim.upper[i]),
                ("velocity", sample.qd[:, i], -lim.velocity[i], lim.velocity[i])):
            bad = np.flatnonzero((values < lo) | (values > hi))
            if bad.size:
                j = int(bad[0])
                out.append(f"joint {name!r} violates its {label} limit [{lo:.4g}, "
                           f"{hi:.4g}] at t = {sample.t[j]:.4f} s (value {values[j]:.4g})")
    return tuple(out)


def verdict(options: SolverOptions, certificate: Certificate | None,
            residual: float, tol: float | None = None) -> tuple[Status, str]:
    """Status and message of a converged solve.

    From its certificate (None when ``options.verify`` is off) and its residual (max-norm
    of the solve's equations), which must be below ``tol`` (default ``options.tol``).
    """
    status, message = Status.SUCCESS, Status.SUCCESS.value
    if certificate is None:
        message = "solved (converged; not certified: SolverOptions(verify=False))"
    elif not certificate.passed:
        status = Status.VERIFICATION_FAILED
        message = f"{status.value}: {certificate.summary()}"
    if status is Status.SUCCESS and residual > (options.tol if tol is None else tol):
        status = Status.VERIFICATION_FAILED
        message = f"{status.value}: residual {residual:.3g} above tol"
    return status, message
