"""Time-optimal planning: guess, continuation, multistart, warm start, verification.

:func:`plan` is the one-shot entry point. For one start it

1. solves a coarse direct transcription (k = 1) from a pair of inverse-kinematics seeds; its
   multipliers are the initial costates (:mod:`tocontrol_ros.core.direct`);
2. solves the boundary-value problem (16), (21) by multiple shooting and Newton at k = 1
   (:mod:`tocontrol_ros.core.shooting`);
3. continues in ``k`` (doubling up to the requested value, bisecting a step that fails),
   with the control law smoothed by ``delta`` at intermediate values;
4. at the requested ``k`` (> 1), moves to a mesh with a node at every sign change of a
   switching function ``S_i`` (switch nodes: the node's time is an unknown with
   ``S_i = 0`` there, and the RK4 steps next to it are graded towards it, see
   :class:`~tocontrol_ros.core.shooting.ShootingGrid`), drives ``delta`` down until ``T`` no
   longer changes, refines the mesh until every interval's RK4 error estimate is below
   tolerance, and confirms on the refined mesh that the next smaller ``delta`` leaves ``T``
   unchanged;
5. verifies the result (residual, ``H``, re-integration of the nominal torques).

Newton keeps its LU factors while they work (chord steps with Broyden's rank-one updates,
also across the solves of one mesh and into a warm start). Because the switch nodes move
with the switches, a warm start after a small move usually keeps the previous mesh: a few
Newton iterations and one error estimate.

Multistart runs step 1 from several seed pairs spread over the self-motion manifolds,
groups the direct solutions by basin and continues the most promising ones; the best is
returned and the others listed. A warm start skips the guess and continues from a previous
solution (e.g. after the target moved).
"""

from __future__ import annotations

import enum
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .direct import DirectCollocation, DirectResult, initial_path
from .errors import ProblemError
from .ik import ik_family
from .pmp import CanonicalSystem
from .problem import Problem
from .shooting import NewtonReport, ShootingGrid, integrate, newton_solve, step_fractions
from .trajectory import Trajectory, TrajectorySample

__all__ = ["Status", "SolverOptions", "StartRecord", "PlanResult", "Planner", "plan", "verify"]


class Status(enum.Enum):
    """Outcome of :func:`plan`; the value is a readable sentence."""

    SUCCESS = "solved and verified"
    TRIVIAL = "start at rest within MIN_MOVE of the target: nothing to move"
    NO_GUESS = "the direct method found no feasible initial guess"
    NEWTON_FAILED = "Newton's method did not converge at k = 1"
    CONTINUATION_FAILED = "continuation in k stalled before the requested k"
    VERIFICATION_FAILED = "converged, but the verification failed"
    CANCELLED = "cancelled by the caller (a newer request or a shutdown)"
    TIME_LIMIT = "the time limit ran out before the solve finished"


@dataclass(frozen=True)
class SolverOptions:
    """Tolerances and limits of :func:`plan` (validated on construction).

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
        the graded intervals at a switch better: 12 gives the paper's example at k = 4 on
        ~45 intervals (6: ~90) at the same accuracy, and halves warm re-solves. With switch
        nodes the k = 1 solve and the continuation in k, whose solutions only lead to the
        switch mesh, take at most :data:`CONTINUATION_STEPS` (6).
    guess_intervals : int
        Mesh intervals of the direct method that makes the initial guess.
    integration_tol : float
        Mesh refinement: max RK4 error estimate per interval (max-norm of ``z``). The
        default keeps ``|H| <= 3e-7`` along the paper's example for k = 1 ... 16 (the issue
        asks for 1e-6) and the re-integrated end point within 1e-6 m.
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
        Seed pairs tried by the direct method (1 = single start). The paper's arm has many
        local optima and the first seed pair is seldom in the best basin, hence 16.
    candidates : int
        Distinct direct solutions (best ``T`` at k = 1 first) continued to the requested
        ``k`` by shooting; the best final ``T`` is returned.
    ik_count : int
        Angles of the self-motion family per end point (see :func:`ik_family`).
    verify : bool
        Re-integrate the nominal torques through the model (adaptive integrator).
    verify_point_tol : float
        Re-integration must reach the target within this (m).
    verify_velocity_tol : float
        ...and end at rest within this (rad/s or m/s).
    time_limit : float
        Wall-time budget (s); the best result so far is reported when it runs out.
    """

    tol: float = 1e-10
    max_newton: int = 30
    intervals: int = 12
    steps: int = 12
    guess_intervals: int = 12
    integration_tol: float = 1e-6
    max_intervals: int = 1000
    smoothing: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 0.0)
    smoothing_intermediate: float = 1e-3
    smoothing_tol: float = 1e-8
    min_k_step: float = 0.05
    switch_nodes: bool = True
    starts: int = 16
    candidates: int = 3
    ik_count: int = 8
    verify: bool = True
    verify_point_tol: float = 1e-4
    verify_velocity_tol: float = 1e-3
    time_limit: float = 60.0

    def __post_init__(self) -> None:
        positive = ("tol", "integration_tol", "smoothing_tol", "min_k_step",
                    "verify_point_tol", "verify_velocity_tol", "time_limit",
                    "smoothing_intermediate")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ProblemError(f"`{name}` must be a positive number, got {value!r}")
        for name in ("max_newton", "intervals", "steps", "guess_intervals", "max_intervals",
                     "starts", "candidates", "ik_count"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 1):
                raise ProblemError(f"`{name}` must be an integer >= 1, got {value!r}")
        sm = tuple(float(d) for d in self.smoothing)
        if not sm or any(d < 0 or not np.isfinite(d) for d in sm) or \
                any(b >= a for a, b in zip(sm, sm[1:], strict=False)):
            raise ProblemError(f"`smoothing` must be a non-empty strictly decreasing sequence "
                             f"of numbers >= 0, got {self.smoothing!r}")
        object.__setattr__(self, "smoothing", sm)


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
        ``T`` of the direct method at k = 1 (s), NaN when it failed.
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
    """Outcome of :func:`plan`, in the manner of ``scipy.integrate.solve_bvp``'s result.

    Attributes
    ----------
    success : bool
    status : Status
    message : str
    T : float
        Minimum time (s); NaN when there is no solution.
    k : float
        Exponent reached (the requested one on success).
    trajectory : Trajectory or None
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
        ``point_error`` (m), ``velocity_error``, ``max_abs_H``, ``max_set_error``
        (``max |sum u^2k - 1|``) and ``reintegration`` details.
    warnings : tuple of str
        E.g. URDF position or velocity limits violated (joint and time).
    starts : tuple of StartRecord
    """

    success: bool
    status: Status
    message: str
    T: float
    k: float
    trajectory: Trajectory | None
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
    _state: dict = field(default_factory=dict, repr=False)


# ----------------------------------------------------------------- planner cache
class Planner:
    """Holds the compiled functions of one model, reused across many solves.

    Parameters
    ----------
    model : RobotModel
    """

    def __init__(self, model) -> None:
        self.model = model
        self.system = CanonicalSystem(model)
        self._direct: dict = {}
        self._lock = threading.Lock()

    def direct(self, problem: Problem, intervals: int, box: bool = False,
               tol: float = 1e-8) -> DirectCollocation:
        """The direct transcription for this problem's kinds (built once, cached)."""
        key = (intervals, problem.start.kind, problem.target.kind, box,
               1.0 - problem.reserve, tol)
        with self._lock:
            if key not in self._direct:
                self._direct[key] = DirectCollocation(
                    self.model, intervals, problem.start.kind, problem.target.kind, box=box,
                    torque_scale=1.0 - problem.reserve, tol=tol)
            return self._direct[key]

    def plan(self, problem: Problem, options: SolverOptions | None = None,
             warm_start: PlanResult | None = None, should_stop=None) -> PlanResult:
        """See :func:`plan`."""
        return _plan(self, problem, options or SolverOptions(), warm_start, should_stop)


_PLANNERS: dict[int, Planner] = {}


def plan(problem: Problem, options: SolverOptions | None = None,
         warm_start: PlanResult | None = None, should_stop=None) -> PlanResult:
    """Solve a time-optimal problem.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions, optional
    warm_start : PlanResult, optional
        A previous successful result of the same model, start kind and target kind: its
        solution is continued to this problem (no guess, no continuation in ``k`` when the
        exponents match). Falls back to a cold solve when it does not converge.
    should_stop : callable, optional
        Polled between Newton iterations; returning True cancels the solve.

    Returns
    -------
    PlanResult
        Never raises for numerical failure: see ``success``, ``status`` and ``message``.
    """
    planner = _PLANNERS.get(id(problem.model))
    if planner is None or planner.model is not problem.model:
        planner = Planner(problem.model)
        _PLANNERS[id(problem.model)] = planner
    return planner.plan(problem, options, warm_start, should_stop)


# ---------------------------------------------------------------------- helpers
def _values(problem: Problem) -> np.ndarray:
    return np.concatenate([problem.start.value, problem.target.value])


def _seed_pairs(problem: Problem, options: SolverOptions) -> list[tuple[np.ndarray, ...]]:
    """Seed pairs (q_start, q_target), most promising first.

    Each start configuration of the family is paired with each target configuration, the
    target unwrapped to the nearest equivalent angles (the short way) and, for continuous
    distal joints, also one full turn the other way; pairs are ranked by a bang-bang time
    estimate with diagonal inertia. The first ``options.starts`` are returned.
    """
    model = problem.model
    n = model.n
    if problem.start.kind == "state":
        starts = [problem.start.value[:n]]
    else:
        starts = ik_family(model, problem.start.value, options.ik_count)
    if problem.target.kind == "state":
        targets = [problem.target.value[:n]]
    else:
        targets = ik_family(model, problem.target.value, options.ik_count)
    if not starts or not targets:
        return []
    cont = ~np.isfinite(model.q_lower) & np.array([b.kind == "revolute" for b in model.bodies])
    acc = model.tau_max * (1 - problem.reserve)
    qa = np.array(starts)                                   # (S, n)
    mass = np.array(model.function("M").map(len(qa))(qa.T))  # (n, S n), blocks per start
    inertia = np.array([np.diag(mass[:, i * n:(i + 1) * n]) for i in range(len(qa))])
    d = np.array(targets)[None, :, :] - qa[:, None, :]      # (S, G, n)
    if problem.target.kind == "point":
        d = np.where(cont, np.angle(np.exp(1j * d)), d)
    variants = [d]
    if problem.target.kind == "point" and cont[-1]:
        last = d[..., -1]
        turn = np.zeros_like(d)
        turn[..., -1] = np.where(last != 0, -2 * np.pi * np.sign(last), 2 * np.pi)
        variants.append(d + turn)
    # (S, G, V, n), in the order start, target, variant; ranked by a stable sort.
    dv = np.stack(variants, axis=2)
    est = np.max(2 * np.sqrt(np.abs(dv) * inertia[:, None, None, :] / acc), axis=-1)
    order = np.argsort(est.ravel(), kind="stable")[:options.starts]
    s_idx, _, _ = np.unravel_index(order, est.shape)
    flat = dv.reshape(-1, n)
    return [(qa[i], qa[i] + flat[j]) for i, j in zip(s_idx, order, strict=True)]


def _nodes_from_direct(direct: DirectResult, tau_nodes: np.ndarray) -> np.ndarray:
    tau_d = direct.t / direct.T
    z = np.hstack([direct.x, direct.psi])
    return np.stack([np.interp(tau_nodes, tau_d, z[:, i]) for i in range(z.shape[1])], axis=1)


def _k_schedule(k: float) -> list[float]:
    ks = [1.0]
    while ks[-1] * 2 < k:
        ks.append(ks[-1] * 2)
    if k > 1:
        ks.append(float(k))
    return ks


@dataclass
class _Run:
    """Mutable state of one start while it is being solved."""

    grid: ShootingGrid
    w: np.ndarray
    k: float
    delta: float
    iterations: int = 0
    log: list = field(default_factory=list)
    residual: float = np.inf
    factors: tuple | None = None  # (grid, LU factors of a Jacobian on that grid)

    def lu(self):
        """The kept LU factors if they belong to the current grid, else None."""
        return self.factors[1] if self.factors and self.factors[0] is self.grid else None


class _StopError(Exception):
    """Internal: the deadline passed or the caller cancelled."""

    def __init__(self, status: Status) -> None:
        super().__init__(status.value)
        self.status = status


def _newton(planner: Planner, run: _Run, problem: Problem, k: float, delta: float,
            options: SolverOptions, deadline: float, should_stop) -> NewtonReport:
    par = np.array([k, delta, 1.0 - problem.reserve])
    rep = newton_solve(run.grid, run.w, _values(problem), par, tol=options.tol,
                       max_iter=options.max_newton, deadline=deadline,
                       should_stop=should_stop, factors=run.lu())
    run.iterations += rep.iterations
    if rep.factors is not None:
        run.factors = (run.grid, rep.factors)
    if rep.message == "cancelled":
        raise _StopError(Status.CANCELLED)
    if rep.message == "time limit reached":
        raise _StopError(Status.TIME_LIMIT)
    if rep.converged:
        run.w, run.k, run.delta, run.residual = rep.w, k, delta, rep.residual
        t_final = run.grid.unpack(rep.w)[1]
        run.log.append((k, delta, t_final, rep.iterations, rep.residual))
    return rep


#: Newton tolerance of the solves along the continuation in k (from the direct guess up to
#: the requested k at the intermediate smoothing): each only starts the next, and the last
#: is solved again to ``options.tol`` (on the switch mesh, or by the mesh refinement).
CONTINUATION_TOL = 1e-6


#: ...and of the last one when switch nodes follow: that solve only locates the switches of
#: the control law, and the switch mesh solves the problem again from its interpolation
#: (whose residual, about 1e-2, dwarfs this).
PLACEMENT_TOL = 1e-5

#: RK4 steps per interval of the k = 1 solve and the continuation in k when switch nodes
#: follow (at most ``options.steps``): those solutions only lead to the switch mesh, which
#: is solved with ``options.steps`` and refined. On the paper's example (one start,
#: bench/work_counts.py) 12 -> 6 takes 0.88 of the RK4 work at k = 4 and 0.65 at k = 16, and
#: 0.79 over 30 random pairs at k = 4, to the same T; 4 does no better.
CONTINUATION_STEPS = 6


def _continuation_options(options: SolverOptions, tol: float = CONTINUATION_TOL
                          ) -> SolverOptions:
    return replace(options, tol=max(options.tol, tol))


def _continue_k(planner, run: _Run, problem, options, deadline, should_stop) -> bool:
    """Continue a converged k = 1 solution to the requested k (bisecting failed steps)."""
    targets = _k_schedule(problem.k)[1:]
    refined_at = None
    for k_goal in targets:
        last = k_goal == targets[-1] and options.switch_nodes
        loose = _continuation_options(options, PLACEMENT_TOL if last else CONTINUATION_TOL)
        while run.k < k_goal:
            k_try = k_goal
            while True:
                rep = _newton(planner, run, problem, k_try, options.smoothing_intermediate,
                              loose, deadline, should_stop)
                if rep.converged:
                    break
                k_try = run.k + 0.5 * (k_try - run.k)
                if k_try - run.k < options.min_k_step:
                    # The mesh may be too coarse for the steeper law: refine it at the
                    # current k, once per stall, and try again.
                    if refined_at == run.k:
                        return False
                    refined_at = run.k
                    saved = _snapshot(run)
                    if _refine(planner, run, problem, options, deadline, should_stop,
                               tol=max(options.integration_tol, 1e-4)):
                        _restore(run, saved)
                        return False
                    k_try = k_goal
    return True


def _interval_errors(planner, starts, lengths, steps, t_final, par, kinds=None,
                     ends=None) -> np.ndarray:
    """RK4 error estimate per interval (Richardson: steps vs 2 * steps), max-norm of z.

    ``ends``, when given, are the intervals' end states with ``steps`` steps (the next
    nodes of a converged solution), so that only the doubled steps are integrated.
    """
    kinds = np.zeros(len(lengths), dtype=int) if kinds is None else kinds
    z_s = ends if ends is not None else integrate(
        planner.system, starts, lengths, steps, t_final, par, False,
        step_fractions(kinds, steps))[0]
    z_2s = integrate(planner.system, starts, lengths, 2 * steps, t_final, par, False,
                     step_fractions(kinds, 2 * steps))[0]
    return np.max(np.abs(z_2s - z_s), axis=1) * 16 / 15


def _refine(planner, run: _Run, problem, options, deadline, should_stop,
            tol: float | None = None) -> str:
    """Refine the mesh until every interval's RK4 error estimate meets the tolerance.

    The tolerance is approached in decades (1e-3, 1e-4, ... down to ``integration_tol``):
    Newton on a coarse mesh moves the nodes most of the way cheaply, and the fine meshes,
    whose iterations cost most, start close to their solution.
    """
    final = options.integration_tol if tol is None else tol
    levels = [t for t in (1e-3, 1e-4, 1e-5) if t > 10 * final and not run.grid.B] + [final]
    for level in levels:
        # Intermediate levels only place the nodes; the last one solves to `tol`.
        last = level == final and tol is None
        opts = options if last else replace(options, tol=max(options.tol, 1e-7))
        why = _refine_to(planner, run, problem, level, opts, deadline, should_stop)
        if why:
            return f"mesh refinement to {level:g} stopped: {why}"
    if tol is None and run.residual > options.tol:
        # The mesh was already fine at the last level: its last solve used a looser tol.
        rep = _newton(planner, run, problem, run.k, run.delta, options, deadline,
                      should_stop)
        if not rep.converged:
            return f"Newton did not reach tol on the final mesh ({rep.message})"
    return ""


#: Two neighbouring intervals are merged when the estimate for the merged one is below
#: the tolerance divided by this (so that the next check does not split them again).
MERGE_MARGIN = 8.0


def _merge_pairs(planner, starts, lengths, kinds, err, break_nodes, steps, t_final, par, tol):
    """Merge neighbouring uniform intervals that together still meet ``tol``.

    Splitting graded intervals at a switch leaves neighbours far finer than they need to
    be (their error estimates 1e-4 of the tolerance: the error of a graded interval falls
    only like its length to the power ``1 + 1/(2k - 1)``, so it is split several times).
    Pairs of intervals with uniform steps, not separated by a switch node, are merged when
    the merged interval's estimate is below ``tol / MERGE_MARGIN``; greedy, left to right,
    two passes. (A split is never undone on the same solution: it was made because the
    estimate was above ``tol``.) Only pairs whose two estimates ``err`` (N,) sum to less
    than that are tried. The paper's example at k = 4: 40 intervals become 24.

    Returns
    -------
    (starts, lengths, kinds, keep) or None
        The new mesh, and which of the old nodes (N + 1,) it keeps; None when nothing
        merges.
    """
    count = len(lengths)
    keep = np.ones(count + 1, dtype=bool)
    starts, lengths, kinds, err = starts.copy(), lengths.copy(), kinds.copy(), err.copy()
    limit = tol / MERGE_MARGIN
    alive = np.arange(count + 1)  # old node index of each current node
    for _ in range(2):
        at_break = np.isin(alive, break_nodes)
        cand = np.flatnonzero((kinds[:-1] == 0) & (kinds[1:] == 0) & ~at_break[1:-1]
                              & (err[:-1] + err[1:] <= limit))
        if not len(cand):
            break
        err_pair = _interval_errors(planner, starts[cand], lengths[cand] + lengths[cand + 1],
                                    steps, t_final, par, np.zeros(len(cand), dtype=int))
        chosen, last = [], -2
        for j in cand[err_pair <= limit]:
            if j > last + 1:
                chosen.append(j)
                last = j
        if not chosen:
            break
        chosen = np.array(chosen)
        lengths[chosen] += lengths[chosen + 1]
        err[chosen] = err_pair[np.searchsorted(cand, chosen)]
        drop = np.zeros(len(lengths), dtype=bool)
        drop[chosen + 1] = True
        keep[alive[chosen + 1]] = False
        alive = np.delete(alive, chosen + 1)
        starts, lengths, kinds, err = (a[~drop] for a in (starts, lengths, kinds, err))
    if keep.all():
        return None
    return starts, lengths, kinds, keep


#: Cascade of a split graded interval: each uniform part ends this many times farther from
#: the switch than it starts (a uniform interval as long as its distance to the switch
#: estimates ~1e-4 of the graded one next to it, on the paper's example).
CASCADE_RATIO = 4.0


def _graded_split(length: float, kind: int, err: float, tol: float, k: float) -> np.ndarray:
    """Part lengths, from the interval's start, of a graded interval that fails ``tol``.

    The error of an interval graded towards a switch falls only like its length to the power
    ``1 + 1/(2k - 1)`` (the singularity of the law, not the smooth solution, dominates), so
    halving it repeatedly takes many rounds and leaves over-fine neighbours. Instead the
    graded part at the switch gets the length that this law predicts for half the tolerance
    (between 1/16 and 1/2 of the interval), and the rest is covered by uniform parts that
    grow away from the switch by :data:`CASCADE_RATIO`.
    """
    expo = 1.0 + 1.0 / (2 * k - 1)
    graded = length * float(np.clip((0.5 * tol / err) ** (1.0 / expo), 1 / 16, 0.5))
    bounds = [graded]
    while bounds[-1] * CASCADE_RATIO < length:
        bounds.append(bounds[-1] * CASCADE_RATIO)
    bounds.append(length)
    out = np.diff(np.concatenate([[0.0], bounds]))  # from the switch outwards
    return out if kind == -1 else out[::-1]


def _part_kinds(kind: int, parts: int) -> list[int]:
    """Step grading of the parts of a split interval: the part at a switch keeps it."""
    out = [0] * parts
    if kind == 1:
        out[-1] = 1
    elif kind == -1:
        out[0] = -1
    return out


def _refine_to(planner, run: _Run, problem, tol, options, deadline, should_stop,
               rounds: int = 6) -> str:
    """One level of :func:`_refine`.

    Each round first splits intervals on the current solution alone (the new nodes are
    integrated from the old ones), repeating until the estimate passes, and only then runs
    Newton on the new mesh: one Newton solve per round, usually one or two rounds. Switch
    nodes stay switch nodes; a split interval's graded steps stay in the part at the switch.
    """
    par = np.array([run.k, run.delta, 1.0 - problem.reserve])
    steps = run.grid.steps
    system = planner.system
    for _ in range(rounds):
        nodes, t_final, nu0, nuT = run.grid.unpack(run.w)
        starts, lengths = nodes[:-1], run.grid.lengths_of(run.w)
        kinds = run.grid.kinds
        node_of = np.arange(len(lengths) + 1)  # original node -> node of the new mesh
        # At a converged solution the next nodes are the intervals' ends to within its
        # residual: no need to integrate them again for the estimate.
        ends = nodes[1:] if run.residual <= 1e-2 * tol else None
        err = _interval_errors(planner, starts, lengths, steps, t_final, par, kinds, ends)
        changed = False
        for _inner in range(8):
            bad = err > tol
            if not np.any(bad):
                break
            # Local RK4 error ~ h^5 where the law is smooth, lower order across switches:
            # split with a conservative exponent, at least two and at most eight parts.
            parts = np.where(bad, np.clip(np.ceil(1.2 * (err / tol)
                                                  ** 0.25), 2, 8), 1).astype(int)
            # Graded intervals: a short graded part and a cascade (see _graded_split).
            splits = {j: _graded_split(lengths[j], kinds[j], err[j], tol, run.k)
                      for j in np.flatnonzero(bad & (kinds != 0))}
            for j, part_lengths in splits.items():
                parts[j] = len(part_lengths)
            room = options.max_intervals - len(lengths)
            if room <= 0:
                return f"interval limit ({options.max_intervals}) reached"
            extra = int((parts - 1).sum())
            if extra > room:  # split the worst intervals first, within the limit
                splits = {}  # (in equal parts)
                order = np.argsort(-err)
                budget = room
                capped = np.ones_like(parts)
                for j in order:
                    if parts[j] > 1 and budget > 0:
                        capped[j] = min(parts[j], budget + 1)
                        budget -= capped[j] - 1
                parts = capped
            idx = np.flatnonzero(parts > 1)
            sub_lens = np.zeros((len(idx), int(parts.max())))
            sub_kinds = np.zeros((len(idx), int(parts.max())), dtype=int)
            for r, j in enumerate(idx):
                sub_lens[r, :parts[j]] = splits.get(j, lengths[j] / parts[j])
                sub_kinds[r, :parts[j]] = _part_kinds(kinds[j], parts[j])
            cur = starts[idx].copy()
            subs = [cur.copy()]
            for p in range(1, int(parts.max())):
                active = parts[idx] > p
                cur[active] = integrate(system, cur[active], sub_lens[active, p - 1], steps,
                                        t_final, par, False,
                                        step_fractions(sub_kinds[active, p - 1], steps))[0]
                subs.append(np.where(active[:, None], cur, np.nan))
            subs = np.stack(subs, axis=1)  # (bad, max parts, nz), NaN past each one's parts
            new_starts, new_lengths, new_err, new_kinds, fresh = [], [], [], [], []
            row = {j: r for r, j in enumerate(idx)}
            new_node = np.zeros(len(lengths) + 1, dtype=int)
            for j in range(len(lengths)):
                new_node[j] = len(new_starts)
                if j in row:
                    r = row[j]
                    for p in range(parts[j]):
                        new_starts.append(subs[r, p])
                        new_lengths.append(sub_lens[r, p])
                        new_err.append(np.nan)
                        new_kinds.append(sub_kinds[r, p])
                        fresh.append(len(new_starts) - 1)
                else:
                    new_starts.append(starts[j])
                    new_lengths.append(lengths[j])
                    new_err.append(err[j])
                    new_kinds.append(kinds[j])
            new_node[-1] = len(new_starts)
            node_of = new_node[node_of]
            starts, lengths = np.array(new_starts), np.array(new_lengths)
            kinds = np.array(new_kinds, dtype=int)
            err = np.array(new_err)
            fresh = np.array(fresh)
            err[fresh] = _interval_errors(planner, starts[fresh], lengths[fresh], steps,
                                          t_final, par, kinds[fresh])
            changed = True
        if changed and not np.any(err > tol):
            # Merging only where this round split: a mesh that passes as it is (a warm
            # start's, the last check) is kept.
            break_nodes = node_of[[j for j, _ in run.grid.breaks]]
            merged = _merge_pairs(planner, starts, lengths, kinds, err, break_nodes, steps,
                                  t_final, par, tol)
            if merged is not None:
                starts, lengths, kinds, keep = merged
                node_of = (np.cumsum(keep) - 1)[node_of]
                changed = True
        if not changed:
            return ""
        saved = (run.grid, run.w)
        breaks = [(int(node_of[j]), i) for j, i in run.grid.breaks]
        run.grid = ShootingGrid(system, lengths, steps, run.grid.start_kind,
                                run.grid.target_kind, kinds=kinds, breaks=breaks)
        run.w = run.grid.pack(np.vstack([starts, nodes[-1:]]), t_final, nu0, nuT)
        rep = _newton(planner, run, problem, run.k, run.delta, options, deadline,
                      should_stop)
        if not rep.converged:
            run.grid, run.w = saved
            return f"Newton did not converge on {len(lengths)} intervals ({rep.message})"
    return f"no convergence of the mesh in {rounds} rounds"


def _switches(planner, traj: Trajectory) -> list[tuple[float, int]]:
    """Sign changes of the switching functions along a solution: (tau, i), in order.

    Located by linear interpolation between the RK4 step points (the trajectory's grid).
    """
    t_grid = traj.t_grid
    s = planner.system.pointwise_batch(traj.z_grid, traj.par)[2]
    t_final = t_grid[-1]
    out = []
    for i in range(s.shape[1]):
        sign = np.sign(s[:, i])
        for j in np.flatnonzero(sign[:-1] * sign[1:] < 0):
            frac = s[j, i] / (s[j, i] - s[j + 1, i])
            out.append(((t_grid[j] + frac * (t_grid[j + 1] - t_grid[j])) / t_final, i))
    return sorted(out)


def _switch_mesh(planner, run: _Run, problem, options, deadline, should_stop) -> bool:
    """Move to a mesh with a node at every switch of the control law.

    Where a switching function ``S_i`` changes sign, ``u_i ~ |S_i|^(1/(2k-1))`` has an
    infinite slope and a uniform RK4 mesh converges slowly. Here each switch becomes a node
    whose time is an unknown (with ``S_i = 0`` there, see :class:`ShootingGrid`), and the
    two intervals that meet at it take RK4 steps graded towards it: the mesh follows the
    switches as Newton (or a warm start) moves them. Returns False, leaving ``run``
    unchanged, when there is no switch or Newton does not converge on the new mesh.
    """
    traj = _trajectory(planner, run, problem)
    found = _switches(planner, traj)
    gap = 0.2 / options.intervals  # switches closer than this to each other or to an end
    chosen: list[tuple[float, int]] = []  # are left to the ordinary refinement
    for tau, i in found:
        if gap <= tau <= 1 - gap and (not chosen or tau - chosen[-1][0] >= gap):
            chosen.append((tau, i))
    if not chosen:
        return False
    bounds = [0.0] + [tau for tau, _ in chosen] + [1.0]
    lengths, kinds, breaks = [], [], []
    for seg in range(len(bounds) - 1):
        length = bounds[seg + 1] - bounds[seg]
        count = max(2, int(np.ceil(length * options.intervals)))
        seg_kinds = [0] * count
        if seg > 0:
            seg_kinds[0] = -1
            breaks.append((len(lengths), chosen[seg - 1][1]))
        if seg < len(bounds) - 2:
            seg_kinds[-1] = 1
        lengths += [length / count] * count
        kinds += seg_kinds
    grid = ShootingGrid(planner.system, np.array(lengths), options.steps,
                        run.grid.start_kind, run.grid.target_kind, kinds=np.array(kinds),
                        breaks=breaks)
    _, t_final, nu0, nuT = run.grid.unpack(run.w)
    nodes = traj.state(grid.tau * t_final)
    saved = _snapshot(run)
    run.grid, run.w = grid, grid.pack(nodes, t_final, nu0, nuT)
    rep = _newton(planner, run, problem, run.k, run.delta, options, deadline, should_stop)
    if not rep.converged:
        _restore(run, saved)
        return False
    return True


def _final_smoothing(planner, run: _Run, problem, options, deadline, should_stop) -> list:
    """Drive delta down at the requested k until T stops changing; refine the mesh."""
    notes = []
    if problem.k == 1.0:
        if run.delta != 0.0:
            _newton(planner, run, problem, 1.0, 0.0, options, deadline, should_stop)
        why = _refine(planner, run, problem, options, deadline, should_stop)
        if why:
            notes.append(why)
        return notes
    t_prev = None
    changes: list[float] = []  # |change of T| from one delta to the next
    converged = []  # snapshots after each delta, to fall back to a smoother law
    switched = options.switch_nodes and _switch_mesh(planner, run, problem, options,
                                                     deadline, should_stop)
    for delta in options.smoothing:
        saved = _snapshot(run)
        if delta == run.delta and run.k == problem.k and run.residual <= options.tol:
            rep = NewtonReport(True, run.w, run.residual, 0, "converged")  # solved already
        else:
            rep = _newton(planner, run, problem, problem.k, delta, options, deadline,
                          should_stop)
        if not rep.converged:
            # A coarse mesh may not resolve the steeper law: refine, then try again.
            _restore(run, saved)
            if _refine(planner, run, problem, options, deadline, should_stop):
                _restore(run, saved)
            saved = _snapshot(run)
            t_prev = run.grid.unpack(run.w)[1]
            rep = _newton(planner, run, problem, problem.k, delta, options, deadline,
                          should_stop)
            if not rep.converged:
                _restore(run, saved)
                notes.append(f"smoothing kept at delta = {run.delta:g}: Newton did not "
                             f"converge at delta = {delta:g} ({rep.message})")
                break
        if delta == options.smoothing[0] and not switched:
            # Resolve the switches to the final tolerance while the law is still smooth:
            # the smaller deltas then only move a fine-mesh solution a little. (Refining
            # after delta is small can stall Newton: where a stage point lands near a
            # switch the law's slope is ~delta^(-(2k-2)/(2k-1)), and the linear model
            # holds only in a tiny neighbourhood.)
            saved = _snapshot(run)
            if _refine(planner, run, problem, options, deadline, should_stop):
                _restore(run, saved)
        converged.append(_snapshot(run))
        t_now = run.grid.unpack(run.w)[1]
        if t_prev is not None:
            changes.append(abs(t_now - t_prev))
            if changes[-1] <= options.smoothing_tol * t_now:
                break
            if switched and _settled(changes, options.smoothing_tol * t_now):
                break  # the next delta is tried on the refined mesh (_confirm_smoothing)
        t_prev = t_now
    why = _refine(planner, run, problem, options, deadline, should_stop)
    if not why and switched:
        # The smoothing loop above ran on the coarse switch mesh: confirm on the refined
        # mesh that the next smaller delta no longer changes T (else keep going down).
        notes += _confirm_smoothing(planner, run, problem, options, deadline, should_stop)
    if not why:
        return notes
    # Near-singular derivatives of the law at a small delta can stall Newton on the refined
    # mesh: fall back to the previous, smoother deltas (T changed by little between them).
    failed_delta = run.delta
    for snap in reversed(converged[:-1]):
        _restore(run, snap)
        if not _refine(planner, run, problem, options, deadline, should_stop):
            notes.append(f"smoothing kept at delta = {run.delta:g}: mesh refinement at "
                         f"delta = {failed_delta:g} failed ({why})")
            return notes
    if converged:
        _restore(run, converged[-1])
    notes.append(why)
    return notes


def _settled(changes: list[float], tol: float) -> bool:
    """Whether the changes of ``T`` from delta to delta have settled below ``tol``.

    Settled: the last change is at most half the one before, and the geometric series it
    starts (the changes still to come, extrapolated) sums to at most ``tol``.

    ``T`` converges like ``delta^2`` on the paper's example (each decade of delta changes it
    about a hundred times less than the one before), so the coarse mesh can stop one delta
    early; the next delta is then solved on the refined mesh, where ``T`` must change by
    less than ``smoothing_tol`` (:func:`_confirm_smoothing`).
    """
    if len(changes) < 2 or changes[-2] <= 0:
        return False
    ratio = changes[-1] / changes[-2]
    return ratio <= 0.5 and changes[-1] * ratio / (1 - ratio) <= tol


def _confirm_smoothing(planner, run: _Run, problem, options, deadline, should_stop) -> list:
    """Decrease delta on the final mesh until ``T`` changes by less than smoothing_tol."""
    smaller = [d for d in options.smoothing if d < run.delta]
    for delta in smaller:
        saved = _snapshot(run)
        t_prev = run.grid.unpack(run.w)[1]
        rep = _newton(planner, run, problem, problem.k, delta, options, deadline,
                      should_stop)
        if not rep.converged:
            _restore(run, saved)
            return [f"smoothing kept at delta = {run.delta:g}: Newton did not converge at "
                    f"delta = {delta:g} on the final mesh ({rep.message})"]
        why = _refine(planner, run, problem, options, deadline, should_stop)
        if why:
            _restore(run, saved)
            return [f"smoothing kept at delta = {run.delta:g}: {why} at delta = {delta:g}"]
        t_now = run.grid.unpack(run.w)[1]
        if abs(t_now - t_prev) <= options.smoothing_tol * t_now:
            break
    return []


def _snapshot(run: _Run) -> tuple:
    return (run.grid, run.w.copy(), run.k, run.delta, run.residual)


def _restore(run: _Run, snap: tuple) -> None:
    run.grid, w, run.k, run.delta, run.residual = snap
    run.w = w.copy()


def _dense(planner: Planner, run: _Run, problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The solution at every RK4 step point: times (K,) in s and states (K, 4n)."""
    grid = run.grid
    nodes, t_final, _, _ = grid.unpack(run.w)
    par = np.array([run.k, run.delta, 1.0 - problem.reserve])
    lengths = grid.lengths_of(run.w)
    system = planner.system
    if system.stagewise:
        z = nodes[:-1].T.copy()
        cols = []
        for i in range(grid.steps):
            h = (t_final * lengths * grid.fractions[:, i])[None, :]
            z = system.step_batch(z, h, par, sensitivities=False)[0]
            cols.append(z.T)
        after = np.stack(cols, axis=1)  # (N, steps, nz): the state after each step
    else:
        after = system.interval_batch(nodes[:-1], t_final * lengths[:, None] * grid.fractions,
                                      None, par, sensitivities=False, dense=True)[0]
    stacked = np.concatenate([nodes[:-1, None], after], axis=1)  # (N, steps + 1, nz)
    z_grid = np.concatenate([stacked[:, :-1].reshape(-1, grid.nz), nodes[-1:]])
    offsets = np.concatenate([np.zeros((grid.N, 1)), np.cumsum(grid.fractions, axis=1)[:, :-1]],
                             axis=1)
    tau = grid.tau_of(run.w)
    t_grid = np.concatenate([((tau[:-1, None] + lengths[:, None] * offsets) * t_final).ravel(),
                             [t_final]])
    return t_grid, z_grid


def _trajectory(planner: Planner, run: _Run, problem: Problem) -> Trajectory:
    t_grid, z_grid = _dense(planner, run, problem)
    par = np.array([run.k, run.delta, 1.0 - problem.reserve])
    return Trajectory(planner.system, t_grid, z_grid, par)


def verify(problem: Problem, trajectory: Trajectory, rtol: float = 1e-11,
           sample: TrajectorySample | None = None) -> dict:
    """Independent checks of a solution.

    Re-integrates the model under the nominal torques ``tau(t)`` of the trajectory with an
    adaptive integrator (scipy's DOP853) from the trajectory's initial state, and evaluates
    ``H`` and the control-set equation on a fine sampling.

    Parameters
    ----------
    problem : Problem
    trajectory : Trajectory
    rtol : float
        Relative tolerance of the integrator (absolute: ``rtol / 10``).
    sample : TrajectorySample, optional
        The sampling on which ``H`` and the control set are checked; default: the one
        :func:`plan` uses (the RK4 step points, filled in where they are more than
        ``T / SAMPLE_GAPS`` apart).

    Returns
    -------
    dict
        ``point_error`` (m): distance of the re-integrated end point to the target point;
        ``state_error``: max-norm of the re-integrated final state minus the trajectory's;
        ``velocity_error``: max |qd(T)| of the re-integration (rad/s); ``max_abs_H``;
        ``max_set_error``: max |sum u^2k - 1|; ``nfev``.
    """
    from scipy.integrate import solve_ivp

    model = problem.model
    n = model.n
    f = model.function("f")
    scale = 1.0 - problem.reserve

    def rhs(t, x):
        u = trajectory.control(t)
        return np.array(f(x, u * scale)).ravel()

    x0 = trajectory.state(0.0)[0, :2 * n]
    sol = solve_ivp(rhs, (0.0, trajectory.T), x0, method="DOP853", rtol=rtol,
                    atol=rtol / 10)
    x_end = sol.y[:, -1]
    planned_end = trajectory.state(trajectory.T)[0, :2 * n]
    if sample is None:
        sample = _fine_sample(trajectory)
    k = trajectory.par[0]
    set_err = np.abs(np.sum(sample.u ** (2 * k), axis=1) - 1)
    return {
        "point_error": float(np.linalg.norm(model.point(x_end[:n]) - problem.target_point)),
        "state_error": float(np.max(np.abs(x_end - planned_end))),
        "velocity_error": float(np.max(np.abs(x_end[n:]))),
        "max_abs_H": float(np.max(np.abs(sample.H))),
        "max_set_error": float(np.max(set_err)),
        "max_abs_u": float(np.max(np.abs(sample.u))),
        "nfev": int(sol.nfev),
        "integrator_success": bool(sol.success),
    }


#: The checks of a result (max |u|, URDF limits, H) sample the solution at its RK4 step
#: points, which crowd at the switches, plus equally spaced times wherever two step points
#: are more than T / SAMPLE_GAPS apart.
SAMPLE_GAPS = 250


def _fine_sample(trajectory: Trajectory) -> TrajectorySample:
    """One sampling for every check of a result (see :data:`SAMPLE_GAPS`).

    On the paper's example this finds max |u| within 2e-7 (k = 4) and 1e-5 (k = 1) of a
    200001-point sampling, and the joint velocity extremes within 5e-5 rad/s, at a quarter
    of the cost of 2001 equally spaced times (most step points need no integration).
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


def _limit_warnings(problem: Problem, sample: TrajectorySample) -> tuple[str, ...]:
    model = problem.model
    out = []
    for i, name in enumerate(model.joint_names):
        for label, values, lo, hi in (
                ("position", sample.q[:, i], model.q_lower[i], model.q_upper[i]),
                ("velocity", sample.qd[:, i], -model.qd_max[i], model.qd_max[i])):
            bad = np.flatnonzero((values < lo) | (values > hi))
            if bad.size:
                j = int(bad[0])
                out.append(f"joint {name!r} violates its URDF {label} limit [{lo:.4g}, "
                           f"{hi:.4g}] at t = {sample.t[j]:.4f} s (value {values[j]:.4g}; "
                           f"limits are checked, not enforced)")
    return tuple(out)


def _failure(problem, status: Status, message: str, timings: dict, starts=(),
             run: _Run | None = None) -> PlanResult:
    return PlanResult(
        success=False, status=status, message=f"{status.value}: {message}",
        T=float("nan"), k=run.k if run else float("nan"), trajectory=None,
        residual=run.residual if run else float("nan"),
        iterations=run.iterations if run else 0, timings=timings,
        continuation=tuple(run.log) if run else (), max_abs_u=float("nan"),
        delta=run.delta if run else float("nan"), intervals=run.grid.N if run else 0,
        starts=tuple(starts), problem=problem)


def _solve_from_guess(planner, problem, options, direct: DirectResult, deadline,
                      should_stop) -> tuple[_Run, Status, str]:
    """Shooting at k = 1 from a direct solution, then continuation and smoothing.

    When Newton does not converge on ``options.intervals`` intervals, it is tried once more
    on twice as many (the direct solution interpolated anew): where the guess's costates are
    rough, shorter intervals keep the initial residual small enough for Newton.
    """
    # The switch mesh (options.steps per interval) takes over after the continuation.
    steps = min(options.steps, CONTINUATION_STEPS) if problem.k > 1 and options.switch_nodes \
        else options.steps
    for count in (options.intervals, 2 * options.intervals):
        lengths = np.full(count, 1.0 / count)
        grid = ShootingGrid(planner.system, lengths, steps, problem.start.kind,
                            problem.target.kind)
        nodes = _nodes_from_direct(direct, grid.tau)
        run = _Run(grid=grid, w=grid.pack(nodes, direct.T), k=1.0, delta=0.0)
        rep = _newton(planner, run, problem, 1.0, 0.0, _continuation_options(options),
                      deadline, should_stop)
        if rep.converged:
            break
    else:
        return run, Status.NEWTON_FAILED, rep.message
    if not _continue_k(planner, run, problem, options, deadline, should_stop):
        return run, Status.CONTINUATION_FAILED, f"stalled at k = {run.k:g}"
    return run, Status.SUCCESS, ""


def _plan(planner: Planner, problem: Problem, options: SolverOptions,
          warm_start: PlanResult | None, should_stop) -> PlanResult:
    t_start = time.perf_counter()
    deadline = t_start + options.time_limit
    timings = {"guess": 0.0, "shooting": 0.0, "refine": 0.0, "verify": 0.0}
    if problem.model is not planner.model:
        raise ValueError("`problem.model` is not the planner's model")
    if problem.is_trivial():
        timings["total"] = time.perf_counter() - t_start
        return PlanResult(success=True, status=Status.TRIVIAL, message=Status.TRIVIAL.value,
                          T=0.0, k=problem.k, trajectory=None, residual=0.0, iterations=0,
                          timings=timings, continuation=(), max_abs_u=0.0, delta=0.0,
                          intervals=0, problem=problem)
    notes: list[str] = []
    run = None
    records: list[StartRecord] = []
    try:
        finished = False
        if warm_start is not None:
            run, finished = _warm(planner, problem, options, warm_start, deadline,
                                  should_stop)
            timings["shooting"] += time.perf_counter() - t_start
            if run is None:
                notes.append("warm start did not converge; solved cold")
        if run is None:
            run, records, status, message = _cold(planner, problem, options, deadline,
                                                  should_stop, timings)
            if status is not Status.SUCCESS:
                timings["total"] = time.perf_counter() - t_start
                return _failure(problem, status, message, timings, records, run)
        t0 = time.perf_counter()
        if finished:
            saved = _snapshot(run)
            why = _refine(planner, run, problem, options, deadline, should_stop)
            if why or run.residual > options.tol:
                # The kept smoothing does not refine cleanly: the full schedule instead.
                _restore(run, saved)
                rep = _newton(planner, run, problem, run.k, options.smoothing[0], options,
                              deadline, should_stop)
                if rep.converged:
                    notes += _final_smoothing(planner, run, problem, options, deadline,
                                              should_stop)
                else:
                    _restore(run, saved)
                    notes.append(why or "the warm solution did not reach tol")
        else:
            notes += _final_smoothing(planner, run, problem, options, deadline, should_stop)
        timings["refine"] += time.perf_counter() - t0
    except _StopError as stop:
        timings["total"] = time.perf_counter() - t_start
        return _failure(problem, stop.status, "solve interrupted", timings, records, run)

    traj = _trajectory(planner, run, problem)
    sample = _fine_sample(traj)
    t0 = time.perf_counter()
    checks = verify(problem, traj, sample=sample) if options.verify else {}
    timings["verify"] = time.perf_counter() - t0
    max_u = float(np.max(np.abs(sample.u)))
    status, message = Status.SUCCESS, Status.SUCCESS.value
    if not options.verify:
        message = "solved (converged; re-integration check off: SolverOptions(verify=False))"
    else:
        bad = []
        if checks["point_error"] > options.verify_point_tol:
            bad.append(f"re-integrated end point misses the target by "
                       f"{checks['point_error']:.3g} m")
        if checks["velocity_error"] > options.verify_velocity_tol:
            bad.append(f"re-integrated end velocity {checks['velocity_error']:.3g}")
        if bad:
            status = Status.VERIFICATION_FAILED
            message = f"{status.value}: " + "; ".join(bad)
    if status is Status.SUCCESS and run.residual > options.tol:
        status = Status.VERIFICATION_FAILED
        message = f"{status.value}: residual {run.residual:.3g} above tol"
    timings["total"] = time.perf_counter() - t_start
    t_final = run.grid.unpack(run.w)[1]
    records = [replace(r, T=t_final) if r.status == "returned" else r for r in records]
    return PlanResult(
        success=status is Status.SUCCESS, status=status, message=message, T=t_final,
        k=run.k, trajectory=traj, residual=run.residual, iterations=run.iterations,
        timings=timings, continuation=tuple(run.log), max_abs_u=max_u, delta=run.delta,
        intervals=run.grid.N, verification=checks,
        warnings=tuple(notes) + _limit_warnings(problem, sample), starts=tuple(records),
        problem=problem, _state={"lengths": run.grid.lengths_of(run.w).copy(), "w": run.w.copy(),
                                 "steps": run.grid.steps, "kinds": run.grid.kinds.copy(),
                                 "breaks": run.grid.breaks, "factors": run.lu()})


def _cold(planner, problem, options, deadline, should_stop, timings):
    """Multistart: direct guesses from seed pairs, the best distinct ones continued."""
    t0 = time.perf_counter()
    pairs = _seed_pairs(problem, options)
    if not pairs:
        return None, [], Status.NO_GUESS, "no inverse-kinematics seed"
    direct = planner.direct(problem, options.guess_intervals)
    guesses = []
    for idx, (qa, qb) in enumerate(pairs):
        if should_stop is not None and should_stop():
            raise _StopError(Status.CANCELLED)
        if time.perf_counter() > deadline:
            raise _StopError(Status.TIME_LIMIT)
        t_guess, x_guess, u_guess = initial_path(problem.model, qa, qb,
                                                 options.guess_intervals,
                                                 1.0 - problem.reserve)
        res = direct.solve(problem.start.value, problem.target.value, 1.0, t_guess,
                           x_guess, u_guess)
        guesses.append((idx, qa, qb, res))
    timings["guess"] += time.perf_counter() - t0
    ok = [g for g in guesses if g[3].success]
    records = {g[0]: StartRecord(g[0], g[1], g[2], g[3].T if g[3].success else np.nan,
                                 np.nan, "guess only" if g[3].success else
                                 f"direct method failed: {g[3].message}") for g in guesses}
    if not ok:
        return None, list(records.values()), Status.NO_GUESS, guesses[0][3].message
    # Distinct basins: direct solutions whose end configurations differ.
    ok.sort(key=lambda g: g[3].T)
    distinct = []
    for g in ok:
        ends = np.concatenate([g[3].x[0, :planner.model.n], g[3].x[-1, :planner.model.n]])
        if all(np.max(np.abs(ends - e)) > 1e-3 for _, e in distinct):
            distinct.append((g, ends))
    best = None
    failures = []
    t0 = time.perf_counter()
    for g, _ in distinct[:options.candidates]:
        run, status, message = _solve_from_guess(planner, problem, options, g[3], deadline,
                                                 should_stop)
        t_final = run.grid.unpack(run.w)[1]
        if status is Status.SUCCESS:
            records[g[0]] = replace(records[g[0]], T=t_final, status="continued")
            if best is None or t_final < best[0].grid.unpack(best[0].w)[1]:
                best = (run, g[0])
        else:
            records[g[0]] = replace(records[g[0]], status=f"{status.value}: {message}")
            failures.append((run, status, message))
    timings["shooting"] += time.perf_counter() - t0
    if best is None:
        run, status, message = failures[0]
        return run, list(records.values()), status, message
    records[best[1]] = replace(records[best[1]], status="returned")
    return best[0], sorted(records.values(), key=lambda r: r.index), Status.SUCCESS, ""


def _warm(planner, problem, options, warm: PlanResult, deadline, should_stop):
    """Continue a previous solution to a new problem.

    Returns
    -------
    (run, finished) or (None, False)
        ``finished`` when the previous exponent and smoothing were kept, so only the mesh
        check remains; None when it does not converge.
    """
    st = warm._state
    prev = warm.problem
    if not st or prev is None or prev.model is not problem.model or \
            prev.start.kind != problem.start.kind or prev.target.kind != problem.target.kind \
            or prev.reserve != problem.reserve:
        return None, False
    grid = ShootingGrid(planner.system, st["lengths"], st["steps"], problem.start.kind,
                        problem.target.kind, kinds=st["kinds"], breaks=st["breaks"])
    run = _Run(grid=grid, w=st["w"].copy(), k=warm.k, delta=warm.delta,
               factors=(grid, st.get("factors")))
    if warm.k == problem.k:
        rep = _newton(planner, run, problem, warm.k, warm.delta, options, deadline,
                      should_stop)
        if rep.converged:
            return run, True
        # At a small delta the law is nearly singular and a moved problem can stall Newton:
        # restart the smoothing schedule from the previous solution instead.
        run = _Run(grid=grid, w=st["w"].copy(), k=warm.k, delta=warm.delta)
        rep = _newton(planner, run, problem, warm.k, options.smoothing[0], options, deadline,
                      should_stop)
        return (run, False) if rep.converged else (None, False)
    # Another exponent: move the boundary values at the old k (intermediate smoothing),
    # then step k directly; the final smoothing schedule follows in the caller.
    for k in (warm.k, problem.k):
        rep = _newton(planner, run, problem, k, max(warm.delta, options.smoothing_intermediate),
                      options, deadline, should_stop)
        if not rep.converged:
            return None, False
    return run, False
