"""Planning problems: start and target, each a task-space point or a joint state.

A point leaves the configuration free on the self-motion manifold ``P(q) = p`` (the paper's
setting, with ``qd = 0``); a joint state fixes ``q`` and ``qd`` (the robot's current state;
a target joint state is always at rest).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.geometry.collision import CollisionModel
from tocontrol_ros.core.geometry.reach import clear_configuration, note_clear
from tocontrol_ros.core.memo import OwnedMemo
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["Endpoint", "Problem", "point", "joint_state", "note_reachable", "MIN_MOVE",
           "REST_SPEED"]

#: Convexification exponents above this make ``|S|^(1/(2k-1))`` numerically a sign function.
MAX_K = 64.0
#: Moves shorter than this (m, or rad between joint states) from rest are nothing to plan:
#: the shooting Newton iteration stalls on some sub-millimetre moves (T ~ sqrt(distance)
#: makes the boundary equations badly scaled), whatever the number of starts.
MIN_MOVE = 1e-3
#: A start whose joint speeds are all below this (rad/s, m/s) is at rest for
#: :meth:`Problem.is_trivial` (a held arm reports tiny non-zero velocities).
REST_SPEED = 1e-6


@dataclass(frozen=True)
class Endpoint:
    """One end of a motion.

    Attributes
    ----------
    kind : {"point", "state"}
    value : ndarray
        The task-space point, shape (m,) (m), or the joint state ``(q, qd)``, shape (2n,).
    """

    kind: str
    value: np.ndarray = field(repr=False)

    def __repr__(self) -> str:
        return f"Endpoint({self.kind}, {np.array2string(self.value, precision=4)})"


def _finite(name: str, arr, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(arr, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"`{name}` must be numeric, got {arr!r}") from exc
    if a.shape != shape:
        raise ProblemError(f"`{name}` must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ProblemError(f"`{name}` must be finite, got {a.tolist()}")
    return a


def point(p) -> Endpoint:
    """A task-space point end (configuration free, at rest). Shape checked by :class:`Problem`."""
    return Endpoint("point", np.atleast_1d(np.asarray(p, dtype=float)))


def joint_state(q, qd=None) -> Endpoint:
    """A joint-state end: positions ``q`` (rad, m) and velocities ``qd`` (default 0)."""
    q = np.atleast_1d(np.asarray(q, dtype=float))
    qd = np.zeros_like(q) if qd is None else np.atleast_1d(np.asarray(qd, dtype=float))
    return Endpoint("state", np.concatenate([q, qd]))


@dataclass(frozen=True)
class Problem:
    """A time-optimal point-to-point problem for one model.

    Parameters
    ----------
    model : RobotModel
    start, target : Endpoint
        Built with :func:`point` or :func:`joint_state`; a target joint state must be at rest.
    k : float
        Convexification exponent of the control set ``sum u_i^(2k) <= 1``, ``1 <= k <= 64``.
        Integers reproduce the paper; the solver continues from 1 up to ``k``.
    reserve : float
        Torque reserve ``r`` in [0, 1): plan against ``(1 - r) tau_max``.
    limits : JointLimits, optional
        Joint position and velocity limits the plan keeps to; default: the URDF's, no
        margin (:meth:`JointLimits.from_model`).
    collision : CollisionModel, optional
        The arm's geometry, the scene and the margin the motion keeps from obstacles and
        between its own links (:func:`~tocontrol_ros.core.geometry.collision.collision_model`);
        default: none (the motion knows no geometry). A start or target joint state closer
        than the margin is refused, naming the pair and the distance; so is a start or
        target point none of whose configurations found inside the limits is that clear
        (:func:`~tocontrol_ros.core.geometry.reach.clear_configuration`: inside an
        obstacle, or reachable only through one), naming the clearest one's closest pair.

    Raises
    ------
    ProblemError
        Wrong shapes, NaN or infinite values, ``k`` or ``reserve`` out of range, an
        unreachable point, a joint state outside the position limits, a moving target state;
        with ``collision``, an end closer than the margin to an obstacle or to the arm
        itself (a point: no clear configuration found).
    """

    model: RobotModel
    start: Endpoint
    target: Endpoint
    k: float = 1.0
    reserve: float = 0.0
    limits: JointLimits | None = None
    collision: CollisionModel | None = None

    def __post_init__(self) -> None:
        model = self.model
        if self.limits is None:
            object.__setattr__(self, "limits", JointLimits.from_model(model))
        elif not isinstance(self.limits, JointLimits) or \
                tuple(self.limits.names) != tuple(model.joint_names):
            raise ProblemError("`limits` must be a JointLimits of the model's joints "
                               f"{list(model.joint_names)}, got {self.limits!r}")
        try:
            k = float(self.k)
        except (TypeError, ValueError) as exc:
            raise ProblemError(f"`k` must be a number, got {self.k!r}") from exc
        if not (np.isfinite(k) and 1.0 <= k <= MAX_K):
            raise ProblemError(f"`k` must be in [1, {MAX_K:g}], got {self.k!r}")
        object.__setattr__(self, "k", k)
        r = float(self.reserve)
        if not (np.isfinite(r) and 0.0 <= r < 1.0):
            raise ProblemError(f"`reserve` must be in [0, 1), got {self.reserve!r}")
        for name in ("start", "target"):
            end = getattr(self, name)
            if not isinstance(end, Endpoint):
                raise ProblemError(f"`{name}` must be an Endpoint (use point() or "
                                   f"joint_state()), got {type(end).__name__}")
            if end.kind == "point":
                p = _finite(f"{name} point", end.value, (model.m,))
                _check_reachable(model, name, p)
            elif end.kind == "state":
                x = _finite(f"{name} joint state", end.value, (2 * model.n,))
                self.limits.check_state(name, x[:model.n], x[model.n:])
                if name == "target" and np.any(x[model.n:] != 0):
                    raise ProblemError("`target` joint state must be at rest (qd = 0), got "
                                       f"qd = {x[model.n:].tolist()}")
            else:
                raise ProblemError(f"`{name}.kind` must be 'point' or 'state', got "
                                   f"{end.kind!r}")
        if self.collision is not None:
            self._check_clearance()

    def _check_clearance(self) -> None:
        """A collision model of this model; joint-state ends at least the margin clear."""
        col = self.collision
        if not isinstance(col, CollisionModel) or \
                tuple(col.model.joint_names) != tuple(self.model.joint_names):
            raise ProblemError(f"`collision` must be a CollisionModel of the model's joints "
                               f"{list(self.model.joint_names)}, got {col!r}")
        for name in ("start", "target"):
            end = getattr(self, name)
            if end.kind == "point":
                self._check_clear_point(name, end.value)
                continue
            found = col.clearance(end.value[:self.model.n])
            if found.minimum < col.margin:
                what = "in collision" if found.minimum < 0 else "within the collision margin"
                raise ProblemError(
                    f"`{name}` joint state is {what}: {found.pair[0]} and {found.pair[1]} are "
                    f"{found.minimum:.4f} m apart (margin {col.margin:g} m)")

    def _check_clear_point(self, name: str, p: np.ndarray) -> None:
        """A point end has a configuration inside the limits clear by the margin."""
        col = self.collision
        found = clear_configuration(col, p, self.limits.plan_lower, self.limits.plan_upper)
        if found.found:
            return
        where = f"`{name}` point {np.round(p, 6).tolist()}"
        if found.tried == 0:
            raise ProblemError(
                f"{where} has no configuration inside the joint limits: none of its "
                f"{found.solutions} IK solutions (from {found.seeds} seeds) is inside them")
        # Coal gives a mesh pair in contact a distance of 0 (no penetration depth).
        what = "in collision" if found.clearance <= 0 else \
            f"{found.clearance:.4f} m clear"
        raise ProblemError(
            f"{where} has no configuration clear of the scene by the margin "
            f"({col.margin:g} m): of {found.tried} IK solutions inside the joint limits "
            f"(from {found.seeds} seeds), the clearest is {what}, {found.pair[0]} and "
            f"{found.pair[1]} closest; the point is inside an obstacle, or the arm reaches "
            f"it only through one (or through itself)")

    @property
    def start_point(self) -> np.ndarray:
        """The start end-effector point, shape (m,), whatever the kind of start."""
        if self.start.kind == "point":
            return self.start.value
        return self.model.point(self.start.value[:self.model.n])

    @property
    def target_point(self) -> np.ndarray:
        """The target end-effector point, shape (m,)."""
        if self.target.kind == "point":
            return self.target.value
        return self.model.point(self.target.value[:self.model.n])

    @property
    def boundary_values(self) -> np.ndarray:
        """``(start.value, target.value)``: the values the BVP's boundary conditions take."""
        return np.concatenate([self.start.value, self.target.value])

    @property
    def torque_scale(self) -> float:
        """Fraction of ``tau_max`` planned against: ``1 - reserve``."""
        return 1.0 - self.reserve

    def is_trivial(self, tol: float = MIN_MOVE, rest: float = REST_SPEED) -> bool:
        """True when the start already satisfies the target at rest: nothing to move.

        The one rule for "start == target" (the solver and the planner node both use it).

        Parameters
        ----------
        tol : float
            Largest distance between start and target (m; rad between two joint states).
        rest : float
            Largest joint speed of a joint-state start (rad/s, m/s).
        """
        n = self.model.n
        if self.start.kind == "state" and np.any(np.abs(self.start.value[n:]) > rest):
            return False
        if self.start.kind == "state" and self.target.kind == "state":
            return bool(np.all(np.abs(self.start.value[:n] - self.target.value[:n]) <= tol))
        if self.target.kind == "state":
            return False
        return bool(np.linalg.norm(self.start_point - self.target_point) <= tol)


#: Points of a model found reachable (:func:`_check_reachable`), newest last: a replan makes
#: several problems with the same target (the running motion's tail, target steps), each
#: check an IK solve from 8 seeds (about 2-3 ms on the paper's arm). The check's IK is
#: seeded, so a remembered answer is the one it would give again.
_REACHABLE = OwnedMemo(256)


def _check_reachable(model: RobotModel, name: str, p: np.ndarray) -> None:
    """Reject points that no configuration reaches, or only singular ones reach.

    Unreachable: numerical IK from a few starts fails. On the workspace boundary: every
    configuration found (three IK runs) is singular. A point found reachable before for the
    same model object is not solved again.
    """
    if _known_reachable(model, p):
        return
    _solve_reachable(model, name, p)
    _remember_reachable(model, p)


def _known_reachable(model: RobotModel, p: np.ndarray) -> bool:
    """Whether ``p`` was found reachable for this model object (refreshed if so)."""
    return _REACHABLE.get(model, (p.dtype.str, p.tobytes()), False)


def _remember_reachable(model: RobotModel, p: np.ndarray) -> None:
    _REACHABLE.put(model, (p.dtype.str, p.tobytes()), True)


def _solve_reachable(model: RobotModel, name: str, p: np.ndarray) -> None:
    """:func:`_check_reachable`'s IK solves."""
    from tocontrol_ros.core.robot.ik import solve_ik

    q = solve_ik(model, p)
    if q is None:
        raise ProblemError(f"`{name}` point {p.tolist()} is not reachable by {model.name!r} "
                           f"(reach about {model.reach():.4g} m from the first joint)")
    if _singular(model, q) and all(
            other is None or _singular(model, other)
            for other in (solve_ik(model, p, rng=np.random.default_rng(s)) for s in (1, 2))):
        raise ProblemError(
            f"`{name}` point {p.tolist()} is on the boundary of the workspace of "
            f"{model.name!r}: only a singular configuration reaches it (e.g. the arm fully "
            f"stretched, reach about {model.reach():.4g} m), from which the arm cannot move "
            f"in every direction; give a point slightly inside")


#: Gauss-Newton steps of :func:`note_reachable` (from a configuration that reaches a point a
#: fraction of a millimetre away: two reach it to about 1e-15 m on the paper's arm).
NEAR_STEPS = 4


def note_reachable(model: RobotModel, p, q_near, collision: CollisionModel | None = None
                   ) -> bool:
    """Show ``p`` reachable from a configuration that reaches a point nearby, if it is.

    A few Gauss-Newton steps from ``q_near`` (about 0.25 ms on the paper's arm, where the
    check of a :class:`Problem` runs its IK from 8 seeds: 1.3-3 ms, and
    :func:`~tocontrol_ros.core.robot.ik.solve_ik` from that one seed 0.7 ms). When they reach ``p``
    within the IK's tolerance at a configuration that is not singular, ``p`` is remembered
    as reachable and a :class:`Problem` with it as an end skips its own check (whose
    verdict this is, or a reachable point that check's seeds missed). Otherwise nothing is
    remembered and the problem checks as always. A replan knows such a configuration: the
    end of the motion it continues.

    Parameters
    ----------
    model : RobotModel
    p : array_like, shape (m,)
        Task-space point (m).
    q_near : array_like, shape (n,)
        A configuration that reaches a point near ``p`` (rad, m).
    collision : CollisionModel, optional
        The collision model of the problems to come: the configuration reaching ``p`` is
        also checked clear of the scene once (:func:`~tocontrol_ros.core.geometry.reach.
        note_clear`), which spares such a problem the search for a clear configuration of
        its point (about 0.04-0.07 s of IK and exact distances on the Panda over a table).

    Returns
    -------
    bool
        Whether ``p`` was shown reachable.
    """
    from tocontrol_ros.core.robot.ik import IK_TOL

    try:
        p = _finite("point", p, (model.m,))
        q = _finite("q_near", q_near, (model.n,)).copy()
    except ProblemError:
        return False
    if _known_reachable(model, p) and collision is None:  # e.g. solved again from a later
        return True  # hand-off
    # P and J in one buffered call, the steps' least-norm solve and the singularity test
    # on the m x m matrix J J^T (m <= 3 task axes): the verdict is the IK tolerance's and
    # SINGULAR_TOL's; the configuration itself is not kept. Two CasADi calls, lstsq and an
    # SVD per step cost about 0.5-1 ms more a replan through the nodes.
    for step in range(NEAR_STEPS + 1):
        point, j = model.point_and_jacobian(q)
        e = point - p
        err = float(np.linalg.norm(e))
        if not err >= 1e-3 * IK_TOL or step == NEAR_STEPS:  # there, NaN, or the last
            break
        try:
            q = q - j.T @ np.linalg.solve(j @ j.T, e)
        except np.linalg.LinAlgError:
            return False
    if not (err < IK_TOL and np.all(np.isfinite(q))) or _singular_near(model, j):
        return False
    _remember_reachable(model, p)
    if collision is not None:
        note_clear(collision, p, q)
    return True


def _singular_near(model: RobotModel, j: np.ndarray) -> bool:
    """:func:`_singular` of the Jacobian ``j`` (m, n), from the eigenvalues of ``J J^T``."""
    if j.shape[0] > j.shape[1]:
        return True
    lowest = float(np.linalg.eigvalsh(j @ j.T)[0])
    return not lowest >= (SINGULAR_TOL * model.reach()) ** 2


#: A configuration is singular for :func:`_check_reachable` when the smallest singular value
#: of its task Jacobian is below this fraction of the reach (the IK's tolerance leaves a
#: boundary point's configuration about this far from exactly singular).
SINGULAR_TOL = 2e-5


def _singular(model: RobotModel, q: np.ndarray) -> bool:
    sigma = np.linalg.svd(model.jacobian(q), compute_uv=False)
    return bool(sigma.size < model.m or sigma[-1] < SINGULAR_TOL * model.reach())
