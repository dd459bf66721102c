"""The tracker node's parameters, declared in one table, read into a frozen config.

:data:`PARAMETERS` (each with its description and range) and :class:`TrackerConfig`, the
checked values the node runs with; the counterpart of
:mod:`tocontrol_ros.nodes.planner_config`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.sim.tracking import (
    PlantConfig,
    TrackingGains,
)
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

__all__ = ["PAPER_START_Q", "PARAMETERS", "TrackerConfig", "plant_text"]

#: Start configuration of the paper's example (Section 5) on the bundled arm: the tip at
#: (1.0, 1.0) (to 2e-10 m), on the self-motion branch where the k = 4 plan starts.
PAPER_START_Q = (-0.5487769600, 2.2111963800, 1.1613502200)


# -------------------------------------------------------------------- parameters
def _gains(values: Mapping[str, Any]) -> TrackingGains:
    """Per-joint gains when ``kp`` or ``kd`` is set (the other zero), else ``bandwidth``'s."""
    if values.get("kp") is None and values.get("kd") is None:
        return TrackingGains(bandwidth=float(values["bandwidth"]))
    return TrackingGains(kp=tuple(values.get("kp") or (0.0,)),
                         kd=tuple(values.get("kd") or (0.0,)))



def _spec(name, default, description, low=None, high=None) -> ParameterSpec:
    return ParameterSpec(name, default, description, low, high, read_only=True)


#: Every parameter: name, default (fixing the type; ``None`` = an optional double array),
#: description with units, inclusive range. All are read-only: the model, the plant and
#: the compiled control law are built at start-up.
PARAMETERS: tuple[ParameterSpec, ...] = (
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_FILE,
    ROBOT_DESCRIPTION_TOPIC,
    ROBOT_DESCRIPTION_TIMEOUT,
    LOCKED_JOINTS,
    _spec("base_link", "", "Base link of the chain; empty: the URDF's root"),
    _spec("tip_link", "", "Tip link (end effector); empty: the only leaf"),
    _spec("bandwidth", 50.0, "Feedback derived from the model (rad/s): the planning "
          "model's inertia at the desired configuration times w^2 e + 2 w de (critically "
          "damped), plus integral action while holding; every mode, aligned joint axes "
          "included, closes at w. At most 0.5 control_rate (the sampled loop's stability "
          "bound with a 2x margin). Used unless kp or kd is set", 0.0, 1000.0),
    _spec("kp", None, "Proportional gains per joint (or one for all), normalised: fraction "
          "of tau_max per rad (per m); set (kp or kd): these per-joint gains instead of "
          "bandwidth's"),
    _spec("kd", None, "Derivative gains per joint (or one for all), normalised: fraction "
          "of tau_max per rad/s (per m/s); set (kp or kd): these per-joint gains instead of "
          "bandwidth's"),
    _spec("mass_scale", 1.0, "Plant: factor on every link mass", 0.01, 100.0),
    _spec("inertia_scale", 1.0, "Plant: factor on every link inertia about its centre of "
          "mass", 0.01, 100.0),
    _spec("friction_scale", 1.0, "Plant: factor on the viscous friction of every joint",
          0.0, 100.0),
    _spec("payload_mass", 0.0, "Plant: point mass at the tip frame origin (kg)", 0.0, 1000.0),
    _spec("torque_noise", 0.0, "Plant: torque noise standard deviation, fraction of tau_max, "
          "drawn per joint and control period", 0.0, 1.0),
    _spec("noise_seed", 0, "Plant: seed of the torque noise", 0, 2**31 - 1),
    _spec("initial_offset", None, "Plant: offset of the initial state from "
          "initial_positions: n positions (rad, m) or 2n (positions, velocities); unset: "
          "none"),
    _spec("initial_positions", None, "Initial configuration (rad, m), held until the first "
          "trajectory; unset: the paper example's start on the bundled arm, else zero "
          "(clipped to 5 % of each range inside the joint limits, where the planner accepts a "
          "start state)"),
    _spec("sim_rate", 2000.0, "Plant integration rate (Hz, fixed-step RK4); an integer "
          "multiple of control_rate", 1.0, 1.0e6),
    _spec("control_rate", 1000.0, "Control-law rate (Hz); the control is held over each "
          "period", 1.0, 1.0e5),
    _spec("publish_rate", 100.0, "Rate of joint_states and ~/tracking_error (Hz of "
          "simulated time)", 0.1, 1.0e4),
    _spec("update_rate", 100.0, "Rate of the simulation timer (Hz of wall time)", 1.0,
          1000.0),
    _spec("time_scale", 1.0, "Simulated seconds per wall second (1: real time; larger: "
          "faster than real time, for tests and batch runs)", 0.001, 1000.0),
    _spec("publish_clock", False, "Publish the simulated time on /clock (stamps then count "
          "from zero)"),
    _spec("trajectory_topic", "planner/trajectory", "Topic of the planner's "
          "trajectory_msgs/JointTrajectory (relative: in the tracker's namespace)"),
    _spec("start_at_first_trajectory", False, "Put the simulated arm at the first "
          "trajectory's first point (positions, velocities, plus initial_offset) when it "
          "arrives, instead of checking it against start_tolerance: for a plan whose start "
          "configuration the planner chooses (a free start on ~/plan). Only before the "
          "first motion and any ~/reset; later trajectories are checked as usual"),
    _spec("start_tolerance", 0.1, "Largest distance (rad, m; any joint) between a "
          "trajectory's first point and the arm's position, now or as published in the last "
          "2 s of wall time (a plan made from the state of a moving arm); farther: rejected",
          0.0, 1.0e3),
    _spec("max_points", 20000, "Largest number of points of a trajectory; more: rejected "
          "before it is parsed", 1, 10_000_000),
    _spec("max_duration", 600.0, "Longest trajectory (s); longer: rejected", 0.001, 1.0e6),
    # ~/follow_joint_trajectory: a joint_trajectory_controller's defaults (its constraints).
    _spec("path_tolerance", 0.0, "Default position tolerance of every joint during an action "
          "goal's motion (rad, m; a goal's path_tolerance overrides it); 0: not checked",
          0.0, 1.0e3),
    _spec("goal_tolerance", 0.0, "Default position tolerance of every joint at an action "
          "goal's end (rad, m; a goal's goal_tolerance overrides it); 0: not checked",
          0.0, 1.0e3),
    _spec("stopped_velocity_tolerance", 0.01, "Largest joint velocity (rad/s, m/s) at which "
          "an action goal's end counts as reached", 0.0, 1.0e3),
    _spec("goal_time", 0.0, "Default time (s) after an action goal's end within which the "
          "goal tolerance must be met (a goal's goal_time_tolerance overrides it); 0: no "
          "limit", 0.0, 1.0e6),
)


@dataclass(frozen=True)
class TrackerConfig:
    """The node's parameters, checked and converted (see :data:`PARAMETERS`)."""

    robot_description: str
    robot_description_file: str
    locked_joints: str
    base_link: str
    tip_link: str
    gains: TrackingGains
    plant: PlantConfig
    initial_positions: tuple[float, ...]
    publish_rate: float
    update_rate: float
    time_scale: float
    publish_clock: bool
    trajectory_topic: str
    start_at_first_trajectory: bool
    start_tolerance: float
    max_points: int
    max_duration: float
    path_tolerance: float = 0.0
    goal_tolerance: float = 0.0
    stopped_velocity_tolerance: float = 0.01
    goal_time: float = 0.0

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> TrackerConfig:
        """Build from parameter values (``None`` for an unset optional array).

        Raises
        ------
        ProblemError
            A value the core rejects (the message names it).
        """
        plant = PlantConfig(
            mass_scale=values["mass_scale"], inertia_scale=values["inertia_scale"],
            friction_scale=values["friction_scale"], payload_mass=values["payload_mass"],
            torque_noise=values["torque_noise"], noise_seed=int(values["noise_seed"]),
            initial_offset=tuple(values["initial_offset"] or ()),
            sim_rate=values["sim_rate"], control_rate=values["control_rate"])
        return cls(
            robot_description=values["robot_description"],
            robot_description_file=values["robot_description_file"],
            locked_joints=values["locked_joints"],
            base_link=values["base_link"], tip_link=values["tip_link"],
            gains=_gains(values),
            plant=plant, initial_positions=tuple(values["initial_positions"] or ()),
            publish_rate=float(values["publish_rate"]),
            update_rate=float(values["update_rate"]), time_scale=float(values["time_scale"]),
            publish_clock=bool(values["publish_clock"]),
            trajectory_topic=values["trajectory_topic"],
            start_at_first_trajectory=bool(values["start_at_first_trajectory"]),
            start_tolerance=float(values["start_tolerance"]),
            max_points=int(values["max_points"]), max_duration=float(values["max_duration"]),
            path_tolerance=float(values.get("path_tolerance", 0.0)),
            goal_tolerance=float(values.get("goal_tolerance", 0.0)),
            stopped_velocity_tolerance=float(values.get("stopped_velocity_tolerance", 0.01)),
            goal_time=float(values.get("goal_time", 0.0)))

    def load_model(self) -> tuple[RobotModel, bool]:
        """The robot model, and whether it is the bundled arm."""
        return load_model(self.robot_description, self.robot_description_file,
                          base_link=self.base_link or None, tip_link=self.tip_link or None,
                          locked_joints=parse_locked_joints(self.locked_joints))

    def start_configuration(self, model: RobotModel, bundled: bool) -> np.ndarray:
        """``initial_positions``, or the default described in :data:`PARAMETERS`."""
        if self.initial_positions:
            q = np.asarray(self.initial_positions, dtype=float)
            if q.shape != (model.n,) or not np.all(np.isfinite(q)):
                raise ProblemError(f"`initial_positions` must be {model.n} finite values, "
                                   f"got {list(self.initial_positions)}")
            return q
        if bundled and model.n == len(PAPER_START_Q):
            return np.array(PAPER_START_Q)
        width = np.where(np.isfinite(model.q_upper - model.q_lower),
                         model.q_upper - model.q_lower, 0.0)
        return np.clip(np.zeros(model.n), model.q_lower + 0.05 * width,
                       model.q_upper - 0.05 * width)


def plant_text(p) -> str:
    """The simulated plant in a line of the start-up log.

    ``p``: the config's :class:`~tocontrol_ros.core.sim.tracking.PlantOptions`.
    """
    if p.identical and p.torque_noise == 0 and not p.initial_offset:
        return f"identical to the model, {p.sim_rate:g} Hz, control {p.control_rate:g} Hz"
    return (f"mass x{p.mass_scale:g}, inertia x{p.inertia_scale:g}, friction "
            f"x{p.friction_scale:g}, payload {p.payload_mass:g} kg, noise "
            f"{p.torque_noise:g}, offset {list(p.initial_offset)}, {p.sim_rate:g} Hz, "
            f"control {p.control_rate:g} Hz")
