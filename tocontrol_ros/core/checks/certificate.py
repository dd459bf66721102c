"""The certificate of any motion: its torques re-integrated, each check with its tolerance.

:func:`certify_open_loop` certifies a motion whatever method made it: the nominal torques
are integrated from ``x(0)`` by a method other than the motion's own, and the items say
where they take the arm (end point, velocity, position for a joint-state target), whether
every torque is inside the convexified set (``sum u_i^(2k) <= 1``, hence ``|u_i| <= 1``),
whether the joint position and velocity limits hold along a fine sampling and the
re-integration (:attr:`CertificateOptions.check_limits`, on by default), and the solver's
own residual. The item builders (:func:`check_item`, :func:`end_checks`,
:func:`torque_checks`, :func:`solver_and_limit_checks`, :func:`certificate_of`) are shared
with the maximum principle's certificate
(:func:`~tocontrol_ros.core.indirect.certificate.certify`), which also re-integrates its
canonical system. The result is a frozen :class:`Certificate`
(:mod:`tocontrol_ros.core.types.certificate`).
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.geometry.tuning import CERTIFY_BISECTIONS, CERTIFY_REFINED, CERTIFY_STEPS
from tocontrol_ros.core.types.certificate import Certificate, CertificateItem, CertificateOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.trajectory import TrajectorySample

#: Where the end items fail, the open loop is integrated once more with ``rtol`` and ``atol``
#: this many times smaller (a fixed amount of work). The integrator's own error grows along
#: an arm whose open loop is unstable: case 14 shelf of bench/collision.py (a 1.96 s motion,
#: 32 spans) ended at 0.0047 rad/s with ``rtol`` 1e-10, atol 1e-11, at 1.1e-3 with atol
#: 1e-12 and 9e-5 with rtol 1e-12 (the motion's own end velocity is 0): the check failed on
#: the integration, not the motion. A motion that misses its end fails either way.
OPEN_LOOP_TIGHTER = 1e-2

__all__ = ["CertificateOptions", "CertificateItem", "Certificate", "certify_open_loop",
           "check_item", "end_checks", "torque_checks", "solver_and_limit_checks",
           "certificate_of", "clearance_checks"]


# ------------------------------------------------- the items every certificate has
def check_item(name: str, value: float, tol: float, unit: str, meaning: str
               ) -> CertificateItem:
    """One check: passed when ``value`` is finite and at most ``tol``."""
    value = float(value)
    passed = bool(np.isfinite(value) and value <= tol)
    return CertificateItem(name, value, float(tol), passed, unit, meaning)




def solver_and_limit_checks(problem: Problem, sample: TrajectorySample, x_path: np.ndarray,
                            solver_residual: float | None, meaning: str,
                            options: CertificateOptions) -> list[CertificateItem]:
    """The solver's own residual (when given, ``meaning`` says what it is) and the limits."""
    items = []
    if solver_residual is not None:
        items.append(check_item("solver_residual", solver_residual, options.residual_tol, "",
                           meaning))
    if options.check_limits:
        items += limit_checks(problem, sample, x_path, options)
    return items


def certificate_of(items: list[CertificateItem], figures: dict, options: CertificateOptions,
             x_T: np.ndarray) -> Certificate:
    """The certificate of ``items``: passed when all pass; their values, then ``figures``."""
    return Certificate(passed=all(i.passed for i in items), items=tuple(items),
                       figures={**{i.name: i.value for i in items}, **figures},
                       options=options, open_loop_end=x_T.copy())


def end_checks(problem: Problem, x_T: np.ndarray, point_err: float, vel_err: float,
               finished: bool, options: CertificateOptions) -> list[CertificateItem]:
    """Where the nominal torques take the arm: the open-loop state at T (2n,)."""
    n = problem.model.n
    items = [
        check_item("integrator_finished", 0.0 if finished else 1.0, 0.5, "",
              "the adaptive integrator reached the end of every segment"),
        check_item("end_point", point_err, options.point_tol, "m",
              "nominal torques integrated from x(0): end point to target"),
        check_item("end_velocity", vel_err, options.velocity_tol, "rad/s",
              "nominal torques integrated from x(0): max |qd(T)|")]
    if problem.target.kind == "state":
        items.append(check_item("end_position", float(np.max(np.abs(
            x_T[:n] - problem.target.value[:n]))), options.position_tol, "rad",
            "nominal torques integrated from x(0): max |q(T) - q_target|"))
    return items


def torque_checks(problem: Problem, u: np.ndarray, options: CertificateOptions
                  ) -> tuple[np.ndarray, list[CertificateItem]]:
    """Torques (K, n) inside the convexified set; also ``sum u_i^(2k)`` per sample."""
    with np.errstate(over="ignore", invalid="ignore"):
        set_sum = np.sum(np.abs(u) ** (2 * problem.k), axis=1)
    # |u_i| = 1 is in the set: where every other S_j = 0 (one joint's switch, n = 2).
    return set_sum, [
        check_item("control_set", float(np.max(set_sum) - 1.0), options.control_set_tol, "",
              "max sum u_i^(2k) - 1 over the samples"),
        check_item("max_abs_u", float(np.max(np.abs(u))), 1.0 + options.control_set_tol, "",
              "max |u_i| over the samples (the torque limits, to rounding)")]


def limit_checks(problem: Problem, sample: TrajectorySample, x_end: np.ndarray,
                 options: CertificateOptions) -> list[CertificateItem]:
    """The problem's joint limits, along the sampling and the open-loop states."""
    n = problem.model.n
    q = np.concatenate([sample.q, x_end[:, :n]])
    qd = np.concatenate([sample.qd, x_end[:, n:]])
    pos, vel = problem.limits.violations(q, qd)
    items = [check_item("position_limits", pos, options.limit_tol, "",
                        "max excess over the joint position limits, fraction of the range"),
             check_item("velocity_limits", vel, options.limit_tol, "",
                        "max excess over the joint velocity limits, fraction of the limit")]
    if problem.limits.has_acceleration:  # joint_limits.yaml's max_acceleration
        items.append(check_item(
            "acceleration_limits", problem.limits.acceleration_violation(sample.qdd),
            options.limit_tol, "", "max excess of the sampled |qdd| over the joint "
            "acceleration limits, fraction of the limit"))
    return items




#: What bounded the joint speeds between the clearance's times (its figure ``clearance_speeds``).
SPEEDS_MEANING = {"motion": "the motion's own joint speed bound on each interval",
                  "limits": "the joint velocity limits"}


def clearance_checks(problem: Problem, trajectory, steps: int = CERTIFY_STEPS
                     ) -> tuple[list[CertificateItem], dict]:
    """The motion's clearance on the URDF's own geometry (none without ``problem.collision``).

    Coal's exact distances of every checked pair (:class:`~tocontrol_ros.core.geometry.
    collision.CollisionModel`) at ``steps + 1`` equally spaced times (by default
    :data:`~tocontrol_ros.core.geometry.tuning.CERTIFY_STEPS` + 1), and between them the bound of
    :meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.swept` under a bound of the
    joint speeds: the motion's own on each interval where the trajectory proves one
    (``joint_speed_bounds(t)``, e.g. :meth:`~tocontrol_ros.core.direct.flat_trajectory.
    FlatTrajectory.joint_speed_bounds`, from its spline's coefficients), else the joint
    velocity limits (which the ``velocity_limits`` item checks; a joint without one: twice
    its largest sampled speed). An interval whose bound falls below the margin is halved
    (:data:`~tocontrol_ros.core.geometry.tuning.CERTIFY_BISECTIONS` times at most, on
    :data:`~tocontrol_ros.core.geometry.tuning.CERTIFY_REFINED` intervals at most): exact
    distances at the new times, the bound on each part. Independent of the optimiser's
    spheres.

    Parameters
    ----------
    problem : Problem
    trajectory : object
        With ``T`` (s) and ``evaluate``; optionally ``joint_speed_bounds``.
    steps : int
        Intervals between the exact distances' times (the certificate's default).

    Returns
    -------
    items : list of CertificateItem
        ``clearance``: the margin minus the least distance any pair can have, at or between
        the times (passes at <= 0).
    figures : dict
        ``min_clearance`` (m, the least exact distance at the times), ``closest_pair``
        ("link/obstacle"), ``closest_time`` (s), ``clearance_bound`` (m),
        ``clearance_speeds`` ("motion" or "limits": which joint speed bound),
        ``clearance_refined`` (intervals halved: those whose bound was below the margin).
    """
    col = problem.collision
    if col is None:
        return [], {}
    t = np.linspace(0.0, trajectory.T, steps + 1)
    sample = trajectory.evaluate(t)
    own = getattr(trajectory, "joint_speed_bounds", None)
    if own is not None and len(t) > 1:
        speeds = "motion"
    else:
        v = problem.limits.velocity
        v = np.where(np.isfinite(v), v, 2.0 * np.max(np.abs(sample.qd), axis=0))
        own, speeds = (lambda times: v), "limits"
    swept = col.swept(t, sample.q, own(t))
    bounds, refined = _bisected(col, trajectory, own, t, swept.interval_bounds)
    lower = float(np.min(bounds)) if len(bounds) else swept.lower_bound
    item = check_item("clearance", col.margin - lower, 0.0, "m",
                      f"margin ({col.margin:g} m) minus the least distance of any checked "
                      f"pair over the motion (exact at {steps + 1} times, bounded "
                      f"between them by {SPEEDS_MEANING[speeds]}, {refined} intervals "
                      f"halved up to {CERTIFY_BISECTIONS} times)")
    return [item], {"min_clearance": swept.minimum, "closest_pair": "/".join(swept.pair),
                    "closest_time": swept.time, "clearance_bound": lower,
                    "clearance_speeds": speeds, "clearance_refined": refined}


def _bisected(col, trajectory, speeds, t: np.ndarray, bounds: np.ndarray
              ) -> tuple[np.ndarray, int]:
    """The intervals' bounds (K - 1,) (m), those below the margin halved again and again.

    Each of the first :data:`~tocontrol_ros.core.geometry.tuning.CERTIFY_REFINED` intervals
    whose bound is below ``col.margin`` is cut into 2, 4, ... 2^CERTIFY_BISECTIONS equal
    parts until its bound (the least over its parts, each by
    :meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.swept` with ``speeds`` of
    the parts' times) reaches the margin; an interval keeps the best of its bounds (each is
    one). Returns the bounds and how many intervals were cut.
    """
    bounds = bounds.copy()
    todo = np.flatnonzero(bounds < col.margin)[:CERTIFY_REFINED]
    refined = len(todo)
    for depth in range(1, CERTIFY_BISECTIONS + 1):
        if not len(todo):
            break
        parts = 2 ** depth
        frac = np.linspace(0.0, 1.0, parts + 1)
        # every interval's parts in one grid; the gaps between two intervals are intervals
        # of that grid too, and their bounds are not read
        grid = (t[todo, None] + frac[None, :] * (t[todo + 1] - t[todo])[:, None]).ravel()
        q = trajectory.state(grid)[:, :col.model.n]  # positions only: no torques
        sub = col.swept(grid, q, speeds(grid), least_exact=False).interval_bounds
        sub = np.append(sub, np.inf).reshape(len(todo), parts + 1)[:, :parts]
        bounds[todo] = np.maximum(bounds[todo], sub.min(axis=1))
        todo = todo[bounds[todo] < col.margin]
    return bounds, refined


def certify_open_loop(problem: Problem, trajectory, options: CertificateOptions | None = None,
                      sample: TrajectorySample | None = None,
                      solver_residual: float | None = None) -> Certificate:
    """Check a motion that has no costates (a direct method's): its torques and states.

    The nominal torques are integrated from ``x(0)`` by scipy's DOP853 (adaptive, error
    control at ``options.rtol``; a different method from the motion's own), through the
    sampling's times, or by the trajectory's own ``open_loop(rtol, atol)`` when it has one
    (:meth:`~tocontrol_ros.core.direct.flat_trajectory.FlatTrajectory.open_loop`: CVODES span
    by span; :meth:`~tocontrol_ros.core.direct.scaled_path.ScaledPath.open_loop`, a first or
    quick motion: the deviation from each segment's path by explicit Heun steps, one per
    output, each step's local error estimate within ``dsigma (atol + rtol |e|)`` in every
    component, or by CVODES where a step fails that test). Either way the forward dynamics
    are integrated under error control at ``options.rtol`` and ``atol`` (where the end items
    fail, once more at :data:`OPEN_LOOP_TIGHTER` times both, figure ``rtol``), with a local error
    test per step, not a global error bound: CVODES tests the weighted RMS norm of its
    estimate per step against ``rtol |e| + atol``, the explicit steps every component of
    theirs against an eighth of that (their eight steps a segment sum to at most one such
    bound); the items are the end point, velocity (and position for a joint-state
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

    def integrated(rtol: float, atol: float) -> tuple:
        if hasattr(trajectory, "open_loop"):  # its own (faster) re-integration, see its docs
            return (*trajectory.open_loop(rtol, atol)[1:], -1)
        x0 = trajectory.state(0.0)[0, :2 * n]
        sol = solve_ivp(rhs, (0.0, trajectory.T), x0, method="DOP853", rtol=rtol,
                        atol=atol, t_eval=sample.t)
        return sol.y.T, bool(sol.success), int(sol.nfev)

    target_qd = problem.target.value[n:] if problem.target.kind == "state" else 0.0
    for scale in (1.0, OPEN_LOOP_TIGHTER):  # tighter only where the end items failed
        rtol, atol = options.rtol * scale, options.atol * scale
        x_path, success, nfev = integrated(rtol, atol)
        x_T = x_path[-1]
        point_err = float(np.linalg.norm(model.point(x_T[:n]) - problem.target_point))
        vel_err = float(np.max(np.abs(x_T[n:] - target_qd)))
        items = end_checks(problem, x_T, point_err, vel_err, success, options)
        if all(item.passed for item in items):
            break
    items += torque_checks(problem, sample.u, options)[1]
    max_u = float(np.max(np.abs(sample.u)))
    items += solver_and_limit_checks(
        problem, sample, x_path, solver_residual,
        "the solver's max-norm of its NLP's constraint violation", options)
    clear_items, clear_figures = clearance_checks(problem, trajectory)
    items += clear_items
    return certificate_of(items, {**clear_figures,
        "point_error": point_err, "velocity_error": vel_err,
        "state_error": float(np.max(np.abs(x_T - trajectory.state(trajectory.T)[0, :2 * n]))),
        "max_abs_u": max_u, "integrator_success": success, "nfev": nfev,
        "rtol": rtol}, options, x_T)
