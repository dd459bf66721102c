"""Continuation of the maximum principle's solution: in ``k``, then in the smoothing ``delta``.

From the direct guess (k = 1) the boundary-value problem is solved by multiple shooting and
continued in ``k`` (doubling up to the requested value, bisecting a step that fails) at an
intermediate smoothing; when that stalls, again from k = 1 at a wide smoothing
(:data:`WIDE_DELTA`). At the requested ``k`` the smoothing ``delta`` is driven down until
``T`` no longer changes, the mesh refined, and the next smaller ``delta`` confirmed on the
refined mesh. These are the stages 2-4 of :mod:`tocontrol_ros.core.planning.solver`, which
sequences them (it hands :func:`final_smoothing` the callback that offers each converged
solution to the caller's deadline).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.sparse.linalg import splu

from tocontrol_ros.core.direct.collocation import (
    DirectResult,
)
from tocontrol_ros.core.indirect.mesh import refine, switch_mesh
from tocontrol_ros.core.indirect.newton import NewtonReport
from tocontrol_ros.core.indirect.run import Run, newton
from tocontrol_ros.core.indirect.shooting import ShootingGrid
from tocontrol_ros.core.indirect.tuning import (
    CONTINUATION_STEPS,
    CONTINUATION_TOL,
    DELTA_FACTOR,
    EASY_K_NEWTON,
    EASY_NEWTON,
    MIN_DELTA_RATIO,
    PLACEMENT_TOL,
    SMOOTHING_BISECT_RATIO,
    STALL_REFINE_TOL,
    TANGENT_DIFFERENCE,
    WIDE_DELTA,
)
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.types.result import PlanResult, Status


def _nodes_from_direct(direct: DirectResult, tau_nodes: np.ndarray) -> np.ndarray:
    """The direct solution's states and costates interpolated at normalised times (N+1,)."""
    tau_d = direct.t / direct.T
    z = np.hstack([direct.x, direct.psi])
    return np.stack([np.interp(tau_nodes, tau_d, z[:, i]) for i in range(z.shape[1])], axis=1)


def solve_from_guess(ctx: SolveContext, direct: DirectResult) -> tuple[Run, Status, str]:
    """Shooting at k = 1 from a direct solution, then continuation in k.

    When Newton does not converge on ``options.intervals`` intervals, it is tried once more
    on twice as many (the direct solution interpolated anew): where the guess's costates are
    rough, shorter intervals keep the initial residual small enough for Newton.
    """
    run, rep = _shoot(ctx, direct, 1.0, 0.0, max(ctx.options.tol, CONTINUATION_TOL))
    if not rep.converged:
        return run, Status.NEWTON_FAILED, f"at k = 1 from the guess: {rep.message}"
    if not _continue_k(ctx, run):
        return run, Status.CONTINUATION_FAILED, f"stalled at k = {run.k:g}"
    return run, Status.SUCCESS, ""


def solve_at_k(ctx: SolveContext, direct: DirectResult) -> tuple[Run, Status, str]:
    """Shooting at the requested k from a direct solution at that k: no continuation in k.

    For a basin whose continuation from k = 1 failed (:func:`solve_from_guess`): the
    direct method went to the requested k instead, and its multipliers give the costates
    there. Newton solves at ``options.smoothing_intermediate``, where the continuation in k
    would have arrived, to its placement tolerance; :func:`final_smoothing` follows.
    """
    options = ctx.options
    loose = max(options.tol, PLACEMENT_TOL if options.switch_nodes else CONTINUATION_TOL)
    run, rep = _shoot(ctx, direct, ctx.problem.k, options.smoothing_intermediate, loose)
    if not rep.converged:
        return run, Status.NEWTON_FAILED, f"at k = {ctx.problem.k:g} from the direct " \
            f"solution at k: {rep.message}"
    return run, Status.SUCCESS, ""


def _shoot(ctx: SolveContext, direct: DirectResult, k: float, delta: float, tol: float
           ) -> tuple[Run, NewtonReport]:
    """Newton on a uniform shooting mesh from a direct solution at ``(k, delta)``.

    On ``options.intervals`` intervals, then (when Newton does not converge) on twice as
    many, the direct solution interpolated anew. Returns the run (at the solution when the
    last report converged) and the last Newton report.
    """
    problem, options = ctx.problem, ctx.options
    # The switch mesh (options.steps per interval) takes over after the continuation.
    steps = min(options.steps, CONTINUATION_STEPS) if problem.k > 1 and options.switch_nodes \
        else options.steps
    for count in (options.intervals, 2 * options.intervals):
        lengths = np.full(count, 1.0 / count)
        grid = ShootingGrid(ctx.system, lengths, steps, problem.start.kind,
                            problem.target.kind)
        nodes = _nodes_from_direct(direct, grid.tau)
        run = Run(grid=grid, w=grid.pack(nodes, direct.T), k=k, delta=delta)
        rep = newton(ctx, run, k, delta, tol)
        if rep.converged:
            break
    return run, rep


def _k_schedule(k: float) -> list[float]:
    """1, 2, 4, ... below ``k``, then ``k``."""
    ks = [1.0]
    while ks[-1] * 2 < k:
        ks.append(ks[-1] * 2)
    if k > 1:
        ks.append(float(k))
    return ks


def _continue_k(ctx: SolveContext, run: Run) -> bool:
    """Continue a converged k = 1 solution to the requested k.

    First at ``options.smoothing_intermediate`` (:func:`_continue_in_k`); when that stalls,
    again from the k = 1 solution along the smoothed path of :func:`_continue_smoothed`.
    """
    start = run.snapshot()
    if _continue_in_k(ctx, run, ctx.options.smoothing_intermediate, stall_refine=True):
        return True
    stalled = run.snapshot()
    run.restore(start)
    if _continue_smoothed(ctx, run):
        return True
    run.restore(stalled)  # report where the first path stalled
    return False


def _continue_in_k(ctx: SolveContext, run: Run, delta: float, stall_refine: bool) -> bool:
    """Continue in k at a fixed smoothing ``delta``.

    Towards 2, 4, ... then the requested k; a failed step is halved, and the next step after
    a success is doubled only when that one converged easily (:data:`EASY_K_NEWTON`).
    With ``stall_refine``, a stall (a step below ``options.min_k_step``) refines the mesh
    and goes on; a second stall at the same k ends the continuation (False, the run where
    it stalled).
    """
    options = ctx.options
    targets = _k_schedule(ctx.problem.k)[1:]
    refined_at = None
    for k_goal in targets:
        last = k_goal == targets[-1] and options.switch_nodes
        loose = max(options.tol, PLACEMENT_TOL if last else CONTINUATION_TOL)
        step = k_goal - run.k
        while run.k < k_goal:
            k_try = min(run.k + step, k_goal)
            rep = newton(ctx, run, k_try, delta, loose)
            if rep.converged:
                if rep.iterations <= EASY_K_NEWTON:
                    step *= 2.0
                continue
            step *= 0.5
            if step < options.min_k_step:
                # The mesh may be too coarse for the steeper law: refine it at the
                # current k, once per stall, and go on from the step that failed (a
                # restart from the full step after each refinement cost the planar 8R
                # tens of seconds of failing Newton solves on 65 intervals).
                if not stall_refine or refined_at == run.k:
                    return False
                refined_at = run.k
                saved = run.snapshot()
                if refine(ctx, run, tol=max(options.integration_tol, STALL_REFINE_TOL)):
                    run.restore(saved)
                    return False
                step *= 2.0
    return True


def _continue_smoothed(ctx: SolveContext, run: Run) -> bool:
    """The other path to the requested k: in k at a wide smoothing, then delta down.

    Why the path at a small delta stalls (planar 5R and 8R): where a switching function
    crosses zero inside an RK4 step, the law's transition (``|S_i| < delta |S|``) is far
    shorter than the step, so the discrete equations are nearly discontinuous there and
    Newton stops at that cliff however short the step in k. At :data:`WIDE_DELTA` the
    transition spans several steps and the continuation in k goes through; then, at the
    requested k, delta comes down on the same mesh, by :data:`DELTA_FACTOR` at first, each
    step from the tangent's prediction (:func:`_predicted`), its ratio adapted to how easily
    Newton converged (:data:`EASY_NEWTON`) and bisected geometrically when Newton fails,
    down to ``options.smoothing_intermediate``, where the usual final smoothing (and its
    switch mesh) takes over.

    No switch mesh on the way down: from a wide delta to a small one the switches of a
    redundant arm appear, merge and vanish, and a node pinned to ``S_i = 0`` cannot follow
    (planar 8R: the steps on a switch mesh failed from delta = 0.15 down to 0.07, where
    the same steps on the continuation's uniform mesh converge in 5 to 10 iterations).
    """
    options = ctx.options
    target = options.smoothing_intermediate
    if target >= WIDE_DELTA or not _continue_in_k(ctx, run, WIDE_DELTA, stall_refine=False):
        return False
    k, delta = ctx.problem.k, WIDE_DELTA
    log_step = float(np.log(DELTA_FACTOR))
    while delta > target:
        d_try = max(delta * float(np.exp(-log_step)), target)
        before = run.w
        run.w = _predicted(ctx, run, d_try)
        rep = newton(ctx, run, k, d_try, CONTINUATION_TOL)
        if rep.converged:
            delta = d_try
            if rep.iterations <= EASY_NEWTON:
                log_step *= 1.5
            elif rep.iterations > 2 * EASY_NEWTON:
                log_step /= 1.5
            continue
        run.w = before
        log_step = 0.5 * float(np.log(delta / d_try))
        if log_step < np.log(MIN_DELTA_RATIO):
            return False
    return True


def _predicted(ctx: SolveContext, run: Run, delta: float) -> np.ndarray:
    """The run's unknowns moved along the tangent of its solution path to ``delta``.

    First order in ``log delta``: ``dw = -J^-1 dG/dlog(delta)``, the derivative of the
    equations by central differences. Along the smoothing path of a redundant arm the
    solution moves far per step (planar 8R: ``T`` by 2 % from delta = 0.1 to 0.09), and from
    the previous solution Newton fails where from this prediction it converges. The
    Jacobian's factors are kept for Newton's first (chord) steps. The unknowns unchanged
    when the Jacobian is singular.
    """
    grid, values = run.grid, ctx.problem.boundary_values
    par = ctx.law(run.k, run.delta).array()
    _, jac = grid.residual(run.w, values, par)
    try:
        lu = splu(jac)
    except RuntimeError:
        return run.w
    run.factors = (grid, lu)
    rel = TANGENT_DIFFERENCE
    up = ctx.law(run.k, run.delta * np.exp(rel)).array()
    down = ctx.law(run.k, run.delta * np.exp(-rel)).array()
    slope = (grid.residual(run.w, values, up, jacobian=False)[0]
             - grid.residual(run.w, values, down, jacobian=False)[0]) / (2 * rel)
    dw = -lu.solve(slope) * float(np.log(delta / run.delta))
    if not np.all(np.isfinite(dw)) or grid.admissible_step(run.w, dw) < 1.0:
        return run.w
    return run.w + dw


# --------------------------------------------------------------------- smoothing
def final_smoothing(ctx: SolveContext, run: Run,
                    offer: Callable[[SolveContext, tuple], None]) -> list[str]:
    """Drive delta down at the requested k until T stops changing; refine the mesh.

    ``offer(ctx, snap)`` is called after each converged delta with the run's
    :meth:`~Run.snapshot` (the orchestration offers the solution to the caller's deadline,
    :meth:`SolveContext.offer`). Returns the warnings (a
    smoothing kept above the schedule's end, a refinement that stopped short).
    """
    problem, options = ctx.problem, ctx.options
    notes = []
    if problem.k == 1.0:
        if run.delta != 0.0:
            newton(ctx, run, 1.0, 0.0)
        why = refine(ctx, run)
        if why:
            notes.append(why)
        return notes
    t_prev = None
    changes: list[float] = []  # |change of T| from one delta to the next
    converged = []  # snapshots after each delta, to fall back to a smoother law
    switched = options.switch_nodes and switch_mesh(ctx, run)
    for delta in options.smoothing:
        saved = run.snapshot()
        if delta == run.delta and run.k == problem.k and run.residual <= options.tol:
            rep = NewtonReport(True, run.w, run.residual, 0, "converged")  # solved already
        else:
            rep = newton(ctx, run, problem.k, delta)
        if not rep.converged:
            # A coarse mesh may not resolve the steeper law: refine, then try again.
            run.restore(saved)
            if refine(ctx, run):
                run.restore(saved)
            t_prev = run.t_final
            why = _smoothing_step(run, delta, lambda d: _newton_at(ctx, run, d))
            if why:
                notes.append(f"smoothing kept at delta = {run.delta:g}: Newton did not "
                             f"converge at delta = {delta:g} ({why})")
                break
        if delta == options.smoothing[0] and not switched:
            # Resolve the switches to the final tolerance while the law is still smooth:
            # the smaller deltas then only move a fine-mesh solution a little. (Refining
            # after delta is small can stall Newton: where a stage point lands near a
            # switch the law's slope is ~delta^(-(2k-2)/(2k-1)), and the linear model
            # holds only in a tiny neighbourhood.)
            saved = run.snapshot()
            if refine(ctx, run):
                run.restore(saved)
        converged.append(run.snapshot())
        offer(ctx, converged[-1])
        t_now = run.t_final
        if t_prev is not None:
            changes.append(abs(t_now - t_prev))
            if changes[-1] <= options.smoothing_tol * t_now:
                break
            if switched and _settled(changes, options.smoothing_tol * t_now):
                break  # the next delta is tried on the refined mesh (_confirm_smoothing)
        t_prev = t_now
    why = refine(ctx, run)
    if not why and switched:
        # The smoothing loop above ran on the coarse switch mesh: confirm on the refined
        # mesh that the next smaller delta no longer changes T (else keep going down).
        notes += _confirm_smoothing(ctx, run)
    if not why:
        return notes
    # Near-singular derivatives of the law at a small delta can stall Newton on the refined
    # mesh: fall back to the previous, smoother deltas (T changed by little between them).
    failed_delta = run.delta
    for snap in reversed(converged[:-1]):
        run.restore(snap)
        if not refine(ctx, run):
            # Go down again on the refined mesh, through intermediate deltas where needed.
            more = _confirm_smoothing(ctx, run)
            if run.delta > failed_delta:
                notes.append(f"smoothing kept at delta = {run.delta:g}: mesh refinement at "
                             f"delta = {failed_delta:g} failed ({why})")
            return notes + more
    if converged:
        run.restore(converged[-1])
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


def _newton_at(ctx: SolveContext, run: Run, delta: float) -> str:
    """Newton at the requested k and ``delta``: "" when it converged, else why not."""
    rep = newton(ctx, run, ctx.problem.k, delta)
    return "" if rep.converged else rep.message


def _newton_refine_at(ctx: SolveContext, run: Run, delta: float) -> str:
    """Newton at ``delta``, then the mesh refinement: "" when both worked, else why not."""
    saved = run.snapshot()
    rep = newton(ctx, run, ctx.problem.k, delta)
    if not rep.converged:
        return f"Newton did not converge at delta = {delta:g} on the final mesh ({rep.message})"
    why = refine(ctx, run)
    if why:
        run.restore(saved)
        return f"{why} at delta = {delta:g}"
    return ""


def _smoothing_step(run: Run, delta: float, step: Callable[[float], str]) -> str:
    """Move ``run`` to ``delta`` by ``step``, through intermediate deltas when it fails.

    A decade of delta can be too long a step where the law is nearly singular (a switching
    function that nearly touches zero becomes two switches, or none, as delta shrinks): a
    failed step is retried through the geometric mean of the two deltas while they are more
    than :data:`SMOOTHING_BISECT_RATIO` apart. ``step(d)`` solves at ``d`` from the run and
    returns "" on success (the run at ``d``), else why not (the run unchanged). Returns ""
    when ``run`` reached ``delta``; else why not, with ``run`` at the smallest delta reached.
    """
    saved = run.snapshot()
    why = step(delta)
    if not why:
        return ""
    run.restore(saved)
    if not (delta > 0 and run.delta > SMOOTHING_BISECT_RATIO * delta):
        return why
    mid = float(np.sqrt(run.delta * delta))
    if _smoothing_step(run, mid, step):
        return why
    return _smoothing_step(run, delta, step)


def _confirm_smoothing(ctx: SolveContext, run: Run) -> list[str]:
    """Decrease delta on the final mesh until ``T`` changes by less than smoothing_tol."""
    options = ctx.options
    smaller = [d for d in options.smoothing if d < run.delta]
    for delta in smaller:
        t_prev = run.t_final
        why = _smoothing_step(run, delta, lambda d: _newton_refine_at(ctx, run, d))
        if why:
            return [f"smoothing kept at delta = {run.delta:g}: {why}"]
        t_now = run.t_final
        if abs(t_now - t_prev) <= options.smoothing_tol * t_now:
            break
    return []


# --------------------------------------------------------------------- warm start
# -------------------------------------------------------------------- warm start
def warm_run(ctx: SolveContext, warm: PlanResult) -> tuple[Run | None, bool]:
    """Continue a previous solution to a new problem.

    Returns
    -------
    (run, finished) or (None, False)
        ``finished`` when the previous exponent and smoothing were kept, so only the mesh
        check remains; None when it does not converge.
    """
    problem, options = ctx.problem, ctx.options
    if not warm.can_warm_start(problem, options.warm_joint_radius):
        return None, False
    st = warm.warm_state
    grid = st.grid(ctx.system, problem.start.kind, problem.target.kind)
    run = Run(grid=grid, w=st.w.copy(), k=warm.k, delta=warm.delta, factors=(grid, st.factors))
    if warm.k == problem.k:
        # At the warm start's smoothing, or the coarser one the options end at (a replan
        # smoothed for speed continues a finer solution there).
        delta = max(warm.delta, options.smoothing[-1])
        rep = newton(ctx, run, warm.k, delta)
        if rep.converged:
            return run, True
        # At a small delta the law is nearly singular and a moved problem can stall Newton:
        # restart the smoothing schedule from the previous solution instead.
        run = Run(grid=grid, w=st.w.copy(), k=warm.k, delta=warm.delta)
        rep = newton(ctx, run, warm.k, options.smoothing[0])
        if rep.converged:
            return run, False
        # A switch appeared or vanished: the switch nodes hold the old structure. The warm
        # motion sampled on a uniform mesh, at the first smoothing; the schedule (which
        # finds the new switches) follows. On a stream of replans of the paper's arm at
        # k = 4 (goals 1.9 cm apart, each warm from the last) 46 of 49 warm solves then
        # converge instead of 36, none in a worse basin than the multistart's. (The nodes
        # are interpolated between the warm mesh's: a tail's trajectory is its motion's.)
        uniform = ShootingGrid(ctx.system, np.full(options.intervals, 1.0 / options.intervals),
                               options.steps, problem.start.kind, problem.target.kind)
        old, t_final, nu0, nu_t = grid.unpack(st.w)
        tau = grid.tau_of(st.w)
        nodes = np.column_stack([np.interp(uniform.tau, tau, col) for col in old.T])
        run = Run(grid=uniform, w=uniform.pack(nodes, t_final, nu0, nu_t), k=warm.k,
                  delta=options.smoothing[0])
        rep = newton(ctx, run, warm.k, options.smoothing[0])
        return (run, False) if rep.converged else (None, False)
    # Another exponent: move the boundary values at the old k (intermediate smoothing),
    # then step k directly; the final smoothing schedule follows in the caller.
    for k in (warm.k, problem.k):
        rep = newton(ctx, run, k, max(warm.delta, options.smoothing_intermediate))
        if not rep.converged:
            return None, False
    return run, False


def finish_warm(ctx: SolveContext, run: Run,
                offer: Callable[[SolveContext, tuple], None]) -> list[str]:
    """Check the mesh of a warm solution that kept its exponent and smoothing.

    When it does not refine cleanly, the full smoothing schedule runs instead (``offer``:
    as for :func:`final_smoothing`). Returns the warnings.
    """
    saved = run.snapshot()
    why = refine(ctx, run)
    if not why and run.residual <= ctx.options.tol:
        return []
    run.restore(saved)
    rep = newton(ctx, run, run.k, ctx.options.smoothing[0])
    if rep.converged:
        return final_smoothing(ctx, run, offer)
    run.restore(saved)
    return [why or "the warm solution did not reach tol"]
