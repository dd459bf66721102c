"""Inverse kinematics: configurations that put the tip at a task-space point.

The solver seeds its starts with configurations spread over the self-motion manifold of
each end point. For a planar arm the manifold is swept by the absolute angle of the last
link (``phi = sum q`` for revolute joints about parallel axes) and the elbow sign; for the
standard planar 3R (link offsets along each frame's x axis) this is closed form. Other arms
use Levenberg-Marquardt (``scipy.optimize.least_squares``) from spread seeds.

Poses (position and orientation of the tip frame, a spatial arm's pick): :func:`ik_pose`,
damped least squares on the six residuals from many seeds at once, with the geometric
Jacobian of the numeric kinematics (:mod:`~tocontrol_ros.core.robot.kinematics`), within the
joint limits; :func:`pose_errors` measures a configuration against a pose.
"""

from __future__ import annotations

import weakref

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["angle_family", "solve_ik", "ik_family", "ik_near", "ik_pose", "pose_errors",
           "wrap_angles"]

#: A configuration counts as reaching a point when ``|P(q) - p|`` is below this (m).
IK_TOL = 1e-9


def wrap_angles(q: np.ndarray, model: RobotModel) -> np.ndarray:
    """Wrap continuous (unlimited revolute) joints into (-pi, pi]; other joints unchanged.

    ``q`` is one configuration (n,) or one per row (K, n).
    """
    q = np.array(q, dtype=float)
    cont = ~np.isfinite(model.q_lower) & np.array([b.kind == "revolute" for b in model.bodies])
    q[..., cont] = np.pi - np.mod(np.pi - q[..., cont], 2 * np.pi)
    return q


def _bounds(model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    return model.q_lower.copy(), model.q_upper.copy()


def _lm(model: RobotModel, p: np.ndarray, seed: np.ndarray, phi: float | None = None):
    fk = model.function("P")
    jac = model.function("J")
    lo, hi = _bounds(model)
    seed = np.clip(seed, np.where(np.isfinite(lo), lo + 1e-9, -np.inf),
                   np.where(np.isfinite(hi), hi - 1e-9, np.inf))

    def res(q):
        r = np.array(fk(q)).ravel() - p
        if phi is not None:
            d = np.sum(q) - phi
            r = np.append(r, np.arctan2(np.sin(d), np.cos(d)))
        return r

    def jacobian(q):
        j = np.array(jac(q))
        if phi is not None:
            j = np.vstack([j, np.ones(model.n)])
        return j

    sol = least_squares(res, seed, jac=jacobian, bounds=(lo, hi), method="trf",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
    err = np.linalg.norm(np.array(fk(sol.x)).ravel() - p)
    return sol.x, err


def _lm_batch(model: RobotModel, p: np.ndarray, seeds: np.ndarray,
              phis: np.ndarray | None = None, max_iter: int = 200, first: bool = False
              ) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt from many seeds at once, within the joint limits.

    All seeds advance together through one mapped call of the kinematics per iteration (the
    per-seed ``least_squares`` spent most of a redundant arm's plan in Python overhead).
    Steps ``dq = -J^T (J J^T + lambda I)^-1 r`` (the minimum-norm step of a redundant arm),
    projected onto the limits; ``lambda`` per seed, lowered after a step that reduces the
    residual, raised (and the step undone) otherwise.

    Parameters
    ----------
    p : ndarray, shape (m,)
        Task-space point (m).
    seeds : ndarray, shape (N, n)
        Start configurations (rad or m).
    phis : ndarray, shape (N,), optional
        Planar arms: the absolute angle ``sum q`` each solution must also have (rad).
    first : bool
        Stop as soon as one seed has converged (the others keep their last iterate).

    Returns
    -------
    q : ndarray, shape (N, n)
    err : ndarray, shape (N,)
        ``|P(q) - p|`` (m).
    """
    seeds = np.atleast_2d(np.asarray(seeds, dtype=float))
    N, n = seeds.shape
    fk, jac = model.function("P").map(N), model.function("J").map(N)
    lo, hi = _bounds(model)
    lo = np.where(np.isfinite(lo), lo + 1e-9, -np.inf)
    hi = np.where(np.isfinite(hi), hi - 1e-9, np.inf)

    def residual(q):
        r = np.array(fk(q.T)).T - p
        if phis is not None:
            d = np.sum(q, axis=1) - phis
            r = np.hstack([r, np.arctan2(np.sin(d), np.cos(d))[:, None]])
        return r

    q = np.clip(seeds, lo, hi)
    r = residual(q)
    cost = np.sum(r * r, axis=1)
    lam = np.full(N, 1e-3)
    stuck = np.zeros(N, dtype=bool)
    for _ in range(max_iter):
        done = cost <= (1e-2 * IK_TOL) ** 2
        active = ~done & ~stuck
        if not active.any() or (first and done.any()):
            break
        J = np.array(jac(q.T)).reshape(-1, N, n).transpose(1, 0, 2)  # (N, m, n)
        if phis is not None:
            J = np.concatenate([J, np.ones((N, 1, n))], axis=1)
        dq = _step(J, r, lam)
        # Joints the step would push through a limit are held there and the step is taken
        # again with the others (plain clipping stalls seeds against the limits).
        held = (q + dq < lo) | (q + dq > hi)
        if held.any():
            dq = _step(J * ~held[:, None, :], r, lam)
        q_new = np.where(active[:, None], np.clip(q + dq, lo, hi), q)
        r_new = residual(q_new)
        cost_new = np.sum(r_new * r_new, axis=1)
        better = active & (cost_new < cost)
        q[better], r[better], cost[better] = q_new[better], r_new[better], cost_new[better]
        lam = np.where(better, np.maximum(lam / 4, 1e-12), np.where(active, lam * 8, lam))
        # A seed whose damping has grown this large is stuck (at a limit or a singularity).
        stuck |= lam > 1e8
    err = np.linalg.norm(np.array(fk(q.T)).T - p, axis=1)
    return q, err


def _step(J: np.ndarray, r: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Damped minimum-norm steps (N, n) for Jacobians J (N, m, n), residuals r (N, m)."""
    mr = J.shape[1]
    scale = np.maximum(np.einsum("kij,kij->k", J, J) / mr, 1e-12)
    A = J @ J.transpose(0, 2, 1) + (lam * scale)[:, None, None] * np.eye(mr)
    return -np.einsum("kji,kj->ki", J, np.linalg.solve(A, r[..., None])[..., 0])


def _planar3r_lengths(model: RobotModel) -> tuple[np.ndarray, float, float, float] | None:
    """Offsets of a standard planar 3R (all frames aligned, offsets along x), else None.

    Computed once per model (the solver asks for every seed).
    """
    if model not in _PLANAR3R:
        _PLANAR3R[model] = _planar3r_lengths_of(model)
    return _PLANAR3R[model]


_PLANAR3R: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _planar3r_lengths_of(model: RobotModel) -> tuple[np.ndarray, float, float, float] | None:
    if model.n != 3 or model.m != 2 or model.task_axes != (0, 1):
        return None
    for b in model.bodies:
        if b.kind != "revolute" or not np.allclose(b.rotation, np.eye(3)) or \
                not np.allclose(b.axis, [0, 0, 1]):
            return None
    offsets = [b.translation for b in model.bodies[1:]] + [model.tip_translation]
    if not np.allclose(model.tip_rotation, np.eye(3)):
        return None
    if any(abs(o[1]) > 1e-12 or o[0] <= 0 for o in offsets):
        return None
    return model.bodies[0].translation[:2], offsets[0][0], offsets[1][0], offsets[2][0]


def _planar3r(model: RobotModel, p: np.ndarray, phis: np.ndarray) -> np.ndarray:
    """Closed-form IK of a planar 3R for absolute end angles ``phis`` (K,), both elbows.

    Returns
    -------
    ndarray, shape (J, 3)
        Per angle, the elbow-up then the elbow-down configuration where ``p`` is reachable
        with that angle (J <= 2K, in that order).
    """
    base, l1, l2, l3 = _planar3r_lengths(model)
    phi = np.repeat(np.asarray(phis, dtype=float), 2)
    elbow = np.tile([1.0, -1.0], len(phis))
    w = (p - base)[None, :] - l3 * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    c2 = (np.sum(w * w, axis=1) - l1**2 - l2**2) / (2 * l1 * l2)
    ok = np.abs(c2) <= 1
    phi, elbow, w, c2 = phi[ok], elbow[ok], w[ok], c2[ok]
    q2 = elbow * np.arccos(np.clip(c2, -1, 1))
    q1 = np.arctan2(w[:, 1], w[:, 0]) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return np.stack([q1, q2, phi - q1 - q2], axis=1)


def solve_ik(model: RobotModel, p, q_seed=None, tries: int = 8,
             rng: np.random.Generator | None = None) -> np.ndarray | None:
    """One configuration with ``P(q) = p``, or None when none is found.

    Parameters
    ----------
    model : RobotModel
    p : array_like, shape (m,)
        Task-space point (m).
    q_seed : array_like, shape (n,), optional
        First seed; random seeds within the limits follow (all solved at once until one
        converges; the first of those in this order gives the result).
    tries : int
        Number of seeds.
    rng : numpy.random.Generator, optional
        Source of the random seeds (default: seeded, so results repeat).

    Returns
    -------
    ndarray, shape (n,) or None
    """
    p = np.asarray(p, dtype=float)
    rng = np.random.default_rng(0) if rng is None else rng
    lo = np.where(np.isfinite(model.q_lower), model.q_lower, -np.pi)
    hi = np.where(np.isfinite(model.q_upper), model.q_upper, np.pi)
    seeds = [np.asarray(q_seed, dtype=float)] if q_seed is not None else []
    seeds += [rng.uniform(lo, hi) for _ in range(tries)]
    q, err = _lm_batch(model, p, np.array(seeds), first=True)
    ok = np.flatnonzero(err < IK_TOL)
    return wrap_angles(q[ok[0]], model) if len(ok) else None


def ik_family(model: RobotModel, p, count: int = 12,
              rng: np.random.Generator | None = None) -> list[np.ndarray]:
    """Configurations spread over the self-motion manifold of ``p``.

    Parameters
    ----------
    model : RobotModel
    p : array_like, shape (m,)
        Task-space point (m).
    count : int
        Planar arms: number of absolute angles of the last link, each with both elbows.
        Other arms: number of seeds.
    rng : numpy.random.Generator, optional

    Returns
    -------
    list of ndarray, shape (n,)
        Distinct configurations (continuous joints wrapped into (-pi, pi]); empty when
        ``p`` is out of reach.
    """
    p = np.asarray(p, dtype=float)
    rng = np.random.default_rng(0) if rng is None else rng
    phis = np.linspace(-np.pi, np.pi, count, endpoint=False)
    if _planar3r_lengths(model) is not None:
        return _distinct_solutions(model, p, list(_planar3r(model, p, phis)))
    if angle_family(model):
        seeds = np.repeat([[0.3], [-0.3]], model.n, axis=1)
        q, err = _lm_batch(model, p, np.tile(seeds, (count, 1)), np.repeat(phis, 2))
        return _distinct_solutions(model, p, list(q[err < IK_TOL]))
    lo = np.where(np.isfinite(model.q_lower), model.q_lower, -np.pi)
    hi = np.where(np.isfinite(model.q_upper), model.q_upper, np.pi)
    return ik_near(model, p, np.array([rng.uniform(lo, hi) for _ in range(count)]))


def ik_near(model: RobotModel, p, seeds) -> list[np.ndarray]:
    """Configurations reaching ``p``, each found from one of ``seeds`` (near it).

    Levenberg-Marquardt's minimum-norm steps from a configuration end on the self-motion
    manifold of ``p`` close to it: a target configuration that needs little motion from a
    start configuration.

    Parameters
    ----------
    model : RobotModel
    p : array_like, shape (m,)
        Task-space point (m).
    seeds : array_like, shape (N, n)
        Configurations to start from (rad, m).

    Returns
    -------
    list of ndarray, shape (n,)
        Distinct configurations (wrapped), in the seeds' order; those that did not converge
        are left out.
    """
    p = np.asarray(p, dtype=float)
    q, err = _lm_batch(model, p, np.atleast_2d(np.asarray(seeds, dtype=float)))
    return _distinct_solutions(model, p, list(q[err < IK_TOL]))


def angle_family(model: RobotModel) -> bool:
    """Whether :func:`ik_family` spreads angles of the last link (each with both elbows).

    True for planar arms of revolute joints with parallel axes (``m = 2``, ``n >= 3``);
    for other arms its ``count`` is the number of random seeds, one configuration each.
    """
    return _planar3r_lengths(model) is not None or (
        model.m == 2 and all(b.kind == "revolute" for b in model.bodies) and model.n >= 3
        and _axes_parallel(model))


def _distinct_solutions(model: RobotModel, p: np.ndarray, cands: list) -> list[np.ndarray]:
    """The candidates (wrapped) that reach ``p``, without repeats, in their order.

    One mapped call of the forward kinematics checks them all.
    """
    if not cands:
        return []
    qs = wrap_angles(np.array(cands), model)  # (K, n)
    points = np.array(model.function("P").map(len(qs))(qs.T)).T  # (K, m)
    qs = qs[np.linalg.norm(points - p, axis=1) <= IK_TOL]
    # Pairwise distances modulo full turns; keep each candidate not within 1e-6 of an
    # earlier kept one (earlier duplicates of a kept one are dropped with it).
    diff = np.angle(np.exp(1j * (qs[:, None, :] - qs[None, :, :])))
    near = np.linalg.norm(diff, axis=2) <= 1e-6
    keep: list[int] = []
    for i in range(len(qs)):
        if not near[i, keep].any():
            keep.append(i)
    return [qs[i] for i in keep]


def _axes_parallel(model: RobotModel) -> bool:
    rot = np.eye(3)
    axes = []
    for b in model.bodies:
        rot = rot @ b.rotation
        axes.append(rot @ b.axis)
    return all(abs(abs(a @ axes[0]) - 1) < 1e-9 for a in axes)


# ---------------------------------------------------------------------------- poses
#: A configuration reaches a pose when its position error is below this (m) and its
#: orientation error below this (rad): the IK's own convergence, far below any goal
#: tolerance (the goal's tolerances are checked on the planned motion, not here).
POSE_IK_TOL = 1e-8
#: Iterations of the damped least squares from each seed (a work count, never a clock):
#: the Panda's seeds that converge do so in 20 to 60.
POSE_IK_ITERATIONS = 200


def _tip_frames_and_jacobians(model: RobotModel, q: np.ndarray):
    """Tip frames and geometric Jacobians at many configurations (numpy only).

    Parameters
    ----------
    q : ndarray, shape (K, n)

    Returns
    -------
    rotation : ndarray, shape (K, 3, 3)
    position : ndarray, shape (K, 3)
        The tip frame in the base frame (m).
    jacobian : ndarray, shape (K, 6, n)
        Rows 0-2 the tip's linear velocity (m/s per joint speed), rows 3-5 its angular
        velocity (rad/s), both in the base frame.
    """
    count, n = q.shape
    rot = np.broadcast_to(np.eye(3), (count, 3, 3)).copy()
    pos = np.zeros((count, 3))
    axes = np.zeros((count, n, 3))
    origins = np.zeros((count, n, 3))
    prismatic = np.array([b.kind == "prismatic" for b in model.bodies])
    for i, body in enumerate(model.bodies):
        pos = pos + rot @ body.translation
        rot = rot @ body.rotation
        axes[:, i] = rot @ body.axis
        origins[:, i] = pos
        if body.kind == "prismatic":
            pos = pos + axes[:, i] * q[:, i:i + 1]
        else:
            k = _skew(body.axis)
            s, c = np.sin(q[:, i])[:, None, None], np.cos(q[:, i])[:, None, None]
            rot = rot @ (np.eye(3) + s * k + (1.0 - c) * (k @ k))
    tip_pos = pos + rot @ model.tip_translation
    tip_rot = rot @ model.tip_rotation
    linear = np.where(prismatic[None, :, None], axes,
                      np.cross(axes, tip_pos[:, None, :] - origins))
    angular = np.where(prismatic[None, :, None], 0.0, axes)
    return tip_rot, tip_pos, np.concatenate([linear, angular], axis=2).transpose(0, 2, 1)


def _skew(a: np.ndarray) -> np.ndarray:
    """The cross-product matrix (3, 3) of a vector (3,)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _pose_residual(rotation, position, goal_rotation, goal_position):
    """Residuals (K, 6): position (m), then the rotation vector of ``R R_goal^T`` (rad)."""
    turn = Rotation.from_matrix(rotation @ goal_rotation.T).as_rotvec()
    return np.hstack([position - goal_position, turn.reshape(-1, 3)])


def pose_errors(model: RobotModel, q, position, rotation) -> tuple[np.ndarray, np.ndarray]:
    """How far the tip at ``q`` is from a pose: position and orientation errors.

    Parameters
    ----------
    model : RobotModel
    q : array_like, shape (n,) or (K, n)
        Configurations (rad, m).
    position : array_like, shape (3,)
        The pose's position in the base frame (m).
    rotation : array_like, shape (3, 3)
        The pose's orientation in the base frame (a rotation matrix).

    Returns
    -------
    position_error : ndarray, shape (K,)
        Distance between the tip's origin and ``position`` (m).
    orientation_error : ndarray, shape (K,)
        The angle of the rotation from the tip's orientation to ``rotation`` (rad, in
        [0, pi]).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rot, pos, _ = _tip_frames_and_jacobians(model, q)
    r = _pose_residual(rot, pos, np.asarray(rotation, dtype=float),
                       np.asarray(position, dtype=float))
    return np.linalg.norm(r[:, :3], axis=1), np.linalg.norm(r[:, 3:], axis=1)


def ik_pose(model: RobotModel, position, rotation, seeds, lower=None, upper=None,
            max_iter: int = POSE_IK_ITERATIONS) -> tuple[list[np.ndarray], float, float]:
    """Configurations within the joint limits that put the tip frame at a pose.

    Damped least squares from every seed at once: steps ``dq = -J^T (J J^T + lambda I)^-1
    r`` on the six residuals (position, rotation vector), the joints a step would push
    through a limit held there; ``lambda`` per seed lowered after a step that reduces the
    residual, raised otherwise; a seed whose damping grows past 1e8 is stuck.

    Parameters
    ----------
    model : RobotModel
    position : array_like, shape (3,)
        The tip's position in the base frame (m).
    rotation : array_like, shape (3, 3)
        The tip's orientation in the base frame (rotation matrix).
    seeds : array_like, shape (N, n)
        Start configurations (rad, m); clipped into the limits.
    lower, upper : array_like, shape (n,), optional
        Position limits (rad, m; infinite: none); default the model's. The planner passes
        its own (with ``limit_margin``).
    max_iter : int
        Iterations per seed.

    Returns
    -------
    solutions : list of ndarray, shape (n,)
        Distinct configurations reaching the pose within :data:`POSE_IK_TOL` (continuous
        joints wrapped), in the order of their seeds; empty when none converged.
    closest_position_error, closest_orientation_error : float
        The errors of the seed that came closest (m, rad): how far an unreachable pose is.
    """
    goal_p = np.asarray(position, dtype=float).reshape(3)
    goal_r = np.asarray(rotation, dtype=float).reshape(3, 3)
    seeds = np.atleast_2d(np.asarray(seeds, dtype=float))
    lo, hi = _bounds(model)
    lo = lo if lower is None else np.asarray(lower, dtype=float)
    hi = hi if upper is None else np.asarray(upper, dtype=float)
    lo = np.where(np.isfinite(lo), lo + 1e-9, -np.inf)
    hi = np.where(np.isfinite(hi), hi - 1e-9, np.inf)
    q = np.clip(seeds, lo, hi)
    count = len(q)

    def evaluate(qs):
        rot, pos, jac = _tip_frames_and_jacobians(model, qs)
        r = _pose_residual(rot, pos, goal_r, goal_p)
        return r, np.sum(r * r, axis=1), jac

    r, cost, jac = evaluate(q)
    lam = np.full(count, 1e-3)
    stuck = np.zeros(count, dtype=bool)
    for _ in range(max_iter):
        active = ~(cost <= (0.1 * POSE_IK_TOL) ** 2) & ~stuck
        if not active.any():
            break
        dq = _step(jac, r, lam)
        held = (q + dq < lo) | (q + dq > hi)
        if held.any():
            dq = _step(jac * ~held[:, None, :], r, lam)
        q_new = np.where(active[:, None], np.clip(q + dq, lo, hi), q)
        r_new, cost_new, jac_new = evaluate(q_new)
        better = active & (cost_new < cost)
        q[better], r[better], cost[better] = q_new[better], r_new[better], cost_new[better]
        jac[better] = jac_new[better]
        lam = np.where(better, np.maximum(lam / 4, 1e-12), np.where(active, lam * 8, lam))
        stuck |= lam > 1e8
    pos_err = np.linalg.norm(r[:, :3], axis=1)
    ang_err = np.linalg.norm(r[:, 3:], axis=1)
    best = int(np.argmin(pos_err + ang_err))
    ok = (pos_err <= POSE_IK_TOL) & (ang_err <= POSE_IK_TOL)
    kept: list[np.ndarray] = []
    for qi in wrap_angles(q[ok], model):
        if all(np.linalg.norm(np.angle(np.exp(1j * (qi - k)))) > 1e-6 for k in kept):
            kept.append(qi)
    return kept, float(pos_err[best]), float(ang_err[best])
