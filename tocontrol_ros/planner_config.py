"""Parameters of the planner node: declared in one table, read into a frozen config.

:data:`PARAMETERS` is the only place a parameter is defined (name, default, range,
description, whether a change needs a restart). The node declares each one with the
:class:`rcl_interfaces.msg.ParameterDescriptor` built here, so that rclpy itself rejects
values out of range or of the wrong type and any change of a read-only one; its
on-set-parameters callback runs :func:`config_from_values` on the would-be values for the
checks that involve more than one parameter or the model. Nothing here needs a running node.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.model import STANDARD_GRAVITY

__all__ = ["ConfigError", "ParameterSpec", "PARAMETERS", "PlannerConfig", "descriptor",
           "config_from_values", "solver_options", "default_values"]

#: The paper's start point (Section 5), in the base frame's task coordinates (m).
PAPER_START = (1.0, 1.0)


class ConfigError(TocontrolError, ValueError):
    """A parameter value that the planner cannot use; the message names the parameter."""


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its default (which fixes its type), range and meaning.

    Attributes
    ----------
    name : str
    default : bool, int, float, str or list of float
    description : str
        Shown by ``ros2 param describe``; includes the unit.
    low, high : float or int, optional
        Inclusive range of a scalar number (rclpy enforces it).
    read_only : bool
        A change needs a restart (the model is built once, at start-up).
    constraints : str
        Conditions that rclpy cannot express (checked by the on-set callback).
    """

    name: str
    default: Any
    description: str
    low: float | int | None = None
    high: float | int | None = None
    read_only: bool = False
    constraints: str = ""

    @property
    def type(self) -> int:
        """The ``rcl_interfaces/ParameterType`` of the default."""
        d = self.default
        if isinstance(d, bool):
            return ParameterType.PARAMETER_BOOL
        if isinstance(d, int):
            return ParameterType.PARAMETER_INTEGER
        if isinstance(d, float):
            return ParameterType.PARAMETER_DOUBLE
        if isinstance(d, str):
            return ParameterType.PARAMETER_STRING
        return ParameterType.PARAMETER_DOUBLE_ARRAY


_RESTART = " Read-only: a change needs a restart."

PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("robot", "", "URDF of the arm: a file path or the URDF XML itself (e.g. the "
                  "robot_description string). Empty: the bundled config/galicki_3r.urdf "
                  "(the paper's planar 3R arm)." + _RESTART, read_only=True),
    ParameterSpec("base_link", "", "Link fixed to the world; start, target and outputs are "
                  "in its frame. Empty: the URDF's root link." + _RESTART, read_only=True),
    ParameterSpec("tip_link", "", "Link whose origin is the end-effector point. Empty: the "
                  "only leaf link." + _RESTART, read_only=True),
    ParameterSpec("task_axes", "", "Base-frame coordinates that form the task space, e.g. "
                  "'xy'. Empty: the plane of motion of a planar arm, else 'xyz'." + _RESTART,
                  read_only=True),
    ParameterSpec("gravity", list(STANDARD_GRAVITY), "Gravity acceleration in the base frame "
                  "(m/s^2), 3 numbers." + _RESTART, read_only=True,
                  constraints="3 finite numbers"),
    ParameterSpec("frame_id", "", "Frame of every point the planner receives and publishes. "
                  "Empty: the base link's name. Requests in another frame are rejected "
                  "(no tf lookup)." + _RESTART, read_only=True),
    ParameterSpec("k", 4.0, "Convexification exponent of the torque set sum u_i^(2k) <= 1 "
                  "(dimensionless); larger is closer to bang-bang.", 1.0, 64.0),
    ParameterSpec("reserve", 0.0, "Torque reserve r (fraction): plan against (1 - r) "
                  "tau_max, leaving r tau_max for feedback.", 0.0, 0.95),
    ParameterSpec("tol", 1e-10, "Newton tolerance on the max-norm of the boundary-value "
                  "equations.", 1e-14, 1e-4),
    ParameterSpec("max_newton", 30, "Newton iterations per solve (each continuation step "
                  "is one solve).", 1, 500),
    # starts and candidates: SolverOptions' defaults (checked by a test).
    ParameterSpec("starts", 16, "Seed pairs tried by the direct method that makes the "
                  "initial guess: the best-ranked of the self-motion grid and its full-turn "
                  "branches (docs/seeding.md); with the default candidates it finds the best "
                  "basin of nearly every problem of the paper's arm (1 = single start: "
                  "faster, often a worse basin).", 1, 256),
    ParameterSpec("candidates", 6, "Distinct direct solutions continued by shooting; the "
                  "fastest motion is returned.", 1, 32, constraints="candidates <= starts"),
    ParameterSpec("time_limit", 30.0, "Wall-time budget of one solve (s); a solve that runs "
                  "out fails with status 'time limit reached'.", 0.1, 600.0),
    ParameterSpec("verify", True, "Certify every solution before it is published: the nominal "
                  "torques re-integrated through the model by an independent adaptive "
                  "integrator must land on the target at rest, the torques stay inside the "
                  "set, H = 0 (a few ms on the paper's arm; see msg_docs/certificate.md). A "
                  "plan that fails is reported as failed, never published."),
    ParameterSpec("warm_start", True, "Also continue the previous solution when the new "
                  "problem is near it (same kinds and reserve, each end point within 0.1 m): "
                  "one more candidate next to the multistart, never instead of it; returned "
                  "only when it is faster. Identical requests give the same T whatever came "
                  "before."),
    ParameterSpec("sample_period", 0.01, "Sample period of ~/trajectory, ~/ee_path and the "
                  "~/plan response (s); the final time is always a sample.", 1e-4, 1.0),
    ParameterSpec("default_start", list(PAPER_START), "Start point (task coordinates in "
                  "frame_id, m) used when no recent joint state is available. Default: the "
                  "paper's start.", constraints="one finite number per task axis"),
    ParameterSpec("joint_state_timeout", 1.0, "A joint state older than this (s) is not "
                  "'recent': goals then start from default_start.", 0.0, 3600.0),
    ParameterSpec("marker_snapshots", 15, "Arm snapshots in ~/markers (as in the paper's "
                  "Figure 4).", 2, 200),
    ParameterSpec("service_timeout", 120.0, "Longest a ~/plan call waits for its outcome "
                  "(s); then it returns an empty path.", 1.0, 3600.0),
)

_SPECS = {spec.name: spec for spec in PARAMETERS}


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of one parameter (type, description, range, read_only)."""
    d = ParameterDescriptor(name=spec.name, type=spec.type, description=spec.description,
                            additional_constraints=spec.constraints,
                            read_only=spec.read_only)
    if spec.low is not None:
        if spec.type == ParameterType.PARAMETER_INTEGER:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                            step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    return d


def default_values() -> dict[str, Any]:
    """Parameter name -> default value."""
    return {spec.name: spec.default for spec in PARAMETERS}


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's parameters, checked (see :data:`PARAMETERS` for meanings and units)."""

    robot: str
    base_link: str
    tip_link: str
    task_axes: str
    gravity: tuple[float, float, float]
    frame_id: str
    k: float
    reserve: float
    tol: float
    max_newton: int
    starts: int
    candidates: int
    time_limit: float
    verify: bool
    warm_start: bool
    sample_period: float
    default_start: tuple[float, ...]
    joint_state_timeout: float
    marker_snapshots: int
    service_timeout: float


def _check_scalar(spec: ParameterSpec, value: Any) -> Any:
    kind = type(spec.default)
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"`{spec.name}` must be true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"`{spec.name}` must be a string, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"`{spec.name}` must be an integer, got {value!r}")
    elif isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"`{spec.name}` must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"`{spec.name}` must be finite, got {value!r}")
    if spec.low is not None and not (spec.low <= value <= spec.high):
        raise ConfigError(f"`{spec.name}` must be in [{spec.low:g}, {spec.high:g}], got "
                          f"{value!r}")
    return kind(value)


def _check_vector(name: str, value: Any, size: int | None) -> tuple[float, ...]:
    try:
        vec = tuple(float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`{name}` must be a list of numbers, got {value!r}") from exc
    if size is not None and len(vec) != size:
        raise ConfigError(f"`{name}` must have {size} entries, got {len(vec)}: {list(vec)}")
    if not all(math.isfinite(v) for v in vec):
        raise ConfigError(f"`{name}` must be finite, got {list(vec)}")
    return vec


def config_from_values(values: Mapping[str, Any], task_dim: int | None = None) -> PlannerConfig:
    """Check a full set of parameter values and return them as a config.

    Parameters
    ----------
    values : mapping of str to value
        Every name of :data:`PARAMETERS`; missing names take their defaults.
    task_dim : int, optional
        The model's task-space dimension m, when known: ``default_start`` must have m
        entries.

    Returns
    -------
    PlannerConfig

    Raises
    ------
    ConfigError
        A value of the wrong type or out of range, or an inconsistent combination; the
        message names the parameter.
    """
    unknown = sorted(set(values) - set(_SPECS))
    if unknown:
        raise ConfigError(f"unknown parameter(s) {unknown}; known: {sorted(_SPECS)}")
    out: dict[str, Any] = {}
    for spec in PARAMETERS:
        value = values.get(spec.name, spec.default)
        if isinstance(spec.default, list):
            size = 3 if spec.name == "gravity" else task_dim
            out[spec.name] = _check_vector(spec.name, value, size)
        else:
            out[spec.name] = _check_scalar(spec, value)
    if out["candidates"] > out["starts"]:
        raise ConfigError(f"`candidates` ({out['candidates']}) must not exceed `starts` "
                          f"({out['starts']}): only the starts' direct solutions can be "
                          f"continued")
    if not out["default_start"]:
        raise ConfigError("`default_start` must not be empty")
    return PlannerConfig(**{f.name: out[f.name] for f in fields(PlannerConfig)})


def solver_options(config: PlannerConfig):
    """The :class:`~tocontrol_ros.core.solver.SolverOptions` of a config."""
    from tocontrol_ros.core.solver import SolverOptions

    return SolverOptions(tol=config.tol, max_newton=config.max_newton, starts=config.starts,
                         candidates=config.candidates, time_limit=config.time_limit,
                         verify=config.verify)
