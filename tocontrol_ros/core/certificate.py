"""The certificate of a plan: independent checks of a solution, each with its tolerance.

A solution of the boundary-value problem is the solver's RK4 grid of the canonical state
``z = (q, qd, psi)`` (:class:`~tocontrol_ros.core.trajectory.Trajectory`). The certificate
checks it with a method that shares only the model and the canonical system's equations
with the solver, not its integrator: an embedded Runge-Kutta pair of order 5(4) (Dormand and
Prince) with step-size control, compiled to C (one call integrates many segments, the
adaptive loop included), at a tolerance far below the certificate's. From each segment
start ``z_j`` of the grid it integrates, together,

- the canonical system (16) with the control law (15): where it lands is compared with the
  next segment start (the *defect*: how far the grid is from an exact solution of (16));
- the model's state under the nominal torques ``u*(z(t))`` (open loop): this state is not
  reset at the segment starts but carried from ``x(0)`` to ``T``, so at ``T`` it is where
  the nominal torques take the arm; it must land on the target at rest.

It also checks, on a fine sampling of the trajectory (the one :func:`plan` samples), every
torque inside the convexified set (``sum u_i^(2k) <= 1``, hence ``|u_i| <= 1``) and
``max |H|``;
the boundary and transversality conditions at both ends, recomputed from the end states
(no multiplier of the solver's); the solver's own residual when given; and the problem's
joint position and velocity limits (:attr:`CertificateOptions.check_limits`, on by
default) along the sampling and the open-loop states.

:func:`certify` is a pure function of the problem and the trajectory; it returns a frozen
:class:`Certificate` with every figure and one :class:`CertificateItem` (value, tolerance,
pass/fail) per check. :func:`certify_open_loop` certifies a motion without costates (the
direct method's, where the joint limits bind): its torques, end state and limits.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.indirect.adaptive import integrator
from tocontrol_ros.core.indirect.pmp import BufferedFunction, CanonicalSystem
from tocontrol_ros.core.problem import Problem
from tocontrol_ros.core.robot.compiled import c_name, compile_function
from tocontrol_ros.core.trajectory import Trajectory, TrajectorySample

__all__ = ["CertificateOptions", "CertificateItem", "Certificate", "certify",
           "certify_open_loop"]



@dataclass(frozen=True)
class CertificateOptions:
    """Tolerances of the certificate (validated on construction).

    Attributes
    ----------
    point_tol : float
        The open-loop end point must be within this of the target (m).
    velocity_tol : float
        ...and the open-loop end joint velocities within this of 0 (rad/s or m/s).
    position_tol : float
        For a joint-state target, the open-loop end joint positions within this (rad, m).
    defect_tol : float
        Max-norm of (re-integrated segment end minus next grid state), relative to
        ``max(1, |z|)`` of that state.
    boundary_tol : float
        Boundary and transversality conditions at both ends (m, rad/s, and the costate
        component along the self-motion manifold, relative to ``max(1, |psi_q|)``).
    hamiltonian_tol : float
        ``max |H|`` over the sampling (``H = 0`` along an exact solution).
    control_set_tol : float
        ``max sum u_i^(2k) - 1`` over the sampling (rounding only).
    residual_tol : float
        The solver's residual (max-norm of its BVP equations), when given.
    rtol, atol : float
        The integrator's tolerances (relative and absolute, per component of the state).
    segment_steps : int
        Grid steps per segment (the solver's RK4 steps per shooting interval gives the
        shooting intervals).
    check_limits : bool
        Check the problem's joint position and velocity limits (along the sampling and the
        open-loop state); the solver enforces them.
    limit_tol : float
        Tolerated excess over a joint limit, as a fraction of the position range or of the
        velocity limit.
    """

    point_tol: float = 1e-4
    velocity_tol: float = 1e-3
    position_tol: float = 1e-4
    defect_tol: float = 1e-5
    boundary_tol: float = 1e-6
    hamiltonian_tol: float = 1e-5
    control_set_tol: float = 1e-9
    residual_tol: float = 1e-6
    rtol: float = 1e-10
    atol: float = 1e-11
    segment_steps: int = 12
    check_limits: bool = True
    limit_tol: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("point_tol", "velocity_tol", "position_tol", "defect_tol",
                     "boundary_tol", "hamiltonian_tol", "control_set_tol", "residual_tol",
                     "rtol", "atol", "limit_tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ProblemError(f"`{name}` must be a positive number, got {value!r}")
        if not (isinstance(self.segment_steps, (int, np.integer)) and self.segment_steps >= 1):
            raise ProblemError(f"`segment_steps` must be an integer >= 1, got "
                               f"{self.segment_steps!r}")
        if self.rtol > 1e-3 * min(self.point_tol, self.defect_tol):
            raise ProblemError(f"`rtol` ({self.rtol:g}) must be at least 1000 times below "
                               f"`point_tol` and `defect_tol`: the integrator's error must "
                               f"not count in the certificate")


@dataclass(frozen=True)
class CertificateItem:
    """One check: ``value`` against ``tol`` (passes when ``value <= tol``).

    Attributes
    ----------
    name : str
    value : float
    tol : float
    passed : bool
    unit : str
    meaning : str
    """

    name: str
    value: float
    tol: float
    passed: bool
    unit: str
    meaning: str

    def __str__(self) -> str:
        verdict = "ok" if self.passed else "FAILED"
        unit = f" {self.unit}" if self.unit else ""
        return f"{self.name} = {self.value:.3g}{unit} (tol {self.tol:.3g}): {verdict}"


@dataclass(frozen=True)
class Certificate:
    """Outcome of :func:`certify`.

    Attributes
    ----------
    passed : bool
        Every item passed.
    items : tuple of CertificateItem
    figures : dict
        Everything measured, the items' values by their names included: ``point_error``
        (m) and ``velocity_error`` (rad/s) of the open loop at ``T``; ``state_error``, its
        final state minus the trajectory's; ``open_loop_deviation``, the same max-norm over
        every segment end; ``max_set_error`` (``max |sum u^2k - 1|``, not only the excess);
        ``integrator_success``; ``steps`` and ``rejected`` (the integrator's), ``nfev``
        (right-hand sides), ``segments``, ``rtol``.
    options : CertificateOptions
    open_loop_end : ndarray, shape (2n,)
        ``(q, qd)`` reached at ``T`` by the nominal torques from ``x(0)``.
    """

    passed: bool
    items: tuple[CertificateItem, ...]
    figures: dict
    options: CertificateOptions
    open_loop_end: np.ndarray = field(repr=False)

    @property
    def failures(self) -> tuple[CertificateItem, ...]:
        """The items that failed."""
        return tuple(i for i in self.items if not i.passed)

    def item(self, name: str) -> CertificateItem:
        """The item called ``name``."""
        for i in self.items:
            if i.name == name:
                return i
        raise KeyError(f"`name` {name!r} is not an item of this certificate; items: "
                       f"{[i.name for i in self.items]}")

    def summary(self) -> str:
        """One line: passed, or the failed items with their values and tolerances."""
        if self.passed:
            return "certified"
        return "certificate failed: " + "; ".join(str(i) for i in self.failures)


_LOCK = threading.Lock()


# --------------------------------------------------------------------- the checks
def _item(name, value, tol, unit, meaning) -> CertificateItem:
    value = float(value)
    passed = bool(np.isfinite(value) and value <= tol)
    return CertificateItem(name, value, float(tol), passed, unit, meaning)


def _kinematics(system: CanonicalSystem) -> BufferedFunction:
    """``q (n, 3) -> (P (m, 3), J (m, n 3))``, compiled: the three end configurations."""
    key = "certificate_kinematics"
    with _LOCK:
        if key not in system._cache:
            model = system.model
            q = ca.SX.sym("q", model.n)
            point = model.point_sym(q)
            fun = ca.Function(f"tocontrol_certkin_{c_name(model.name)}_{model.n}", [q],
                              [point, ca.densify(ca.jacobian(point, q))])
            system._cache[key] = BufferedFunction(compile_function(fun)[0].map(3, "serial"))
        return system._cache[key]


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
    items += _end_items(problem, x_T, point_err, vel_err, stats["finished"], options)
    items.append(_item("max_defect", float(np.max(defects)), options.defect_tol, "",
                       "canonical system (16) re-integrated per segment: max |z_end - z_next| "
                       "/ max(1, |z_next|)"))

    # Boundary and transversality conditions, recomputed from the end states.
    e0, t0 = _boundary(problem, z_grid[0], points[:, 0], jacs[:, 0], "start")
    e1, t1 = _boundary(problem, z_grid[-1], points[:, 1], jacs[:, 1], "target")
    items.append(_item("boundary", max(e0, e1), options.boundary_tol, "",
                       "start and target conditions (point or joint state, at rest)"))
    items.append(_item("transversality", max(t0, t1), options.boundary_tol, "",
                       "costate psi_q orthogonal to the self-motion manifold at point ends"))

    # Along the sampling: torques inside the convexified set, H = 0.
    set_sum, torque_items = _torque_items(problem, sample.u, options)
    items += torque_items
    max_u = float(np.max(np.abs(sample.u)))
    max_h = float(np.max(np.abs(sample.H)))
    items.append(_item("max_abs_H", max_h, options.hamiltonian_tol, "",
                       "max |H| over the samples"))
    items += _solver_and_limit_items(problem, sample, x_end, solver_residual,
                                     "the solver's max-norm of its BVP equations", options)
    return _checked(items, {
        "point_error": point_err, "velocity_error": vel_err,
        "state_error": float(np.max(np.abs(x_T - z_grid[-1, :2 * n]))),
        "open_loop_deviation": float(np.max(np.abs(x_end - z_next[:, :2 * n]))),
        "max_set_error": float(np.max(np.abs(set_sum - 1.0))), "max_abs_u": max_u,
        "max_abs_H": max_h, "integrator_success": stats["finished"],
        "steps": stats["steps"], "rejected": stats["rejected"],
        "nfev": 6 * (stats["steps"] + stats["rejected"]) + len(lengths),
        "segments": len(lengths), "rtol": options.rtol}, options, x_T)


def _solver_and_limit_items(problem: Problem, sample: TrajectorySample, x_path: np.ndarray,
                            solver_residual: float | None, meaning: str,
                            options: CertificateOptions) -> list[CertificateItem]:
    """The solver's own residual (when given, ``meaning`` says what it is) and the limits."""
    items = []
    if solver_residual is not None:
        items.append(_item("solver_residual", solver_residual, options.residual_tol, "",
                           meaning))
    if options.check_limits:
        items += _limit_items(problem, sample, x_path, options)
    return items


def _checked(items: list[CertificateItem], figures: dict, options: CertificateOptions,
             x_T: np.ndarray) -> Certificate:
    """The certificate of ``items``: passed when all pass; their values, then ``figures``."""
    return Certificate(passed=all(i.passed for i in items), items=tuple(items),
                       figures={**{i.name: i.value for i in items}, **figures},
                       options=options, open_loop_end=x_T.copy())


def _end_items(problem: Problem, x_T: np.ndarray, point_err: float, vel_err: float,
               finished: bool, options: CertificateOptions) -> list[CertificateItem]:
    """Where the nominal torques take the arm: the open-loop state at T (2n,)."""
    n = problem.model.n
    items = [
        _item("integrator_finished", 0.0 if finished else 1.0, 0.5, "",
              "the adaptive integrator reached the end of every segment"),
        _item("end_point", point_err, options.point_tol, "m",
              "nominal torques integrated from x(0): end point to target"),
        _item("end_velocity", vel_err, options.velocity_tol, "rad/s",
              "nominal torques integrated from x(0): max |qd(T)|")]
    if problem.target.kind == "state":
        items.append(_item("end_position", float(np.max(np.abs(
            x_T[:n] - problem.target.value[:n]))), options.position_tol, "rad",
            "nominal torques integrated from x(0): max |q(T) - q_target|"))
    return items


def _torque_items(problem: Problem, u: np.ndarray, options: CertificateOptions
                  ) -> tuple[np.ndarray, list[CertificateItem]]:
    """Torques (K, n) inside the convexified set; also ``sum u_i^(2k)`` per sample."""
    with np.errstate(over="ignore", invalid="ignore"):
        set_sum = np.sum(np.abs(u) ** (2 * problem.k), axis=1)
    # |u_i| = 1 is in the set: where every other S_j = 0 (one joint's switch, n = 2).
    return set_sum, [
        _item("control_set", float(np.max(set_sum) - 1.0), options.control_set_tol, "",
              "max sum u_i^(2k) - 1 over the samples"),
        _item("max_abs_u", float(np.max(np.abs(u))), 1.0 + options.control_set_tol, "",
              "max |u_i| over the samples (the torque limits, to rounding)")]


def _limit_items(problem: Problem, sample: TrajectorySample, x_end: np.ndarray,
                 options: CertificateOptions) -> list[CertificateItem]:
    """The problem's joint limits, along the sampling and the open-loop states."""
    n = problem.model.n
    q = np.concatenate([sample.q, x_end[:, :n]])
    qd = np.concatenate([sample.qd, x_end[:, n:]])
    pos, vel = problem.limits.violations(q, qd)
    return [_item("position_limits", pos, options.limit_tol, "",
                  "max excess over the joint position limits, fraction of the range"),
            _item("velocity_limits", vel, options.limit_tol, "",
                  "max excess over the joint velocity limits, fraction of the limit")]


def certify_open_loop(problem: Problem, trajectory, options: CertificateOptions | None = None,
                      sample: TrajectorySample | None = None,
                      solver_residual: float | None = None) -> Certificate:
    """Check a motion that has no costates (a direct method's): its torques and states.

    The nominal torques are integrated from ``x(0)`` by scipy's DOP853 (adaptive, error
    control at ``options.rtol``; a different method from the motion's own), through the
    sampling's times, or by the trajectory's own ``open_loop(rtol, atol)`` when it has one
    (:meth:`~tocontrol_ros.core.direct.flat_trajectory.FlatTrajectory.open_loop`: CVODES span
    by span); the items are the end point, velocity (and position for a joint-state
    target), the torques inside the set, the joint limits along the sampling and the
    integration, and the solver's residual. There is no ``H``, boundary-of-costate or
    defect item: the motion carries no costates.

    Parameters
    ----------
    problem : Problem
    trajectory : object
        With ``T``, ``t_grid``, ``evaluate``, ``state`` and ``control`` (e.g.
        :class:`~tocontrol_ros.core.direct.flat_trajectory.FlatTrajectory`).
    options : CertificateOptions, optional
    sample : TrajectorySample, optional
        Default: 2001 equally spaced times.
    solver_residual : float, optional

    Returns
    -------
    Certificate
    """
    from scipy.integrate import solve_ivp

    options = options or CertificateOptions()
    model, n = problem.model, problem.model.n
    if sample is None:
        sample = trajectory.evaluate(np.linspace(0.0, trajectory.T, 2001))
    f = model.function("f")
    scale = problem.torque_scale

    def rhs(t, x):
        return np.array(f(x, trajectory.control(t) * scale)).ravel()

    if hasattr(trajectory, "open_loop"):  # its own (faster) re-integration, see its docs
        _, x_path, success = trajectory.open_loop(options.rtol, options.atol)
        nfev = -1
    else:
        x0 = trajectory.state(0.0)[0, :2 * n]
        sol = solve_ivp(rhs, (0.0, trajectory.T), x0, method="DOP853", rtol=options.rtol,
                        atol=options.atol, t_eval=sample.t)
        x_path, success, nfev = sol.y.T, bool(sol.success), int(sol.nfev)
    x_T = x_path[-1]
    point_err = float(np.linalg.norm(model.point(x_T[:n]) - problem.target_point))
    target_qd = problem.target.value[n:] if problem.target.kind == "state" else 0.0
    vel_err = float(np.max(np.abs(x_T[n:] - target_qd)))
    items = _end_items(problem, x_T, point_err, vel_err, success, options)
    items += _torque_items(problem, sample.u, options)[1]
    max_u = float(np.max(np.abs(sample.u)))
    items += _solver_and_limit_items(
        problem, sample, x_path, solver_residual,
        "the solver's max-norm of its NLP's constraint violation", options)
    return _checked(items, {
        "point_error": point_err, "velocity_error": vel_err,
        "state_error": float(np.max(np.abs(x_T - trajectory.state(trajectory.T)[0, :2 * n]))),
        "max_abs_u": max_u, "integrator_success": success, "nfev": nfev,
        "rtol": options.rtol}, options, x_T)
