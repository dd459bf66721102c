"""Tolerances and limits of the solver, validated on construction."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.types.certificate import CertificateOptions
from tocontrol_ros.core.types.tuning import WARM_JOINT_RADIUS

#: Fewest spans of ``SolverOptions.replan_spans`` (a cubic spline on fewer barely bends).
MIN_REPLAN_SPANS = 4

__all__ = ["SolverOptions"]


@dataclass(frozen=True)
class SolverOptions:
    """Tolerances and limits of :func:`~tocontrol_ros.core.planning.solver.plan` (validated).

    Attributes
    ----------
    tol : float
        Newton converges when the max-norm of the BVP equations is below this.
    max_newton : int
        Newton iterations per solve (each continuation step is one solve).
    intervals : int
        Initial number of shooting intervals.
    steps : int
        RK4 steps per shooting interval. With switch nodes, more steps per interval resolve
        the graded intervals at a switch better (fewer intervals at the same accuracy, and
        cheaper warm re-solves). With switch nodes the k = 1 solve and the continuation in
        k, whose solutions only lead to the switch mesh, take at most
        :data:`~tocontrol_ros.core.indirect.tuning.CONTINUATION_STEPS`.
    guess_intervals : int
        Mesh intervals of the direct method that makes the initial guess. Its IPOPT solves
        are most of a plan's time; 10 finds the same best motions as 12 on the benchmark's
        pairs of the paper's arm for less time, 8 misses more (``docs/seeding.md``).
    guess_tol : float
        IPOPT tolerance of those direct solves: the shooting refines the guess and a guess's
        ``T`` only ranks the candidates, so a tight tolerance buys nothing (the same basins
        as at 1e-8, ``docs/seeding.md``).
    integration_tol : float
        Mesh refinement: max RK4 error estimate per interval (max-norm of ``z``). The
        default keeps ``|H|`` below 1e-6 along the paper's example for k = 1 ... 16 and the
        re-integrated end point within 1e-6 m.
    max_intervals : int
        Mesh refinement stops here.
    smoothing : tuple of float
        Decreasing ``delta`` schedule tried at the requested ``k`` (for k > 1).
    smoothing_intermediate : float
        ``delta`` used at intermediate continuation values of ``k``.
    smoothing_tol : float
        Decreasing ``delta`` stops once ``T`` changes by less than this, relatively.
    min_k_step : float
        Continuation gives up when a failed step in ``k`` would be bisected below this.
    switch_nodes : bool
        For k > 1, put a mesh node at every sign change of a switching function, with its
        time an unknown and the RK4 steps graded towards it (far fewer intervals for the
        same accuracy, and the mesh follows the switches in warm starts).
    starts : int
        Seed pairs tried by the direct method (1 = single start): the best-ranked of the
        self-motion grids and their full-turn branches (``docs/seeding.md``). The paper's arm
        has dozens of local optima and the first seed pair is seldom in the best basin. Up to
        ``3 * starts // 4`` more (at most 12) cross the ends of the best direct solutions.
        On an arm with random inverse-kinematics seeds (not a planar arm) whose joint limits
        are active, ``starts // 2`` more (24 for the default 16; one stays one: the limits
        cut the self-motion manifold into more basins, ``tuning.RANDOM_STARTS_EXTRA``).
    candidates : int
        At most this many distinct direct solutions (best ``T`` at k = 1 first) continued to
        the requested ``k`` by shooting; the best final ``T`` is returned. The best motion's
        direct solution is not always the first by ``T`` at k = 1 (up to the fifth on the
        benchmark's pairs), hence 6; those that cannot beat the best found are not continued
        (``docs/seeding.md``).
    ik_count : int
        Angles of the self-motion family per end point, each with both elbows (see
        :func:`~tocontrol_ros.core.robot.ik.ik_family`); an arm whose family is random
        inverse-kinematics seeds instead (a spatial arm) gets ``ik_count`` seeds, or
        ``RANDOM_IK_FACTOR`` (2) times as many when the problem has joint limits
        (:mod:`~tocontrol_ros.core.methods.tuning`).
    exhaustive : bool
        Reference mode of the benchmark (slow: minutes per problem on the paper's arm):
        a dense self-motion grid, every full-turn branch, many seed pairs solved by the
        direct method and many distinct direct solutions continued; ``starts`` and
        ``candidates`` are ignored (see :mod:`~tocontrol_ros.core.methods.seeding`).
    verify : bool
        Certify every solution (:func:`~tocontrol_ros.core.indirect.certificate.certify`: the
        nominal torques re-integrated through the model by an adaptive integrator, the
        canonical system re-integrated per shooting interval, the torques inside the set,
        ``H``, the boundary conditions); a solution that fails is not a success.
    verify_point_tol : float
        The re-integrated nominal torques must reach the target within this (m).
    verify_velocity_tol : float
        ...and end at rest within this (rad/s or m/s).
    certificate : CertificateOptions or None
        The certificate's other tolerances (default: :class:`CertificateOptions`'s);
        ``verify_point_tol`` and ``verify_velocity_tol`` override its point and velocity
        tolerances, ``tol`` its residual tolerance.
    time_limit : float
        Wall-time budget (s); the best result so far is reported when it runs out.
    direct_fallback : bool
        When the maximum principle's shooting fails on every candidate (Newton at ``k = 1``
        or the continuation in ``k``: seen on planar arms of 5-8 links), solve the same
        problem as a B-spline path with its torques as inverse dynamics
        (``docs/limits.md``, the method of plans whose joint limits bind) from the same
        guesses. The result then says ``method="direct"``, and its warnings name the
        shooting's failure; it is certified like any other. ``False`` reports the
        shooting's failure instead.
    warm_only : bool
        With a ``warm_start`` that applies (:meth:`PlanResult.can_warm_start`), return its
        solution without running the multistart when it succeeds (and is certified): the
        quickest re-plan after a small move, in the previous motion's basin, which the
        multistart might beat. When it fails, the multistart runs as usual. Default False:
        the multistart always runs, and the warm solution is one more candidate.
    warm_joint_radius : float
        A warm start applies to a problem whose joint-state ends are within this of its own
        (max-norm of positions and velocities, rad and rad/s; its end points within
        ``WARM_RADIUS`` too: :meth:`PlanResult.can_warm_start`). The default keeps a warm
        start in the multistart's basin; the planner node's replans allow more
        (:data:`~tocontrol_ros.core.planning.tuning.REPLAN_JOINT_RADIUS`): along a stream of goals
        each start moves by a few centimetres, and the warm solve still converges.
    replan_spans : int
        Bounded solves (``docs/limits.md``) of a replan stay on a coarse mesh: a warm start
        (a ``"direct"`` solution) is solved again on this many uniform spans, from its path
        fitted there when its own mesh has another number, and a solve without one keeps
        its uniform mesh, unrefined. 0 (the default): full accuracy (a warm start on its own
        mesh, from its path and multipliers; every candidate refined). The planner node's
        replans use :data:`~tocontrol_ros.core.planning.tuning.REPLAN_SPANS`: a replan's motion is
        short, IPOPT's iterations on a refined mesh of 56-128 spans cost 3-4 times more, and
        ``T`` stays within about 1e-3 (BENCHMARKS.md "Replanning").
    warm_parametric : bool
        A bounded warm start with multipliers on its own mesh (a ``"direct"`` solution of a
        nearby problem, e.g. a previous replan's on ``replan_spans``) is first carried to
        this problem by the parametric primal-dual step
        (:mod:`~tocontrol_ros.core.direct.sensitivity`: Newton steps on the barrier KKT
        system from the converged point, the rows that block a step held at their bounds,
        a work budget of steps), certified as every plan;
        when it does not converge or is not certified, IPOPT re-solves warm as before (the
        result's warnings say which route). Default True; False: IPOPT alone.
    warm_follow : bool
        With ``warm_parametric``: a warm start whose own problem (``PlanResult.problem``)
        is farther than one sub-move from this one (more than 2 cm of a point end, 0.05 rad
        of a joint state end: a memory's hit) is walked to it in sub-moves, the parametric
        step from each sub-move's answer (:mod:`~tocontrol_ros.core.direct.path_following`),
        instead of one step; IPOPT as above when the walk does not arrive. Default False:
        on the Panda's 64-span serving mesh the walk arrived on few hits (docs/memory.md,
        "Hits by parametric path following").
    warm_far : bool
        The warm start is a stored neighbour a few centimetres away (a memory's hit, which
        :func:`~tocontrol_ros.core.memory.recall.recall` sets), not a replan's small move: a
        bounded warm start with multipliers whose own problem is more than one sub-move
        away (2 cm of a point end, 0.05 rad of a joint state end; a nearer one keeps the
        replans' start, which the wider barrier costs iterations there) goes straight to
        IPOPT, its barrier from
        :data:`~tocontrol_ros.core.direct.tuning.FAR_MU` and its start pushed as far inside
        its bounds (``FlatTranscription(warm="dual_far")``; on the Panda cell's hits half
        the iterations of the default's, none failed), without the single parametric step
        (which arrived on none of them; ``warm_follow`` walks when asked). Default False.
    workers : int
        Processes that solve a plan's independent pieces side by side, the caller's
        included: the bounded solve's candidates on the uniform mesh and each level of
        their refinement (``docs/limits.md``). 1 (the default): all in the caller's
        process; 0: one per core this process may use. The answer is the same for any
        number (each piece is computed alike wherever it runs, and taken in its order);
        more workers only make it sooner. Workers are started on first use and kept
        (:mod:`~tocontrol_ros.core.planning.pool`); a worker that dies is replaced by the caller's
        process.
    method : str
        The method that solves a cold request, by its name in the method contract's
        registry (:func:`~tocontrol_ros.core.methods.contract.method_names`): ``"auto"``
        (the default: the maximum principle, which solves the bounded B-spline problem
        where the joint limits bind), ``"indirect"`` (the same), ``"direct"`` (the bounded
        B-spline solve), ``"first"`` (a seed path timed by TOPP-RA: certified, not
        optimal), or a method registered by the caller
        (:func:`~tocontrol_ros.core.methods.contract.register`). A warm start is continued
        by the method that made it. An unknown name is refused when the solve starts.
    """

    tol: float = 1e-10
    max_newton: int = 30
    intervals: int = 12
    steps: int = 12
    guess_intervals: int = 10
    guess_tol: float = 1e-5
    integration_tol: float = 1e-6
    max_intervals: int = 1000
    smoothing: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 0.0)
    smoothing_intermediate: float = 1e-3
    smoothing_tol: float = 1e-8
    min_k_step: float = 0.05
    switch_nodes: bool = True
    starts: int = 16
    candidates: int = 6
    ik_count: int = 8
    exhaustive: bool = False
    verify: bool = True
    verify_point_tol: float = 1e-4
    verify_velocity_tol: float = 1e-3
    time_limit: float = 60.0
    certificate: CertificateOptions | None = None
    direct_fallback: bool = True
    warm_only: bool = False
    warm_joint_radius: float = WARM_JOINT_RADIUS
    replan_spans: int = 0
    warm_parametric: bool = True
    warm_follow: bool = False
    warm_far: bool = False
    workers: int = 1
    method: str = "auto"

    def __post_init__(self) -> None:
        positive = ("tol", "guess_tol", "integration_tol", "smoothing_tol", "min_k_step",
                    "verify_point_tol", "verify_velocity_tol", "time_limit",
                    "smoothing_intermediate", "warm_joint_radius")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ProblemError(f"`{name}` must be a positive number, got {value!r}")
        for name in ("max_newton", "intervals", "steps", "guess_intervals", "max_intervals",
                     "starts", "candidates", "ik_count"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 1):
                raise ProblemError(f"`{name}` must be an integer >= 1, got {value!r}")
        if not (isinstance(self.replan_spans, (int, np.integer))
                and not isinstance(self.replan_spans, bool)
                and (self.replan_spans == 0 or self.replan_spans >= MIN_REPLAN_SPANS)):
            raise ProblemError(f"`replan_spans` must be 0 or an integer >= "
                               f"{MIN_REPLAN_SPANS}, got {self.replan_spans!r}")
        for name in ("warm_parametric", "warm_follow", "warm_far"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ProblemError(f"`{name}` must be True or False, got "
                                   f"{getattr(self, name)!r}")
        if not (isinstance(self.workers, (int, np.integer)) and not isinstance(self.workers, bool)
                and self.workers >= 0):
            raise ProblemError(f"`workers` must be an integer >= 0 (0: one per core), got "
                               f"{self.workers!r}")
        if not (isinstance(self.method, str) and self.method):
            raise ProblemError(f"`method` must be a method's name (a non-empty string), got "
                               f"{self.method!r}")
        sm = tuple(float(d) for d in self.smoothing)
        if not sm or any(d < 0 or not np.isfinite(d) for d in sm) or \
                any(b >= a for a, b in zip(sm, sm[1:], strict=False)):
            raise ProblemError(f"`smoothing` must be a non-empty strictly decreasing sequence "
                             f"of numbers >= 0, got {self.smoothing!r}")
        object.__setattr__(self, "smoothing", sm)
        if self.certificate is not None and not isinstance(self.certificate,
                                                           CertificateOptions):
            raise ProblemError(f"`certificate` must be a CertificateOptions or None, got "
                               f"{type(self.certificate).__name__}")
        self.certificate_options(1)  # the tolerances together must be valid

    def certificate_options(self, steps: int) -> CertificateOptions:
        """The certificate's tolerances; its segments are the shooting intervals.

        Parameters
        ----------
        steps : int
            RK4 steps per shooting interval of the solution.
        """
        return replace(self.certificate or CertificateOptions(),
                       point_tol=self.verify_point_tol, velocity_tol=self.verify_velocity_tol,
                       residual_tol=self.tol, segment_steps=steps)
