"""The shooting mesh: RK4 error estimates, refinement, merging, and the switch mesh.

In the manner of scipy's ``solve_bvp``, each mesh change is a function from the old mesh and
its error estimates to a new mesh (:class:`Mesh`):

- :func:`interval_errors` estimates each interval's RK4 error (Richardson);
- :func:`plan_splits` decides from the estimates how to split each failing interval (pure);
  :func:`graded_split` gives the parts of an interval graded towards a switch;
- :func:`split` makes the split mesh (the new nodes integrated from the old ones);
- :func:`merge_pairs` merges neighbours that together still pass;
- :func:`switch_layout` places a node at every switch of the control law (pure).

The drivers :func:`refine` and :func:`switch_mesh` move a
:class:`~tocontrol_ros.core.indirect.run.Run` to the new mesh and solve on it by Newton.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.indirect.pmp import CanonicalSystem
from tocontrol_ros.core.indirect.run import Run, newton, trajectory
from tocontrol_ros.core.indirect.shooting import ShootingGrid, integrate, step_fractions
from tocontrol_ros.core.indirect.trajectory import Trajectory
from tocontrol_ros.core.indirect.tuning import (
    CASCADE_RATIO,
    MERGE_MARGIN,
    PLACING_TOL,
    SPLIT_PASSES,
)
from tocontrol_ros.core.methods.context import SolveContext

__all__ = ["Mesh", "find_switches", "graded_split", "interval_errors", "merge_pairs",
           "part_kinds", "plan_splits", "refine", "split", "switch_layout", "switch_mesh"]


@dataclass(frozen=True, eq=False)
class Mesh:
    """A shooting mesh under refinement, with the states at its nodes.

    Attributes
    ----------
    starts : ndarray, shape (N, 4n)
        Canonical state at the start of each interval.
    lengths : ndarray, shape (N,)
        Interval lengths in normalised time.
    kinds : ndarray of int, shape (N,)
        Step grading (0 uniform, 1 towards the interval's end, -1 towards its start).
    err : ndarray, shape (N,)
        RK4 error estimate of each interval (:func:`interval_errors`).
    node_of : ndarray of int, shape (N0 + 1,)
        Index in this mesh of each node of the mesh refinement started from (default: the
        identity, this mesh is that one).
    """

    starts: np.ndarray
    lengths: np.ndarray
    kinds: np.ndarray
    err: np.ndarray
    node_of: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.node_of is None:
            object.__setattr__(self, "node_of", np.arange(len(self.lengths) + 1))


def interval_errors(system: CanonicalSystem, starts: np.ndarray, lengths: np.ndarray,
                    steps: int, t_final: float, par: np.ndarray,
                    kinds: np.ndarray | None = None, ends: np.ndarray | None = None
                    ) -> np.ndarray:
    """RK4 error estimate per interval (Richardson: steps vs 2 * steps), max-norm of z.

    Parameters
    ----------
    system : CanonicalSystem
    starts : ndarray, shape (N, 4n)
    lengths : ndarray, shape (N,)
        Normalised lengths.
    steps : int
    t_final : float
        ``T`` (s).
    par : ndarray, shape (3,)
        :meth:`LawParams.array`.
    kinds : ndarray of int, shape (N,), optional
        Step grading (default uniform).
    ends : ndarray, shape (N, 4n), optional
        The intervals' end states with ``steps`` steps (the next nodes of a converged
        solution), so that only the doubled steps are integrated.

    Returns
    -------
    ndarray, shape (N,)
    """
    kinds = np.zeros(len(lengths), dtype=int) if kinds is None else kinds
    z_s = ends if ends is not None else integrate(
        system, starts, lengths, steps, t_final, par, False, step_fractions(kinds, steps))[0]
    z_2s = integrate(system, starts, lengths, 2 * steps, t_final, par, False,
                     step_fractions(kinds, 2 * steps))[0]
    return np.max(np.abs(z_2s - z_s), axis=1) * 16 / 15


# ----------------------------------------------------------------------- splitting
def graded_split(length: float, kind: int, err: float, tol: float, k: float) -> np.ndarray:
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


def part_kinds(kind: int, parts: int) -> list[int]:
    """Step grading of the parts of a split interval: the part at a switch keeps it."""
    out = [0] * parts
    if kind == 1:
        out[-1] = 1
    elif kind == -1:
        out[0] = -1
    return out


def plan_splits(err: np.ndarray, lengths: np.ndarray, kinds: np.ndarray, tol: float,
                k: float, room: int) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """How to split the intervals whose estimate ``err`` (N,) is above ``tol``.

    Returns
    -------
    parts : ndarray of int, shape (N,)
        Parts per interval (1: kept). Uniform intervals are split in equal parts; at most
        ``room`` new intervals in all, the worst intervals first.
    graded : dict of int to ndarray
        Part lengths of the graded intervals split by :func:`graded_split` (the others are
        split in equal parts).
    """
    bad = err > tol
    # Local RK4 error ~ h^5 where the law is smooth, lower order across switches:
    # split with a conservative exponent, at least two and at most eight parts.
    parts = np.where(bad, np.clip(np.ceil(1.2 * (err / tol) ** 0.25), 2, 8), 1).astype(int)
    graded = {j: graded_split(lengths[j], kinds[j], err[j], tol, k)
              for j in np.flatnonzero(bad & (kinds != 0))}
    for j, part_lengths in graded.items():
        parts[j] = len(part_lengths)
    if int((parts - 1).sum()) <= room:
        return parts, graded
    capped = np.ones_like(parts)  # in equal parts, the worst first, within the room
    budget = room
    for j in np.argsort(-err):
        if parts[j] > 1 and budget > 0:
            capped[j] = min(parts[j], budget + 1)
            budget -= capped[j] - 1
    return capped, {}


def _part_starts(system: CanonicalSystem, starts: np.ndarray, sub_lens: np.ndarray,
                 sub_kinds: np.ndarray, parts: np.ndarray, steps: int, t_final: float,
                 par: np.ndarray) -> np.ndarray:
    """Start states (S, max parts, 4n) of the parts of S split intervals.

    Integrated from each interval's start; NaN past each one's parts.
    """
    cur = starts.copy()
    subs = [cur.copy()]
    for p in range(1, int(parts.max())):
        active = parts > p
        cur[active] = integrate(system, cur[active], sub_lens[active, p - 1], steps, t_final,
                                par, False, step_fractions(sub_kinds[active, p - 1], steps))[0]
        subs.append(np.where(active[:, None], cur, np.nan))
    return np.stack(subs, axis=1)


def split(system: CanonicalSystem, mesh: Mesh, parts: np.ndarray,
          graded: dict[int, np.ndarray], steps: int, t_final: float, par: np.ndarray) -> Mesh:
    """The mesh with interval ``j`` split in ``parts[j]`` parts (:func:`plan_splits`).

    The new nodes are integrated from the old ones on the current solution, and the new
    intervals' errors estimated; the kept intervals keep theirs.
    """
    idx = np.flatnonzero(parts > 1)
    width = int(parts.max())
    sub_lens = np.zeros((len(idx), width))
    sub_kinds = np.zeros((len(idx), width), dtype=int)
    for r, j in enumerate(idx):
        sub_lens[r, :parts[j]] = graded.get(j, mesh.lengths[j] / parts[j])
        sub_kinds[r, :parts[j]] = part_kinds(mesh.kinds[j], parts[j])
    subs = _part_starts(system, mesh.starts[idx], sub_lens, sub_kinds, parts[idx], steps,
                        t_final, par)
    first = np.concatenate([[0], np.cumsum(parts)])  # new index of each old node
    src = np.repeat(np.arange(len(parts)), parts)  # old interval of each new one
    row = np.full(len(parts), -1)
    row[idx] = np.arange(len(idx))
    fresh = np.flatnonzero(parts[src] > 1)
    r, p = row[src[fresh]], (np.arange(first[-1]) - first[src])[fresh]
    starts, lengths = mesh.starts[src], mesh.lengths[src]
    kinds, err = mesh.kinds[src], mesh.err[src]
    starts[fresh], lengths[fresh], kinds[fresh] = subs[r, p], sub_lens[r, p], sub_kinds[r, p]
    err[fresh] = interval_errors(system, starts[fresh], lengths[fresh], steps, t_final, par,
                                 kinds[fresh])
    return Mesh(starts, lengths, kinds, err, first[mesh.node_of])


def merge_pairs(system: CanonicalSystem, mesh: Mesh, break_nodes: np.ndarray, steps: int,
                t_final: float, par: np.ndarray, tol: float
                ) -> tuple[Mesh, np.ndarray] | None:
    """Merge neighbouring uniform intervals that together still meet ``tol``.

    Splitting graded intervals at a switch leaves neighbours far finer than they need to
    be (the error of a graded interval falls only like its length to the power
    ``1 + 1/(2k - 1)``, so it is split several times). Pairs of intervals with uniform
    steps, not separated by a switch node (``break_nodes``, indices into ``mesh``'s nodes),
    are merged when the merged interval's estimate is below ``tol / MERGE_MARGIN``; greedy,
    left to right, two passes. (A split is never undone on the same solution: it was made
    because the estimate was above ``tol``.) Only pairs whose two estimates sum to less than
    that are tried.

    Returns
    -------
    (Mesh, keep) or None
        The merged mesh, and which of ``mesh``'s nodes (N + 1,) it keeps; None when nothing
        merges.
    """
    count = len(mesh.lengths)
    keep = np.ones(count + 1, dtype=bool)
    starts, lengths = mesh.starts.copy(), mesh.lengths.copy()
    kinds, err = mesh.kinds.copy(), mesh.err.copy()
    limit = tol / MERGE_MARGIN
    alive = np.arange(count + 1)  # old node index of each current node
    for _ in range(2):
        at_break = np.isin(alive, break_nodes)
        cand = np.flatnonzero((kinds[:-1] == 0) & (kinds[1:] == 0) & ~at_break[1:-1]
                              & (err[:-1] + err[1:] <= limit))
        if not len(cand):
            break
        err_pair = interval_errors(system, starts[cand], lengths[cand] + lengths[cand + 1],
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
    return Mesh(starts, lengths, kinds, err, (np.cumsum(keep) - 1)[mesh.node_of]), keep


# ------------------------------------------------------------------------ refinement
def _split_until_within(system: CanonicalSystem, mesh: Mesh, tol: float, k: float,
                        max_intervals: int, steps: int, t_final: float, par: np.ndarray
                        ) -> tuple[Mesh, str]:
    """Split ``mesh`` on the current solution until every estimate passes ``tol``.

    At most :data:`SPLIT_PASSES` passes. Returns the mesh and why it stopped short ("" if
    it did not).
    """
    for _ in range(SPLIT_PASSES):
        if not np.any(mesh.err > tol):
            break
        room = max_intervals - len(mesh.lengths)
        if room <= 0:
            return mesh, f"interval limit ({max_intervals}) reached"
        parts, graded = plan_splits(mesh.err, mesh.lengths, mesh.kinds, tol, k, room)
        mesh = split(system, mesh, parts, graded, steps, t_final, par)
    return mesh, ""


def _solve_on(ctx: SolveContext, run: Run, mesh: Mesh, newton_tol: float) -> str:
    """Move ``run`` to ``mesh`` (same ``T`` and multipliers) and solve there by Newton.

    Back to the old mesh, with the reason, when Newton does not converge.
    """
    old_grid, old_w = run.grid, run.w
    nodes, t_final, nu0, nu_t = old_grid.unpack(old_w)
    breaks = [(int(mesh.node_of[j]), i) for j, i in old_grid.breaks]
    run.grid = ShootingGrid(ctx.system, mesh.lengths, old_grid.steps, old_grid.start_kind,
                            old_grid.target_kind, kinds=mesh.kinds, breaks=breaks)
    run.w = run.grid.pack(np.vstack([mesh.starts, nodes[-1:]]), t_final, nu0, nu_t)
    rep = newton(ctx, run, run.k, run.delta, newton_tol)
    if not rep.converged:
        run.grid, run.w = old_grid, old_w
        return f"Newton did not converge on {len(mesh.lengths)} intervals ({rep.message})"
    return ""


def refine_to(ctx: SolveContext, run: Run, tol: float, newton_tol: float,
              rounds: int = 6) -> str:
    """One level of :func:`refine`: every interval's estimate below ``tol``.

    Each round splits intervals on the current solution alone (the new nodes are integrated
    from the old ones) until the estimate passes, merges where that left neighbours too
    fine, and only then runs Newton on the new mesh: one Newton solve per round, usually one
    or two rounds. Switch nodes stay switch nodes; a split interval's graded steps stay in
    the part at the switch. Returns why it stopped short ("" when the mesh passes).
    """
    par = ctx.law(run.k, run.delta).array()
    steps = run.grid.steps
    for _ in range(rounds):
        nodes, t_final, _, _ = run.grid.unpack(run.w)
        # At a converged solution the next nodes are the intervals' ends to within its
        # residual: no need to integrate them again for the estimate.
        ends = nodes[1:] if run.residual <= 1e-2 * tol else None
        lengths, kinds = run.grid.lengths_of(run.w), run.grid.kinds
        err = interval_errors(ctx.system, nodes[:-1], lengths, steps, t_final, par, kinds,
                              ends)
        mesh = Mesh(nodes[:-1], lengths, kinds, err)
        new, why = _split_until_within(ctx.system, mesh, tol, run.k, ctx.options.max_intervals,
                                       steps, t_final, par)
        if why:
            return why
        if new is mesh:
            return ""
        if not np.any(new.err > tol):
            # Merging only where this round split: a mesh that passes as it is (a warm
            # start's, the last check) is kept.
            break_nodes = new.node_of[[j for j, _ in run.grid.breaks]]
            merged = merge_pairs(ctx.system, new, break_nodes, steps, t_final, par, tol)
            if merged is not None:
                new = merged[0]
        why = _solve_on(ctx, run, new, newton_tol)
        if why:
            return why
    return f"no convergence of the mesh in {rounds} rounds"


def refine(ctx: SolveContext, run: Run, tol: float | None = None) -> str:
    """Refine the mesh until every interval's RK4 error estimate meets the tolerance.

    The tolerance (default ``options.integration_tol``, solved to ``options.tol``; a given
    ``tol`` only places the nodes) is approached in decades (1e-3, 1e-4, ... down to it):
    Newton on a coarse mesh moves the nodes most of the way cheaply, and the fine meshes,
    whose iterations cost most, start close to their solution. Returns why it stopped short
    ("" when it did not).
    """
    options = ctx.options
    final = options.integration_tol if tol is None else tol
    levels = [t for t in (1e-3, 1e-4, 1e-5) if t > 10 * final and not run.grid.B] + [final]
    for level in levels:
        last = level == final and tol is None
        newton_tol = options.tol if last else max(options.tol, PLACING_TOL)
        why = refine_to(ctx, run, level, newton_tol)
        if why:
            return f"mesh refinement to {level:g} stopped: {why}"
    if tol is None and run.residual > options.tol:
        # The mesh was already fine at the last level: its last solve used a looser tol.
        rep = newton(ctx, run, run.k, run.delta)
        if not rep.converged:
            return f"Newton did not reach tol on the final mesh ({rep.message})"
    return ""


# ---------------------------------------------------------------------- switch mesh
def find_switches(system: CanonicalSystem, traj: Trajectory) -> list[tuple[float, int]]:
    """Sign changes of the switching functions along a solution: (tau, i), in order.

    Located by linear interpolation between the RK4 step points (the trajectory's grid);
    ``tau`` is normalised time, ``i`` the joint.
    """
    t_grid = traj.t_grid
    s = system.pointwise_batch(traj.z_grid, traj.par)[2]
    t_final = t_grid[-1]
    out = []
    for i in range(s.shape[1]):
        sign = np.sign(s[:, i])
        for j in np.flatnonzero(sign[:-1] * sign[1:] < 0):
            frac = s[j, i] / (s[j, i] - s[j + 1, i])
            out.append(((t_grid[j] + frac * (t_grid[j + 1] - t_grid[j])) / t_final, i))
    return sorted(out)


def switch_layout(found: list[tuple[float, int]], intervals: int
                  ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]] | None:
    """A mesh with a node at each switch (:func:`find_switches`) and graded steps towards it.

    Switches closer than ``0.2 / intervals`` to each other or to an end are left to the
    ordinary refinement; each segment between switches gets ``intervals`` per unit of
    normalised time (at least two).

    Returns
    -------
    (lengths (N,), kinds (N,), breaks) or None
        The mesh and its switch nodes ``(node, i)``; None when no switch is kept.
    """
    gap = 0.2 / intervals
    chosen: list[tuple[float, int]] = []
    for tau, i in found:
        if gap <= tau <= 1 - gap and (not chosen or tau - chosen[-1][0] >= gap):
            chosen.append((tau, i))
    if not chosen:
        return None
    bounds = [0.0] + [tau for tau, _ in chosen] + [1.0]
    lengths, kinds, breaks = [], [], []
    for seg in range(len(bounds) - 1):
        length = bounds[seg + 1] - bounds[seg]
        count = max(2, int(np.ceil(length * intervals)))
        seg_kinds = [0] * count
        if seg > 0:
            seg_kinds[0] = -1
            breaks.append((len(lengths), chosen[seg - 1][1]))
        if seg < len(bounds) - 2:
            seg_kinds[-1] = 1
        lengths += [length / count] * count
        kinds += seg_kinds
    return np.array(lengths), np.array(kinds), breaks


def switch_mesh(ctx: SolveContext, run: Run) -> bool:
    """Move to a mesh with a node at every switch of the control law.

    Where a switching function ``S_i`` changes sign, ``u_i ~ |S_i|^(1/(2k-1))`` has an
    infinite slope and a uniform RK4 mesh converges slowly. Here each switch becomes a node
    whose time is an unknown (with ``S_i = 0`` there, see :class:`ShootingGrid`), and the
    two intervals that meet at it take RK4 steps graded towards it: the mesh follows the
    switches as Newton (or a warm start) moves them. Returns False, leaving ``run``
    unchanged, when there is no switch or Newton does not converge on the new mesh.
    """
    traj = trajectory(ctx, run)
    layout = switch_layout(find_switches(ctx.system, traj), ctx.options.intervals)
    if layout is None:
        return False
    lengths, kinds, breaks = layout
    grid = ShootingGrid(ctx.system, lengths, ctx.options.steps, run.grid.start_kind,
                        run.grid.target_kind, kinds=kinds, breaks=breaks)
    _, t_final, nu0, nu_t = run.grid.unpack(run.w)
    nodes = traj.state(grid.tau * t_final)
    saved = run.snapshot()
    run.grid, run.w = grid, grid.pack(nodes, t_final, nu0, nu_t)
    rep = newton(ctx, run, run.k, run.delta)
    if not rep.converged:
        run.restore(saved)
        return False
    return True
