"""The multistart's direct guesses: one direct solve per seed pair.

Within the joint limits when the first guess reaches them, else without bounds, as on an arm
without limits. Without bounds a guess solves ``k = 1`` (the maximum principle's shooting
continues from there in ``k``); within the limits it solves the requested ``k``: the bounded
B-spline solve starts from these guesses at that ``k``, and the basins of ``k = 1`` are not
those of ``k = 4`` (on the Panda's 50 reference cases of BENCHMARKS.md the best basin's
``k = 1`` guess was 17 % slower than the best ``k = 1`` guess in one case, 2 % faster at
``k = 4``). Called by the maximum principle's multistart
(:mod:`tocontrol_ros.core.indirect.method`).
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.direct.collocation import initial_paths
from tocontrol_ros.core.direct.limited import state_bounds, touches
from tocontrol_ros.core.direct.tuning import PAD
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.methods.contract import Compiled
from tocontrol_ros.core.methods.seeding import distinct_basins, recombined_pairs, revolute_joints
from tocontrol_ros.core.methods.tuning import RECOMBINED_PARENTS, RECOMBINED_STARTS

__all__ = ["solve_guesses", "recombined_guesses"]


def solve_guesses(planner: Compiled, ctx: SolveContext, pairs: list
                  ) -> tuple[list, tuple[np.ndarray, np.ndarray] | None]:
    """The direct guesses from the seed pairs, within the joint limits where they bind.

    At ``k = 1`` without bounds, at the problem's ``k`` within them (see the module).

    Returns
    -------
    (guesses, x_bounds)
        ``(index, qa, qb, DirectResult)`` per pair, and the state bounds they were solved
        within (None: without bounds).
    """
    problem = ctx.problem
    # When the first guess reaches the joint limits, it and the others are solved within
    # them (at k): the bounded solve then starts from these guesses (no second round). Otherwise
    # they are solved without bounds, as on an arm without limits (bounds that never bind
    # still move IPOPT's iterates, and with them which basin a guess lands in). The first
    # is solved within the limits first: on a real arm it usually reaches them, and its
    # solve without them (110 of 180 ms of a Panda's guess) is then not needed. Whether it
    # reaches them is decided at k within the bounds (the motion the bounded solve starts
    # from), or at k = 1 without them (the motion the shooting starts from).
    bounds = state_bounds(problem, PAD) if problem.limits.active else None
    x_bounds = None
    guesses = []
    paths = _initial_paths(ctx, pairs)
    if pairs:
        ctx.check()
        path = (paths[0][0], paths[1][0], paths[2][0])
        if bounds is not None:
            within = _guess(planner, ctx, path, bounds)
            if within.success and touches(problem, within.x):
                x_bounds, res = bounds, within
            else:
                res = _guess(planner, ctx, path, None)
                if res.success and touches(problem, res.x):
                    # Within the limits it kept off them, without them it reaches them.
                    x_bounds, res = bounds, within
        else:
            res = _guess(planner, ctx, path, None)
        guesses.append((0, *pairs[0], res))
    # The others, side by side (planner.map), within the bounds the first one chose.
    rest = range(1, len(pairs))
    solved = planner.map(_guess_item, ctx, [((paths[0][i], paths[1][i], paths[2][i]), x_bounds)
                                            for i in rest])
    for idx, res in zip(rest, solved, strict=True):
        guesses.append((idx, *pairs[idx], res))
    return guesses, x_bounds


def recombined_guesses(planner: Compiled, ctx: SolveContext, guesses: list,
                       pairs: list) -> tuple[list, list]:
    """The guesses and seed pairs with those of the recombined seeds added.

    Seeds that cross the ends of the :data:`RECOMBINED_PARENTS` best distinct guesses
    (:func:`~tocontrol_ros.core.methods.seeding.recombined_pairs`), at most
    :data:`RECOMBINED_STARTS` and ``3 * options.starts // 4``, solved like the others (k = 1,
    without bounds: only after :func:`solve_guesses` solved its own without them), side by
    side; their indices follow the pairs'.

    Returns
    -------
    (guesses, pairs)
        ``(index, qa, qb, DirectResult)`` per pair, and the pairs, both extended (new lists).
    """
    problem = ctx.problem
    parents = distinct_basins([g for g in guesses if g[3].success], lambda g: g[3],
                              problem.model.n, revolute_joints(problem.model))
    more = recombined_pairs(problem, [g[3] for g in parents[:RECOMBINED_PARENTS]], pairs,
                            min(RECOMBINED_STARTS, 3 * ctx.options.starts // 4))
    if not more:
        return guesses, pairs
    paths = _initial_paths(ctx, more)
    solved = planner.map(_guess_item, ctx, [((paths[0][i], paths[1][i], paths[2][i]), None)
                                            for i in range(len(more))])
    added = [(len(pairs) + i, *more[i], res) for i, res in enumerate(solved)]
    return guesses + added, pairs + more


def _initial_paths(ctx: SolveContext, pairs: list) -> tuple:
    """:func:`initial_paths` of the seed pairs (their direct solves' starting paths)."""
    problem = ctx.problem
    return initial_paths(problem.model, np.array([p[0] for p in pairs]),
                         np.array([p[1] for p in pairs]), ctx.options.guess_intervals,
                         problem.torque_scale, problem.limits.plan_velocity)


def _guess_item(planner: Compiled, ctx: SolveContext, path: tuple,
                x_bounds: tuple[np.ndarray, np.ndarray] | None):
    """One seed pair's direct guess (:func:`_guess`) after the deadline's check.

    A piece of :meth:`~tocontrol_ros.core.direct.limited.Compiled.map`.
    """
    ctx.check()
    return _guess(planner, ctx, path, x_bounds)


def _guess(planner: Compiled, ctx: SolveContext, path: tuple,
           x_bounds: tuple[np.ndarray, np.ndarray] | None):
    """The direct solve from an initial ``path``, within ``x_bounds`` (None: without).

    At the problem's ``k`` within bounds, at ``k = 1`` without (see the module).
    ``path``: the states, controls and ``T`` of :func:`initial_paths` for one seed pair.
    """
    problem, options = ctx.problem, ctx.options
    direct = planner.direct(problem, options.guess_intervals, tol=options.guess_tol)
    k = 1.0 if x_bounds is None else problem.k
    return direct.solve(problem.start.value, problem.target.value, k, *path,
                        x_bounds=x_bounds)
