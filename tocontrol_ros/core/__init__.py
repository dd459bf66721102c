"""Numerical core of tocontrol_ros: model, maximum principle, solver, trajectory.

Pure Python and numerics (numpy, scipy, CasADi); never imports rclpy or message types.

What a caller needs is importable from here::

    from tocontrol_ros.core import plan, Problem, SolverOptions, PlanResult, Status
    from tocontrol_ros.core import point, joint_state, load_robot

The layout (``docs/architecture.md``): ``robot/`` (URDF, dynamics, kinematics, limits,
compiled functions), ``indirect/`` (the maximum principle, shooting, mesh, continuation),
``direct/`` (the collocation guess and the bounded B-spline solve), ``sim/`` (the
tracker's plant), and here the problem, options, result, certificate and the orchestration
(:mod:`tocontrol_ros.core.planning.solver`), which chooses between the methods.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tocontrol_ros.core.planning.solver import Planner, plan  # noqa: F401
    from tocontrol_ros.core.robot.model import load_robot  # noqa: F401
    from tocontrol_ros.core.types.options import SolverOptions  # noqa: F401
    from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: F401
    from tocontrol_ros.core.types.result import PlanResult, Status  # noqa: F401

#: Public name -> module that defines it. Loaded on first use (PEP 562), so that importing
#: one light module of the core (``errors``, ``robot.kinematics``: the nodes' conversions,
#: the report) does not pull in CasADi and the whole solver.
_EXPORTS = {
    "plan": "tocontrol_ros.core.planning.solver",
    "Planner": "tocontrol_ros.core.planning.solver",
    "Problem": "tocontrol_ros.core.types.problem",
    "point": "tocontrol_ros.core.types.problem",
    "joint_state": "tocontrol_ros.core.types.problem",
    "SolverOptions": "tocontrol_ros.core.types.options",
    "PlanResult": "tocontrol_ros.core.types.result",
    "Status": "tocontrol_ros.core.types.result",
    "load_robot": "tocontrol_ros.core.robot.model",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    """Load a re-exported name from its module on first use."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tocontrol_ros.core' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
