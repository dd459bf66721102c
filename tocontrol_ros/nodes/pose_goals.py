"""Pose goals (position and orientation of the tip), without ROS: IK, candidates, the check.

A pose goal (``~/goal_pose``, ``~/plan_motion``'s ``TARGET_POSE``) is planned as a MoveIt
user expects: the pose is solved to joint configurations by inverse kinematics
(:func:`~tocontrol_ros.core.robot.ik.ik_pose`, ``pose_ik_seeds`` seeds: the start's
configuration, then fixed pseudo-random ones within the joint limits with ``limit_margin``),
each distinct solution a joint goal at rest. Each is timed by the first motion (TOPP-RA on a
seed path, certified, milliseconds); the ``pose_candidates`` with the least first-motion
``T`` are planned to the optimum by the joint-goal route; the least-``T`` certified motion of
them all is published, after its last sample's tip pose was checked against the goal by the
per-configuration forward kinematics (:func:`end_pose_errors`: neither the solver's CasADi
kinematics nor the IK's batched ones) within ``pose_position_tolerance`` and
``pose_orientation_tolerance``. Why this route rather than the orientation as terminal rows
of the bounded solve: docs/goals.md.

:func:`pose_target` converts the message's fields (the frame, a NaN, a quaternion that is
not unit: the ROS convention of tf2, normalised within 1 % of unit length, refused beyond);
:class:`PoseGoals` serves a request for :class:`~tocontrol_ros.nodes.planning_service.
PlanningService`. Nothing here imports rclpy or a message package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.geometry.reach import clear_pose_configuration
from tocontrol_ros.core.robot.ik import ik_pose
from tocontrol_ros.core.robot.kinematics import joint_transform, quaternion_from_matrix, tip_pose
from tocontrol_ros.core.types.problem import REST_SPEED
from tocontrol_ros.nodes.outcomes import result_values
from tocontrol_ros.nodes.planner_config import solver_options

__all__ = ["QUATERNION_TOL", "PoseGoalError", "PoseTarget", "PoseGoals", "accepted_frames",
           "end_pose_errors", "ik_seeds", "pose_target", "rotation_from_quaternion"]

#: A quaternion is taken (and normalised) when its squared norm is within this of 1, and
#: refused beyond: tf2's rule (``TF_DENORMALIZED_QUATERNION`` in ``BufferCore``, 0.01).
QUATERNION_TOL = 0.01
#: The seeds' generator: fixed, so that the same pose from the same start gives the same
#: IK solutions, the same candidates and the same plan (docs/determinism.md).
SEED = 52


class PoseGoalError(TocontrolError, ValueError):
    """A pose goal that cannot be planned: bad fields, a frame not accepted, unreachable."""


@dataclass(frozen=True)
class PoseTarget:
    """A pose goal in the base frame.

    Attributes
    ----------
    position : ndarray, shape (3,)
        The tip's position (m).
    rotation : ndarray, shape (3, 3)
        The tip's orientation (rotation matrix).
    frame_id : str
        The frame it was given in (the base frame, or a link's frame at the start).
    """

    position: np.ndarray
    rotation: np.ndarray
    frame_id: str

    @property
    def quaternion(self) -> np.ndarray:
        """The orientation as a unit quaternion ``(x, y, z, w)``, shape (4,), ``w >= 0``."""
        return quaternion_from_matrix(self.rotation)


def rotation_from_quaternion(x: float, y: float, z: float, w: float, name: str) -> np.ndarray:
    """The rotation matrix (3, 3) of a quaternion, normalised as tf2 does.

    Raises
    ------
    PoseGoalError
        A NaN or infinite component, or a squared norm farther than :data:`QUATERNION_TOL`
        from 1 (a zero quaternion included); the message names ``name``.
    """
    quat = np.array([x, y, z, w], dtype=float)
    if not np.all(np.isfinite(quat)):
        raise PoseGoalError(f"`{name}` must be finite, got (x, y, z, w) = {quat.tolist()}")
    norm2 = float(quat @ quat)
    if abs(norm2 - 1.0) > QUATERNION_TOL:
        raise PoseGoalError(
            f"`{name}` is not a unit quaternion: |q| = {math.sqrt(norm2):.6g} (x, y, z, w) = "
            f"{quat.tolist()}; quaternions within {QUATERNION_TOL:g} of unit squared norm are "
            "normalised (tf2's rule), others refused")
    x, y, z, w = quat / math.sqrt(norm2)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def accepted_frames(model, planner_frame: str) -> tuple[str, ...]:
    """The frames a pose may be given in: the planner's and base frame, then the links.

    The links are each moving joint's child link (its frame is the joint's) and the tip
    link; a pose in one of them is taken at the start configuration.
    """
    names = [planner_frame, model.base_link]
    names += [body.links[0] for body in model.bodies if body.links]
    names.append(model.tip_link)
    return tuple(dict.fromkeys(names))


def _link_frame(model, frame_id: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and origin (3,) (m) of ``frame_id`` (a link) in the base frame at q."""
    rot, pos = np.eye(3), np.zeros(3)
    for i, body in enumerate(model.bodies):
        r, p = joint_transform(body, q[i])
        pos, rot = pos + rot @ p, rot @ r
        if body.links and body.links[0] == frame_id:
            return rot, pos
    return rot @ model.tip_rotation, pos + rot @ model.tip_translation


def pose_target(position, quaternion, frame_id: str, model, planner_frame: str, start: tuple,
                name: str) -> PoseTarget:
    """A pose message's fields as a :class:`PoseTarget` in the base frame.

    Parameters
    ----------
    position : sequence of 3 float
        ``pose.position`` (m) in ``frame_id``.
    quaternion : sequence of 4 float
        ``pose.orientation`` ``(x, y, z, w)`` in ``frame_id``.
    frame_id : str
        ``header.frame_id``: the planner's frame (``frame_id`` parameter), the base link,
        or a link of the chain (:func:`accepted_frames`), taken at the start.
    model : RobotModel
    planner_frame : str
    start : tuple
        The request's start, ``("state", q, qd)`` or ``("point", p)``; a pose in a moving
        link needs the former.
    name : str
        The message field, for the errors (e.g. ``"target_pose"``).

    Raises
    ------
    PoseGoalError
        A frame not accepted (the message lists those accepted), a NaN, a quaternion that
        is not unit, a link frame without a joint-state start.
    """
    frames = accepted_frames(model, planner_frame)
    if frame_id not in frames:
        raise PoseGoalError(f"`{name}.header.frame_id` {frame_id!r} is not a frame of this "
                            f"planner (no tf lookup); accepted: {', '.join(frames)}")
    p = np.array(position, dtype=float)
    for axis, value in zip("xyz", p, strict=True):
        if not math.isfinite(value):
            raise PoseGoalError(f"`{name}.pose.position.{axis}` must be finite, got {value!r}")
    rot = rotation_from_quaternion(*quaternion, name=f"{name}.pose.orientation")
    if frame_id in (planner_frame, model.base_link):
        return PoseTarget(p, rot, frame_id)
    if start[0] != "state":
        raise PoseGoalError(f"`{name}.header.frame_id` {frame_id!r} is a moving link: a pose "
                            "in it is taken at the start configuration, and there is no "
                            "joint state (the start is a point); give the pose in "
                            f"{planner_frame!r}")
    link_rot, link_pos = _link_frame(model, frame_id, np.asarray(start[1], dtype=float))
    return PoseTarget(link_pos + link_rot @ p, link_rot @ rot, frame_id)


def end_pose_errors(model, q, pose: PoseTarget) -> tuple[float, float]:
    """Position (m) and orientation (rad) errors of the tip at ``q`` (n,) against ``pose``.

    The check before publishing, independent of the IK's own residuals
    (:func:`~tocontrol_ros.core.robot.ik.pose_errors`): the per-configuration kinematics of
    :func:`~tocontrol_ros.core.robot.kinematics.tip_pose`, and the angle of ``R^T R_goal``
    from its trace and skew part (``atan2``: accurate near 0 and near pi).
    """
    rot, pos = tip_pose(model, q)
    rel = rot.T @ pose.rotation
    skew = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    angle = math.atan2(0.5 * float(np.linalg.norm(skew)), 0.5 * (float(np.trace(rel)) - 1.0))
    return float(np.linalg.norm(pos - pose.position)), abs(angle)


def ik_seeds(model, limits, start: tuple, count: int) -> np.ndarray:
    """The IK's seeds, shape (count, n): the start's configuration, then fixed random ones.

    Random seeds are uniform within the position limits (continuous joints in [-pi, pi]),
    from a generator seeded with :data:`SEED`.
    """
    lo = np.where(np.isfinite(limits.lower), limits.lower, -np.pi)
    hi = np.where(np.isfinite(limits.upper), limits.upper, np.pi)
    rng = np.random.default_rng(SEED)
    seeds = [np.clip(np.asarray(start[1], dtype=float), lo, hi)] if start[0] == "state" \
        else []
    seeds += list(rng.uniform(lo, hi, size=(max(count - len(seeds), 0), model.n)))
    return np.array(seeds[:count])


class PoseGoals:
    """Serves pose requests for a planning service (its planner, outputs, publication).

    Parameters
    ----------
    service : PlanningService
    """

    def __init__(self, service) -> None:
        self.service = service

    def solutions(self, req) -> list[np.ndarray]:
        """The pose's distinct IK solutions within the limits (with ``limit_margin``).

        Raises
        ------
        PoseGoalError
            None found (the message gives the closest errors: an unreachable pose).
        """
        service, config, pose = self.service, req.config, req.target_pose
        limits = service.limits.with_margin(config.limit_margin)
        seeds = ik_seeds(service.model, limits, req.start, config.pose_ik_seeds)
        model = service.model
        found, pos_err, ang_err = ik_pose(model, pose.position, pose.rotation, seeds,
                                          limits.lower, limits.upper)
        if not found:
            raise PoseGoalError(
                f"the pose (position {np.round(pose.position, 6).tolist()} m, orientation "
                f"(x, y, z, w) {np.round(pose.quaternion, 6).tolist()} in "
                f"{service.frame_id!r}) is unreachable within the joint limits: no IK "
                f"solution from {len(seeds)} seeds (pose_ik_seeds); the closest is "
                f"{pos_err:.3g} m and {ang_err:.3g} rad away")
        return found

    def serve(self, req) -> None:
        """Plan ``req`` (a pose request) and publish its least-``T`` certified motion.

        Always finishes ``req``: ``solved`` with the achieved errors in its values, or
        ``failed`` (unreachable, no certified motion, the end pose off the tolerances).
        """
        service, config = self.service, req.config
        if self._at_rest_on_the_pose(req):
            return
        try:
            solutions = self.solutions(req)
        except TocontrolError as exc:
            service.finish(req, "ERROR", "failed", str(exc))
            return
        problems, refused = [], []
        for q in solutions:  # a solution in collision (with the scene) is left out
            try:
                problems.append(service.problem(config, req.start, service.model.point(q), q))
            except TocontrolError as exc:
                refused.append(str(exc))
        searched = ""
        if not problems and service.collision is not None:  # look further for a clear one
            q, searched = self._clear_solution(req)
            if q is not None:
                solutions.append(q)
                try:
                    problems.append(service.problem(config, req.start,
                                                    service.model.point(q), q))
                except TocontrolError as exc:
                    refused.append(str(exc))
        if not problems:
            service.finish(req, "ERROR", "failed", f"none of the pose's {len(solutions)} IK "
                           f"solutions can be planned to: {'; '.join(dict.fromkeys(refused))}"
                           f"{searched}")
            return
        options = solver_options(config)
        firsts = []
        for problem in problems:
            if service.finish_stopped(req, {}):
                return
            firsts.append(service.planner.first(problem, options))
        timed = [f.success and f.trajectory is not None for f in firsts]
        order = sorted(range(len(problems)), key=lambda i: firsts[i].T
                       if timed[i] else math.inf)
        motions = [(firsts[i], problems[i]) for i in order if timed[i]]
        if motions:  # the best certified motion so far: what a cancel returns
            req.first = motions[0][0]
        planned = order[:config.pose_candidates]
        times = ", ".join(f"{firsts[i].T:.4g}" if timed[i] else "none" for i in order)
        service.status(req, "OK", "candidates", f"request {req.id}: {len(solutions)} IK "
                       f"solutions of the pose, first motions T = {times} s; planning the "
                       f"optimum to the best {len(planned)}",
                       {"ik_solutions": len(solutions),
                        "best_T": motions[0][0].T if motions else 0.0})
        for i in planned:
            if service.finish_stopped(req, {}):
                return
            motions.append((service.planner.plan(problems[i], options,
                                                 should_stop=service.should_stop(req)),
                            problems[i]))
        extra = {"ik_solutions": len(solutions), "pose_candidates": len(planned),
                 "ik_refused": len(refused)}
        if service.finish_stopped(req, extra):
            return
        self._publish(req, motions, extra)

    def _clear_solution(self, req) -> tuple[np.ndarray | None, str]:
        """A solution of the pose clear of the scene, when none of the first ones was.

        :func:`~tocontrol_ros.core.geometry.reach.clear_pose_configuration`: more IK seeds
        (a fixed amount), the first solution clear by the margin (n,) (rad), or None; and
        what the search found, for the refusal's message.
        """
        service, config, pose = self.service, req.config, req.target_pose
        limits = service.limits.with_margin(config.limit_margin)
        found = clear_pose_configuration(service.collision, pose.position, pose.rotation,
                                         limits.lower, limits.upper)
        if found.found:
            return found.q, ""
        if not found.tried:
            return None, (f"; searched further with the scene: no IK solution inside the limits "
                        f"from {found.seeds} more seeds")
        return None, (f"; searched further with the scene: of {found.tried} more IK solutions "
                    f"inside the limits (from {found.seeds} seeds) none is clear by the margin "
                    f"({service.collision.margin:g} m), the clearest has "
                    f"{' and '.join(found.pair)} {found.clearance:.4f} m apart")

    def _at_rest_on_the_pose(self, req) -> bool:
        """Finish ``req`` when its start is at rest on the pose already (True): T = 0."""
        service, config, pose = self.service, req.config, req.target_pose
        if req.start[0] != "state" or np.max(np.abs(req.start[2]), initial=0.0) > REST_SPEED:
            return False
        q = np.asarray(req.start[1], dtype=float)
        pos_err, ang_err = end_pose_errors(service.model, q, pose)
        if pos_err > config.pose_position_tolerance or \
                ang_err > config.pose_orientation_tolerance:
            return False
        service.finish(req, "OK", "solved", f"nothing to plan: the start at rest is on the pose "
                       f"(within {pos_err:.2g} m and {ang_err:.2g} rad); T = 0, no trajectory "
                       "published", {"position_error": pos_err, "orientation_error": ang_err,
                                     "samples": 1},
                       path=service.out.rest_path(service.model.point(q)))
        return True

    def _publish(self, req, motions: list, extra: dict[str, Any]) -> None:
        service, config, pose = self.service, req.config, req.target_pose
        # A motion to a solution within MIN_MOVE of the start is TRIVIAL (no trajectory).
        good = [(m, p) for m, p in motions if m.trajectory is not None and (
            m.success or m.status.name == "TIME_LIMIT")]
        if not good:
            why = "; ".join(dict.fromkeys(m.message for m, _ in motions)) or "no candidate"
            service.finish(req, "ERROR", "failed", f"no certified motion to the pose's IK "
                           f"solutions ({why})", extra)
            return
        best, problem = min(good, key=lambda pair: pair[0].T)
        sample = best.trajectory.sample(config.sample_period)
        pos_err, ang_err = end_pose_errors(service.model, sample.q[-1], pose)
        extra = {**extra, **result_values(best), "position_error": pos_err,
                 "orientation_error": ang_err,
                 "target_orientation": pose.quaternion,
                 "method_of_published": "first motion" if best.method == "first"
                 else "optimum"}
        if pos_err > config.pose_position_tolerance or \
                ang_err > config.pose_orientation_tolerance:
            service.finish(req, "ERROR", "failed", f"the motion's end misses the pose: "
                           f"position error {pos_err:.3g} m (pose_position_tolerance "
                           f"{config.pose_position_tolerance:g}), orientation error "
                           f"{ang_err:.3g} rad (pose_orientation_tolerance "
                           f"{config.pose_orientation_tolerance:g}); nothing published",
                           extra)
            return
        service.publish_final(req, best, None, message_prefix="", extra=extra,
                              start_point=problem.start_point,
                              note=f"; pose reached within {pos_err:.2g} m and "
                              f"{ang_err:.2g} rad")

