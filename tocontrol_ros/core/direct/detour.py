"""Seeds that avoid obstacles: a collision-free joint path from a sampling planner (issue 51).

The bounded solve's seeds (:func:`~tocontrol_ros.core.methods.seeding.seed_pairs` and their
coarse direct guesses) know nothing of the scene: where their paths go through an obstacle,
IPOPT must push the whole path to one side of it, and from the free optimum's side it may
not converge at all (docs/collision.md, case 3 shelf). :func:`detour_guess` gives the
bounded solve one more candidate that starts on a collision-free route:

1. **Goals**: the target's configurations (a joint-state target's own, else the seed
   pairs' and :func:`~tocontrol_ros.core.robot.ik.ik_family`'s, :data:`IK_COUNT` seeds,
   inside the joint limits), those whose spheres keep the margin plus :data:`CLEAR`
   from every obstacle and every self pair first (a hand beside the base whose spheres
   touch the base's comes later: the rows could not hold there), then those clear by
   the margin by the exact distances; each group by the velocity-limited straight-line
   time from the start; the first :data:`GOALS` are tried.
2. **A path to each** by OMPL's RRTConnect in joint space, a state valid when every
   checked pair's spheres (:func:`sphere_distances`, which hold the links' geometry) are
   at least the margin plus :data:`CLEAR` apart, or as far apart as at the start (or the
   goal) where that has less (the spheres stand up to their gap outside the geometry).
   OMPL's seed generator is set to :data:`SAMPLER_SEED` before each query (OMPL logs
   that a seed set after the first random numbers will not give deterministic sampling;
   it resets its generator all the same, and ``test_detour.py`` checks the same path
   after other queries) and the query stops after :data:`MAX_CHECKS` validity checks (a
   count, not a clock): the same request gives the same path (docs/determinism.md). The
   path is shortened greedily (from each waypoint to the farthest one a straight segment
   reaches, checked every :data:`STEP` rad): OMPL's own simplifier draws from a generator
   that cannot be seeded per query.
3. **The guess**: of the paths found, the one of least velocity-limited time, its
   waypoints joined by a monotone (PCHIP) interpolant in the chord length, run along a
   smoothstep in time and timed as the straight seeds are
   (:func:`~tocontrol_ros.core.direct.collocation.initial_path`'s rule: the velocity
   limits at :data:`~tocontrol_ros.core.direct.tuning.GUESS_LOAD`, the peak normalised
   torque rescaled twice).

OMPL is optional (the ``ompl`` wheel, extras ``collision`` and ``test``): without it there
is no detour and the caller says so.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from tocontrol_ros.core.direct.tuning import GUESS_LOAD
from tocontrol_ros.core.geometry.collision import CollisionModel, body_frames
from tocontrol_ros.core.robot.ik import ik_family
from tocontrol_ros.core.types.problem import Problem

__all__ = ["Detour", "DetourGuess", "detour_guess", "sphere_distances", "path_collides",
           "CLEAR", "GOALS", "MAX_CHECKS", "SAMPLER_SEED", "STEP"]

#: Seed of OMPL's random number generator, set before each query (determinism).
SAMPLER_SEED = 51
#: Work budget of one RRTConnect query: validity checks (a state each).
MAX_CHECKS = 20000
#: Goal configurations tried, one query each.
GOALS = 3
#: Joint step (rad, the largest joint's change) at which a straight segment is checked,
#: by OMPL's motion validator (as a fraction of the space's extent) and by the shortcut.
STEP = 0.03
#: The spheres' distance (m) a state keeps from obstacles and between its own links, beyond
#: the margin: the seed is only a seed, but the rows ask for the margin at every sample.
CLEAR = 0.01
#: Intervals of the guess's sampled path (the bounded solve fits its B-spline to it).
GUESS_SAMPLES = 160
#: IK seeds per target point (:func:`~tocontrol_ros.core.robot.ik.ik_family`'s ``count``):
#: more than the multistart's 12, as few of them may keep clear of an obstacle near the
#: target (case 3 shelf of bench/collision.py: 1 of 12 clear by Coal).
IK_COUNT = 48

#: One query at a time: OMPL's seed generator is global to the process.
_OMPL_LOCK = threading.Lock()


@dataclass(frozen=True)
class DetourGuess:
    """A timed rest-to-rest path from the start to a goal configuration (a seed).

    Attributes
    ----------
    T : float
        Its time (s).
    t : ndarray, shape (K,)
        Sample times (s).
    x : ndarray, shape (K, 2n)
        Positions and velocities at ``t`` (rad, rad/s).
    waypoints : ndarray, shape (m, n)
        The collision-free joint path it follows (rad), shortened.
    """

    T: float
    t: np.ndarray
    x: np.ndarray
    waypoints: np.ndarray


@dataclass(frozen=True)
class Detour:
    """What :func:`detour_guess` found, and what it did.

    Attributes
    ----------
    guess : DetourGuess or None
        None when no path was found (``note`` says why).
    note : str
        One line for the plan's warnings.
    checks : int
        Validity checks spent (all queries).
    """

    guess: DetourGuess | None
    note: str
    checks: int


def sphere_distances(collision: CollisionModel, q: np.ndarray) -> np.ndarray:
    """Every checked pair's least sphere distance at configurations ``q`` (K, n).

    Obstacle pairs: the obstacle's exact signed distance to each sphere centre less its
    radius; self pairs: centre distance less both radii. The spheres hold the links'
    geometry, so a pair's exact distance is at least this.

    Returns
    -------
    ndarray, shape (K, P)
        Metres, in the order of ``collision.obstacle_pairs() + collision.self_pairs``.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rots, poss = body_frames(collision.model, q)
    spheres = collision.spheres
    body = np.concatenate([np.full(len(s.radii), s.body + 1) for s in spheres])
    centers = np.concatenate([s.centers for s in spheres])
    radii = np.concatenate([s.radii for s in spheres])
    starts = np.cumsum([0] + [len(s.radii) for s in spheres])[:-1]
    index = {s.link: i for i, s in enumerate(spheres)}
    world = poss[:, body] + np.einsum("kmij,mj->kmi", rots[:, body], centers)  # (K, M, 3)
    cols = []
    per_obstacle = {}
    for a, b in collision.obstacle_pairs():
        if b not in per_obstacle:  # every sphere to this obstacle, then each link's least
            ob = next(o for o in collision.scene.obstacles if o.name == b)
            d = ob.distance(world.reshape(-1, 3)).reshape(len(q), -1) - radii
            per_obstacle[b] = np.minimum.reduceat(d, starts, axis=1)
        cols.append(per_obstacle[b][:, index[a]])
    if collision.self_pairs:
        gap = np.linalg.norm(world[:, :, None, :] - world[:, None, :, :], axis=3)
        gap -= radii[:, None] + radii[None, :]
        links = np.minimum.reduceat(np.minimum.reduceat(gap, starts, axis=1), starts, axis=2)
        cols += [links[:, index[a], index[b]] for a, b in collision.self_pairs]
    return np.array(cols).T.reshape(len(q), len(cols))


def path_collides(collision: CollisionModel, q: np.ndarray) -> bool:
    """Whether sampled positions ``q`` (K, n) bring a pair's spheres closer than the margin.

    Only pairs the first sample keeps at least the margin apart count (a start the spheres
    already see closer is the ends' allowance's business, not a collision of the path).
    """
    d = sphere_distances(collision, q)
    watched = d[0] >= collision.margin
    return bool(np.any(d[1:, watched] < collision.margin))


def _floors(collision: CollisionModel, q0: np.ndarray) -> np.ndarray:
    """The spheres' distance each pair must keep (P,): ``margin + CLEAR``, or the start's."""
    return np.minimum(collision.margin + CLEAR, sphere_distances(collision, q0)[0] - 1e-9)


def _goals(problem: Problem, q0: np.ndarray, pairs, floors: np.ndarray
           ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Up to :data:`GOALS` target configurations and their floors (P,), fastest first.

    Those whose spheres keep ``floors`` first; then those the exact distances (Coal) keep
    the margin from everything, whose own sphere distances lower their query's floors
    (a target near an obstacle cannot be reached otherwise).
    """
    model, lim, col = problem.model, problem.limits, problem.collision
    n = model.n
    if problem.target.kind == "state":
        cands = [np.asarray(problem.target.value[:n], dtype=float)]
    else:
        cands = [np.asarray(b, dtype=float) for _, b in (pairs or ())]
        cands += ik_family(model, problem.target.value, count=IK_COUNT)
    lo = np.where(np.isfinite(lim.plan_lower), lim.plan_lower, -np.inf)
    hi = np.where(np.isfinite(lim.plan_upper), lim.plan_upper, np.inf)
    cands = [q for q in cands if np.all(q >= lo) and np.all(q <= hi)]
    if not cands:
        return []
    qs = np.array(cands)
    d = sphere_distances(col, qs)
    valid = np.all(d >= floors[None, :], axis=1)
    speed = np.where(lim.plan_velocity > 0, lim.plan_velocity, np.inf)
    est = np.max(np.abs(qs - q0) / speed, axis=1)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for tier in (True, False):
        for i in sorted(np.flatnonzero(valid == tier), key=lambda i: (est[i], i)):
            if len(out) == GOALS:
                return out
            if any(np.max(np.abs(qs[i] - g)) < STEP for g, _ in out):
                continue
            if tier:
                out.append((qs[i], floors))
            elif col.clearance(qs[i]).minimum >= col.margin:
                out.append((qs[i], np.minimum(floors, d[i] - 1e-9)))
    return out


def _segment(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Points of the straight segment from ``qa`` to ``qb`` at most :data:`STEP` apart."""
    count = max(int(np.ceil(np.max(np.abs(qb - qa)) / STEP)), 1)
    return qa + np.linspace(0.0, 1.0, count + 1)[:, None] * (qb - qa)


def _shortcut(col: CollisionModel, way: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """``way`` (m, n) shortened: from each waypoint, the farthest one a segment reaches."""
    out, i = [way[0]], 0
    while i < len(way) - 1:
        j = len(way) - 1
        while j > i + 1:
            seg = _segment(way[i], way[j])
            if np.all(sphere_distances(col, seg) >= floors[None, :]):
                break
            j -= 1
        out.append(way[j])
        i = j
    return np.array(out)


def _query(problem: Problem, q0: np.ndarray, goal: np.ndarray, floors: np.ndarray
           ) -> tuple[np.ndarray | None, int]:
    """One RRTConnect query from ``q0`` to ``goal``: its waypoints (or None), checks spent."""
    from ompl import base as ob
    from ompl import geometric as og

    col, lim = problem.collision, problem.limits
    n = problem.model.n
    lo, hi = lim.plan_lower, lim.plan_upper
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(min(lo[i], q0[i], goal[i])))
        bounds.setHigh(i, float(max(hi[i], q0[i], goal[i])))
    space.setBounds(bounds)
    checks = [0]

    def valid(state) -> bool:
        checks[0] += 1
        q = np.array([state[i] for i in range(n)])
        return bool(np.all(sphere_distances(col, q)[0] >= floors))

    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(STEP / space.getMaximumExtent())
    start, end = space.allocState(), space.allocState()
    for i in range(n):
        start[i], end[i] = float(q0[i]), float(goal[i])
    ss.setStartAndGoalStates(start, end)
    ss.setPlanner(og.RRTConnect(si))
    solved = ss.solve(ob.PlannerTerminationCondition(lambda: checks[0] >= MAX_CHECKS))
    if not solved or not ss.haveExactSolutionPath():
        return None, checks[0]
    path = ss.getSolutionPath()
    way = np.array([[path.getState(j)[i] for i in range(n)]
                    for j in range(path.getStateCount())])
    return way, checks[0]


def _timed(problem: Problem, way: np.ndarray) -> DetourGuess:
    """The waypoints as a rest-to-rest path, timed as the straight seeds are (see the module)."""
    model = problem.model
    n = model.n
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(way, axis=0), axis=1))])
    path = PchipInterpolator(chord / chord[-1], way, axis=0)
    tau = np.linspace(0.0, 1.0, GUESS_SAMPLES + 1)
    u, du, ddu = 3 * tau**2 - 2 * tau**3, 6 * tau - 6 * tau**2, 6 - 12 * tau
    q, dq, ddq = path(u), path(u, 1), path(u, 2)
    scale = model.tau_max * problem.torque_scale
    inertia = model.diagonal_inertia(way[:1])[0]
    dist = np.sum(np.abs(np.diff(way, axis=0)), axis=0)
    T = max(1.5 * float(np.max(2 * np.sqrt(dist * inertia / scale))), 1e-2)
    speed = problem.limits.plan_velocity
    t_vel = float(np.max(np.abs(dq * du[:, None]) / (GUESS_LOAD * speed)))
    T = max(T, t_vel)
    for _ in range(2):
        qd = dq * (du / T)[:, None]
        qdd = ddq * (du / T)[:, None] ** 2 + dq * (ddu / T**2)[:, None]
        torque = np.array(model.function("id")(q.T, qd.T, qdd.T)).T / scale
        peak = float(np.max(np.linalg.norm(torque, axis=1)))
        if np.isfinite(peak) and peak > 0:
            T = max(T * float(np.clip(np.sqrt(peak / GUESS_LOAD), 0.25, 4.0)), t_vel, 1e-2)
    qd = dq * (du / T)[:, None]
    return DetourGuess(T, tau * T, np.hstack([q, qd]).reshape(-1, 2 * n), way)


def detour_guess(problem: Problem, pairs=None) -> Detour:
    """A seed on a collision-free route for ``problem`` (with a collision model; see the module).

    Parameters
    ----------
    problem : Problem
        Its ``collision`` set; a joint-state start (else the first seed pair's start).
    pairs : list of (ndarray, ndarray), optional
        The multistart's seed pairs ``(q_start, q_target)`` (n,) (rad): their target
        configurations are goals too.

    Returns
    -------
    Detour
        The guess of least velocity-limited time over the goals, or None and why.
    """
    col = problem.collision
    if col is None:
        raise ValueError("`problem` has no collision model: no detour to plan")
    try:
        from ompl import util as ou
    except ImportError:
        return Detour(None, "no detour seed: OMPL (the `ompl` wheel) is not installed", 0)
    n = problem.model.n
    if problem.start.kind == "state":
        q0 = np.asarray(problem.start.value[:n], dtype=float)
    elif pairs:
        q0 = np.asarray(pairs[0][0], dtype=float)
    else:
        return Detour(None, "no detour seed: no start configuration", 0)
    floors = _floors(col, q0)
    goals = _goals(problem, q0, pairs, floors)
    if not goals:
        return Detour(None, "no detour seed: no target configuration inside the limits "
                      "and clear of every pair by the margin", 0)
    speed = np.where(problem.limits.plan_velocity > 0, problem.limits.plan_velocity, np.inf)
    best, spent, found = None, 0, 0
    for goal, floor in goals:
        with _OMPL_LOCK:
            level = ou.getLogLevel()
            ou.setLogLevel(ou.LOG_NONE)  # reseeding after the first query logs an error
            try:
                ou.RNG.setSeed(SAMPLER_SEED)
                way, checks = _query(problem, q0, goal, floor)
            finally:
                ou.setLogLevel(level)
        spent += checks
        if way is None:
            continue
        found += 1
        way = _shortcut(col, way, floor)
        est = float(np.sum(np.max(np.abs(np.diff(way, axis=0)) / speed, axis=1)))
        if best is None or est < best[0]:
            best = (est, way)
    if best is None:
        return Detour(None, f"no detour seed: RRTConnect found no path to {len(goals)} "
                      f"goal configurations within {MAX_CHECKS} checks each", spent)
    guess = _timed(problem, best[1])
    return Detour(guess, f"a detour seed (OMPL RRTConnect, {found}/{len(goals)} goals "
                  f"reached, {len(best[1])} waypoints, {spent} checks)", spent)
