"""Seed pairs of the multistart: start and target configurations, most promising first.

The configurations come from the inverse kinematics
(:func:`~tocontrol_ros.core.robot.ik.ik_family`, spread over each end point's self-motion
manifold); this module pairs them, adds the 2 pi-shifted branches of the joints that may
turn the long way, and ranks every (start, target, branch) by a cheap time estimate, so that
many seeds cost little and only the best few are solved by the direct method.
See ``docs/seeding.md``.
"""

from __future__ import annotations

import itertools
import weakref

import numpy as np

from tocontrol_ros.core.methods.tuning import (
    EXHAUSTIVE_IK_COUNT,
    EXHAUSTIVE_STARTS,
    GRAVITY_FREE,
    MAX_BRANCH_JOINTS,
    NEAR_TARGETS,
    RANDOM_IK_FACTOR,
    RANDOM_STARTS_EXTRA,
    RECOMBINED_NEAR,
    SAME_BASIN,
    SEED_SPACING,
)
from tocontrol_ros.core.robot.ik import angle_family, ik_family, ik_near
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem

__all__ = ["distinct_basins", "revolute_joints", "seed_pairs", "seed_grid", "shiftable_joints",
           "branch_shifts", "recombined_pairs", "gravity_free", "time_ratio_bound",
           "starts_solved"]


def shiftable_joints(problem: Problem) -> np.ndarray:
    """Joints whose target may be taken a full turn further (when the target is a point).

    Revolute joints whose range is at least 2 pi, continuous joints included.

    A joint-state target is one exact angle, so it has no branches.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    model = problem.model
    revolute = revolute_joints(model)
    if problem.target.kind != "point":
        return np.zeros(model.n, dtype=bool)
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    with np.errstate(invalid="ignore"):
        wide = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi - lo >= 2 * np.pi)
    return revolute & wide


def revolute_joints(model) -> np.ndarray:
    """Revolute joints (continuous included): a configuration 2 pi further is the same pose.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    return np.array([b.kind == "revolute" for b in model.bodies])


def branch_shifts(shiftable: np.ndarray) -> np.ndarray:
    """Full-turn multiples added to the short-way displacements: -1, 0 or +1 turn per joint.

    With the short way ``d`` in (-pi, pi], ``d - 2 pi sign(d)`` is the long way and
    ``d + 2 pi sign(d)`` the short way plus a full turn (the best motions of the paper's arm
    take each of the three).

    Parameters
    ----------
    shiftable : ndarray of bool, shape (n,)

    Returns
    -------
    ndarray, shape (V, n)
        ``2 pi m`` per variant (rad), ``V = 3^J`` for J shiftable joints (at most
        :data:`MAX_BRANCH_JOINTS` of them); variant 0 is the short way on every joint.
    """
    idx = np.flatnonzero(shiftable)[:MAX_BRANCH_JOINTS]
    combos = np.array(list(itertools.product((0, -1, 1), repeat=len(idx))), dtype=float)
    out = np.zeros((len(combos), len(shiftable)))
    out[:, idx] = 2 * np.pi * combos
    return out


def _bang_bang_estimate(d: np.ndarray, inertia: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The ranking's time estimate (s): ``max_i 2 sqrt(|d_i| M_ii / tau_i)``, last axis.

    Parameters
    ----------
    d : ndarray, shape (..., n)
        Displacements (rad, m).
    inertia : ndarray, shape broadcastable to ``d``
        Diagonals of the inertia matrix at the start.
    acc : ndarray, shape (n,)
        Torque limits (N·m, N) times the problem's torque scale.
    """
    return np.max(2 * np.sqrt(np.abs(d) * inertia / acc), axis=-1)


def seed_grid(problem: Problem, options: SolverOptions, exhaustive: bool = False):
    """Every (start, target, branch) seed with its time estimate, unranked.

    Returns
    -------
    qa : ndarray, shape (S, n)
        Start configurations (rad, m).
    dv : ndarray, shape (S, G, V, n)
        Displacement to the target per start, target configuration and branch.
    est : ndarray, shape (S, G, V)
        Bang-bang time estimate with diagonal inertia at the start (s); ``inf`` where the
        start or the branch's target is outside the position limits.
    """
    model = problem.model
    n = model.n
    count = max(options.ik_count, EXHAUSTIVE_IK_COUNT) if exhaustive else options.ik_count
    # Random seeds on an arm whose limits cut its self-motion manifold into pieces (each a
    # basin): as many configurations as angles give, and the target's near each start.
    cut = _cut(problem)
    if cut:
        count *= RANDOM_IK_FACTOR
    if problem.start.kind == "state":
        starts = [problem.start.value[:n]]
    else:
        starts = ik_family(model, problem.start.value, count)
    if problem.target.kind == "state":
        targets = [problem.target.value[:n]]
    else:
        targets = ik_family(model, problem.target.value, count)
        if cut and NEAR_TARGETS and starts:
            targets = ik_near(model, problem.target.value, starts) + targets
    if not starts or not targets:
        return np.zeros((0, n)), np.zeros((0, 0, 0, n)), np.zeros((0, 0, 0))
    shiftable = shiftable_joints(problem)
    acc = model.tau_max * problem.torque_scale
    qa = np.array(starts)                                   # (S, n)
    inertia = model.diagonal_inertia(qa)                    # (S, n)
    d = np.array(targets)[None, :, :] - qa[:, None, :]      # (S, G, n)
    d = np.where(shiftable, np.angle(np.exp(1j * d)), d)
    dv = d[:, :, None, :] + branch_shifts(shiftable)        # (S, G, V, n)
    est = _bang_bang_estimate(dv, inertia[:, None, None, :], acc)
    q_end = qa[:, None, None, :] + dv
    lo, hi = problem.limits.plan_lower, problem.limits.plan_upper
    inside = np.all((q_end >= lo - 1e-12) & (q_end <= hi + 1e-12), axis=-1)
    inside &= np.all((qa >= lo - 1e-12) & (qa <= hi + 1e-12), axis=-1)[:, None, None]
    est = np.where(inside, est, np.inf)
    return qa, dv, est


def _cut(problem: Problem) -> bool:
    """Whether the arm's seeds are random and its joint limits cut their manifold."""
    return problem.limits.active and not angle_family(problem.model)


def starts_solved(problem: Problem, options: SolverOptions) -> int:
    """How many seed pairs the multistart solves: ``options.starts``, more where limits cut.

    On an arm whose self-motion family is random seeds and whose joint limits are active,
    :data:`~tocontrol_ros.core.methods.tuning.RANDOM_STARTS_EXTRA` of ``starts`` more (rounded
    down: a single start stays one).
    """
    extra = int(options.starts * RANDOM_STARTS_EXTRA) if _cut(problem) else 0
    return options.starts + extra


#: The last :func:`seed_pairs` call: its problem (weakly), options and pairs. The planner
#: node's first motion and its plan ask for the pairs of one problem (the same object; a
#: :class:`Problem` is frozen) one after the other: the second call skips the inverse
#: kinematics (25-90 ms on the Panda).
_LAST: tuple = (None, None, None)


def seed_pairs(problem: Problem, options: SolverOptions, exhaustive: bool = False
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Seed pairs (q_start, q_target), most promising first.

    Every start configuration of the family is paired with every target configuration and
    every branch (:func:`branch_shifts`: the target unwrapped to the short way, and each
    joint that may turn a full turn also the long way and the short way plus a turn); the
    pairs are ranked by a bang-bang time estimate with diagonal inertia (one vectorised
    expression over start x target x branch), ties kept in that order. The
    :func:`starts_solved` best (``starts``, more on an arm whose limits cut its random
    seeds' manifold) are returned, except that a seed within :data:`SEED_SPACING` of a
    better one at both ends comes after every farther one. Ranking costs microseconds per
    pair; each returned pair costs one direct solve.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
        ``starts`` (how many pairs, :func:`starts_solved`) and ``ik_count``
        (configurations per end point).
    exhaustive : bool
        The reference mode of the benchmark: at least :data:`EXHAUSTIVE_IK_COUNT` angles
        per end point and (``starts`` ignored) the :data:`EXHAUSTIVE_STARTS` pairs taken in
        turn from each branch, best-ranked first within the branch.

    Returns
    -------
    list of (ndarray, ndarray), each shape (n,)
        ``(q_start, q_target)`` (rad, m); empty when an end point has no IK solution. The
        same problem (object) asked again with the same options gets copies of the last
        answer.
    """
    global _LAST
    key = (options.starts, options.ik_count, exhaustive)
    last_problem, last_key, last_pairs = _LAST
    if last_problem is not None and last_problem() is problem and last_key == key:
        return [(a.copy(), b.copy()) for a, b in last_pairs]
    pairs = _seed_pairs(problem, options, exhaustive)
    _LAST = (weakref.ref(problem), key, [(a.copy(), b.copy()) for a, b in pairs])
    return pairs


def _seed_pairs(problem: Problem, options: SolverOptions, exhaustive: bool
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`seed_pairs` computed."""
    qa, dv, est = seed_grid(problem, options, exhaustive)
    if est.size == 0:
        return []
    flat = est.ravel()
    if exhaustive:
        order = _round_robin(est)[:EXHAUSTIVE_STARTS]
    else:
        order = np.argsort(flat, kind="stable")
        order = order[np.isfinite(flat[order])]
    s_idx = np.unravel_index(order, est.shape)[0]
    dflat = dv.reshape(-1, qa.shape[1])
    if not exhaustive:
        keep = _spread(qa[s_idx], qa[s_idx] + dflat[order], starts_solved(problem, options))
        order, s_idx = order[keep], s_idx[keep]
    return [(qa[i], qa[i] + dflat[j]) for i, j in zip(s_idx, order, strict=True)]


def _round_robin(est: np.ndarray) -> np.ndarray:
    """Flat indices of ``est`` (S, G, V): the best of each branch, then the second, ..."""
    per_branch = []
    for v in range(est.shape[2]):
        flat = np.ravel_multi_index(np.indices(est.shape[:2]).reshape(2, -1).tolist()
                                    + [[v] * est[:, :, v].size], est.shape)
        vals = est[:, :, v].ravel()
        order = np.argsort(vals, kind="stable")
        per_branch.append(flat[order[np.isfinite(vals[order])]])
    out = []
    for rank in range(max((len(b) for b in per_branch), default=0)):
        out += [b[rank] for b in per_branch if rank < len(b)]
    return np.array(out, dtype=int)


def _spread(q_a: np.ndarray, q_b: np.ndarray, count: int) -> np.ndarray:
    """Indices of up to ``count`` seeds, those far from the ones kept before first.

    Far: farther than :data:`SEED_SPACING` (max-norm) at one end or the other; the near ones
    follow in their order. Seeds that close lead the direct method to the same solution: a
    direct solve each would be spent on one basin.
    """
    keep: list[int] = []
    skipped: list[int] = []
    for i in range(len(q_a)):
        if len(keep) >= count:
            break
        if keep:
            near = np.maximum(np.max(np.abs(q_a[keep] - q_a[i]), axis=1),
                              np.max(np.abs(q_b[keep] - q_b[i]), axis=1)) < SEED_SPACING
            if near.any():
                skipped.append(i)
                continue
        keep.append(i)
    return np.array((keep + skipped)[:count], dtype=int)


def recombined_pairs(problem: Problem, parents: list, tried: list, count: int
                     ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Seed pairs that join the start of one direct solution to the end of another.

    The direct method frees both ends on their self-motion manifolds, so the ends of its
    solutions are better placed than the inverse-kinematics grid's; the best motion often
    starts where one of them starts and ends where another ends (on the paper's arm, in
    four of the six pairs of the reference the ranked seeds missed). Each ordered pair of
    parents ``(a, b)`` (``a == b`` included) gives the straight path from ``a``'s start to
    ``b``'s end with the turns of each parent in turn: per shiftable joint the displacement
    (wrapped to the short way, :func:`shiftable_joints`) plus the multiple of 2 pi nearest
    to that parent's own displacement. Seeds that are a parent's own basin again (start
    modulo 2 pi and displacement within :data:`RECOMBINED_NEAR`), repeat one tried before
    or leave the position limits are dropped; the others come by their parents' ``T``
    (the slower parent's, then the faster's; then the faster parent's turns first).

    Parameters
    ----------
    problem : Problem
    parents : list of DirectResult
        Distinct direct solutions, with ``T`` and states ``x`` (N + 1, 2n).
    tried : list of (ndarray, ndarray)
        Seed pairs already solved (rad, m).
    count : int
        At most this many pairs.

    Returns
    -------
    list of (ndarray, ndarray), each shape (n,)
        ``(q_start, q_target)`` (rad, m), most promising first.
    """
    model = problem.model
    n = model.n
    shiftable = shiftable_joints(problem)
    revolute = revolute_joints(model)
    lo, hi = np.tile(problem.limits.plan_lower, 2), np.tile(problem.limits.plan_upper, 2)
    starts = [p.x[0, :n] for p in parents]
    moves = [p.x[-1, :n] - p.x[0, :n] for p in parents]
    own = [np.concatenate([np.where(revolute, np.mod(q, 2 * np.pi), q), m])
           for q, m in zip(starts, moves, strict=True)]
    inertia = model.diagonal_inertia(np.array(starts)) if parents else np.zeros((0, n))
    acc = model.tau_max * problem.torque_scale
    ranked = []
    for a, b in itertools.product(range(len(parents)), repeat=2):
        d = starts[b] + moves[b] - starts[a]
        d = np.where(shiftable, np.angle(np.exp(1j * d)), d)
        for parent in (a, b):
            turns = np.where(shiftable, np.round((moves[parent] - d) / (2 * np.pi)), 0.0)
            dv = d + 2 * np.pi * turns
            # The faster parent's turns first; ties broken by the bang-bang estimate.
            est = _bang_bang_estimate(dv, inertia[a], acc)
            key = (max(parents[a].T, parents[b].T), min(parents[a].T, parents[b].T),
                   parents[parent].T, est)
            ranked.append((key, a, dv))
    ranked.sort(key=lambda r: r[0])
    seen = [np.concatenate(pair) for pair in tried]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for _, a, dv in ranked:
        if len(out) >= count:
            break
        qa = starts[a]
        row = np.concatenate([np.where(revolute, np.mod(qa, 2 * np.pi), qa), dv])
        if any(_basin_distance(row, other, revolute) <= RECOMBINED_NEAR for other in own):
            continue
        pair = np.concatenate([qa, qa + dv])
        if any(np.max(np.abs(pair - other)) <= SAME_BASIN for other in seen) or \
                np.any(pair < lo - 1e-12) or np.any(pair > hi + 1e-12):
            continue
        seen.append(pair)
        out.append((qa.copy(), qa + dv))
    return out


def distinct_basins(items: list, result, n: int, periodic: np.ndarray | None = None) -> list:
    """``items`` by increasing ``T``, one per basin.

    Two direct solutions are in one basin when their start and end configurations are within
    :data:`SAME_BASIN` of each other. For the ``periodic`` joints the start configurations
    are compared modulo 2 pi, and the displacements (end minus start) instead of the ends: a
    revolute joint that starts a full turn further and turns by the same angle makes the same
    motion (the dynamics are 2 pi-periodic in it), and the inverse-kinematics families hold
    both.

    Parameters
    ----------
    items : list
        Anything that holds a direct solution.
    result : callable
        ``item -> DirectResult`` (with ``T`` and states ``x`` of shape (N + 1, 2n)).
    n : int
        Joints.
    periodic : ndarray of bool, shape (n,), optional
        Joints whose start configuration counts modulo 2 pi (default: none).
    """
    wrap = np.zeros(n, dtype=bool) if periodic is None else np.asarray(periodic, dtype=bool)
    out, seen = [], []
    for item in sorted(items, key=lambda it: result(it).T):
        x = result(item).x
        start = np.where(wrap, np.mod(x[0, :n], 2 * np.pi), x[0, :n])
        ends = np.concatenate([start, np.where(wrap, x[-1, :n] - x[0, :n], x[-1, :n])])
        if all(_basin_distance(ends, e, wrap) > SAME_BASIN for e in seen):
            out.append(item)
            seen.append(ends)
    return out


def _basin_distance(a: np.ndarray, b: np.ndarray, wrap: np.ndarray) -> float:
    """Max-norm distance of two (start, displacement) rows, the wrapped starts on the circle."""
    diff = np.abs(a - b)
    n = len(wrap)
    diff[:n] = np.where(wrap, np.minimum(diff[:n], 2 * np.pi - diff[:n]), diff[:n])
    return float(np.max(diff))


# ----------------------------------------------------- which candidates to continue
def time_ratio_bound(n: int, k: float) -> float:
    """A lower bound of ``T_k / T_1`` for a gravity- and friction-free arm: ``n^(-(k-1)/(4k))``.

    ``sum u_i^(2k) <= 1`` lies inside the ball ``|u|_2 <= c`` with ``c = n^((k-1)/(2k))``,
    and without gravity and friction scaling the torques by ``c`` scales the minimum time by
    ``1 / sqrt(c)``; so no motion at ``k`` is faster than ``T_1 / sqrt(c)``.
    """
    return float(n ** (-(k - 1) / (4 * k)))


def gravity_free(model, q: np.ndarray) -> bool:
    """Whether gravity loads no joint at the configurations ``q`` (K, n) (rad, m)."""
    zero = np.zeros((model.n, len(q)))
    g = np.array(model.function("id")(q.T, zero, zero))
    return bool(np.max(np.abs(g) / model.tau_max[:, None]) <= GRAVITY_FREE)
