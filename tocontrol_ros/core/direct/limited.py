"""Plans whose joint limits bind: detection, and the bounded direct solve.

:func:`~tocontrol_ros.core.planning.solver.plan` solves the maximum principle first; when its best
direct guess comes within :data:`TOUCH` of a joint limit (:func:`touches`), or its solution
leaves the limits, :func:`plan_limited` solves the problem again with the limits as hard
bounds:

1. every seed pair gets a coarse Hermite-Simpson solve with the bounds at its mesh points,
   at the requested ``k``, from the initial path timed within the velocity limits (the
   multistart's own when it solved them within the bounds, as where they bind);
2. the best ``options.candidates`` (exhaustive mode: more) distinct ones whose ``T`` is
   within :data:`GUESS_WINDOW` of the best guess's are solved as B-spline joint paths whose
   torques are their inverse dynamics (:mod:`~tocontrol_ros.core.direct.flat`) on
   :data:`SPANS` uniform spans (a basin that fails is replaced by the next, repeats
   dropped); those within :data:`REFINE_WINDOW` of the best are solved again level by level
   (at most :data:`REFINEMENTS` levels) with the spans halved where the acceleration
   changes (the junctions of arcs), each level leaving behind those too far above the best
   (:data:`LEVEL_WINDOWS`);
3. the least ``T`` is verified (re-integration, limits included), ``method="direct"``.

See ``docs/limits.md`` for the formulation and why the maximum principle does not carry the
limits itself.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.interpolate import make_interp_spline

from tocontrol_ros.core.direct import active_rows, set_pads
from tocontrol_ros.core.direct.checked import FirstIterate, stretched, verified
from tocontrol_ros.core.direct.collocation import DirectResult, initial_path
from tocontrol_ros.core.direct.detour import detour_guess, path_collides
from tocontrol_ros.core.direct.early import iterate_watch
from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory, refined_breaks
from tocontrol_ros.core.direct.path_following import MAX_MOVES, follow, move_size, sub_moves
from tocontrol_ros.core.direct.sensitivity import (
    PATH_SOLVES,
    PATH_STEPS,
    PATH_SUB_BUDGET,
    PATH_SUBMOVES,
    sensitivity_solve,
)
from tocontrol_ros.core.direct.tuning import (
    FAR_MU,
    FAR_STEP_MOVE,
    FINE_GUESS_INTERVALS,
    FINE_GUESS_TOL,
    GUESS_WINDOW,
    INSIDE_TIE,
    LEVEL_WINDOWS,
    NEAR_MAX_ITER,
    PAD,
    PAD_ROUNDS,
    REFINE_WINDOW,
    REFINEMENTS,
    SAME_T,
    SCENE_MAX_SPANS,
    SET_MARGIN,
    SET_PAD,
    SPAN_BUCKET,
    SPANS,
    T_SETTLED,
    TOUCH,
)
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.methods.contract import Compiled
from tocontrol_ros.core.methods.seeding import distinct_basins, seed_pairs
from tocontrol_ros.core.methods.tuning import EXHAUSTIVE_CANDIDATES, SAME_BASIN
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, StartRecord, Status

#: The seeds' guesses are checked for collisions at this many times their mesh's intervals.
DETOUR_DENSITY = 8
#: Uniform spans of the detour's second try, where its solve on SPANS fails (_detour_solve).
DETOUR_SPANS = 64

__all__ = ["finer_guess", "plan_limited", "plan_limited_warm", "state_bounds", "touches"]


def finer_guess(planner: Compiled, problem: Problem, coarse: DirectResult,
                k: float = 1.0) -> DirectResult:
    """A direct solution solved again, finer, at the exponent ``k`` (default: 1, as a guess).

    On :data:`FINE_GUESS_INTERVALS` intervals to :data:`FINE_GUESS_TOL`, from itself
    interpolated.
    """
    direct = planner.direct(problem, FINE_GUESS_INTERVALS, tol=FINE_GUESS_TOL)
    # States and controls interpolated linearly onto the finer mesh.
    linear = make_interp_spline(coarse.t, np.hstack([coarse.x, coarse.u]), k=1)
    xu = linear(np.linspace(0.0, coarse.T, FINE_GUESS_INTERVALS + 1))
    n2 = coarse.x.shape[1]
    return direct.solve(problem.start.value, problem.target.value, k, coarse.T,
                        xu[:, :n2], xu[:, n2:])


def touches(problem: Problem, x: np.ndarray) -> bool:
    """Whether states ``x`` (K, 2n) come within :data:`TOUCH` of the planning limits."""
    lim = problem.limits
    if not lim.active:
        return False
    n = problem.model.n
    lo, hi, v = lim.plan_lower, lim.plan_upper, lim.plan_velocity
    width = hi - lo
    q, qd = x[:, :n], x[:, n:2 * n]
    with np.errstate(invalid="ignore"):
        near_q = np.isfinite(width) & ((q - lo < TOUCH * width) | (hi - q < TOUCH * width))
        near_v = np.isfinite(v) & (np.abs(qd) > (1 - TOUCH) * v)
    return bool(np.any(near_q) or np.any(near_v))


def state_bounds(problem: Problem, pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (2n,) of the state: the planning limits shrunk by ``pad`` of each range.

    Widened where needed to hold a start or target joint state.
    """
    lim = problem.limits
    n = problem.model.n
    lo, hi, v = lim.plan_lower, lim.plan_upper, lim.plan_velocity
    width = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    lower = np.concatenate([lo + pad * width, -(1 - pad) * v])
    upper = np.concatenate([hi - pad * width, (1 - pad) * v])
    if problem.start.kind == "state":
        x0 = problem.start.value
        lower, upper = np.minimum(lower, x0), np.maximum(upper, x0)
    if problem.target.kind == "state":
        xt = problem.target.value[:n]
        lower[:n], upper[:n] = np.minimum(lower[:n], xt), np.maximum(upper[:n], xt)
    return lower, upper


def plan_limited(planner: Compiled, ctx: SolveContext, timings: dict, t_start: float,
                 notes: list[str], reason: str | None = None,
                 only: frozenset[int] | None = None) -> PlanResult:
    """Solve ``ctx.problem`` with its joint limits as hard bounds (see the module).

    ``reason`` replaces the note that the limits bind (the solve is also the fallback of a
    failed shooting, :attr:`SolverOptions.direct_fallback`). The fallback starts each
    candidate from its finer guess and solves it on the uniform mesh by continuation in
    ``k`` (:func:`_continued_in_k`); a plan whose limits bind solves at the requested ``k``
    first (:func:`_uniform`). ``only``: the seed pairs (indices) to solve from, the others
    recorded as not solved (default: all).
    """
    problem, options = ctx.problem, ctx.options
    t0 = time.perf_counter()
    notes = list(notes) + [reason or "joint limits bind: solved as a B-spline path with "
                           "hard bounds (docs/limits.md)"]
    bounds = state_bounds(problem, PAD)
    values = (problem.start.value, problem.target.value, problem.k)
    records, solved = [], []
    pairs = ctx.memo.get("pairs")
    if pairs is None:
        pairs = seed_pairs(problem, options)
    # The multistart's guesses, when it solved them within these bounds (at k).
    known = dict(ctx.memo.get("guesses", ()))
    # After a failed shooting, the guess it was retried from (finer, tighter).
    known.update(ctx.memo.get("finer", {}))
    coarse = None
    for idx, (qa, qb) in enumerate(pairs):
        ctx.check()
        if only is not None and idx not in only:
            records.append(StartRecord(idx, qa, qb, np.nan, np.nan, "not solved directly"))
            continue
        res = known.get(idx)
        if res is None:
            coarse = coarse or planner.direct(problem, options.guess_intervals)
            guess = initial_path(problem.model, qa, qb, options.guess_intervals,
                                 problem.torque_scale, problem.limits.plan_velocity)
            res = coarse.solve(*values, *guess, x_bounds=bounds)
        records.append(StartRecord(idx, qa, qb, res.T if res.success else np.nan, np.nan,
                                   "guess only" if res.success else
                                   f"direct method failed: {res.message}"))
        if res.success:
            solved.append((idx, res))
    timings["guess"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    # Every candidate basin on the uniform mesh (a failed one is replaced by the next); the
    # refinement, the costly part, only for those that can still be the best.
    first = []
    count = EXHAUSTIVE_CANDIDATES if options.exhaustive else options.candidates
    fallback = reason is not None
    basins = distinct_basins(solved, lambda g: g[1], problem.model.n)
    near = len(basins)
    if basins and not (options.exhaustive or fallback):
        # By increasing T: those whose guess is far slower come last, and only if
        # the near ones all fail.
        cutoff = (1 + GUESS_WINDOW) * basins[0][1].T
        near = sum(b[1].T <= cutoff for b in basins)
    # With a scene: one more candidate on a collision-free route where the seeds collide.
    extra = []
    if problem.collision is not None and not options.replan_spans:
        if fallback:  # the paths the solves start from (_uniform_item's), checked
            basins[:count] = [(i, _finer(planner, problem, g)) for i, g in basins[:count]]
        extra = _detour(ctx, pairs, basins[:count], records, notes)
    # The detour does not count among the candidates: the seeds' basins are solved as
    # without it (case 1 table of bench/collision.py: its first basin failed, the detour
    # stood alone and was refused on a self pair, the next basin was not solved).
    found, detour = 0, {idx for idx, _ in extra}
    while (found < count and basins and (near > 0 or not found)) or extra:
        # As many as are still needed, side by side (planner.map); a failed one is
        # replaced by the next basin, as one after the other would.
        size = min(count - found, near) if near > 0 else count - found
        batch, basins = basins[:size], basins[size:]
        near -= len(batch)
        items = [(bounds, res, fallback) for _, res in batch] + \
            [(bounds, guess, fallback, False) for _, guess in extra]
        batch, extra = batch + extra, []
        outs = planner.map(_uniform_item, ctx, items)
        for (idx, _), res in zip(batch, outs, strict=True):
            if not res.success:
                records[idx] = replace(records[idx], T=np.nan,
                                       status=f"bounded solve failed: {res.message}")
                continue
            records[idx] = replace(records[idx], T=res.T, status="continued")
            flat = planner.flat(problem, SPANS)
            if flat.K != len(res.P):  # a detour solved on DETOUR_SPANS
                flat = planner.flat(problem, len(res.P) - flat.degree)
            out = (res, FlatTrajectory(flat, res, problem.k), flat)
            first.append((idx, out))
            found += idx not in detour
            _offer(ctx, bounds, *out, notes)
    every, first = first, _distinct_solutions(first)
    best, raced = None, []
    if first:
        levels = 0 if options.replan_spans else REFINEMENTS  # a replan stays coarse
        raced = _race(planner, ctx, bounds, first, levels)
        for idx, res, traj, contender in raced:
            records[idx] = replace(records[idx], T=res.T)
            if contender and (best is None or res.T < best[1].T):
                best = (idx, res, traj)
    timings["shooting"] += time.perf_counter() - t0
    if best is None:
        return _infeasible(problem, _why_none(records), timings, t_start, warnings=tuple(notes),
                           starts=tuple(records))
    idx, res, traj = best
    records[idx] = replace(records[idx], status="returned")
    out = verified(ctx, res, traj, records, notes, timings, t_start)
    if out.success or problem.collision is None:
        return out
    return _next_certified(planner, ctx, bounds, out, idx, every, raced, records, notes,
                           timings, t_start)


def _detour(ctx: SolveContext, pairs: list, basins: list, records: list, notes: list
            ) -> list:
    """The detour seed (:mod:`~.detour`) as one more candidate, where the seeds' paths collide.

    The guesses of ``basins`` (the candidates solved first) are checked by the spheres
    (:func:`~.detour.path_collides`) at :data:`DETOUR_DENSITY` times their mesh points;
    when every one is clear, there is no detour. Otherwise the detour's guess is appended
    to ``records`` (its index is the next one) and its note to ``notes``.

    Returns
    -------
    list of (int, DetourGuess)
        One entry, or none.
    """
    problem = ctx.problem
    n = problem.model.n
    clear = []
    for _, res in basins:
        t = np.linspace(0.0, res.T, DETOUR_DENSITY * (len(res.t) - 1) + 1)
        q = np.column_stack([np.interp(t, res.t, res.x[:, j]) for j in range(n)])
        clear.append(not path_collides(problem.collision, q))
    if clear and all(clear):
        return []
    found = detour_guess(problem, pairs)
    ctx.check()
    notes.append(found.note)
    if found.guess is None:
        return []
    guess, idx = found.guess, len(records)
    records.append(StartRecord(idx, guess.waypoints[0], guess.waypoints[-1], guess.T, np.nan,
                               "detour seed"))
    return [(idx, guess)]


def _next_certified(planner: Compiled, ctx: SolveContext, bounds, refused: PlanResult,
                    idx: int, first: list, raced: list, records: list, notes: list,
                    timings: dict, t_start: float) -> PlanResult:
    """With a scene, after the least-``T`` motion was refused: the others, least ``T`` first.

    Each candidate solved (its last refinement where it was refined, else its
    uniform-mesh solution; those :func:`_distinct_solutions` left out as repeats too: on
    case 1 table of bench/collision.py the detour's motion, refused on a self pair, and a
    basin's 0.7 % slower one counted as one) is held inside the control set
    (:func:`_inside_set`) and certified; the first certified one is returned. At most one
    try per candidate (a count). None certified: ``refused`` (the planner's self rows then
    start from it).
    """
    problem = ctx.problem
    last = {i: (res, traj) for i, res, traj, _ in raced}
    solved = {i: last.get(i, sol[:2]) for i, sol in first if i != idx}
    records[idx] = replace(records[idx], status=f"refused: {refused.message}")
    for _, i in sorted((res.T, i) for i, (res, _) in solved.items()):
        res, traj = solved[i]
        flat = planner.flat(problem, np.array(traj.breaks))
        res, traj = _inside_set(planner, ctx, bounds, res, traj, flat)
        records[i] = replace(records[i], T=res.T, status="returned")
        note = (f"the least-T motion (T = {refused.T:.6f} s, seed {idx}) was refused by its "
                f"certificate; the next candidate, seed {i}")
        again = verified(ctx, res, traj, records, notes + [note], timings, t_start)
        if again.success:
            return again
        records[i] = replace(records[i], status=f"refused: {again.message}")
    records[idx] = replace(records[idx], status="returned")
    return replace(refused, starts=tuple(records))


def plan_limited_warm(planner: Compiled, ctx: SolveContext, warm: PathWarmState,
                      timings: dict, t_start: float, trajectory=None,
                      solved: Problem | None = None) -> PlanResult:
    """The bounded solve of ``ctx.problem`` from a previous ``"direct"`` solution.

    On its mesh, from its path, ``T`` and, where they fit this NLP (same kinds of start and
    target), multipliers (``FlatTranscription(warm="dual")``, else ``warm=True``); with
    ``ctx.options.replan_spans`` and its ``trajectory``, on that many uniform spans when its
    mesh has another number, from its path fitted there (``warm=True``). Within
    :data:`NEAR_MAX_ITER`, then held inside the control set between the samples and verified
    as :func:`plan_limited` does. A failure is reported (the caller then solves cold).

    With multipliers that fit (and ``ctx.options.warm_parametric``) the parametric step is
    tried first; with ``ctx.options.warm_follow`` and ``solved``, the problem the warm state
    solves, of the same kinds of ends, it walks from it in sub-moves
    (:func:`~.path_following.follow`: a memory's hit, 2-8 cm from its stored neighbour),
    else in one move (a replan). With ``ctx.options.warm_far`` (a memory's hit), IPOPT
    starts from the multipliers as ``FlatTranscription(warm="dual_far")`` does, whatever the
    move; the single step is tried before it only for a move from ``solved`` of at most
    :data:`~.tuning.FAR_STEP_MOVE` sub-moves (0.6 cm of a point end; the walk, with
    ``warm_follow``, for longer ones). IPOPT's certified iterates go to ``ctx.early``
    (:mod:`~.early`).
    """
    problem = ctx.problem
    t0 = time.perf_counter()
    bounds = state_bounds(problem, PAD)
    values = (problem.start.value, problem.target.value, problem.k)
    spans, P, duals, mesh = ctx.options.replan_spans, warm.P, {}, "its mesh"
    route, pad = [], SET_PAD
    if spans and trajectory is not None and len(warm.breaks) - 1 != spans:
        flat, mesh = planner.flat(problem, spans, warm=True), "a uniform mesh"
        path = trajectory.evaluate(np.linspace(0.0, warm.T, 4 * flat.K))
        P = flat.fit(warm.T, path.t, path.q, path.qd)
    else:
        flat = planner.flat(problem, warm.breaks, warm=True)  # usually kept from the refinement
        pad = set_pads.warm_row_pads(flat, warm, problem.k)  # the pads its path asks for
        if (warm.lam_g is not None and warm.lam_x is not None and len(warm.lam_g) == flat.rows
                and len(warm.lam_x) == flat.K * flat.model.n + 1):
            # A memory's hit (warm_far): IPOPT from the distant start whatever the move; a
            # move of FAR_STEP_MOVE or less tries the parametric step first (a replan, one
            # sub-move or less). From the replans' start IPOPT failed 10 of 72 hits of
            # 0.5-2 cm (150 iterations, up to 8 s) where the distant start certified 72 of
            # 72 (bench/memory_density.py, docs/memory.md "A denser memory").
            far = ctx.options.warm_far
            step_first = not far or (_same_kinds(solved, problem) and move_size(
                (solved.start.value, solved.target.value, solved.k), values) <= FAR_STEP_MOVE)
            flat = planner.flat(problem, warm.breaks, warm="dual_far" if far else "dual")
            duals = {"lam_g0": warm.lam_g, "lam_x0": warm.lam_x}
            if ctx.options.warm_parametric and (ctx.options.warm_follow or step_first):
                done, why = _parametric(ctx, flat, warm, bounds, values, timings, t_start, t0,
                                        solved, pad)
                if done is not None:
                    return done
                route = [f"{why}; solved by IPOPT instead"
                         + (f", from its multipliers with the barrier from {FAR_MU:g}"
                            if far else "") + " (route: ipopt)"]
            elif far:
                route = [f"a distant warm start (warm_far): IPOPT from its multipliers, the "
                         f"barrier from {FAR_MU:g} (route: ipopt)"]
    # Capped as a refinement is: a warm solve that crawls must not eat the multistart's time.
    if not set_pads.FALLBACK_PADS:
        pad = SET_PAD
    watch = iterate_watch(  # its certified iterates offered to ctx.early (a memory hit's)
        ctx, flat, values, bounds, pad, timings, t_start,
        f"a warm re-solve on {mesh} of {flat.spans} spans")
    out = flat.solve(*values, warm.T, P, *bounds, set_pad=pad, **_budget(ctx, NEAR_MAX_ITER),
                     **duals, watch=watch)
    ctx.check()
    if not out.success and warm.rows_added and not duals:
        # New rows that the path breaks by centimetres: from the warm barrier (and resumed
        # at RESUME_MU) IPOPT stopped at its limit on case 1 table of bench/collision.py,
        # from its default start it converged (146 iterations, certified). The same NLP,
        # its pads per sample included: only IPOPT's start differs.
        flat = planner.flat(problem, warm.breaks, warm="restart")
        out = flat.solve(*values, warm.T, P, *bounds, set_pad=pad, **_budget(ctx, NEAR_MAX_ITER))
        ctx.check()
    traj = None
    if out.success:
        out, traj = _inside_set(planner, ctx, bounds, out,
                                FlatTrajectory(flat, out, problem.k), flat, pad)
    timings["shooting"] += time.perf_counter() - t0
    if traj is None:
        return _infeasible(problem, f"the warm bounded solve failed ({out.message})",
                           timings, t_start, residual=out.residual,
                           iterations=out.iterations, intervals=flat.spans)
    notes = [f"solved as a B-spline path with hard bounds (docs/limits.md), warm from the "
             f"previous solution on {mesh} of {flat.spans} spans", *route]
    return verified(ctx, out, traj, [], notes, timings, t_start)


def _parametric(ctx: SolveContext, flat: FlatTranscription, warm: PathWarmState, bounds,
                values, timings: dict, t_start: float, t0: float,
                solved: Problem | None = None, pad: float | np.ndarray = SET_PAD
                ) -> tuple[PlanResult | None, str]:
    """The warm re-solve by the parametric step (:mod:`~.sensitivity`), certified.

    With ``options.warm_follow``, from ``solved`` (the warm state's own problem) when its
    ends are of the same kinds and shapes as ``ctx.problem``'s and the move needs 2 to
    :data:`~.path_following.MAX_MOVES` sub-moves: in sub-moves
    (:func:`~.path_following.follow`); else in one move, as before (a replan's 2 cm, or a
    move too far to walk).

    The certified result, or None and why not: the steps did not converge within their
    work budget, the torques leave the set between the samples even slowed down, or the
    certificate failed. The caller then re-solves with IPOPT.

    The steps start at ``pad``, the set's pad (one, or one per sample:
    :func:`~.set_pads.warm_row_pads`);
    a pad round widens it (:func:`_wider`).
    """
    problem = ctx.problem
    w0 = np.concatenate([np.asarray(warm.P, dtype=float).ravel(), [warm.T]])
    old = (solved.start.value, solved.target.value, solved.k) \
        if ctx.options.warm_follow and _same_kinds(solved, problem) else None
    # The first certified iterate goes to ctx.early at once (real-time iterations).
    watch = FirstIterate(ctx, flat, bounds, values, f"solved as a B-spline path with hard "
                         f"bounds (docs/limits.md), warm from the previous solution on its "
                         f"mesh of {flat.spans} spans", timings, t_start, t0) \
        if ctx.early is not None else None
    if old is not None and 1 < sub_moves(old, values) <= MAX_MOVES:
        # The walk in the request's parameters (warm_follow: a memory hit's distant start).
        step, _ = follow(flat, w0, warm.lam_g, warm.lam_x, old, values, *bounds, pad,
                         should_stop=ctx.should_stop)
        ctx.check()
    else:
        step = _steps(ctx, flat, w0, warm.lam_g, warm.lam_x, values, bounds, pad, watch)
    why = step.message
    if not step.success:  # the caller's solve time counts from t0 on
        return None, why
    traj = FlatTrajectory(flat, step, problem.k)
    excess = float(np.max(traj.set_values())) - (1.0 - SET_MARGIN)
    slower = stretched(flat, step, traj, values, bounds) if excess > 0.0 else (step, traj)
    for _ in range(PAD_ROUNDS if slower is None else 0):
        # As _inside_set does with IPOPT: the set's pad widened, the step carried there
        # from its own answer (the rows held at the old pad move with it).
        pad = _wider(pad, excess, traj, flat)
        w1 = np.concatenate([step.P.ravel(), [step.T]])
        again = _steps(ctx, flat, w1, step.lam_g, step.lam_x, values, bounds, pad, watch)
        if not again.success:
            why = f"{why}; pad {np.max(pad):.2g}: {again.message}"
            break
        step, traj = again, FlatTrajectory(flat, again, problem.k)
        excess = float(np.max(traj.set_values())) - (1.0 - SET_MARGIN)
        why = f"{why}; pad {np.max(pad):.2g}: {again.message}"
        slower = stretched(flat, step, traj, values, bounds) if excess > 0.0 \
            else (step, traj)
        if slower is not None:
            break
    if slower is None:
        return None, f"{why}, but its torques leave the set between the samples"
    step, traj = slower
    notes = [f"solved as a B-spline path with hard bounds (docs/limits.md), warm from the "
             f"previous solution on its mesh of {flat.spans} spans by the {why} (route: "
             f"parametric)"]
    elapsed = time.perf_counter() - t0
    timings["shooting"] += elapsed
    done = verified(ctx, step, traj, [], notes, timings, t_start)
    if done.success:
        return done, why
    timings["shooting"] -= elapsed
    return None, f"{why}, but not certified ({done.message})"


def _wider(pad: float | np.ndarray, excess: float, traj: FlatTrajectory,
           flat: FlatTranscription) -> float | np.ndarray:
    """The pad of a pad round after ``traj`` left the set by ``excess`` between samples.

    Per sample where ``pad`` is one per sample (:func:`~.set_pads.widened`, with
    :data:`~.set_pads.LOCAL_ROUNDS`), else all alike by twice ``excess``.
    """
    if np.ndim(pad) and set_pads.LOCAL_ROUNDS:
        return set_pads.widened(pad, traj, flat.samples, SET_MARGIN)
    return pad + 2.0 * excess


def _steps(ctx: SolveContext, flat: FlatTranscription, w0: np.ndarray, lam_g: np.ndarray,
           lam_x: np.ndarray, values, bounds, pad: float | np.ndarray,
           watch: FirstIterate | None = None) -> FlatResult:
    """The parametric steps to ``values`` from the solution ``w0`` with its multipliers.

    The whole move first (:func:`~.sensitivity.sensitivity_solve`); where its steps do not
    converge, the move followed in :data:`~.sensitivity.PATH_SUBMOVES` sub-moves from the
    same point (path-following in the parameter, its own budget of steps and
    factorisations). The result's message says what each did. ``watch`` sees every
    iterate that is not an answer (the first motion).
    """
    step, out = sensitivity_solve(flat, w0, lam_g, lam_x, *values, *bounds, pad,
                                  should_stop=ctx.should_stop, on_step=watch)
    ctx.check()
    if step.success or out.reason == "cancelled" or PATH_SUBMOVES <= 1:
        return step
    again, _ = sensitivity_solve(flat, w0, lam_g, lam_x, *values, *bounds, pad,
                                 should_stop=ctx.should_stop, submoves=PATH_SUBMOVES,
                                 max_steps=PATH_STEPS, max_solves=PATH_SOLVES,
                                 sub_budget=PATH_SUB_BUDGET, on_step=watch)
    ctx.check()
    return replace(again, message=f"{step.message}; {again.message}",
                   solve_time=step.solve_time + again.solve_time)


def _same_kinds(solved: Problem | None, problem: Problem) -> bool:
    """``solved`` is given and its ends have ``problem``'s kinds and shapes."""
    return solved is not None and all(
        a.kind == b.kind and np.shape(a.value) == np.shape(b.value)
        for a, b in ((solved.start, problem.start), (solved.target, problem.target)))


def _why_none(records: list) -> str:
    """The message of a multistart whose bounded solves all failed: what the starts tried said.

    The first start's record alone may be a guess that was never solved bounded (``"guess
    only"``: its basin was another's, or the near ones were tried first); the records of the
    starts that were solved bounded, or whose guess failed, say why.
    """
    if not records:
        return "no inverse-kinematics seed"
    told = [r.status for r in records if r.status not in ("guess only", "not solved directly")]
    if not told:
        return records[0].status
    return f"no bounded solve succeeded ({len(told)} of {len(records)} starts): {told[0]}" + (
        f"; {len(told) - 1} more" if len(told) > 1 else "")


def _infeasible(problem: Problem, why: str, timings: dict, t_start: float,
                **fields) -> PlanResult:
    """A failed bounded solve (``LIMITS_INFEASIBLE``), ``why`` in its message."""
    timings["total"] = time.perf_counter() - t_start
    return PlanResult.failure(problem, Status.LIMITS_INFEASIBLE, why, timings, method="direct",
                              **fields)


def _offer(ctx: SolveContext, bounds, res: FlatResult, traj: FlatTrajectory,
           flat: FlatTranscription, notes: list[str]) -> None:
    """Offer a bounded solution (:meth:`SolveContext.offer`) for a result at the deadline.

    Built, it is first slowed down just enough to hold its torques inside the set between
    the samples (:func:`~.checked.stretched`, no re-solve), as :func:`_inside_set` would first try.
    """
    if not res.success:
        return
    problem = ctx.problem

    def build(timings: dict, t_start: float) -> PlanResult:
        out, path = res, traj
        if float(np.max(traj.set_values())) > 1.0 - SET_MARGIN:
            values = (problem.start.value, problem.target.value, problem.k)
            out, path = stretched(flat, res, traj, values, bounds) or (res, traj)
        return verified(ctx, out, path, [], list(notes), timings, t_start)

    ctx.offer(res.T, build)


def _distinct_solutions(first: list) -> list:
    """The uniform-mesh solutions less repeats.

    Two guesses of different basins can meet in one B-spline solution (same
    ``T`` to :data:`SAME_T`, control points within
    :data:`~tocontrol_ros.core.methods.tuning.SAME_BASIN`), which would be refined twice.
    """
    out = []
    for idx, sol in first:
        res = sol[0]
        if not any(abs(res.T - o.T) <= SAME_T * o.T and np.max(np.abs(res.P - o.P)) <= SAME_BASIN
                   for _, (o, *_) in out):
            out.append((idx, sol))
    return out


def _budget(ctx: SolveContext, max_iter: int | None = None) -> dict:
    """One B-spline solve's limits: the caller's deadline and cancel, ``max_iter`` iterations."""
    return {"deadline": ctx.deadline, "should_stop": ctx.should_stop, "max_iter": max_iter}


def _uniform_item(planner: Compiled, ctx: SolveContext, bounds, guess: DirectResult,
                  fallback: bool, finer: bool = True) -> FlatResult:
    """One candidate's solve on the uniform mesh (:func:`_uniform`): its result only.

    A piece of :meth:`Compiled.map` (the caller builds the trajectory). The fallback
    of a failed shooting starts from the candidate's finer guess: the planar 8R's coarse
    guesses (T 0.260 s where the k = 1 optimum has 0.338 s) failed at k = 1 (300 iterations,
    9 s each: 50-60 s in all, at the time limit), from the finer ones 39-141 (14.7 s).
    Not with ``finer`` False (a detour seed, :mod:`~.detour`: the direct solve, which knows
    no obstacle, would take it back through them).
    """
    if not finer:
        return _detour_solve(planner, ctx, bounds, guess)
    if fallback:
        guess = _finer(planner, ctx.problem, guess)
    return _uniform(planner, ctx, bounds, guess, in_k=fallback or bool(ctx.options.replan_spans))


def _finer(planner: Compiled, problem: Problem, guess: DirectResult) -> DirectResult:
    """The fallback's guess, :func:`finer_guess` of ``guess`` (itself: on that mesh, or failed)."""
    if len(guess.t) - 1 == FINE_GUESS_INTERVALS:
        return guess
    fine = finer_guess(planner, problem, guess)
    return fine if fine.success else guess


def _detour_solve(planner: Compiled, ctx: SolveContext, bounds, guess) -> FlatResult:
    """The detour seed's solve on :data:`SPANS` uniform spans, by continuation in the rows.

    The seed keeps the margin at its samples, but its speed term (the rows' bound between
    the samples) asks up to 10 cm more mid-motion on a large joint move: from the seed
    itself the true rows stopped at 300 iterations with ``T`` rising to 7.9 s (case 3 shelf
    of bench/collision.py). So first the rows without the speed term
    (:meth:`~.flat.FlatTranscription.with_speed_term` 0) at ``k`` = 1, then at the
    problem's ``k`` warm from it, then the true rows at ``k`` warm from that: on that case 13 + 12
    iterations, then 125 (T 1.290 s). A step that fails stops; where one does, the steps
    again on :data:`DETOUR_SPANS` (the speed term halves with the spans; case 25 table:
    the true rows stopped at 300 iterations on 32 spans, T rising to 4.7 s, and converged in
    66 on 64, T 1.164 s). Returns the last solve.
    """
    problem = ctx.problem
    n = problem.model.n
    values = (problem.start.value, problem.target.value)
    steps = list(dict.fromkeys([(1.0, 0.0), (problem.k, 0.0), (problem.k, 1.0)]))
    for spans in (SPANS, DETOUR_SPANS):
        T, P = guess.T, planner.flat(problem, spans).fit(guess.T, guess.t, guess.x[:, :n],
                                                         guess.x[:, n:])
        for i, (k, scale) in enumerate(steps):
            flat = planner.flat(problem, spans, warm=i > 0).with_speed_term(scale)
            out = flat.solve(*values, k, T, P, *bounds, **_budget(ctx))
            ctx.check()
            if not out.success:
                break
            T, P = out.T, out.P
        if out.success:
            break
    return out


def _uniform(planner: Compiled, ctx: SolveContext, bounds, guess: DirectResult,
             in_k: bool = False) -> FlatResult:
    """The B-spline solve on :data:`SPANS` uniform spans from a direct guess.

    A solve that stops at its iteration limit is continued once from where it stopped,
    warm (``FlatTranscription(warm=True)``): seen on a UR5 case, 300 iterations at the
    solution's ``T`` with its residual at 1e-5, which the warm start finished. One that
    still fails is solved again by continuation in ``k`` (:func:`_continued_in_k`). With
    ``in_k`` (the fallback of a failed shooting) the continuation in ``k`` is the only
    solve (the planar 8R of bench/scaling.py, k = 4, one start: 14.5 s instead of 31 s, the
    solve at ``k = 4`` failing after 600 iterations; the planar 5R 2.0 s instead of 2.6 s).
    A replan (``replan_spans``) too: the Panda's one-start replans from rest to 9 goals
    1.3-19 cm away took 0.31-0.50 s each instead of 0.16-1.8 s, the same ``T``.
    """
    problem = ctx.problem
    n = problem.model.n
    values = (problem.start.value, problem.target.value, problem.k)
    flat = planner.flat(problem, SPANS)
    P0 = flat.fit(guess.T, guess.t, guess.x[:, :n], guess.x[:, n:])
    if in_k and problem.k > 1.0:
        return _continued_in_k(planner, ctx, bounds, guess.T, P0)
    out = flat.solve(*values, guess.T, P0, *bounds, **_budget(ctx))
    ctx.check()
    if not out.success and out.message == "Maximum_Iterations_Exceeded" \
            and np.all(np.isfinite(out.P)) and np.isfinite(out.T):
        warm = planner.flat(problem, SPANS, warm=True)
        out = warm.solve(*values, out.T, out.P, *bounds, **_budget(ctx))
        ctx.check()
    if not out.success and problem.k > 1.0:
        again = _continued_in_k(planner, ctx, bounds, guess.T, P0)
        out = again if again.success else out
    return out


def k_steps(k: float) -> list[float]:
    """Exponents of the continuation in ``k`` of :func:`_continued_in_k`: from 1 to ``k``.

    Steps of 1 up to 4, then of half the last exponent (1, 2, 3, 4, 6, 9, 13, 16 for 16).
    """
    ks = [1.0]
    while ks[-1] < k:
        ks.append(min(float(k), ks[-1] + max(1.0, float(np.floor(ks[-1] / 2)))))
    return ks


def _continued_in_k(planner: Compiled, ctx: SolveContext, bounds, T: float, P: np.ndarray
                    ) -> FlatResult:
    """The uniform-mesh solve by continuation in ``k`` from the guess ``(T, P)``.

    At ``k = 1`` from the guess, then at each of :func:`k_steps` from the last solution
    (warm). Where the solve at the requested ``k`` does not converge from the guess: the
    planar 8R (bench/scaling.py, k = 4, one start) stopped at 300 iterations twice (T
    creeping from 0.330 to 0.291 s: IPOPT regularising a Hessian that is not positive
    definite on the redundancy) after its shooting had stalled at k = 1.625; by
    continuation from the same guess, 202 + 220 + 53 + 59 iterations, T = 0.289712 s.
    A step that fails from the last solution with the barrier at
    :data:`~tocontrol_ros.core.direct.tuning.WARM_MU` is solved again from it with the barrier
    at :data:`~tocontrol_ros.core.direct.tuning.RESUME_MU` (``warm="resume"``): the paper's
    arm from a moving state (the planner node's CI run, one start) went from T 0.466 s at
    k = 1 to 0.402 s at k = 2 in 300 iterations without converging, where from 1e-5 it took
    0.05 s (T 0.424 s); the planar 8R's steps fail from 1e-5 and converge from 1e-7, so that
    order.
    Returns the last solve (a failure stops there).
    """
    problem = ctx.problem
    ends = (problem.start.value, problem.target.value)
    for i, k in enumerate(k_steps(problem.k)):  # k_steps starts with 1: never empty
        modes = (False,) if i == 0 else (True, "resume")
        for warm in modes:
            flat = planner.flat(problem, SPANS, warm=warm)
            out = flat.solve(*ends, k, T, P, *bounds, **_budget(ctx))
            ctx.check()
            if out.success:
                break
        if not out.success:
            break
        T, P = out.T, out.P
    return out


def _race(planner: Compiled, ctx: SolveContext, bounds, first: list,
          levels: int = REFINEMENTS) -> list:
    """The uniform-mesh solutions refined level by level, the hopeless ones left behind.

    All candidates within :data:`REFINE_WINDOW` of the best are refined one level at a time
    (spans halved at the junctions, at most ``levels``, until ``T`` changes by less than
    :data:`T_SETTLED`; with a scene, up to :data:`SCENE_MAX_SPANS` spans); after level ``l``
    those more than ``LEVEL_WINDOWS[l]`` above the best ``T`` so far stop there. Those kept
    are then held inside the control set between their samples (:func:`_inside_set`),
    fastest first, until the next cannot beat the best so held by more than
    :data:`INSIDE_TIE`.

    Returns
    -------
    list of (int, FlatResult, FlatTrajectory, bool)
        The seed index, last solve and trajectory of every candidate refined, and whether it
        is still a contender (within the last window, and held inside the control set), in
        the order of ``first``.
    """
    problem = ctx.problem
    cutoff = (1 + REFINE_WINDOW) * min(out[0].T for _, out in first)
    # idx -> [result, trajectory, transcription, still refining]
    race = {idx: [*out, True] for idx, out in first if out[0].T <= cutoff}
    for level in range(levels):
        level_items = []
        for entry in race.values():
            out, traj, flat, going = entry
            if not going:
                continue
            breaks = refined_breaks(traj)
            if len(breaks) == len(traj.breaks):
                entry[3] = False
                continue
            breaks = _bucketed(breaks)
            if problem.collision is not None and len(breaks) - 1 > SCENE_MAX_SPANS:
                entry[3] = False  # with clearance rows a mesh this fine costs minutes
                continue
            level_items.append((entry, breaks, traj.control_points_on(breaks)))
        # The level's solves side by side (planner.map), taken in the candidates' order.
        agains = planner.map(_refine_item, ctx, [(bounds, breaks, entry[0].T, P0)
                                                 for entry, breaks, P0 in level_items])
        for (entry, breaks, _), again in zip(level_items, agains, strict=True):
            if not again.success:  # a refinement that crawls is given up: the coarser stands
                entry[3] = False
                continue
            finer = planner.flat(problem, breaks)
            entry[:] = [again, FlatTrajectory(finer, again, problem.k), finer,
                        abs(again.T - entry[0].T) > T_SETTLED * again.T]
            _offer(ctx, bounds, *entry[:3], [])
        best = min(entry[0].T for entry in race.values())
        window = LEVEL_WINDOWS[min(level, len(LEVEL_WINDOWS) - 1)]
        for entry in race.values():
            if entry[0].T > (1 + window) * best:
                entry[3] = False
        if not any(entry[3] for entry in race.values()):
            break
    cutoff = (1 + LEVEL_WINDOWS[-1]) * min(entry[0].T for entry in race.values())
    # Held inside the set fastest first; one that cannot beat the best so held by more than
    # INSIDE_TIE is left as it is (its re-solves would be spent on a motion not returned).
    out, best = {}, np.inf
    for _, idx in sorted((entry[0].T, idx) for idx, entry in race.items()):
        entry = race[idx]
        if entry[0].T > cutoff or entry[0].T >= (1 - INSIDE_TIE) * best:
            out[idx] = (idx, entry[0], entry[1], False)
            continue
        res, traj = _inside_set(planner, ctx, bounds, *entry[:3])
        out[idx] = (idx, res, traj, True)
        best = min(best, res.T)
    return [out[idx] for idx in race]


def _refine_item(planner: Compiled, ctx: SolveContext, bounds, breaks: np.ndarray,
                 T: float, P0: np.ndarray) -> FlatResult:
    """One refinement solve of :func:`_race`, a piece of :meth:`Compiled.map`.

    On ``breaks`` from ``(T, P0)`` (the coarser path's control points on them), within
    :data:`NEAR_MAX_ITER` iterations; with a scene, first with the clearance rows of the
    samples near an obstacle only (:func:`~.active_rows.active_rows_solve`).
    """
    problem = ctx.problem
    finer = planner.flat(problem, breaks)
    values = (problem.start.value, problem.target.value, problem.k)
    again = active_rows.active_rows_solve(finer, values, T, P0, bounds,
                                          **_budget(ctx, NEAR_MAX_ITER)) \
        if active_rows.ACTIVE_ROWS else None
    ctx.check()
    if again is None:
        again = finer.solve(*values, T, P0, *bounds, **_budget(ctx, NEAR_MAX_ITER))
        ctx.check()
    return again


def _inside_set(planner: Compiled, ctx: SolveContext, bounds, out: FlatResult,
                traj: FlatTrajectory, flat: FlatTranscription,
                pad: float | np.ndarray = SET_PAD) -> tuple[FlatResult, FlatTrajectory]:
    """Widen the set's pad until the torques between the sample times stay inside the set.

    First the same path slowed down (:func:`~.checked.stretched`); if that is not enough, at most
    :data:`PAD_ROUNDS` re-solves, each from the last solution and within
    :data:`NEAR_MAX_ITER` iterations; a re-solve that fails (IPOPT's step computation, seen
    on the xArm7) is tried again with a wider pad. The wider pad makes the last solution
    infeasible at its samples: the re-solves start IPOPT's barrier at
    :data:`~tocontrol_ros.core.direct.tuning.RESUME_MU` (``warm="resume"``), not at the warm
    start's ``1e-7`` (from which all three failed on a Panda case); one that fails is tried from
    IPOPT's default start (``warm="restart"``, whose 1 % push into the bounds changes the
    short spans' torques by orders of magnitude: it crawled on Panda cases until its
    regularisation was capped,
    :data:`~tocontrol_ros.core.direct.tuning.RESTART_MAX_PERTURBATION`;
    on bench/limits.py's Panda case 29 the three resumed ones failed,
    Error_In_Step_Computation, and the plan failed its certificate before this).
    """
    problem = ctx.problem
    values = (problem.start.value, problem.target.value, problem.k)
    excess = float(np.max(traj.set_values())) - (1.0 - SET_MARGIN)
    if excess > 0.0:
        slower = stretched(flat, out, traj, values, bounds)
        if slower is not None:
            return slower
    for _ in range(PAD_ROUNDS):
        if excess <= 0.0:
            break
        pad = _wider(pad, excess, traj, flat)
        for start in ("resume", "restart"):
            again_flat = planner.flat(problem, flat.breaks, warm=start)
            again = again_flat.solve(*values, out.T, out.P, *bounds, set_pad=pad,
                                     **_budget(ctx, NEAR_MAX_ITER))
            ctx.check()
            if again.success:
                out, traj = again, FlatTrajectory(again_flat, again, problem.k)
                excess = float(np.max(traj.set_values())) - (1.0 - SET_MARGIN)
                break
    return out, traj


def _bucketed(breaks: np.ndarray) -> np.ndarray:
    """``breaks`` with the longest spans halved to a multiple of :data:`SPAN_BUCKET` spans."""
    breaks = np.asarray(breaks, dtype=float)
    while (len(breaks) - 1) % SPAN_BUCKET:
        j = int(np.argmax(np.diff(breaks)))
        breaks = np.insert(breaks, j + 1, 0.5 * (breaks[j] + breaks[j + 1]))
    return breaks
