"""The direct methods as methods of the contract: the bounded B-spline solve, the first motion.

:class:`BoundedPath` (``SolverOptions.method`` ``"direct"``) solves a problem with its joint
limits as hard bounds, as a B-spline joint path whose torques are its inverse dynamics
(:func:`~tocontrol_ros.core.direct.limited.plan_limited`; the maximum principle hands it the
problems whose limits bind), and continues a previous ``"direct"`` solution warm
(:func:`~tocontrol_ros.core.direct.limited.plan_limited_warm`). :class:`FirstMotion`
(``"first"``) times a seed configurations' joint path by TOPP-RA
(:func:`~tocontrol_ros.core.direct.first_motion.first_motion`): certified at once, slower
than the optimum. Both are certified open loop
(:func:`~tocontrol_ros.core.checks.certificate.certify_open_loop`).
"""

from __future__ import annotations

from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.first_motion import first_motion
from tocontrol_ros.core.direct.limited import plan_limited, plan_limited_warm
from tocontrol_ros.core.direct.shifted import first_from_warm
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.methods.context import SolveContext
from tocontrol_ros.core.methods.contract import Compiled, Method, register
from tocontrol_ros.core.types.certificate import Certificate, CertificateOptions
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult
from tocontrol_ros.core.types.trajectory import Motion

__all__ = ["BoundedPath", "FirstMotion"]


class _OpenLoopCertified(Method):
    """A method whose motions carry no costates: certified open loop."""

    def certify(self, problem: Problem, motion: Motion,
                options: CertificateOptions) -> Certificate:
        """The nominal torques re-integrated, the set and the limits (open loop)."""
        return certify_open_loop(problem, motion, options)


class BoundedPath(_OpenLoopCertified):
    """The bounded B-spline solve (docs/limits.md); ``PlanResult.method`` ``"direct"``."""

    name = "direct"

    def solve(self, compiled: Compiled, ctx: SolveContext, timings: dict,
              t_start: float) -> PlanResult:
        """From the seed pairs' guesses within the bounds, candidates refined level by level."""
        return plan_limited(compiled, ctx, timings, t_start, [], reason=(
            "solved as a B-spline path with hard bounds (docs/limits.md), as asked "
            "(method 'direct')"))

    def owns(self, warm_state: object) -> bool:
        """A previous bounded solution's mesh, path and multipliers."""
        return isinstance(warm_state, PathWarmState)

    def warm_start(self, compiled: Compiled, ctx: SolveContext, previous: PlanResult,
                   timings: dict, t_start: float) -> PlanResult:
        """On the previous solution's mesh, from its path and multipliers (and problem)."""
        return plan_limited_warm(compiled, ctx, previous.warm_state, timings, t_start,
                                 previous.trajectory, previous.problem)

    def first_from(self, compiled: Compiled, ctx: SolveContext, previous: PlanResult
                   ) -> tuple[PlanResult | None, str]:
        """The stored path moved onto the request's ends and timed (:mod:`~.shifted`)."""
        return first_from_warm(compiled, ctx, previous.warm_state)


class FirstMotion(_OpenLoopCertified):
    """A seed path timed by TOPP-RA inside every limit; ``PlanResult.method`` ``"first"``."""

    name = "first"

    def solve(self, compiled: Compiled, ctx: SolveContext, timings: dict,
              t_start: float) -> PlanResult:
        """The best-ranked seed paths timed at rest, the fastest certified one."""
        return first_motion(ctx.problem, ctx.options, ctx.memo.get("pairs"))


register(BoundedPath())
register(FirstMotion())
