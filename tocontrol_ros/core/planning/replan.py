"""On-line replanning: the executing motion's tail as a warm start, the hand-off lead.

A motion that is being executed and a new target near its own: the rest of the executing
motion from the hand-off time ``t_h`` on is, by the principle of optimality, the
time-optimal motion from the state ``x(t_h)`` to the old target, with the same costates.
:func:`tail_warm_start` cuts the executing solution's shooting mesh at ``t_h`` and returns
it as a warm start of the problem "from ``x(t_h)`` (a joint state) to the old target", so
that a replan to a target nearby is a few Newton steps from a converged solution (no guess,
no continuation), whatever the executing motion started from.

:class:`LatencyEstimate` keeps the recent replan latencies and gives the lead (how far
ahead of now the hand-off is put) with a margin. No ROS here.
"""

from __future__ import annotations

import collections
import math
import time
from dataclasses import replace

import numpy as np

from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.indirect.warm import WarmState
from tocontrol_ros.core.planning.tuning import (
    HIGH_QUANTILE,
    REPLAN_JOINT_RADIUS,
    REPLAN_SPANS,
    TAIL_MERGE,
    TAIL_MIN_REMAINING,
    TARGET_STEPS,
)
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.core.types.result import PlanResult, Status

__all__ = ["tail_warm_start", "path_tail_warm_start", "warm_replan", "LatencyEstimate",
           "replan_options"]


def tail_warm_start(result: PlanResult, t: float) -> PlanResult | None:
    """The executing solution from time ``t`` on, as a warm start from its state at ``t``.

    Parameters
    ----------
    result : PlanResult
        A successful maximum-principle solve (``warm_state`` a :class:`WarmState`).
    t : float
        Hand-off time on the motion's own clock (s), ``0 <= t < T``.

    Returns
    -------
    PlanResult or None
        A result whose ``problem`` is "from the joint state ``x(t)`` to the old target"
        (same model, target, ``k`` and reserve), ``T`` the time left and ``warm_state`` the
        cut mesh: pass it as ``warm_start`` to
        :meth:`~tocontrol_ros.core.planning.solver.Planner.plan` for a new target near the old one.
        None when there is nothing to continue: no shooting solution (a B-spline or first
        motion), or less than :data:`TAIL_MIN_REMAINING` of the motion left.

    Raises
    ------
    ProblemError
        ``t`` not finite or negative.
    """
    if not (isinstance(t, (int, float)) and math.isfinite(t) and t >= 0.0):
        raise ProblemError(f"`t` must be a finite time >= 0 (s), got {t!r}")
    st, traj, prev = result.warm_state, result.trajectory, result.problem
    if not isinstance(st, WarmState) or traj is None or prev is None or \
            not math.isfinite(result.T) or result.T <= 0:
        return None
    T = float(result.T)
    if t >= T * (1.0 - TAIL_MIN_REMAINING):
        return None
    n = prev.model.n
    m = prev.model.m
    nz = 4 * n
    N = len(st.lengths)
    n_nu0 = m if prev.start.kind == "point" else 0
    n_nuT = m if prev.target.kind == "point" else 0
    B = len(st.breaks)
    w = np.asarray(st.w, dtype=float)
    nodes = w[:nz * (N + 1)].reshape(N + 1, nz)
    col_T = nz * (N + 1)
    nuT = w[col_T + 1 + n_nu0: col_T + 1 + n_nu0 + n_nuT]
    # Node times in normalised time at the solution (the breaks move the mesh).
    lengths = np.asarray(st.lengths, dtype=float)
    if B:
        bounds_nodes = np.array([0] + [j for j, _ in st.breaks] + [N])
        t_breaks = w[col_T + 1 + n_nu0 + n_nuT:]
        bounds = np.concatenate([[0.0], t_breaks, [1.0]])
        segment = np.searchsorted(bounds_nodes, np.arange(N), side="right") - 1
        seg_len = np.add.reduceat(lengths, bounds_nodes[:-1])
        lengths = lengths / seg_len[segment] * np.diff(bounds)[segment]
    tau = np.concatenate([[0.0], np.cumsum(lengths)])
    tau_h = t / T
    # First kept node: the first one after the cut, unless the cut is very near it.
    first = int(np.searchsorted(tau, tau_h, side="right"))
    if first < N and tau[first] - tau_h < TAIL_MERGE * lengths[first - 1]:
        first += 1
    z_h = traj.state(t)[0]
    kept = nodes[first:]
    new_tau = np.concatenate([[tau_h], tau[first:]])
    new_tau = (new_tau - tau_h) / (1.0 - tau_h)
    new_lengths = np.diff(new_tau)
    new_nodes = np.vstack([z_h[None, :], kept])
    kinds = np.concatenate([[st.kinds[first - 1]], st.kinds[first:]]).astype(int)
    shift = first - 1
    breaks = [(j - shift, i) for j, i in st.breaks if j - shift > 0]
    new_breaks_t = np.array([new_tau[j] for j, _ in breaks])
    new_w = np.concatenate([new_nodes.ravel(), [T - t], nuT, new_breaks_t])
    warm = WarmState(lengths=new_lengths / new_lengths.sum(), w=new_w, steps=st.steps,
                     kinds=kinds, breaks=breaks, factors=None)
    q_h, qd_h = z_h[:n], z_h[n:2 * n]
    problem = Problem(prev.model, joint_state(q_h, qd_h), prev.target, k=prev.k,
                      reserve=prev.reserve, limits=prev.limits)
    return replace(result, problem=problem, warm_state=warm, T=T - t, starts=())


class _ShiftedMotion:
    """``motion`` from its time ``t0`` on, on a clock that starts there.

    What a path warm start evaluates (:func:`path_tail_warm_start`).
    """

    def __init__(self, motion, t0: float) -> None:
        self._motion, self._t0 = motion, float(t0)

    def evaluate(self, t):
        sample = self._motion.evaluate(np.asarray(t, dtype=float) + self._t0)
        return replace(sample, t=sample.t - self._t0)

    def state(self, t):
        return self._motion.state(np.asarray(t, dtype=float) + self._t0)


def path_tail_warm_start(result: PlanResult, t: float) -> PlanResult | None:
    """Any certified motion from time ``t`` on, as a bounded solve's warm start.

    A motion without a maximum-principle or bounded solution to continue (a quick motion,
    ``method="first"``) still has a path: its rest from ``t`` is a feasible motion from the
    state ``x(t)`` to its target, and the bounded B-spline solve
    (:class:`~tocontrol_ros.core.direct.method.BoundedPath`) takes it as its start, fitted on
    the ``replan_spans`` uniform mesh (no multipliers): the optimum from there is then the
    bounded solve's (``method="direct"``), on an arm whose limits do not bind too. None
    with less than :data:`TAIL_MIN_REMAINING` of the motion left.

    Parameters
    ----------
    result : PlanResult
        A successful result with a trajectory.
    t : float
        Time on the motion's own clock (s), ``0 <= t < T``.

    Returns
    -------
    PlanResult or None
        ``problem`` "from ``x(t)`` to the target", ``T`` the time left, ``warm_state`` a
        :class:`PathWarmState` whose mesh is the whole interval (so that the warm solve
        fits the path on its own uniform mesh: ``SolverOptions.replan_spans`` must be set),
        ``trajectory`` the motion from ``t`` on.
    """
    if not (isinstance(t, (int, float)) and math.isfinite(t) and t >= 0.0):
        raise ProblemError(f"`t` must be a finite time >= 0 (s), got {t!r}")
    traj, prev = result.trajectory, result.problem
    if not result.success or traj is None or prev is None or \
            not math.isfinite(result.T) or t >= result.T * (1.0 - TAIL_MIN_REMAINING):
        return None
    n = prev.model.n
    z = traj.state(t)[0]
    problem = Problem(prev.model, joint_state(z[:n], z[n:2 * n]), prev.target, k=prev.k,
                      reserve=prev.reserve, limits=prev.limits)
    left = float(result.T) - float(t)
    warm = PathWarmState(breaks=np.array([0.0, 1.0]), P=np.zeros((1, n)), T=left)
    return replace(result, problem=problem, warm_state=warm, T=left, starts=(),
                   trajectory=_ShiftedMotion(traj, t))


class LatencyEstimate:
    """Recent replan latencies (s) and the lead they call for.

    Parameters
    ----------
    margin : float
        Factor on the recent latencies' :data:`HIGH_QUANTILE` (>= 1).
    floor : float
        Lead added to it (s), > 0: delivery to the executor and its update period; a plan
        published later than ``floor`` before its hand-off is late.
    window : int
        How many recent latencies count.
    initial : float
        Lead before any latency was measured (s).
    """

    def __init__(self, margin: float, floor: float, window: int = 10,
                 initial: float = 0.2) -> None:
        if not (math.isfinite(margin) and margin >= 1.0):
            raise ProblemError(f"`margin` must be a finite number >= 1, got {margin!r}")
        if not (math.isfinite(floor) and floor > 0.0):
            raise ProblemError(f"`floor` must be a finite time > 0 (s), got {floor!r}")
        if not (isinstance(window, int) and window >= 1):
            raise ProblemError(f"`window` must be an integer >= 1, got {window!r}")
        self.margin, self.floor, self.initial = float(margin), float(floor), float(initial)
        self._recent: collections.deque = collections.deque(maxlen=window)

    def record(self, seconds: float) -> None:
        """One measured latency (s): solve start to trajectory published."""
        if math.isfinite(seconds) and seconds >= 0:
            self._recent.append(float(seconds))

    def typical(self) -> float:
        """The median of the recent latencies (s); 0 before any was measured."""
        return float(np.median(self._recent)) if self._recent else 0.0

    def lead(self) -> float:
        """How far ahead of now the next hand-off is put (s)."""
        # A high quantile, not the maximum: one slow solve (a page fault, a busy core)
        # does not push every later hand-off back; a late plan is solved again anyway.
        high = _quantile(self._recent, HIGH_QUANTILE) if self._recent else self.initial
        return self.floor + self.margin * high


def _quantile(values, q: float) -> float:
    """``numpy.quantile(values, q)`` (linear) in plain Python.

    A replan asks at each goal, and numpy's call on ten values cost 0.1-0.2 ms of its
    latency through the nodes.
    """
    ordered = sorted(values)
    h = q * (len(ordered) - 1)
    lo = int(math.floor(h))
    hi = min(lo + 1, len(ordered) - 1)
    return float(ordered[lo] + (ordered[hi] - ordered[lo]) * (h - lo))


def replan_options(options, smoothing: float = 0.0, spans: int = REPLAN_SPANS):
    """The options of a replan near the running motion: warm alone, one start if not.

    Parameters
    ----------
    options : SolverOptions
        The caller's (tolerances, time limit, verification).
    smoothing : float
        With ``smoothing > 0``, the final smoothing ``delta`` of the control law (the
        schedule is that one value; a warm start from a finer solution is continued at
        it), and the certificate's Hamiltonian tolerance ``max(its default, smoothing)``:
        the smoothed law's Hamiltonian is constant only to about ``0.3 smoothing``. On the
        circle's stream of replans of the paper's arm (k = 4), ``smoothing = 1e-3`` gave
        ``T`` within 6e-5 (relative) of the default plan's, and warm solves from the
        predicted goal's solution in a median 5 Newton iterations (14 at the default
        schedule's 1e-6..1e-7). 0: the options' schedule.

    spans : int
        ``SolverOptions.replan_spans``: a bounded warm start is solved on this many uniform
        spans (0: on its own mesh).

    Returns
    -------
    SolverOptions
        ``warm_only``, ``starts = candidates = 1``, ``warm_joint_radius =``
        :data:`REPLAN_JOINT_RADIUS`, ``replan_spans = spans``, and the smoothing above.
    """
    from tocontrol_ros.core.types.certificate import CertificateOptions

    out = replace(options, warm_only=True, starts=1, candidates=1,
                  warm_joint_radius=REPLAN_JOINT_RADIUS, replan_spans=int(spans))
    if smoothing > 0.0:
        cert = options.certificate or CertificateOptions()
        out = replace(out, smoothing=(float(smoothing),),
                      certificate=replace(cert, hamiltonian_tol=max(cert.hamiltonian_tol,
                                                                    float(smoothing))))
    return out


def warm_replan(planner, problem: Problem, warm, options=None,
                should_stop=None) -> PlanResult:
    """Re-solve ``problem`` warm from ``warm`` alone: no guess, no multistart.

    Each warm start is continued to the new target directly, in its order; when none
    converges, the first that applies is continued in two, then four steps along the segment
    from its target to the new one (a homotopy in the target, each step warm from the last).
    Bounded by work: at most one solve per warm start and six more, each a warm Newton
    solve.

    Parameters
    ----------
    planner : Planner
    problem : Problem
        The new problem; its start and target kinds must be the warm starts'.
    warm : PlanResult or sequence of PlanResult
        E.g. :func:`tail_warm_start`'s, or a previous solution from a start nearby; several:
        tried in this order (None entries skipped).
    options : SolverOptions, optional
        ``warm_joint_radius`` says which warm starts apply.
    should_stop : callable, optional
        Polled between Newton iterations; True cancels.

    Returns
    -------
    PlanResult
        The first success, else the last failure (the caller decides on a cold solve).
    """
    from tocontrol_ros.core.planning.solver import solve_once
    from tocontrol_ros.core.types.options import SolverOptions

    options = options or SolverOptions()
    t_start = time.perf_counter()
    deadline = t_start + options.time_limit
    radius = options.warm_joint_radius
    sources = [w for w in ([warm] if isinstance(warm, PlanResult) else warm) if w is not None]
    sources = [w for i, w in enumerate(sources) if all(w is not v for v in sources[:i])]
    new = problem.target_point
    result = None

    def done(r: PlanResult) -> PlanResult:
        r.timings["total"] = time.perf_counter() - t_start
        return r

    applicable = [w for w in sources if w.can_warm_start(problem, radius)]
    for source in applicable:
        result = solve_once(planner, problem, options, source, should_stop, deadline)
        if result.success:
            return done(result)
        if should_stop is not None and should_stop():
            return done(result)
    if applicable:
        source0 = applicable[0]
        old = source0.problem.target_point
        for fractions in TARGET_STEPS[1:]:
            source = source0
            for f in fractions:
                step = problem if f == 1.0 else replace(
                    problem, target=point(old + f * (new - old)))
                if not source.can_warm_start(step, radius):
                    break
                result = solve_once(planner, step, options, source, should_stop, deadline)
                if not result.success:
                    break
                source = result
            if result is not None and result.success and result.problem is problem:
                return done(result)
            if should_stop is not None and should_stop():
                break
    if result is None:
        return PlanResult.failure(problem, Status.NEWTON_FAILED,
                                  "the warm start does not apply to this problem",
                                  {"total": time.perf_counter() - t_start})
    return done(result)
