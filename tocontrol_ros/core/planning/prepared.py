"""The compiled functions of one model, built once and reused across many solves.

:class:`PreparedModel` holds a model's canonical system and its direct and bounded
B-spline transcriptions, and prepares (generates and compiles) what a problem's kinds need.
The orchestration's :class:`~tocontrol_ros.core.planning.solver.Planner` is one, with ``plan``; the
methods that take one (the bounded solve, :mod:`tocontrol_ros.core.direct.limited`) see
only this class, so they do not import the orchestration.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import numpy as np

from tocontrol_ros.core.direct.clearance import clearance_rows
from tocontrol_ros.core.direct.collocation import (
    DirectCollocation,
    compile_direct,
)
from tocontrol_ros.core.direct.flat import FlatTranscription, compile_flat
from tocontrol_ros.core.direct.flat_trajectory import compile_open_loop
from tocontrol_ros.core.direct.time_scaling import compile_sweeps
from tocontrol_ros.core.direct.tuning import SPANS
from tocontrol_ros.core.indirect.pmp import CanonicalSystem
from tocontrol_ros.core.indirect.shooting import ShootingGrid
from tocontrol_ros.core.indirect.tuning import CONTINUATION_STEPS
from tocontrol_ros.core.planning.pool import available_cores, shared_pool
from tocontrol_ros.core.planning.tuning import FLAT_CACHE
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.core.robot.compiled import c_name
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem

__all__ = ["PreparedModel"]


class PreparedModel:
    """Holds the compiled functions of one model, reused across many solves.

    Parameters
    ----------
    model : RobotModel
    """

    def __init__(self, model) -> None:
        self.model = model
        #: Optimised libraries in the cache when this planner was made (see :meth:`stale`).
        self.generation = compiled.generation()
        self.system = CanonicalSystem(model)
        self._direct: dict = {}
        self._prepared: set = set()
        self._lock = threading.Lock()

    def stale(self) -> bool:
        """Whether optimised libraries landed since this planner was made, none pending.

        A planner keeps the compiled functions it loaded; when the first use of a model got
        quick builds (:mod:`~tocontrol_ros.core.robot.compiled`), a new planner made once the
        optimised ones are in the cache solves faster.
        """
        return compiled.generation() != self.generation and compiled.pending_builds() == 0

    def prepare(self, problem: Problem, options: SolverOptions | None = None,
                parallel: bool = True, shooting: bool = True) -> None:
        """Build and compile what solving problems of ``problem``'s kinds needs.

        First what every solve starts with: the direct transcription (the guesses) and,
        when ``problem`` has joint limits, the bounded B-spline transcription; then, with
        ``shooting``, what the maximum principle's solve needs (:meth:`prepare_shooting`),
        which a plan whose joint limits bind never uses (:func:`plan` leaves it to the
        first solve that gets there). With ``parallel``, the C sources are generated first
        and compiled on every core at once
        (:func:`~tocontrol_ros.core.robot.compiled.parallel_builds`), then loaded. Without
        ``shooting`` the bounded transcription is only started: its library builds while
        the guesses are solved, and the first bounded solve waits for it. The bounded
        motion's re-integration (its certificate's right-hand side,
        :func:`~tocontrol_ros.core.direct.flat_trajectory.compile_open_loop`) is built
        beside the bounded transcription; the other certificate functions on their first
        use.
        """
        options = options or SolverOptions()
        key = ("guess", problem.start.kind, problem.target.kind, options.guess_intervals,
               problem.torque_scale, problem.limits.active)
        if key not in self._prepared:
            model, kinds = self.model, (problem.start.kind, problem.target.kind)
            if parallel:
                with compiled.parallel_builds(wait=False):
                    compile_direct(model, options.guess_intervals, *kinds)
                    if problem.limits.active:
                        compile_flat(model)
                        compile_open_loop(model)  # the certificate's re-integration
                    compile_sweeps(problem)  # the first motion's and quick replans' TOPP-RA
            self.direct(problem, options.guess_intervals, tol=options.guess_tol)
            self._prepared.add(key)
        if shooting:
            if problem.limits.active:
                self.flat(problem, SPANS)
            self.prepare_shooting(problem, options, parallel)

    def prepare_shooting(self, problem: Problem, options: SolverOptions | None = None,
                         parallel: bool = True) -> float:
        """Build and compile the maximum principle's functions for ``problem``'s kinds.

        The canonical system's compiled functions (the RK4 step's Jacobian, the plain step,
        the pointwise evaluation, the switching functions) and the boundary conditions of
        the start and target kinds: a solve that follows compiles nothing of these. With
        ``parallel``, a first pass on a scratch copy of this planner only generates the C
        sources and compiles them on every core at once; the second finds them in the
        cache. (Skipped when the cache already holds a library of this model: generating
        the sources twice costs seconds on a 7-joint arm.)

        Returns
        -------
        float
            Wall time spent here (s): 0 once prepared.
        """
        options = options or SolverOptions()
        key = ("shooting", problem.start.kind, problem.target.kind, options.intervals,
               options.steps)
        if key in self._prepared:
            return 0.0
        t0 = time.perf_counter()
        name = f"tocontrol_pointwise_{c_name(self.model.name)}_{self.model.n}_"
        if parallel and not compiled.in_cache(name):
            with compiled.parallel_builds():
                self._scratch()._build_shooting(problem, options)
        self._build_shooting(problem, options)
        self._prepared.add(key)
        return time.perf_counter() - t0

    def _scratch(self) -> PreparedModel:
        """A planner sharing this one's symbolic system, with empty caches of functions."""
        scratch = object.__new__(type(self))
        scratch.model, scratch.generation = self.model, self.generation
        scratch.system = self.system.scratch()
        scratch._direct, scratch._prepared, scratch._lock = {}, set(), threading.Lock()
        return scratch

    def _build_shooting(self, problem: Problem, options: SolverOptions) -> None:
        """The builds of :meth:`prepare_shooting`, in this planner's caches."""
        system = self.system
        if system.stagewise:
            system.rhs_jacobian_function()
        else:
            system.step_function(True)
            for steps in sorted({min(options.steps, CONTINUATION_STEPS), options.steps}):
                system.interval_function(steps, True)
                system.interval_function(steps, False)
        system.step_function(False)
        system.pointwise()
        grid = ShootingGrid(system, np.full(options.intervals, 1.0 / options.intervals),
                            options.steps, problem.start.kind, problem.target.kind)
        grid.compile()

    def map(self, fn: Callable, ctx, items: list) -> Iterator:
        """``fn(self, ctx, *item)`` for each item, in order, on ``ctx.options.workers``.

        With one worker (the default), each item is solved when the iterator reaches it.
        With more, the items are shared out between this process and worker processes
        (:class:`~tocontrol_ros.core.planning.pool.WorkerPool`, one per number of workers) and the
        iterator yields their results in the items' order once all have ended, the first
        exception raised where its item stands: the same values either way.
        """
        workers = ctx.options.workers or available_cores()
        if workers > 1 and len(items) > 1:
            yield from shared_pool(workers, PreparedModel).map(fn, self, ctx, items)
            return
        for item in items:
            yield fn(self, ctx, *item)

    def direct(self, problem: Problem, intervals: int, box: bool = False,
               tol: float = 1e-8) -> DirectCollocation:
        """The direct transcription for this problem's kinds (built once, cached)."""
        scale = problem.torque_scale
        key = (intervals, problem.start.kind, problem.target.kind, box, scale, tol)
        with self._lock:
            if key not in self._direct:
                self._direct[key] = DirectCollocation(
                    self.model, intervals, problem.start.kind, problem.target.kind, box=box,
                    torque_scale=scale, tol=tol)
            return self._direct[key]

    def flat(self, problem: Problem, spans: int | np.ndarray,
             warm: bool | str | None = None) -> FlatTranscription:
        """The bounded B-spline transcription for this problem's kinds.

        ``spans``: a number of uniform spans, or breakpoints (the refined meshes). Built
        once per number of spans (and kinds, torque scale, ``warm``), then reused on other
        breakpoints with as many spans (:meth:`FlatTranscription.on`); the
        :data:`FLAT_CACHE` most recently used are kept. ``warm`` (default:
        for given breakpoints, which are only solved from the coarser mesh's solution):
        ``FlatTranscription(warm=True)``; ``"resume"`` for re-solves with a wider set pad,
        ``"dual"`` for warm re-solves from a solution and its multipliers.
        """
        warm = np.ndim(spans) != 0 if warm is None else warm
        count = int(spans) if np.ndim(spans) == 0 else len(spans) - 1
        # Acceleration limits add rows (a problem without them keeps the NLP it had).
        accel = tuple(problem.limits.plan_acceleration) \
            if problem.limits.has_acceleration else None
        key = ("flat", problem.start.kind, problem.target.kind, problem.torque_scale,
               count, warm) + ((accel,) if accel is not None else ())
        col = problem.collision
        if col is not None:  # its own transcription: the scene's rows
            key += (col.key(),)
        with self._lock:
            base = self._direct.pop(key, None)
            if base is None:
                base = FlatTranscription(
                    self.model, count, problem.start.kind, problem.target.kind,
                    torque_scale=problem.torque_scale, warm=warm,
                    acceleration=None if accel is None else np.array(accel),
                    clearance=None if col is None else clearance_rows(col))
            self._direct[key] = base  # the most recently used last
            for old in [k for k in self._direct if k[0] == "flat"][:-FLAT_CACHE]:
                del self._direct[old]
        return base if np.ndim(spans) == 0 else base.on(spans)
