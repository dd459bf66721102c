"""Parameters of the planner node: one table, a frozen config, what the node builds from it.

:data:`PARAMETERS` is the only place a parameter is defined (name, default, range,
description, whether a change needs a restart). The node declares each one with the
:class:`rcl_interfaces.msg.ParameterDescriptor` built by :mod:`tocontrol_ros.nodes.params`, so
that rclpy itself rejects values out of range or of the wrong type and any change of a
read-only one; its on-set-parameters callback runs :func:`config_from_values` on the
would-be values for the checks that involve more than one parameter or the model. Nothing
here needs a running node.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.geometry.tuning import DEFAULT_MARGIN
from tocontrol_ros.core.robot.model import STANDARD_GRAVITY
from tocontrol_ros.core.types.options import MIN_REPLAN_SPANS, SolverOptions
from tocontrol_ros.nodes.parameter_specs import (
    LOCKED_JOINTS,
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_FILE,
    ROBOT_DESCRIPTION_TIMEOUT,
    ROBOT_DESCRIPTION_TOPIC,
    ParameterSpec,
    load_model,
    parse_locked_joints,
)

__all__ = ["ConfigError", "PARAMETERS", "PlannerConfig", "PUBLISH_MODES", "FIRST_THEN_OPTIMUM",
           "config_from_values", "solver_options", "default_values", "planner_model",
           "planner_limits", "warm_up_problems", "plan_problem"]

#: ``publish``: the optimum only (the default), or first a certified motion at once.
FIRST_THEN_OPTIMUM = "first_then_optimum"
PUBLISH_MODES = ("optimum", FIRST_THEN_OPTIMUM)

class ConfigError(TocontrolError, ValueError):
    """A parameter value that the planner cannot use; the message names the parameter."""


#: The core's defaults: a parameter that maps to a solver option (:data:`SOLVER_PARAMETERS`)
#: takes the option's default, so that the node and ``tocontrol_ros.core.plan`` answer a
#: request alike unless told otherwise.
_CORE = SolverOptions()

#: The node parameters that are solver options of the same name
#: (:class:`~tocontrol_ros.core.types.options.SolverOptions`), read by :func:`solver_options`.
SOLVER_PARAMETERS = ("tol", "max_newton", "starts", "candidates", "time_limit", "verify",
                     "warm_only", "workers")

#: The one parameter whose default differs from its option's, and why: a planner node owns
#: its machine and solves on every core (measured: the Panda's plan 1.5 times faster on two
#: cores, BENCHMARKS.md "deployed_panda"), where a library call does not start processes
#: unasked (``SolverOptions.workers`` 1).
NODE_DEFAULTS = {"workers": 0}

PARAMETERS: tuple[ParameterSpec, ...] = (
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_FILE,
    ROBOT_DESCRIPTION_TOPIC,
    ROBOT_DESCRIPTION_TIMEOUT,
    LOCKED_JOINTS,
    ParameterSpec("joint_limits", "", "Path of a MoveIt joint_limits.yaml narrowing the URDF's "
                  "position, velocity and effort limits (has_position_limits, min_position, "
                  "max_position, has_velocity_limits, max_velocity, has_effort_limits, "
                  "max_effort; the tighter of the two wins) and adding acceleration limits "
                  "(has_acceleration_limits, max_acceleration), held on the whole motion; "
                  "jerk entries are not enforced (docs/limits.md). Empty: the URDF's limits.",
                  read_only=True),
    ParameterSpec("limit_margin", 0.0, "Fraction of each joint's position range and velocity "
                  "limit kept free by the plans (as reserve does for torque).", 0.0, 0.5),
    ParameterSpec("scene_file", "", "Path of a YAML file of obstacles (boxes, spheres, "
                  "cylinders in the base frame) and allowed pairs (msg_docs/scene_file.md); "
                  "plans keep the collision margin from them and between the arm's own links, "
                  "certified with Coal on the URDF's collision geometry. Empty: no obstacles "
                  "(and no collision checking unless robot_description_semantic is set or a "
                  "scene arrives on ~/scene).", read_only=True),
    ParameterSpec("margin", DEFAULT_MARGIN, "Collision margin (m): the least distance every "
                  "published motion keeps between the arm and the obstacles and between its "
                  "own checked links, when collision checking is on.", 0.0, 0.5),
    ParameterSpec("robot_description_semantic", "", "SRDF XML or the path of an SRDF file "
                  "(as MoveIt takes it): its disable_collisions pairs are not checked. "
                  "Setting it turns collision checking on (self-collision). Empty: all link "
                  "pairs but adjacent ones.", read_only=True),
    ParameterSpec("base_link", "", "Link fixed to the world; start, target and outputs are "
                  "in its frame. Empty: the URDF's root link.", read_only=True),
    ParameterSpec("tip_link", "", "Link whose origin is the end-effector point. Empty: the "
                  "only leaf link.", read_only=True),
    ParameterSpec("task_axes", "", "Base-frame coordinates that form the task space, e.g. "
                  "'xy'. Empty: the plane of motion of a planar arm, else 'xyz'.",
                  read_only=True),
    ParameterSpec("gravity", list(STANDARD_GRAVITY), "Gravity acceleration in the base frame "
                  "(m/s^2), 3 numbers.", read_only=True,
                  constraints="3 finite numbers"),
    ParameterSpec("frame_id", "", "Frame of every point the planner receives and publishes. "
                  "Empty: the base link's name. Requests in another frame are rejected "
                  "(no tf lookup).", read_only=True),
    ParameterSpec("k", 4.0, "Convexification exponent of the torque set sum u_i^(2k) <= 1 "
                  "(dimensionless); larger is closer to bang-bang.", 1.0, 64.0),
    # Not Problem's 0 (the paper's problem): a node drives an arm, whose feedback needs
    # room (issue 49; msg_docs/parameters.md).
    ParameterSpec("reserve", 0.1, "Torque reserve r (fraction): plan against (1 - r) "
                  "tau_max, leaving r tau_max for feedback (0.1: a 10 % model error, e.g. "
                  "a payload, costs T about 5 %; 0: the paper's problem).", 0.0, 0.95),
    ParameterSpec("tol", _CORE.tol,
                  "Newton tolerance on the max-norm of the boundary-value "
                  "equations.", 1e-14, 1e-4),
    ParameterSpec("max_newton", _CORE.max_newton,
                  "Newton iterations per solve (each continuation step "
                  "is one solve).", 1, 500),
    # starts and candidates: SolverOptions' defaults (checked by a test).
    ParameterSpec("starts", _CORE.starts,
                  "Seed pairs tried by the direct method that makes the "
                  "initial guess: the best-ranked of the self-motion grid and its full-turn "
                  "branches (docs/seeding.md); with the default candidates it finds the best "
                  "basin of nearly every problem of the paper's arm (1 = single start: "
                  "faster, often a worse basin). On an arm with random IK seeds and joint "
                  "limits (not a planar arm) starts // 2 more are solved.", 1, 256),
    ParameterSpec("candidates", _CORE.candidates,
                  "At most this many distinct direct solutions continued by "
                  "shooting, fastest direct T first, stopping where the rest cannot beat the "
                  "best found (docs/seeding.md); the fastest motion is returned.", 1, 32,
                  constraints="candidates <= starts"),
    ParameterSpec("time_limit", _CORE.time_limit,
                  "Wall-time budget of one solve (s), the solver's one "
                  "reading of the clock that changes its course (it decides by work "
                  "otherwise: the same request gives the same plan on any load). A solve "
                  "that runs out ends with status TIME_LIMIT; when it had found a motion that "
                  "passes its certificate, the best one is published with a WARN status "
                  "(not shown to be the optimum), else nothing is.", 0.1, 600.0),
    ParameterSpec("workers", NODE_DEFAULTS["workers"],
                  "Processes that solve a plan's independent pieces side by "
                  "side, the planner's own included (the multistart's direct guesses, the "
                  "bounded solve's candidates and refinement levels): 0 = one per core the "
                  "node may use, 1 = all in the planner's process. The plan is the same for "
                  "any number; more only make it sooner. Worker processes start with the "
                  "first request that uses them and stay until the node exits.", 0, 64),
    ParameterSpec("verify", _CORE.verify,
                  "Certify every solution before it is published: the nominal "
                  "torques re-integrated through the model by an independent adaptive "
                  "integrator must land on the target at rest, the torques stay inside the "
                  "set, H = 0 (a few ms on the paper's arm; see msg_docs/certificate.md). A "
                  "plan that fails is reported as failed, never published."),
    ParameterSpec("warm_start", True, "Also continue the previous solution when the new "
                  "problem is near it (same kinds and reserve, each end point within 0.1 m): "
                  "one more candidate next to the multistart, never instead of it (unless "
                  "warm_only); returned only when it is faster. Identical requests give the "
                  "same T whatever came before."),
    ParameterSpec("warm_only", _CORE.warm_only,
                  "With warm_start, return the previous solution "
                  "continued to the new problem without running the multistart, when it "
                  "succeeds: the quickest re-plan after a small move (the Panda with its "
                  "limits: 0.2-0.5 s against seconds), in the previous motion's basin, which "
                  "the multistart might beat. A failed warm start falls back to the "
                  "multistart."),
    ParameterSpec("publish", "optimum", "What ~/trajectory carries: 'optimum' (the plan, "
                  "once solved) or 'first_then_optimum' (first a certified motion inside "
                  "every limit, a seed path timed by TOPP-RA, as soon as it exists, tens of "
                  "milliseconds; then the optimum when it comes and is faster). The ~/plan "
                  "answer is the last motion published (msg_docs/parameters.md).",
                  constraints="optimum or first_then_optimum"),
    ParameterSpec("sample_period", 0.01, "Sample period of ~/trajectory, ~/ee_path and the "
                  "~/plan response (s); the final time is always a sample.", 1e-4, 1.0),
    ParameterSpec("default_start", list(PAPER_START), "Start point (task coordinates in "
                  "frame_id, m) used when no recent joint state is available. Default: the "
                  "paper's start; on an arm whose task space is not the plane, none (a "
                  "request then needs a recent joint state).",
                  constraints="one finite number per task axis"),
    ParameterSpec("joint_state_timeout", 1.0, "A joint state older than this (s) is not "
                  "'recent': goals then start from default_start.", 0.0, 3600.0),
    ParameterSpec("marker_snapshots", 15, "Arm snapshots in ~/markers (as in the paper's "
                  "Figure 4).", 2, 200),
    ParameterSpec("replan", True, "A goal that arrives while a published motion runs is "
                  "planned from the state the motion will be in at the hand-off (now plus the "
                  "measured replan latency times replan_margin), stamped with that time, so "
                  "that the tracker splices it in there; a goal within replan_radius of the "
                  "running motion's target is re-solved warm from that motion's rest "
                  "(msg_docs/parameters.md, 'Replanning'). False: every goal is planned from "
                  "the latest joint state and starts on receipt."),
    ParameterSpec("replan_radius", 0.1, "A goal within this distance (m) of the running "
                  "motion's target is re-solved warm from that motion (its basin continued, "
                  "no multistart); farther, the cold multistart plans it from the hand-off "
                  "state. At most the core's warm-start radius, 0.1 m.", 0.0, 0.1),
    ParameterSpec("replan_margin", 2.0, "The hand-off lead is replan_min_lead plus this "
                  "factor times the 80th percentile of the last 10 replan latencies of the "
                  "same kind (solve start to publication).", 1.0, 10.0),
    ParameterSpec("replan_min_lead", 0.05, "Smallest hand-off lead (s): delivery to the "
                  "tracker and its update period.", 0.001, 1.0),
    ParameterSpec("handoff_grid", 0.001, "Hand-off times are the latest joint state's stamp "
                  "plus a multiple of this (s): a multiple of the tracker's control period "
                  "puts the splice on a control instant.", 1e-4, 0.1),
    ParameterSpec("replan_smoothing", 1e-2, "Final smoothing delta of the control law of a "
                  "replan near the running motion (and of the goal solved ahead): T within "
                  "about 1.4e-3 (relative) of the unsmoothed optimum (1e-3: 7e-5), a few "
                  "Newton iterations warm; the certificate's Hamiltonian tolerance is raised "
                  "to it. 0: the full "
                  "schedule down to 0, as for new motions (msg_docs/parameters.md, "
                  "'Replanning').", 0.0, 0.01),
    ParameterSpec("replan_spans", 24, "An arm whose limits bind: a replan near the running "
                  "motion is solved on this many uniform B-spline spans, at least 4 (a coarse "
                  "mesh: T within about 1e-3, about 3 times faster on the Panda). 0: on the "
                  "running motion's own mesh (msg_docs/parameters.md, 'Replanning').",
                  0, 256),
    ParameterSpec("replan_quick", True, "A replan publishes at once a quick certified "
                  "motion (the target's configuration found near the running motion's end, "
                  "the path from the hand-off state timed by TOPP-RA: milliseconds, T "
                  "typically 5-25 % above the optimum), then solves the optimum from a later "
                  "hand-off on it, while no other goal waits, and publishes it when it "
                  "arrives in time and ends sooner. False: the optimum only "
                  "(msg_docs/parameters.md, 'Replanning')."),
    ParameterSpec("replan_on_callback", False, "With replan_quick: a goal's quick motion is "
                  "served on the goal's callback thread when the worker idles, without "
                  "waking the worker (issue 47; measured without a net gain on a loaded "
                  "machine: docs/speed.md, fifth pass). False: always by the worker."),
    ParameterSpec("replan_predict", True, "While goals stream in at a steady rate along a "
                  "smooth path, the worker solves the goal they predict (the quadratic "
                  "through the last three) between goals, as the real goal's first warm start "
                  "(msg_docs/parameters.md, 'Replanning')."),
    ParameterSpec("goal_queue", 50, "Goals that wait behind each other while the worker "
                  "solves (replanning): each is solved in turn, none is dropped unless more "
                  "than this many wait (then the oldest is superseded). 1: newest wins "
                  "(lower latency on an idle machine, fewer goals answered on a busy one).",
                  1, 1000),
    ParameterSpec("goal_max_backlog", 3.0, "Once replans take longer than the interval "
                  "between goals (the worker falls behind the stream), the oldest waiting "
                  "goals are superseded while solving those waiting would take longer than "
                  "this (s; their count times the recent replans' median solve time): newest "
                  "wins. Solves that keep up answer every goal.", 0.0, 3600.0),
    # Pose goals (~/goal_pose, ~/plan_motion's TARGET_POSE: tocontrol_ros/nodes/pose_goals.py).
    ParameterSpec("pose_position_tolerance", 1e-4, "A pose goal is reached when the planned "
                  "motion's last sample puts the tip within this distance of the pose's "
                  "position (m), checked by forward kinematics before publishing (MoveIt's "
                  "default goal_position_tolerance).", 1e-9, 1.0),
    ParameterSpec("pose_orientation_tolerance", 1e-3, "... and within this angle of its "
                  "orientation (rad; the angle of the rotation between the two; MoveIt's "
                  "default goal_orientation_tolerance).", 1e-9, 3.14159),
    ParameterSpec("pose_ik_seeds", 16, "A pose goal is solved to joint configurations by "
                  "inverse kinematics from this many seeds (the start's configuration, then "
                  "fixed pseudo-random ones within the limits: the same pose gives the same "
                  "solutions); each distinct solution within the joint limits is a candidate "
                  "joint goal.", 1, 256),
    ParameterSpec("pose_candidates", 2, "Of a pose goal's IK solutions, each timed by the "
                  "first motion (TOPP-RA, certified, milliseconds), this many with the least "
                  "first-motion T are planned to the optimum; the least T certified motion "
                  "(optimum or first motion) is published.", 1, 32),
    # The memory of optimal motions (tocontrol_ros/nodes/memory_policy.py, docs/memory.md).
    ParameterSpec("memory", "", "Path of a memory of optimal motions (a SQLite file that "
                  "`ros2 run tocontrol_ros memory build` made for this robot and these k, "
                  "reserve, joint limits and margin): a request near a stored motion is "
                  "answered by re-solving the nearest ones warm (memory: hit on ~/status), "
                  "else planned as without it (miss). A missing, corrupt, locked or other "
                  "robot's file: a WARN status, and plans without it. Empty: no memory."),
    ParameterSpec("memory_radius", 1.0, "Largest distance of a hit, in units of the warm "
                  "start's radii (each end point 0.1 m, each joint-state end 0.05 rad): a "
                  "stored motion farther from the request is not tried.", 0.0, 5.0),
    ParameterSpec("memory_basins", 3, "Stored motions re-solved warm per hit, nearest "
                  "first, one per basin (end configurations more than 0.3 rad apart), side "
                  "by side in the worker processes when workers is not 1; the least T "
                  "certified is published.", 1, 16),
    ParameterSpec("memory_first_success", False, "Re-solve the next basin only when the "
                  "nearer one failed: one warm solve per hit instead of memory_basins, at the "
                  "nearest basin's T (above the multistart's by more than 1e-3 on 8 of 37 "
                  "hits of the benchmark's Panda cell, against 3 of 37 with two basins)."),
    ParameterSpec("memory_spans", 64, "A stored motion of an arm whose limits bind is "
                  "re-solved on this many uniform B-spline spans, from its serving state on "
                  "this mesh (memory build / memory upgrade) or else its stored path (T "
                  "above the optimum by about 1/spans^2: 5e-4 at 64 on the Panda); 0: on its "
                  "own refined mesh, from its multipliers (a transcription built per mesh "
                  "size: slow).", 0, 256, constraints="0 or at least 4"),
    ParameterSpec("memory_learn", False, "Add every certified plan the node publishes to "
                  "the memory (made if the file does not exist), so that a cell learns."),
    ParameterSpec("service_timeout", 120.0, "Longest a ~/plan call waits for its outcome "
                  "(s); then it returns an empty path.", 1.0, 3600.0),
    # Execution on a controller (tocontrol_ros/nodes/controller_client.py).
    ParameterSpec("controller_action", "", "A control_msgs/action/FollowJointTrajectory "
                  "action (the tracker's /tracker/follow_joint_trajectory, or a "
                  "joint_trajectory_controller's /<controller>/follow_joint_trajectory) that "
                  "every published plan is sent to, the outcome on ~/status. Empty: none.",
                  read_only=True),
    ParameterSpec("controller_effort", False, "The controller takes effort (an effort "
                  "command interface): goals carry the nominal torques. False: no effort "
                  "(a default joint_trajectory_controller refuses goals with effort)."),
    ParameterSpec("controller_goal_time_tolerance", 1.0, "goal_time_tolerance of the goals "
                  "(s): how long after the motion's end the controller may take to reach the "
                  "goal tolerance. 0: the controller's default.", 0.0, 3600.0),
    ParameterSpec("controller_goal_tolerance", 0.0, "Position tolerance of every joint at "
                  "the goal's end (rad, m). 0: the controller's default.", 0.0, 1000.0),
    ParameterSpec("controller_path_tolerance", 0.0, "Position tolerance of every joint "
                  "during the motion (rad, m). 0: the controller's default.", 0.0, 1000.0),
)

_SPECS = {spec.name: spec for spec in PARAMETERS}


def default_values() -> dict[str, Any]:
    """Parameter name -> default value."""
    return {spec.name: spec.default for spec in PARAMETERS}


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's parameters, checked (see :data:`PARAMETERS` for meanings and units)."""

    robot_description: str
    robot_description_file: str
    locked_joints: str
    joint_limits: str
    limit_margin: float
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
    workers: int
    verify: bool
    warm_start: bool
    warm_only: bool
    publish: str
    sample_period: float
    default_start: tuple[float, ...]
    joint_state_timeout: float
    marker_snapshots: int
    service_timeout: float
    robot_description_topic: str = ""
    robot_description_timeout: float = 30.0
    controller_action: str = ""
    controller_effort: bool = False
    controller_goal_time_tolerance: float = 1.0
    controller_goal_tolerance: float = 0.0
    controller_path_tolerance: float = 0.0
    replan: bool = True
    replan_radius: float = 0.1
    replan_margin: float = 2.0
    replan_min_lead: float = 0.05
    handoff_grid: float = 0.001
    replan_smoothing: float = 1e-2
    replan_spans: int = 24
    replan_quick: bool = True
    replan_on_callback: bool = False
    replan_predict: bool = True
    goal_queue: int = 50
    goal_max_backlog: float = 3.0
    scene_file: str = ""
    margin: float = DEFAULT_MARGIN
    robot_description_semantic: str = ""
    memory: str = ""
    memory_radius: float = 1.0
    memory_basins: int = 3
    memory_first_success: bool = False
    memory_spans: int = 64
    memory_learn: bool = False
    pose_position_tolerance: float = 1e-4
    pose_orientation_tolerance: float = 1e-3
    pose_ik_seeds: int = 16
    pose_candidates: int = 2


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
        if spec.name == "default_start" and list(value) == list(PAPER_START) and \
                task_dim not in (None, len(PAPER_START)):
            out[spec.name] = ()  # the paper's start, the default, means nothing to this arm
            continue
        if isinstance(spec.default, list):
            size = 3 if spec.name == "gravity" else task_dim
            out[spec.name] = _check_vector(spec.name, value, size)
        else:
            out[spec.name] = _check_scalar(spec, value)
    if out["publish"] not in PUBLISH_MODES:
        raise ConfigError(f"`publish` must be one of {', '.join(PUBLISH_MODES)}, got "
                          f"{out['publish']!r}")
    if out["candidates"] > out["starts"]:
        raise ConfigError(f"`candidates` ({out['candidates']}) must not exceed `starts` "
                          f"({out['starts']}): only the starts' direct solutions can be "
                          f"continued")
    if 0 < out["memory_spans"] < MIN_REPLAN_SPANS:
        raise ConfigError(f"`memory_spans` must be 0 or at least {MIN_REPLAN_SPANS}, got "
                          f"{out['memory_spans']}")
    if 0 < out["replan_spans"] < MIN_REPLAN_SPANS:
        raise ConfigError(f"`replan_spans` must be 0 or at least {MIN_REPLAN_SPANS}, got "
                          f"{out['replan_spans']}")
    if not out["default_start"] and task_dim in (None, len(PAPER_START)):
        raise ConfigError("`default_start` must not be empty")
    return PlannerConfig(**{f.name: out[f.name] for f in fields(PlannerConfig)})


def planner_model(config: PlannerConfig):
    """The planner's :class:`~tocontrol_ros.core.robot.model.RobotModel` of a config.

    The ``joint_limits`` file's ``max_effort`` entries narrow the URDF's torque limits
    (the model plans against the tighter).
    """
    model = load_model(config.robot_description, config.robot_description_file,
                       base_link=config.base_link or None, tip_link=config.tip_link or None,
                       gravity=config.gravity, task_axes=config.task_axes or None,
                       locked_joints=parse_locked_joints(config.locked_joints))[0]
    if config.joint_limits:
        from tocontrol_ros.core.robot.limits import load_joint_limits_yaml, narrowed_efforts

        tau = narrowed_efforts(model.joint_names, model.tau_max,
                               load_joint_limits_yaml(config.joint_limits),
                               f"`joint_limits` file {config.joint_limits!r}")
        if np.any(tau != model.tau_max):
            model = replace(model, tau_max=tau)
    return model


def planner_collision(config: PlannerConfig, model, scene=None):
    """The collision model of a config (None when collision checking is off).

    On when ``scene_file`` or ``robot_description_semantic`` is set, or a ``scene`` is
    given (one from ``~/scene``). Raises the core's ModelError (a mesh that cannot be found,
    a malformed SRDF) or ProblemError (a malformed scene file), naming what was wrong.
    """
    if scene is None and not (config.scene_file or config.robot_description_semantic):
        return None
    from tocontrol_ros.core.geometry.collision import collision_model
    from tocontrol_ros.core.geometry.scene import Scene, load_scene
    from tocontrol_ros.core.robot.model import default_urdf_path

    if scene is None:
        scene = load_scene(config.scene_file, frame=model.base_link) if config.scene_file \
            else Scene()
    urdf = config.robot_description.strip() or config.robot_description_file.strip() or \
        default_urdf_path()
    return collision_model(model, urdf, config.robot_description_semantic.strip() or None,
                           scene, config.margin)


def planner_limits(config: PlannerConfig, model):
    """The URDF's joint limits narrowed by the ``joint_limits`` file (no margin yet)."""
    from tocontrol_ros.core.robot.limits import JointLimits, load_joint_limits_yaml

    limits = JointLimits.from_model(model)
    if config.joint_limits:
        limits = limits.narrowed(load_joint_limits_yaml(config.joint_limits),
                                 f"`joint_limits` file {config.joint_limits!r}")
    return limits


def solver_options(config: PlannerConfig):
    """The :class:`~tocontrol_ros.core.types.options.SolverOptions` of a config."""
    return SolverOptions(**{name: getattr(config, name) for name in SOLVER_PARAMETERS})


def warm_up_problems(config: PlannerConfig, model, limits) -> list:
    """One problem of each kind the node serves, inside ``limits``: the warm-up's.

    A point start and a joint-state start, both to a point target, on a generic move
    (alternating signs: not along a singular one) inside the position limits.
    """
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    lo, hi = limits.plan_lower, limits.plan_upper
    bounded = np.isfinite(lo) & np.isfinite(hi)
    lo, hi = np.where(bounded, lo, 0.0), np.where(bounded, hi, 0.0)
    qa = np.where(bounded, lo + 0.4 * (hi - lo), 0.3)
    qb = np.where(bounded, qa + 0.2 * (hi - lo) * (-1.0) ** np.arange(model.n),
                  qa + 0.5 * (-1.0) ** np.arange(model.n))
    limits = limits.with_margin(config.limit_margin)
    return [Problem(model, start, point(model.point(qb)), k=config.k,
                    reserve=config.reserve, limits=limits)
            for start in (point(model.point(qa)), joint_state(qa))]


def plan_problem(config: PlannerConfig, model, limits, start: tuple, target,
                 collision=None, target_q=None):
    """The problem from ``start`` to ``target`` (m); raises TocontrolError.

    ``collision``: the collision model in use (:func:`planner_collision`, its scene perhaps
    from ``~/scene``), with the config's ``margin``; None: no geometry.
    ``target_q`` (rad, m; shape (n,)): a joint-space target at rest instead of ``target``.

    ``start``: ``("point", p)`` or ``("state", q, qd)`` (a request's start, or a
    hand-off's state). ``limits``: :func:`planner_limits` (the margin is applied here). A
    joint-state velocity a little over a planning limit (a measured arm's tracking
    overshoot, or the published samples' interpolant at a hand-off where the motion runs at
    the limit) is planned from the limit
    (:meth:`~tocontrol_ros.core.robot.limits.JointLimits.admissible_velocity`).
    """
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    limits = limits.with_margin(config.limit_margin)
    begin = point(start[1]) if start[0] == "point" else \
        joint_state(start[1], limits.admissible_velocity(start[2]))
    if collision is not None and collision.margin != config.margin:
        collision = collision.with_scene(margin=config.margin)
    end = point(target) if target_q is None else joint_state(target_q)
    return Problem(model, begin, end, k=config.k, reserve=config.reserve, limits=limits,
                   collision=collision)
