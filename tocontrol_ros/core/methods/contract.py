"""The method contract: what every way of solving a problem implements, and a registry.

A *method* turns a :class:`~tocontrol_ros.core.types.problem.Problem` into a certified
:class:`~tocontrol_ros.core.types.result.PlanResult`. The orchestration
(:func:`~tocontrol_ros.core.planning.solver.plan`) sees only this contract: it picks a
method by name (``SolverOptions.method``), asks it to :meth:`~Method.prepare` what a
problem's kind needs, to :meth:`~Method.solve` cold, or to :meth:`~Method.warm_start` from a
previous result whose warm state the method :meth:`~Method.owns`; it handles the deadline,
cancellation and the motions offered so far (:class:`~.context.SolveContext`) the same way
for every method. Each method certifies its own motions (:meth:`~Method.certify`), at least
with the open-loop certificate every motion passes
(:func:`~tocontrol_ros.core.checks.certificate.certify_open_loop`).

The methods of the package: ``"indirect"`` (the paper's maximum principle,
:class:`tocontrol_ros.core.indirect.method.MaximumPrinciple`, which hands a problem whose
joint limits bind to the bounded solve), ``"direct"`` (the bounded B-spline solve,
:class:`tocontrol_ros.core.direct.method.BoundedPath`) and ``"first"`` (a seed path timed by
TOPP-RA, :class:`tocontrol_ros.core.direct.method.FirstMotion`). ``"auto"`` (the default) is
the maximum principle. A new method subclasses :class:`Method`, lives in its own module, and
is made available by :func:`register`; nothing in the orchestration changes. (The package's
own methods register themselves when their modules are imported, which the orchestration
does.)

A method's solve receives ``compiled`` (:class:`Compiled`: the model's compiled functions,
kept by the planner across solves), the solve's context, and the ``timings`` dict it fills
(keys ``"guess"``, ``"shooting"``, ``"refine"``, ``"verify"``: seconds) with ``t_start``
(``time.perf_counter()`` at the request), as every result reports them.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.types.certificate import Certificate, CertificateOptions
from tocontrol_ros.core.types.options import SolverOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult
from tocontrol_ros.core.types.trajectory import Motion

if TYPE_CHECKING:
    from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["Compiled", "Method", "register", "method_named", "method_owning",
           "method_names", "AUTO"]

#: ``SolverOptions.method`` of the default rule: the maximum principle, which solves the
#: bounded problem itself where the joint limits bind.
AUTO = "auto"


class Compiled(Protocol):
    """A model's compiled functions, kept across solves (the planner is one).

    The methods reach their transcriptions through it, so that they never import the
    orchestration that owns them.
    """

    model: RobotModel
    system: Any

    def direct(self, problem: Problem, intervals: int, box: bool = False,
               tol: float = 1e-8) -> Any:
        """The direct collocation transcription for ``problem``'s kinds (built once)."""

    def flat(self, problem: Problem, spans: int | np.ndarray,
             warm: bool | str | None = None) -> Any:
        """The bounded B-spline transcription for ``problem``'s kinds."""

    def map(self, fn: Callable, ctx: SolveContext, items: list) -> Iterator:
        """``fn(self, ctx, *item)`` per item, in order, maybe on several processes."""

    def prepare_shooting(self, problem: Problem, options: SolverOptions | None = None,
                         parallel: bool = True) -> float:
        """Build the maximum principle's compiled functions; seconds spent (0 once built)."""


class Method(ABC):
    """One way to solve a time-optimal problem (see the module docstring).

    Attributes
    ----------
    name : str
        The value of ``SolverOptions.method`` that selects it, and ``PlanResult.method``.
    """

    name: str = ""

    def prepare(self, compiled: Compiled, problem: Problem, options: SolverOptions) -> float:
        """Build what solving problems of ``problem``'s kind needs; seconds spent.

        Called before :meth:`solve`; the time it takes is added to the caller's deadline
        (compiling is not solving). The default builds nothing.
        """
        return 0.0

    @abstractmethod
    def solve(self, compiled: Compiled, ctx: SolveContext, timings: dict,
              t_start: float) -> PlanResult:
        """A cold solve of ``ctx.problem``: a certified result, or a failure saying why.

        Raises
        ------
        StopError
            When the caller cancelled or the deadline passed (``ctx.check()``); a motion
            :meth:`SolveContext.offer`-ed before may still be returned.
        """

    def owns(self, warm_state: object) -> bool:
        """Whether ``warm_state`` (a previous result's) is this method's to continue."""
        return False

    def warm_start(self, compiled: Compiled, ctx: SolveContext, previous: PlanResult,
                   timings: dict, t_start: float) -> PlanResult:
        """A solve of ``ctx.problem`` continued from ``previous`` (whose state it owns).

        A failure is reported, not replaced by a cold solve (the orchestration decides).
        The default solves cold.
        """
        return self.solve(compiled, ctx, timings, t_start)

    def first_from(self, compiled: Compiled, ctx: SolveContext, previous: PlanResult
                   ) -> tuple[PlanResult | None, str]:
        """A motion for ``ctx.problem`` made at once from ``previous`` (whose state it owns).

        No solve: a first motion to publish while :meth:`warm_start` solves (a memory hit's,
        ``publish: first_then_optimum``); checked like every plan (``success`` says whether
        it is certified). Returns ``(result or None, why)``; the default has none.
        """
        return None, f"the {self.name or 'method'} method makes no first motion from a warm state"

    @abstractmethod
    def certify(self, problem: Problem, motion: Motion,
                options: CertificateOptions) -> Certificate:
        """The independent checks of one of this method's motions."""


_REGISTRY: dict[str, Method] = {}
_LOCK = threading.Lock()


def register(method: Method, replace: bool = False) -> Method:
    """Make ``method`` available as ``SolverOptions(method=method.name)``.

    Raises
    ------
    ProblemError
        When ``method`` is not a :class:`Method`, its name is empty or ``"auto"``, or the
        name is taken (unless ``replace``).
    """
    if not isinstance(method, Method):
        raise ProblemError(f"`method` must be a Method, got {type(method).__name__}")
    if not isinstance(method.name, str) or not method.name or method.name == AUTO:
        raise ProblemError(f"`method.name` must be a non-empty string other than {AUTO!r}, "
                           f"got {method.name!r}")
    with _LOCK:
        if method.name in _REGISTRY and not replace:
            raise ProblemError(f"a method named {method.name!r} is already registered")
        _REGISTRY[method.name] = method
    return method


def method_names() -> tuple[str, ...]:
    """The names ``SolverOptions.method`` takes: ``"auto"`` and every registered one."""
    with _LOCK:
        return (AUTO,) + tuple(sorted(_REGISTRY))


def method_named(name: str) -> Method:
    """The method ``SolverOptions.method`` names (``"auto"``: the maximum principle).

    Raises
    ------
    ProblemError
        Naming the known methods, when ``name`` is none of them.
    """
    with _LOCK:
        found = _REGISTRY.get("indirect" if name == AUTO else name)
    if found is None:
        raise ProblemError(f"`method` must be one of {', '.join(map(repr, method_names()))}, "
                           f"got {name!r}")
    return found


def method_owning(warm_state: object) -> Method | None:
    """The registered method that continues from ``warm_state``, or None."""
    with _LOCK:
        methods = list(_REGISTRY.values())
    return next((m for m in methods if m.owns(warm_state)), None)
