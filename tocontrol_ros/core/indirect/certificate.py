"""The maximum principle's certificate: its canonical system re-integrated, independently.

A solution of the boundary-value problem is the solver's RK4 grid of the canonical state
``z = (q, qd, psi)`` (:class:`~tocontrol_ros.core.indirect.trajectory.Trajectory`).
:func:`certify` checks it with a method that shares only the model and the canonical
system's equations with the solver, not its integrator (:mod:`.adaptive`): the defects of
(16) per segment, the open-loop state under the nominal torques, the boundary and
transversality conditions recomputed from the end states, ``H`` and every item of
:mod:`tocontrol_ros.core.checks.certificate` (torques inside the set, limits, residual).
"""

from __future__ import annotations

import threading

import casadi as ca
import numpy as np

from tocontrol_ros.core.checks.certificate import (
    certificate_of,
    check_item,
    clearance_checks,
    end_checks,
    solver_and_limit_checks,
    torque_checks,
)
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.indirect.adaptive import integrator
from tocontrol_ros.core.indirect.pmp import BufferedFunction, CanonicalSystem
from tocontrol_ros.core.indirect.trajectory import Trajectory
from tocontrol_ros.core.robot.compiled import c_name, compile_function
from tocontrol_ros.core.types.certificate import Certificate, CertificateItem, CertificateOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.trajectory import TrajectorySample

__all__ = ["certify"]

_LOCK = threading.Lock()


def _kinematics(system: CanonicalSystem) -> BufferedFunction:
    """``q (n, 3) -> (P (m, 3), J (m, n 3))``, compiled: the three end configurations."""
    key = "certificate_kinematics"
    with _LOCK:
        if key not in system.function_cache:
            model = system.model
            q = ca.SX.sym("q", model.n)
            point = model.point_sym(q)
            fun = ca.Function(f"tocontrol_certkin_{c_name(model.name)}_{model.n}", [q],
                              [point, ca.densify(ca.jacobian(point, q))])
            mapped = compile_function(fun)[0].map(3, "serial")
            system.function_cache[key] = BufferedFunction(mapped)
        return system.function_cache[key]




def _boundary(problem: Problem, z: np.ndarray, point: np.ndarray, jac: np.ndarray,
              end: str) -> tuple[float, float]:
    """(position/velocity error, transversality error) of one end of the solution.

    ``point`` (m,) and ``jac`` (m, n) are ``P`` and its Jacobian at the end's ``q``.
    """
    model, n = problem.model, problem.model.n
    endpoint = problem.start if end == "start" else problem.target
    qd, psi_q = z[n:2 * n], z[2 * n:3 * n]
    if endpoint.kind == "state":
        return float(np.max(np.abs(z[:2 * n] - endpoint.value))), 0.0
    err = max(float(np.linalg.norm(point - endpoint.value)), float(np.max(np.abs(qd))))
    if model.n == model.m:
        return err, 0.0
    # psi_q = J^T nu for some nu: psi_q has no component along null(J), the tangent space of
    # the self-motion manifold (checked without the solver's multiplier).
    _, sv, vt = np.linalg.svd(jac)
    null = vt[np.sum(sv > 1e-10 * sv[0]):]
    trans = float(np.max(np.abs(null @ psi_q))) / max(1.0, float(np.max(np.abs(psi_q))))
    return err, trans




def certify(problem: Problem, trajectory: Trajectory, options: CertificateOptions | None = None,
            sample: TrajectorySample | None = None,
            solver_residual: float | None = None) -> Certificate:
    """Check a solution independently; every check with its tolerance.

    Parameters
    ----------
    problem : Problem
    trajectory : Trajectory
        The solution (its grid of canonical states is what is checked).
    options : CertificateOptions, optional
    sample : TrajectorySample, optional
        The sampling on which the torques, ``H`` and the limits are checked; default: the
        trajectory's grid points.
    solver_residual : float, optional
        The solver's own residual, checked against ``options.residual_tol`` when given.

    Returns
    -------
    Certificate
    """
    options = options or CertificateOptions()
    if problem.model is not trajectory.system.model:
        raise ProblemError("`trajectory` was not computed for `problem.model`")
    model, n = problem.model, problem.model.n
    t_grid, z_grid = trajectory.t_grid, trajectory.z_grid
    if sample is None:
        sample = trajectory.evaluate(t_grid)
    items: list[CertificateItem] = []

    # Re-integration: canonical system per segment, open-loop state through the whole chain.
    idx = np.unique(np.append(np.arange(0, len(t_grid) - 1, options.segment_steps),
                              len(t_grid) - 1))
    lengths = np.diff(t_grid[idx])
    integ = integrator(trajectory.system, options.rtol, options.atol)
    x0 = z_grid[0, :2 * n]
    z_end, x_end, stats = integ.run(z_grid[idx[:-1]], lengths, x0, trajectory.law,
                                    problem.torque_scale,
                                    h0=float(np.min(lengths[lengths > 0])))
    z_next = z_grid[idx[1:]]
    with np.errstate(invalid="ignore"):  # a non-finite state fails as NaN
        scale = np.maximum(1.0, np.max(np.abs(z_next), axis=1))
        defects = np.max(np.abs(z_end - z_next), axis=1) / scale
    x_T = x_end[-1]
    points, jacs = _kinematics(trajectory.system)(
        np.stack([z_grid[0, :n], z_grid[-1, :n], x_T[:n]], axis=1))
    points = points.reshape(model.m, 3)
    jacs = jacs.reshape(model.m, 3, n)  # (m, n) blocks side by side
    point_err = float(np.linalg.norm(points[:, 2] - problem.target_point))
    vel_err = float(np.max(np.abs(x_T[n:] - (problem.target.value[n:]
                                             if problem.target.kind == "state" else 0.0))))
    items += end_checks(problem, x_T, point_err, vel_err, stats["finished"], options)
    items.append(check_item("max_defect", float(np.max(defects)), options.defect_tol, "",
                       "canonical system (16) re-integrated per segment: max |z_end - z_next| "
                       "/ max(1, |z_next|)"))

    # Boundary and transversality conditions, recomputed from the end states.
    e0, t0 = _boundary(problem, z_grid[0], points[:, 0], jacs[:, 0], "start")
    e1, t1 = _boundary(problem, z_grid[-1], points[:, 1], jacs[:, 1], "target")
    items.append(check_item("boundary", max(e0, e1), options.boundary_tol, "",
                       "start and target conditions (point or joint state, at rest)"))
    items.append(check_item("transversality", max(t0, t1), options.boundary_tol, "",
                       "costate psi_q orthogonal to the self-motion manifold at point ends"))

    # Along the sampling: torques inside the convexified set, H = 0.
    set_sum, torque_items = torque_checks(problem, sample.u, options)
    items += torque_items
    max_u = float(np.max(np.abs(sample.u)))
    max_h = float(np.max(np.abs(sample.H)))
    items.append(check_item("max_abs_H", max_h, options.hamiltonian_tol, "",
                       "max |H| over the samples"))
    items += solver_and_limit_checks(problem, sample, x_end, solver_residual,
                                     "the solver's max-norm of its BVP equations", options)
    clear_items, clear_figures = clearance_checks(problem, trajectory)
    items += clear_items
    return certificate_of(items, {**clear_figures,
        "point_error": point_err, "velocity_error": vel_err,
        "state_error": float(np.max(np.abs(x_T - z_grid[-1, :2 * n]))),
        "open_loop_deviation": float(np.max(np.abs(x_end - z_next[:, :2 * n]))),
        "max_set_error": float(np.max(np.abs(set_sum - 1.0))), "max_abs_u": max_u,
        "max_abs_H": max_h, "integrator_success": stats["finished"],
        "steps": stats["steps"], "rejected": stats["rejected"],
        "nfev": 6 * (stats["steps"] + stats["rejected"]) + len(lengths),
        "segments": len(lengths), "rtol": options.rtol}, options, x_T)
