"""What a solve returns: the status, one record per start, the result and its warm state."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from tocontrol_ros.core.types.certificate import Certificate
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.trajectory import Motion
from tocontrol_ros.core.types.tuning import WARM_JOINT_RADIUS, WARM_RADIUS

__all__ = ["Status", "StartRecord", "PlanResult"]


class Status(enum.Enum):
    """Outcome of :func:`~tocontrol_ros.core.plan`; the value is a readable sentence."""

    SUCCESS = "solved and verified"
    TRIVIAL = "start at rest within MIN_MOVE of the target: nothing to move"
    NO_GUESS = "the direct method found no feasible initial guess"
    NEWTON_FAILED = "Newton's method did not converge"
    CONTINUATION_FAILED = "continuation in k stalled before the requested k"
    VERIFICATION_FAILED = "converged, but the verification failed"
    CANCELLED = "cancelled by the caller (a newer request or a shutdown)"
    TIME_LIMIT = "the time limit ran out before the solve finished"
    LIMITS_INFEASIBLE = "no motion within the joint limits was found"
    SCALING_FAILED = "the seed path could not be timed within the limits"


@dataclass(frozen=True)
class StartRecord:
    """One start of a multistart: its seeds and what became of it.

    Attributes
    ----------
    index : int
        Rank of the seed pair (0 = the first start).
    q_start, q_target : ndarray, shape (n,)
        Seed configurations (rad, m).
    guess_T : float
        ``T`` of the direct method's guess (s), NaN when it failed: at k = 1 for the
        multistart's guesses without bounds (the maximum principle's starts), at the
        requested k for those within the joint limits (the bounded solve's starts,
        ``method="direct"``).
    T : float
        Final ``T`` at the requested k (s), NaN when not continued or failed.
    status : str
    """

    index: int
    q_start: np.ndarray
    q_target: np.ndarray
    guess_T: float
    T: float
    status: str


@dataclass(frozen=True)
class PlanResult:
    """Outcome of :func:`~tocontrol_ros.core.planning.solver.plan` (like ``solve_bvp``'s result).

    Attributes
    ----------
    success : bool
    status : Status
    message : str
    T : float
        Minimum time (s); NaN when there is no solution.
    k : float
        Exponent reached (the requested one on success).
    trajectory : Motion or None
    residual : float
        Max-norm of the BVP equations (continuity, boundary, transversality, ``H(T)``).
    iterations : int
        Newton iterations, all continuation steps of the returned start included.
    timings : dict of str to float
        Wall time per phase (s): ``guess``, ``shooting``, ``refine``, ``verify``, ``total``.
    continuation : tuple of (k, delta, T, iterations, residual)
    max_abs_u : float
        ``max_i,t |u_i|``: the headroom left is ``1 - max_abs_u``.
    delta : float
        Smoothing of the control law in the returned solution (0 = the paper's law).
    intervals : int
        Shooting intervals of the final mesh.
    verification : dict
        The certificate's figures (:attr:`Certificate.figures`): ``point_error`` (m),
        ``velocity_error``, ``max_abs_H``, ``max_set_error`` (``max |sum u^2k - 1|``),
        ``max_defect``, ... (empty with ``verify=False``).
    warnings : tuple of str
        E.g. URDF position or velocity limits violated (joint and time).
    starts : tuple of StartRecord
    problem : Problem or None
        The problem solved.
    warm_state : object or None
        The method's own (:class:`~tocontrol_ros.core.indirect.warm.WarmState`,
        :class:`~tocontrol_ros.core.direct.warm.PathWarmState`, ...); only that method reads it.
        What a warm start continues from (None on failure): the final shooting mesh and
        unknowns, or for a ``"direct"`` result the final B-spline mesh and path.
    method : str
        ``"indirect"``: the maximum principle (multiple shooting of the canonical system);
        ``"direct"``: the joint limits bind, and the bounded B-spline transcription solved
        the problem (:mod:`~tocontrol_ros.core.direct.limited`, ``docs/limits.md``);
        ``"first"``: not the optimum but the first motion, a seed path timed by TOPP-RA
        (:mod:`~tocontrol_ros.core.direct.first_motion`; its timings are ``guess``,
        ``scaling``, ``verify``, ``total``).
    certificate : Certificate or None
        Every check with its value, tolerance and verdict (None with ``verify=False`` or
        without a solution).
    """

    success: bool
    status: Status
    message: str
    T: float
    k: float
    trajectory: Motion | None
    residual: float
    iterations: int
    timings: dict
    continuation: tuple
    max_abs_u: float
    delta: float
    intervals: int
    verification: dict = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    starts: tuple[StartRecord, ...] = ()
    problem: Problem | None = field(default=None, repr=False)
    warm_state: object | None = field(default=None, repr=False)
    certificate: Certificate | None = None
    method: str = "indirect"

    @classmethod
    def failure(cls, problem: Problem, status: Status, message: str, timings: dict,
                **fields) -> PlanResult:
        """A failed result: no trajectory, NaN figures, ``"<status>: <message>"``.

        ``fields`` set the others (``method``, ``starts``, the solve's ``iterations``...).
        """
        nan = float("nan")
        return cls(**{"success": False, "status": status,
                      "message": f"{status.value}: {message}", "T": nan, "k": problem.k,
                      "trajectory": None, "residual": nan, "iterations": 0,
                      "timings": timings, "continuation": (), "max_abs_u": nan,
                      "delta": nan, "intervals": 0, "problem": problem, **fields})

    @classmethod
    def trivial(cls, problem: Problem, timings: dict, method: str = "indirect"
                ) -> PlanResult:
        """The result of a problem whose start is its target (``T = 0``, no trajectory)."""
        return cls(success=True, status=Status.TRIVIAL, message=Status.TRIVIAL.value, T=0.0,
                   k=problem.k, trajectory=None, residual=0.0, iterations=0,
                   timings=timings, continuation=(), max_abs_u=0.0, delta=0.0,
                   intervals=0, problem=problem, method=method)

    def can_warm_start(self, problem: Problem,
                       joint_radius: float = WARM_JOINT_RADIUS) -> bool:
        """Whether :func:`~tocontrol_ros.core.planning.solver.plan` continues this to ``problem``.

        It does from a warm state with the same model, start and target kinds and reserve,
        when ``problem`` is near this one: each end point within :data:`WARM_RADIUS` of
        the previous one, and each joint-state end within ``joint_radius`` (max-norm of
        positions and velocities, rad and rad/s; by default :data:`WARM_JOINT_RADIUS`,
        ``SolverOptions.warm_joint_radius`` in a solve). The
        exponent may differ (the solve then steps ``k``). The one rule: ``plan`` applies it
        to any ``warm_start`` it is given (and then solves the warm start as one more
        candidate next to the multistart, never instead of it), so callers may pass their
        last result unconditionally.
        """
        prev = self.problem
        if not (self.warm_state is not None and prev is not None
                and prev.model is problem.model and prev.start.kind == problem.start.kind
                and prev.target.kind == problem.target.kind
                and prev.reserve == problem.reserve):
            return False
        return self.warm_distance(problem, joint_radius) <= 1.0

    def warm_distance(self, problem: Problem,
                      joint_radius: float = WARM_JOINT_RADIUS) -> float:
        """How near ``problem`` is to the one solved, in units of the warm-start radii.

        The largest of ``|p - p_prev| / WARM_RADIUS`` over both end points and, for
        joint-state ends, ``max |x - x_prev| / joint_radius``; ``inf`` without a
        previous problem or when the kinds differ. At most 1 means near.
        """
        prev = self.problem
        if prev is None or prev.model is not problem.model or \
                prev.start.kind != problem.start.kind or \
                prev.target.kind != problem.target.kind:
            return float("inf")
        dist = max(float(np.linalg.norm(problem.start_point - prev.start_point)),
                   float(np.linalg.norm(problem.target_point - prev.target_point))) \
            / WARM_RADIUS
        for new, old in ((problem.start, prev.start), (problem.target, prev.target)):
            if new.kind == "state":
                dist = max(dist, float(np.max(np.abs(new.value - old.value)))
                           / joint_radius)
        return dist
