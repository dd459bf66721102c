"""Recall: the nearest stored motions of a request, re-solved warm; and remembering one.

The metric is the warm start's own (:meth:`PlanResult.warm_distance
<tocontrol_ros.core.types.result.PlanResult.warm_distance>`): the largest of the end
points' moves in units of :data:`~tocontrol_ros.core.types.tuning.WARM_RADIUS` and, for
joint-state ends, the joint moves (max-norm of positions and velocities) in units of
``SolverOptions.warm_joint_radius``; only entries of the request's kinds count. So a
distance of at most 1 is what the warm start is made for, and the node's ``memory_radius``
says how far beyond (or short of) that a stored motion is still tried.

Among the entries within the radius, nearest first, one per *basin* (end configurations
more than :data:`BASIN_RADIUS` apart, max-norm, rad) is kept, up to ``basins`` of them
(several basins, as Lembono et al. 2020 found, beat any single guess); each is re-solved
warm through the method contract (:func:`~tocontrol_ros.core.planning.solver.solve_once`:
the method that owns the stored warm state continues it, and certifies the motion as any
solve of it would), and the least ``T`` among the successes is returned; with
``first_success`` the next basin is re-solved only when the one before failed (one warm
solve per hit, at the price of the nearest basin's ``T``: on the benchmark's Panda cell 8
of 37 hits were then above the multistart's ``T`` by more than 1e-3, against 3 of 37 with
two basins).

A bounded motion with a serving state (the ``serve`` blob,
:mod:`~tocontrol_ros.core.memory.serve`: its own request solved on the ``spans`` uniform
spans the hit is solved on, with the NLP's multipliers) continues it on that mesh, from the
solution and its multipliers, then (if that fails) from the solution alone. On the 37 hits
of the benchmark's cell the multipliers took a median 78 IPOPT iterations, the solution
alone 87 and the old start (the stored path fitted to the mesh) 87; the multipliers' gain is
large for some requests (18 against 64) and a loss for others (4 failures in 150), with no
distance that tells them apart. Since issue 50's measurements (docs/memory.md) the
re-solves are *distant* warm starts (``SolverOptions.warm_far``): IPOPT's barrier from
1e-5 and the start pushed as far into its bounds, not the replans' 1e-7 and 1e-3: on the
cell's 14 hits of the first 20 requests a median 41 iterations instead of 89, none failing
(3 did), and the single parametric step (which arrived on none) not tried. Without a
serving state (a file not converted, a motion the planner learnt), from its stored path
fitted to the mesh, as before; on its own mesh
(``spans`` 0), from its path and multipliers, then its path alone. Bounded by work: at most
two warm solves per basin tried.

With more than one basin to re-solve, all of them bounded motions (a real arm's; a maximum
principle's result does not cross processes), and neither ``first_success`` nor a ``first``
receiver still waiting for its motion (below), the basins' re-solves run side by side where
``options.workers`` gives more than one process (0: one per core, the planner node's
default), as the multistart's pieces do
(:meth:`~tocontrol_ros.core.planning.prepared.PreparedModel.map`: this process and the
planner's worker processes), so a hit takes about its slowest basin's time instead of their
sum; each re-solve is a deterministic function of its inputs and the results are compared in
the same order, so the answer is the one of the re-solves one after the other.

With a ``first`` receiver (the planner's ``publish: first_then_optimum``), a motion to run
while the re-solves go on to the optimum (whose answer is the same to the bit with or
without it) goes to ``first`` once. First, before any re-solve, the nearest entry's stored
motion moved onto the request's ends and timed (its method's
:meth:`~tocontrol_ros.core.methods.contract.Method.first_from`:
:mod:`~tocontrol_ros.core.direct.shifted`, tens of milliseconds, a median 12 % slower than
the optimum on the Panda's cell, docs/memory.md "A hit's first motion at once"); the
re-solves then need no receiver and go side by side as above. Where that motion is not
made or not certified, the first warm re-solve's IPOPT iterates are checked as they come
(every :data:`EARLY_EVERY`-th: the NLP's residual, the set between the samples, the
certificate; :mod:`~tocontrol_ros.core.direct.early`) and the first certified one goes to
``first``: it comes at about half of the solve's iterations, a few per cent slower than the
optimum (docs/memory.md, "A hit at its first publishable iterate").
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from tocontrol_ros.core.memory.codec import (
    CodecError,
    SampledPath,
    decode_sample,
    encode_sample,
    encode_warm,
    warm_result,
    without_multipliers,
)
from tocontrol_ros.core.memory.keys import options_hash, options_summary, robot_hash
from tocontrol_ros.core.memory.store import MemoryFileError, MotionStore, Request
from tocontrol_ros.core.methods.context import EarlyMotion, SolveContext
from tocontrol_ros.core.methods.contract import method_owning
from tocontrol_ros.core.planning.solver import solve_in
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.core.types.result import PlanResult
from tocontrol_ros.core.types.tuning import WARM_RADIUS

__all__ = ["Recall", "recall", "distances", "choose", "remember", "entry_fields", "open_memory",
           "stored_problem", "BASIN_RADIUS", "DEFAULT_BASINS", "DEFAULT_RADIUS", "DEFAULT_SPANS",
           "EARLY_EVERY", "SAMPLE_PERIOD"]

#: End configurations farther apart than this (max-norm, rad) are distinct basins: the
#: Panda's distinct optima of one request differ by tenths of a radian to radians in some
#: joint, neighbours of one basin by far less.
BASIN_RADIUS = 0.3
#: Basins re-solved per request by default: the nearest three (each costs one warm solve;
#: side by side on the planner's worker processes). On the benchmark's full cell (50 hits,
#: session 39) two basins left `T` more than 1e-3 above the default multistart's on 3
#: (cases 32, 39, 42: +2.3, +0.45, +1.8 %), three on 2 (case 32 then +0.04 %), four on 1.
DEFAULT_BASINS = 3
#: Default radius of a hit, in warm units (1 = the warm start's own radius).
DEFAULT_RADIUS = 1.0
#: Uniform B-spline spans of a bounded warm re-solve (``SolverOptions.replan_spans``): the
#: stored motions' refined meshes have 50-140 spans, each count its own transcription to
#: build (a minute for the Panda under load) and its warm re-solve from multipliers stalled
#: there; one uniform mesh is built once and re-solved from each stored path fitted to it.
#: Its T is above the refined mesh's by about 1/N^2: on three Panda requests 2-5.5e-3 at 24
#: spans, 0.5-1.5e-3 at 48; 64 aims below the issue's 1e-3.
DEFAULT_SPANS = 64
#: A hit's IPOPT iterate is checked for a first motion every this many iterations (with a
#: ``first`` receiver): the residual comes free with the iterate (the rows IPOPT evaluated),
#: the set and the certificate (10-30 ms on the Panda) only once it is within tolerance.
EARLY_EVERY = 1
#: Spacing of the stored trajectory's samples (s): the planner's default sample period.
SAMPLE_PERIOD = 0.005
#: A hit's first motion (``first``: the stored motion moved, or a certified IPOPT iterate)
#: is offered only when its ``T`` is at most this times the slowest of the stored motions
#: re-solved: on the Panda cell's 50 hits the first motions were a median 1.45 % above the
#: optimum that followed, and one 14 times above it (BENCHMARKS.md, issue 50), which a node
#: then ran first.
FIRST_MAX_RATIO = 1.5


@dataclass(frozen=True)
class Recall:
    """What a lookup and its warm re-solves gave.

    Attributes
    ----------
    hit : bool
        A stored motion was within the radius.
    distance : float
        The nearest entry's distance (warm units; ``inf`` for an empty memory or no entry
        of the request's kinds).
    result : PlanResult or None
        The best successful warm re-solve (least ``T``); None on a miss or when every one
        failed (the caller then plans cold).
    entries : tuple of int
        Ids of the entries re-solved, in the order tried.
    stored_T : tuple of float
        Their stored ``T`` (s).
    messages : tuple of str
        One per re-solve: its outcome.
    timings : dict
        ``lookup`` (s: the distances and the choice), ``decode`` (reading and decoding the
        warm states), ``solve`` (the warm re-solves, their certificates included),
        ``certificate`` (the certificates' part of it), ``total``.
    iterations : int
        IPOPT iterations of every warm re-solve together.
    starts : tuple of str
        What each warm re-solve started from: ``serve+multipliers``, ``serve``,
        ``path fit`` (a stored path fitted to the mesh), ``own mesh``, ``own path``.
    first : PlanResult or None
        The certified motion given to ``first`` before the answer (None: none, or no
        ``first`` receiver); its ``iterations`` the IPOPT iteration it came from (0: the
        stored motion moved onto the request).
    first_time : float
        Seconds from the call's start to it (nan: none).
    """

    hit: bool
    distance: float
    result: PlanResult | None = None
    entries: tuple[int, ...] = ()
    stored_T: tuple[float, ...] = ()
    messages: tuple[str, ...] = ()
    timings: dict = field(default_factory=dict)
    iterations: int = 0
    starts: tuple[str, ...] = ()
    first: PlanResult | None = None
    first_time: float = math.nan


def open_memory(path, problem: Problem, method: str = "auto", create: bool = False,
                cell: dict | None = None) -> MotionStore:
    """The memory at ``path`` for ``problem``'s robot and class (made when ``create``).

    Raises
    ------
    MemoryFileError
        See :class:`~tocontrol_ros.core.memory.store.MotionStore`.
    """
    model = problem.model
    meta = {"robot": {"name": model.name, "joints": list(model.joint_names),
                      "base_link": model.base_link, "tip_link": model.tip_link},
            "options": options_summary(problem, method)}
    if cell is not None:
        meta["cell"] = cell
    return MotionStore(path, robot_hash(model), options_hash(problem, method), create=create,
                       meta=meta)


def distances(keys: dict, problem: Problem, joint_radius: float) -> np.ndarray:
    """Each entry's distance to ``problem`` (warm units, shape (E,); ``inf``: other kinds)."""
    E = len(keys["id"])
    if E == 0:
        return np.zeros(0)
    d = np.maximum(np.linalg.norm(keys["start_point"] - problem.start_point, axis=1),
                   np.linalg.norm(keys["target_point"] - problem.target_point, axis=1)) \
        / WARM_RADIUS
    for name, end in (("start", problem.start), ("target", problem.target)):
        kinds = np.array([k == end.kind for k in keys[f"{name}_kind"]])
        d[~kinds] = np.inf
        if end.kind == "state":
            for i in np.flatnonzero(kinds):
                other = keys[name][i]
                d[i] = max(d[i], float(np.max(np.abs(other - end.value))) / joint_radius) \
                    if other.shape == end.value.shape else np.inf
    return d


def choose(keys: dict, dist: np.ndarray, radius: float, basins: int) -> list[int]:
    """Rows of ``keys`` to re-solve: nearest first, one per basin, at most ``basins``."""
    order = [int(i) for i in np.argsort(dist, kind="stable") if dist[i] <= radius]
    chosen: list[int] = []
    for i in order:
        if len(chosen) >= basins:
            break
        end = keys["end_q"][i]
        if all(np.max(np.abs(end - keys["end_q"][j])) > BASIN_RADIUS for j in chosen):
            chosen.append(i)
    return chosen


def stored_problem(problem: Problem, request: Request) -> Problem:
    """The stored request as a problem of ``problem``'s model, class and limits."""
    n = problem.model.n

    def end(kind, value):
        return point(value) if kind == "point" else joint_state(value[:n], value[n:])

    return Problem(problem.model, end(request.start_kind, request.start),
                   end(request.target_kind, request.target), k=problem.k,
                   reserve=problem.reserve, limits=problem.limits)


def recall(planner, problem: Problem, options, store: MotionStore,
           radius: float = DEFAULT_RADIUS, basins: int = DEFAULT_BASINS,
           should_stop=None, spans: int = DEFAULT_SPANS,
           first_success: bool = False, far: bool = True,
           first: Callable[[PlanResult], None] | None = None) -> Recall:
    """Look ``problem`` up in ``store`` and re-solve the chosen entries warm.

    Parameters
    ----------
    planner : Planner
        The caller's (its model is ``problem.model``).
    problem : Problem
    options : SolverOptions
        The solve's (tolerances, certificate, ``time_limit`` for all the re-solves
        together, ``warm_joint_radius`` in the metric).
    store : MotionStore
        Opened for this robot and class (:func:`open_memory`).
    radius : float
        Largest distance of a hit (warm units).
    basins : int
        Most entries re-solved (distinct basins).
    should_stop : callable, optional
    spans : int
        A bounded motion is re-solved on this many uniform spans, from its serving state
        when it has one on this mesh, else from its stored path (0: on its own mesh, from
        its path and multipliers).
    first_success : bool
        Re-solve the next basin only when the one before failed (else every one, the least
        ``T`` returned).
    far : bool
        Re-solve as a distant warm start (``SolverOptions.warm_far``: IPOPT's barrier from
        1e-5, no single parametric step); False: as a replan's (the route before).
    first : callable, optional
        ``first(result)``: called once with a certified motion before the answer: the
        nearest stored motion moved onto the request (``iterations`` 0), else from inside
        the solve the first certified IPOPT iterate of the re-solves (checked every
        :data:`EARLY_EVERY` iterations) before it converged; not slower than
        :data:`FIRST_MAX_RATIO` times the slowest stored motion chosen. The re-solves then
        go on as without it.

    Returns
    -------
    Recall

    Raises
    ------
    MemoryFileError
        The file cannot be read (the caller plans without it).
    """
    t0 = time.perf_counter()
    keys = store.keys()
    dist = distances(keys, problem, options.warm_joint_radius)
    nearest = float(dist.min()) if dist.size else math.inf
    rows = choose(keys, dist, radius, basins)
    t_lookup = time.perf_counter() - t0
    if not rows:
        return Recall(False, nearest, timings={"lookup": t_lookup, "decode": 0.0,
                                               "solve": 0.0, "certificate": 0.0,
                                               "total": t_lookup})
    deadline = t0 + options.time_limit
    warm_options = replace(options, warm_only=True, replan_spans=int(spans),
                           warm_far=bool(far))
    best, messages, starts = None, [], []
    t_decode = t_solve = t_cert = 0.0
    iterations = 0
    offered: list = []

    def offer(result: PlanResult) -> bool:
        offered.append((time.perf_counter() - t0, result))
        first(result)
        return True
    early = EarlyMotion(offer, EARLY_EVERY, max_T=FIRST_MAX_RATIO * max(
        float(keys["T"][i]) for i in rows)) if first is not None else None
    # The early receiver offers once (EarlyMotion.done), whichever re-solve comes first.
    ctx = SolveContext(planner.system, problem, warm_options, deadline, should_stop,
                       early=early)
    # Side by side where nothing depends on the order (PreparedModel.map decides whether
    # there are workers to share them with).
    side_by_side = early is None and not first_success and len(rows) > 1
    pending: list = []  # (row, entry, its starts): decoded, not yet re-solved
    solved: list = []  # (row, entry, _entry_item's out), in the rows' order
    for i in rows:
        if should_stop is not None and should_stop():
            break
        t1 = time.perf_counter()
        try:
            entry = store.get(int(keys["id"][i]))
            pending.append((i, entry, _warm_starts(problem, entry, spans)))
        except (CodecError, MemoryFileError) as exc:
            messages.append(f"entry {int(keys['id'][i])}: {exc}")
            continue
        finally:
            t_decode += time.perf_counter() - t1
        if early is not None and not solved and len(pending) == 1:
            # The nearest's stored motion moved onto the request, offered before any
            # re-solve; once offered, IPOPT's iterates are not checked and the re-solves
            # may go side by side (their receiver is gone).
            _moved_first(planner, ctx, pending[0][2], early)
            if early.done:
                ctx = replace(ctx, early=None)
                side_by_side = not first_success and len(rows) > 1
        if side_by_side:
            continue
        i, entry, tries = pending.pop()
        t2 = time.perf_counter()
        out = _entry_item(planner, ctx, tries)
        t_solve += time.perf_counter() - t2
        solved.append((i, entry, out))
        if first_success and out[0] is not None and out[0].success:
            break
    if pending:
        t2 = time.perf_counter()
        outs = None
        if all(entry.warm_kind == "path" for _, entry, _ in pending):
            # The basins' re-solves side by side (the planner's worker processes, as the
            # multistart's pieces): the hit takes the slowest one's time, not their sum;
            # each result is a deterministic function of its inputs: the same answer.
            try:
                outs = list(planner.map(_entry_item, ctx, [(t,) for _, _, t in pending]))
            except RuntimeError as exc:  # a worker's failure (a result that won't pickle)
                messages.append(f"side by side failed ({exc}): one after the other")
        if outs is None:
            # A maximum principle's motion holds CasADi expressions that do not cross
            # processes: one after the other (a bounded motion, a real arm's, goes above).
            outs = [_entry_item(planner, ctx, tries) for _, _, tries in pending]
        t_solve += time.perf_counter() - t2
        solved += [(i, entry, out) for (i, entry, _), out in zip(pending, outs, strict=True)]
    for i, entry, out in solved:
        best = _count(out, entry, dist[i], best, messages, starts)
        iterations += out[2]
        t_cert += out[3]
    total = time.perf_counter() - t0
    return Recall(True, nearest, best, tuple(int(keys["id"][i]) for i in rows),
                  tuple(float(keys["T"][i]) for i in rows), tuple(messages),
                  {"lookup": t_lookup, "decode": t_decode, "solve": t_solve,
                   "certificate": t_cert, "total": total}, iterations, tuple(starts),
                  offered[0][1] if offered else None,
                  offered[0][0] if offered else math.nan)


def _moved_first(compiled, ctx: SolveContext, tries: list, early: EarlyMotion) -> None:
    """The nearest entry's stored motion moved onto the request, offered to ``early``.

    Its method's :meth:`~tocontrol_ros.core.methods.contract.Method.first_from` (the
    bounded method's: :mod:`~tocontrol_ros.core.direct.shifted`) from the entry's first
    start; offered when certified and not slower than ``early.max_T``. Recorded in
    ``early.seen`` (``"shifted": True``, ``why``, ``error``) either way; an exception is
    recorded and the re-solves' iterates are offered as before.
    """
    warm = next((w for _, w in tries if w is not None), None)
    method = method_owning(warm.warm_state) if warm is not None else None
    if method is None:
        return
    t0 = time.perf_counter()
    seen = {"iteration": 0, "shifted": True, "T": math.nan, "certified": None, "at": t0}
    try:
        result, seen["why"] = method.first_from(compiled, ctx, warm)
        if result is not None:
            seen.update(T=float(result.T), certified=bool(result.success))
            early.give(result, seen)
    except Exception as exc:  # noqa: BLE001  (a first motion never ends the hit)
        seen["error"] = f"{type(exc).__name__}: {exc}"
    seen["seconds"] = time.perf_counter() - t0
    early.seen.append(seen)


def _entry_item(compiled, ctx: SolveContext, tries: list) -> tuple:
    """One entry's warm re-solves, its starts in order until one succeeds.

    A piece of :meth:`~tocontrol_ros.core.planning.prepared.PreparedModel.map` (maybe in a
    worker process: ``compiled`` is then the worker's prepared model). Each re-solve in a
    context of its own (:func:`~tocontrol_ros.core.planning.solver.solve_in`). Returns
    ``(result or None, the starts tried, IPOPT iterations, certificate seconds)``.
    """
    result, tried, iterations, cert = None, [], 0, 0.0
    for start, warm in tries:
        if warm is None or (result is not None and result.success) or \
                (ctx.should_stop is not None and ctx.should_stop()):
            continue
        result = solve_in(compiled, replace(ctx, memo={}), warm)
        iterations += int(result.iterations)
        cert += float(result.timings.get("verify", 0.0))
        tried.append(start)
    return result, tried, iterations, cert


def _count(out: tuple, entry, distance: float, best: PlanResult | None, messages: list,
           starts: list) -> PlanResult | None:
    """Record one entry's re-solves (:func:`_entry_item`'s ``out``); the better result."""
    result, tried = out[0], out[1]
    starts.extend(tried)
    messages.append(f"entry {entry.id} (d = {distance:.3g}, stored T = {entry.T:.6g} s, "
                    f"from {' then '.join(tried)}): "
                    + (result.message if result is not None else "not solved"))
    if result is not None and result.success and (best is None or result.T < best.T):
        return result
    return best


def _warm_starts(problem: Problem, entry, spans: int) -> list:
    """``(name, warm PlanResult or None)`` to try in order for one entry (decoded here)."""
    own = stored_problem(problem, entry.request)
    what = f"entry {entry.id}"
    if spans and entry.warm_kind == "path" and entry.serve is not None:
        warm = warm_result(own, "path", entry.serve, entry.method, f"{what} (serving state)")
        if len(warm.warm_state.breaks) - 1 == spans:
            return [("serve+multipliers", warm), ("serve", without_multipliers(warm))]
    if spans and entry.warm_kind == "path":
        path = SampledPath(decode_sample(entry.trajectory, what))
        warm = warm_result(own, entry.warm_kind, entry.warm, entry.method, what, path)
        if len(warm.warm_state.breaks) - 1 != spans:
            return [("path fit", warm)]
        return [("own mesh", warm), ("own path", without_multipliers(warm))]
    warm = warm_result(own, entry.warm_kind, entry.warm, entry.method, what)
    return [("own mesh", warm), ("own path", without_multipliers(warm))]


def entry_fields(result: PlanResult, source: str, solve_time: float,
                 sample_period: float = SAMPLE_PERIOD) -> dict | None:
    """What :meth:`MotionStore.add` stores of a certified result; None when it is not one.

    Only a success with a trajectory, a certificate that passed (or ``verify`` off: none)
    and a warm state a memory can hold is stored. Plain data (bytes, arrays), so that a
    build's worker process returns it.
    """
    problem = result.problem
    if not (result.success and result.trajectory is not None and problem is not None
            and math.isfinite(result.T)):
        return None
    if result.certificate is not None and not result.certificate.passed:
        return None
    try:
        warm_kind, warm = encode_warm(result)
    except CodecError:
        return None
    sample = result.trajectory.sample(sample_period)
    cert = {"passed": None if result.certificate is None else bool(result.certificate.passed),
            "summary": "not verified" if result.certificate is None
            else result.certificate.summary(),
            "figures": {k: v for k, v in (result.verification or {}).items()
                        if isinstance(v, (int, float, np.floating, np.integer, bool))}}
    request = Request(problem.start.kind, np.asarray(problem.start.value, float),
                      problem.target.kind, np.asarray(problem.target.value, float))
    return {"request": request, "start_point": np.asarray(problem.start_point, float),
            "target_point": np.asarray(problem.target_point, float),
            "end_q": np.asarray(sample.q[-1], dtype=float), "T": float(result.T),
            "status": result.status.name, "method": result.method, "certificate": cert,
            "warm_kind": warm_kind, "warm": warm, "trajectory": encode_sample(sample),
            "source": source, "solve_time": float(solve_time)}


def remember(store: MotionStore, result: PlanResult, source: str, solve_time: float,
             sample_period: float = SAMPLE_PERIOD) -> bool:
    """Store a certified result (:func:`entry_fields`).

    False when it is not one, or when the same request is stored with a ``T`` as low.

    Raises
    ------
    MemoryFileError
        The file cannot be written.
    """
    fields = entry_fields(result, source, solve_time, sample_period)
    if fields is None:
        return False
    request = fields.pop("request")
    return store.add(request, **fields)
