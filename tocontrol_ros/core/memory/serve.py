"""Stored motions on the serving mesh, with their multipliers: what a hit continues.

A build stores each motion as its wide search found it: on the refined mesh of its own
request (50-140 spans for the Panda, each count a transcription of its own). A hit is
re-solved on ``memory_spans`` uniform spans (one transcription for every stored motion),
and a stored motion on another mesh can only start that solve from its path fitted there,
without multipliers: IPOPT starts almost cold. :func:`serving_state` re-solves the stored
motion's *own* request once on the serving mesh, warm from its path, and keeps that
solution and its NLP multipliers (``PathWarmState(breaks, P, T, lam_g, lam_x)``) as the
entry's ``serve`` blob; a hit then starts on the same mesh from a solution of that mesh
(``recall`` chooses the multipliers or the path alone by the request's distance).

:func:`convert` does it for every entry that has none (the ``memory upgrade`` verb, and the
build after each motion): one warm solve per motion through the method contract
(:func:`~tocontrol_ros.core.planning.solver.solve_once`), each committed at once, so an
interrupted conversion run again goes on where it stopped. An entry whose conversion fails
keeps no serving state and is served from its path as before (counted, with the reason).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.memory.codec import (
    CodecError,
    SampledPath,
    decode_sample,
    decode_warm,
    encode_warm,
    warm_result,
)
from tocontrol_ros.core.memory.recall import DEFAULT_SPANS, stored_problem
from tocontrol_ros.core.memory.store import MotionStore, StoredMotion
from tocontrol_ros.core.planning.solver import solve_once
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult

__all__ = ["serving_state", "serve_result", "serve_spans", "convert", "Conversion"]


@dataclass(frozen=True)
class Conversion:
    """What :func:`convert` did.

    Attributes
    ----------
    converted, failed, skipped : int
        Entries given a serving state; whose warm solve failed (kept without one); already
        on this mesh or of a kind without one (the maximum principle's shooting states).
    iterations : tuple of int
        IPOPT iterations of each conversion that succeeded.
    T_change : tuple of float
        Each converted motion's ``T`` on the serving mesh relative to its stored ``T``
        (``T_serve / T - 1``: about 1/spans^2 above the refined mesh's optimum).
    messages : tuple of str
        One per failure: the entry and why.
    seconds : float
        Wall time of the conversion (s).
    """

    converted: int = 0
    failed: int = 0
    skipped: int = 0
    iterations: tuple[int, ...] = ()
    T_change: tuple[float, ...] = ()
    messages: tuple[str, ...] = ()
    seconds: float = 0.0


def serve_spans(serve: bytes | None) -> int:
    """Spans of a serving state's mesh (0 for None or a blob that does not decode)."""
    if serve is None:
        return 0
    try:
        state, _ = decode_warm("path", serve, "serving state")
    except CodecError:
        return 0
    return len(state.breaks) - 1 if isinstance(state, PathWarmState) else 0


def serving_state(planner, problem: Problem, entry: StoredMotion, options,
                  spans: int = DEFAULT_SPANS) -> tuple[PlanResult, bytes | None]:
    """The stored motion re-solved on ``spans`` uniform spans; ``(result, blob or None)``.

    Parameters
    ----------
    planner : Planner
        Of ``problem.model``.
    problem : Problem
        Any problem of the memory's robot and class (its model, ``k``, ``reserve`` and
        limits rebuild the entry's own request).
    entry : StoredMotion
        A motion of the bounded solve (``warm_kind`` ``path``).
    options : SolverOptions
        Tolerances and certificate (``time_limit`` bounds the solve).
    spans : int
        The serving mesh (the node's ``memory_spans``).

    Returns
    -------
    PlanResult, bytes or None
        The warm solve of the entry's request on the serving mesh, and its warm state
        (:func:`~tocontrol_ros.core.memory.codec.encode_warm`, with the multipliers) when it
        succeeded and its certificate passed; None otherwise (``result.message`` says why).

    Raises
    ------
    CodecError
        The entry's blobs do not decode.
    """
    own = stored_problem(problem, entry.request)
    path = SampledPath(decode_sample(entry.trajectory, f"entry {entry.id}"))
    warm = warm_result(own, entry.warm_kind, entry.warm, entry.method, f"entry {entry.id}",
                       path)
    return serve_result(planner, warm, options, spans)


def serve_result(planner, result: PlanResult, options,
                 spans: int = DEFAULT_SPANS) -> tuple[PlanResult, bytes | None]:
    """A bounded ``result`` re-solved on ``spans`` uniform spans: ``(result, blob or None)``.

    The warm solve of ``result.problem`` from ``result`` (its warm state and trajectory: a
    fresh solve's, or a stored one's from :func:`~tocontrol_ros.core.memory.codec.warm_result`
    with its :class:`~tocontrol_ros.core.memory.codec.SampledPath`) on the serving mesh, and
    that solution's warm state as a blob when it succeeded and its certificate passed (see
    :func:`serving_state`).
    """
    warm_options = replace(options, warm_only=True, replan_spans=int(spans))
    out = solve_once(planner, result.problem, warm_options, result, None,
                     time.perf_counter() + options.time_limit)
    state = out.warm_state
    if not (out.success and isinstance(state, PathWarmState)
            and len(state.breaks) - 1 == spans and state.lam_g is not None
            and (out.certificate is None or out.certificate.passed)):
        return out, None
    return out, encode_warm(out)[1]


def convert(store: MotionStore, planner, problem: Problem, options,
            spans: int = DEFAULT_SPANS, limit: int | None = None,
            progress: Callable[[int, int, str], None] | None = None) -> Conversion:
    """Give every bounded entry of ``store`` without one a serving state on ``spans``.

    Parameters
    ----------
    store : MotionStore
        Opened for ``problem``'s robot and class.
    planner, problem, options, spans
        As :func:`serving_state`.
    limit : int, optional
        Convert at most this many (the rest stays for a later run).
    progress : callable (done, total, line) -> None, optional
        Called after each entry.

    Returns
    -------
    Conversion

    Raises
    ------
    MemoryFileError
        The file cannot be read or written.
    """
    t0 = time.perf_counter()
    keys = store.keys()
    todo, skipped = [], 0
    for i, entry_id in enumerate(keys["id"]):
        if not keys["serve"][i]:
            todo.append(int(entry_id))
        elif serve_spans(store.get(int(entry_id)).serve) == spans:
            skipped += 1
        else:  # another mesh: converted again
            todo.append(int(entry_id))
    if limit is not None:
        todo = todo[:max(int(limit), 0)]
    converted, failed, iterations, changes, messages = 0, 0, [], [], []
    for done, entry_id in enumerate(todo, start=1):
        entry = store.get(entry_id)
        if entry.warm_kind != "path":
            skipped += 1
            line = f"entry {entry_id}: {entry.warm_kind} state, none needed"
        else:
            try:
                result, blob = serving_state(planner, problem, entry, options, spans)
            except CodecError as exc:
                result, blob = None, None
                line = f"entry {entry_id}: {exc}"
            if blob is not None:
                store.set_serve(entry_id, blob)
                converted += 1
                iterations.append(int(result.iterations))
                changes.append(result.T / entry.T - 1.0 if entry.T > 0 else math.nan)
                line = (f"entry {entry_id}: T {entry.T:.6g} -> {result.T:.6g} s on {spans} "
                        f"spans, {result.iterations} iterations")
            else:
                store.set_serve(entry_id, None)
                failed += 1
                if result is not None:
                    line = f"entry {entry_id}: not converted ({result.message})"
                messages.append(line)
        if progress is not None:
            progress(done, len(todo), line)
    return Conversion(converted, failed, skipped, tuple(iterations), tuple(changes),
                      tuple(messages), time.perf_counter() - t0)

