"""URDF -> serial chain: the numeric description of the bodies the dynamics are built on.

The URDF is parsed with ``urdf_parser_py`` (the ROS parser). The chain between a base link
and a tip link is reduced to one rigid body per moving joint: links attached by fixed joints
(or by joints the caller locks) are lumped into the body they ride on. Stages:
:func:`read_urdf` (file or XML string -> parsed URDF), :class:`_Tree` (the link tree, checked:
no closed chain, defined links, the base and tip), :meth:`_Tree.path` (the joints from the
base to the tip), :meth:`_Tree.rigid_group` (the links riding on one body) and
:func:`chain_from_urdf`, which assembles a :class:`Chain`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import ModelError
from tocontrol_ros.core.robot.kinematics import axis_rotation

__all__ = ["Body", "Chain", "JointFrame", "MOVING_TYPES", "chain_from_urdf",
           "default_urdf_path", "joint_frames", "link_placements", "origin_pose", "read_urdf"]

MOVING_TYPES = ("revolute", "continuous", "prismatic")
#: Lumped bodies lighter than this (kg) count as "no inertia".
MIN_MASS = 1e-12


def default_urdf_path() -> Path:
    """Path of the paper's arm, ``config/galicki_3r.urdf``, installed or in the source tree.

    Looks in the package's share directory found through the ament index (a colcon install,
    or a pip install with ``AMENT_PREFIX_PATH`` naming its prefix), then in
    ``sys.prefix/share/tocontrol_ros/config`` (a pip install without the ament
    environment), then in the source tree's ``config/``.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FileNotFoundError
        When none of those holds the file; the message lists where it looked.
    """
    import sys

    dirs = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        dirs.append(Path(get_package_share_directory("tocontrol_ros")) / "config")
    except (ImportError, PackageNotFoundError, OSError):
        pass  # not in an ament index (OSError: AMENT_PREFIX_PATH unset)
    dirs.append(Path(sys.prefix) / "share" / "tocontrol_ros" / "config")
    dirs.append(Path(__file__).resolve().parents[2] / "config")
    candidates = [d / "galicki_3r.urdf" for d in dirs]
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError("bundled URDF 'galicki_3r.urdf' not found; looked in: "
                            + ", ".join(str(p) for p in candidates))


def _rpy_matrix(rpy: Sequence[float]) -> np.ndarray:
    """Rotation matrix of URDF roll-pitch-yaw angles, ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _origin(elem) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) of a URDF ``<origin>`` (identity when absent)."""
    if elem is None:
        return np.eye(3), np.zeros(3)
    xyz = np.zeros(3) if elem.xyz is None else np.asarray(elem.xyz, dtype=float)
    rpy = np.zeros(3) if elem.rpy is None else np.asarray(elem.rpy, dtype=float)
    return _rpy_matrix(rpy), xyz


def origin_pose(elem) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) (m) of a parsed URDF ``<origin>`` (or None)."""
    return _origin(elem)


@dataclass(frozen=True)
class Body:
    """One moving joint and the rigid body it moves (numeric constants of the chain).

    Attributes
    ----------
    joint : str
        Name of the URDF joint.
    kind : str
        ``"revolute"`` (also for URDF ``continuous``) or ``"prismatic"``.
    rotation, translation : ndarray, shape (3, 3) and (3,)
        Placement of the joint frame in the previous body's frame (m).
    axis : ndarray, shape (3,)
        Unit joint axis in the joint (= body) frame.
    mass : float
        Lumped mass of the body (kg).
    com : ndarray, shape (3,)
        Centre of mass in the body frame (m).
    inertia : ndarray, shape (3, 3)
        Inertia about the centre of mass, body axes (kg m^2).
    links : tuple of str
        URDF links lumped into this body.
    """

    joint: str
    kind: str
    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    links: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class Chain:
    """A serial chain read from a URDF: bodies, tip frame and per-joint limits.

    Attributes
    ----------
    name : str
        URDF robot name.
    joint_names : tuple of str, length n
    bodies : tuple of Body, length n
    tip_rotation, tip_translation : ndarray, shape (3, 3) and (3,)
        Tip frame in the last body's frame.
    base_link, tip_link : str
    tau_max : ndarray, shape (n,)
        Torque (N m) or force (N) limits, from ``<limit effort>``.
    damping : ndarray, shape (n,)
        Viscous friction (N m s/rad or N s/m), from ``<dynamics damping>``.
    coulomb : ndarray, shape (n,)
        ``<dynamics friction>``.
    q_lower, q_upper : ndarray, shape (n,)
        Position limits (rad or m); infinite for continuous joints.
    qd_max : ndarray, shape (n,)
        Velocity limits (rad/s or m/s); infinite when absent.
    locked : tuple of (str, float)
        Moving joints held fixed and their positions (rad or m): those of ``locked_joints``
        and those at or below the tip link, locked at 0 moved into their limits.
    """

    name: str
    joint_names: tuple[str, ...]
    bodies: tuple[Body, ...]
    tip_rotation: np.ndarray
    tip_translation: np.ndarray
    base_link: str
    tip_link: str
    tau_max: np.ndarray
    damping: np.ndarray
    q_lower: np.ndarray
    q_upper: np.ndarray
    qd_max: np.ndarray
    coulomb: np.ndarray
    locked: tuple[tuple[str, float], ...]


def read_urdf(source) -> tuple[object, str]:
    """Parse a URDF file path or XML string; returns the parsed robot and a label for errors.

    Raises
    ------
    ModelError
        A missing file, a malformed URDF, or a ``source`` of another type.
    """
    from urdf_parser_py.urdf import URDF

    text = None
    label = "URDF string"
    if isinstance(source, os.PathLike) or (
            isinstance(source, str) and not source.lstrip().startswith("<")):
        path = Path(source)
        label = str(path)
        if not path.is_file():
            raise ModelError(f"URDF file not found: {path}")
        # Bytes, so that lxml honours an `<?xml ... encoding="..."?>` declaration (it
        # rejects a str that carries one, and xacro output always does).
        text = path.read_bytes()
    elif isinstance(source, str):
        # A str is already decoded: its encoding declaration is stale, and lxml refuses it.
        text = re.sub(r"^\s*<\?xml[^>]*\?>", "", source, count=1)
    else:
        raise ModelError(f"`source` must be a URDF path or XML string, got "
                         f"{type(source).__name__}")
    # urdf_parser_py reports unknown tags on stderr and raises on structural errors.
    import contextlib
    import io

    sink = io.StringIO()
    try:
        with contextlib.redirect_stderr(sink):
            robot = URDF.from_xml_string(text)
    except Exception as exc:  # noqa: BLE001 - parser raises lxml, ParseError, ValueError...
        raise ModelError(f"malformed URDF ({label}): {exc}") from exc
    return robot, label


class _Tree:
    """The link tree of a parsed URDF, checked: links defined, no link with two parents."""

    def __init__(self, robot, label: str) -> None:
        self.label = label
        self.links = {link.name: link for link in robot.links}
        self.parent_joint: dict[str, object] = {}
        self.children: dict[str, list] = {name: [] for name in self.links}
        for j in robot.joints:
            for role, link_name in (("parent", j.parent), ("child", j.child)):
                if link_name not in self.links:
                    raise ModelError(f"joint {j.name!r}: {role} link {link_name!r} is not "
                                     f"defined")
            if j.child in self.parent_joint:
                raise ModelError(
                    f"closed chain: link {j.child!r} is the child of both joint "
                    f"{self.parent_joint[j.child].name!r} and joint {j.name!r}")
            self.parent_joint[j.child] = j
            self.children[j.parent].append(j)

    def ends(self, base_link: str | None, tip_link: str | None) -> tuple[str, str]:
        """The base and tip links: the given ones, checked, or the root and the only leaf."""
        if base_link is None:
            roots = [name for name in self.links if name not in self.parent_joint]
            if len(roots) != 1:
                raise ModelError(f"closed chain or several trees: root links {roots}; "
                                 f"pass `base_link`")
            base_link = roots[0]
        self._check_link("base", base_link)
        if tip_link is None:
            leaves = _leaves_below(base_link, self.children)
            if len(leaves) != 1:
                raise ModelError(f"several leaf links below {base_link!r}: {leaves}; pass "
                                 f"`tip_link`")
            tip_link = leaves[0]
        self._check_link("tip", tip_link)
        return base_link, tip_link

    def _check_link(self, role: str, name: str) -> None:
        if name not in self.links:
            raise ModelError(f"{role} link {name!r} is not a link of {self.label} "
                             f"(links: {sorted(self.links)})")

    def path(self, base_link: str, tip_link: str) -> list:
        """The joints from the base to the tip, of supported types."""
        path = []
        link = tip_link
        while link != base_link:
            if link not in self.parent_joint:
                raise ModelError(f"tip link {tip_link!r} is not below base link "
                                 f"{base_link!r}")
            j = self.parent_joint[link]
            path.append(j)
            link = j.parent
        path.reverse()
        for j in path:
            if j.type not in MOVING_TYPES + ("fixed",):
                raise ModelError(f"joint {j.name!r}: unsupported type {j.type!r} (supported: "
                                 f"revolute, continuous, prismatic, fixed)")
        return path

    def rigid_group(self, root_link: str, next_joint, locked: Mapping[str, float],
                    on_path: set[str], ends: tuple[str, str]) -> dict:
        """Links rigidly attached to ``root_link``, with their pose in its frame.

        The walk stops at ``next_joint`` (the next moving joint of the chain); any other
        moving joint that is not ``locked`` makes the chain branch (an error naming it).

        Returns
        -------
        dict of str to (ndarray (3, 3), ndarray (3,))
            Link name -> rotation and translation in ``root_link``'s frame.
        """
        poses = {root_link: (np.eye(3), np.zeros(3))}
        stack = [root_link]
        while stack:
            lk = stack.pop()
            rot_l, pos_l = poses[lk]
            for j in self.children[lk]:
                if next_joint is not None and j is next_joint:
                    continue
                if j.type in MOVING_TYPES and j.name not in locked:
                    where = "on" if j.name in on_path else "off"
                    raise ModelError(
                        f"branching chain: moving joint {j.name!r} ({where} the "
                        f"{ends[0]!r} -> {ends[1]!r} path) branches off link {lk!r}; "
                        f"choose another tip link or lock it with `locked_joints`")
                if j.type not in MOVING_TYPES + ("fixed",):
                    raise ModelError(f"joint {j.name!r}: unsupported type {j.type!r}")
                value = float(locked.get(j.name, 0.0))
                r, p = _joint_motion(j, value) if j.type != "fixed" else _origin(j.origin)
                poses[j.child] = (rot_l @ r, pos_l + rot_l @ p)
                stack.append(j.child)
        return poses


@dataclass(frozen=True)
class JointFrame:
    """One joint of a whole URDF tree: where its child link sits on its parent link.

    What robot_state_publisher needs to broadcast the link frames (``/tf``, ``/tf_static``);
    :func:`tocontrol_ros.core.robot.kinematics.joint_transform` gives the child's frame in
    the parent's at a joint position.

    Attributes
    ----------
    joint : str
        Name of the URDF joint.
    kind : str
        ``"fixed"``, ``"revolute"`` (also for URDF ``continuous``) or ``"prismatic"``.
    parent, child : str
        The joint's parent and child links.
    rotation, translation : ndarray, shape (3, 3) and (3,)
        The joint's ``<origin>`` in the parent link's frame (m).
    axis : ndarray, shape (3,)
        Unit joint axis in the joint frame (``[1, 0, 0]`` for a fixed joint).
    rest : float
        Position (rad, m) for a moving joint that no joint state names: 0, moved into the
        position limits if 0 is outside them (as a joint locked below the tip).
    """

    joint: str
    kind: str
    parent: str
    child: str
    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray
    rest: float


def joint_frames(source) -> tuple[JointFrame, ...]:
    """Every fixed and moving joint of a URDF, parents before children.

    Parameters
    ----------
    source : str or os.PathLike
        URDF XML or the path of a URDF file.

    Returns
    -------
    tuple of JointFrame
        In tree order from the root link(s). Joints of other types (``floating``,
        ``planar``) are left out, as robot_state_publisher leaves them to other
        broadcasters.

    Raises
    ------
    ModelError
        A URDF that cannot be parsed, a link with two parents, an axis of zero length.
    """
    robot, label = read_urdf(source)
    tree = _Tree(robot, label)
    roots = [name for name in tree.links if name not in tree.parent_joint]
    out = []
    stack = list(reversed(roots))
    while stack:
        link = stack.pop()
        for j in reversed(tree.children[link]):
            stack.append(j.child)
        for j in tree.children[link]:
            if j.type not in MOVING_TYPES + ("fixed",):
                continue
            rot, pos = _origin(j.origin)
            if j.type == "fixed":
                out.append(JointFrame(j.name, "fixed", j.parent, j.child, rot, pos,
                                      np.array([1.0, 0.0, 0.0]), 0.0))
                continue
            lim = j.limit
            lo = -math.inf if lim is None or lim.lower is None or j.type == "continuous" \
                else float(lim.lower)
            hi = math.inf if lim is None or lim.upper is None or j.type == "continuous" \
                else float(lim.upper)
            kind = "prismatic" if j.type == "prismatic" else "revolute"
            out.append(JointFrame(j.name, kind, j.parent, j.child, rot, pos, _joint_axis(j),
                                  float(min(max(0.0, lo), hi))))
    return tuple(out)


def _joint_motion(j, value: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a moving joint's child frame at position ``value`` (rad or m)."""
    rot, pos = _origin(j.origin)
    axis = _joint_axis(j)
    if j.type == "prismatic":
        return rot, pos + rot @ axis * value
    return rot @ axis_rotation(axis, value), pos


def _dynamics(j) -> tuple[float, float]:
    """``<dynamics damping>`` (>= 0) and ``<dynamics friction>`` of a joint (0 if absent)."""
    dyn = j.dynamics
    damping = float(dyn.damping or 0.0) if dyn is not None else 0.0
    coulomb = float(dyn.friction or 0.0) if dyn is not None else 0.0
    if damping < 0:
        raise ModelError(f"joint {j.name!r}: <dynamics damping> must be >= 0, got "
                         f"{damping}")
    return damping, coulomb


def chain_from_urdf(robot, label: str, base_link: str | None = None,
                    tip_link: str | None = None,
                    locked_joints: Mapping[str, float] | None = None) -> Chain:
    """The serial chain of a parsed URDF (:func:`read_urdf`) between two links.

    Parameters
    ----------
    robot : urdf_parser_py.urdf.Robot
    label : str
        Names the URDF in errors.
    base_link, tip_link, locked_joints
        See :func:`~tocontrol_ros.core.robot.model.load_robot`.

    Returns
    -------
    Chain

    Raises
    ------
    ModelError
        Missing links, a chain that branches or closes, an unsupported joint type, a body
        without mass, a missing or non-positive limit.
    """
    locked = dict(locked_joints or {})
    joint_names = {j.name for j in robot.joints}
    for name in locked:
        if name not in joint_names:
            raise ModelError(f"`locked_joints` names joint {name!r}, which is not in {label}")
    tree = _Tree(robot, label)
    base_link, tip_link = tree.ends(base_link, tip_link)
    path = tree.path(base_link, tip_link)
    locked = _lock_beyond_tip(tree, tip_link, locked)
    on_path = {j.name for j in path}
    moving = [j for j in path if j.type in MOVING_TYPES and j.name not in locked]
    if not moving:
        raise ModelError(f"no moving joint between {base_link!r} and {tip_link!r}")

    bodies, limits, frictions = [], [], []
    frame_poses = tree.rigid_group(base_link, moving[0], locked, on_path, (base_link, tip_link))
    tip_pose = None
    for idx, j in enumerate(moving):
        rot_parent, pos_parent = frame_poses[j.parent]
        rot_o, pos_o = _origin(j.origin)
        nxt = moving[idx + 1] if idx + 1 < len(moving) else None
        poses = tree.rigid_group(j.child, nxt, locked, on_path, (base_link, tip_link))
        mass, com, inertia = _lump_inertia(poses, tree.links)
        if mass < MIN_MASS:
            raise ModelError(
                f"link {j.child!r} (moved by joint {j.name!r}) has no <inertial> mass, nor "
                f"does anything rigidly attached to it; the dynamics need mass and inertia")
        bodies.append(Body(
            joint=j.name, kind="prismatic" if j.type == "prismatic" else "revolute",
            rotation=rot_parent @ rot_o, translation=pos_parent + rot_parent @ pos_o,
            axis=_joint_axis(j), mass=mass, com=com, inertia=inertia,
            links=tuple(poses)))
        limits.append(_joint_limits(j))
        frictions.append(_dynamics(j))
        if tip_link in poses:
            tip_pose = poses[tip_link]
        frame_poses = poses
    if tip_pose is None:  # pragma: no cover - the tip is on the path by construction
        raise ModelError(f"tip link {tip_link!r} not reached")
    tau_max, lower, upper, vmax = (np.array(col) for col in zip(*limits, strict=True))
    damping, coulomb = (np.array(col) for col in zip(*frictions, strict=True))
    return Chain(name=robot.name or "robot", joint_names=tuple(b.joint for b in bodies),
                 bodies=tuple(bodies), tip_rotation=tip_pose[0], tip_translation=tip_pose[1],
                 base_link=base_link, tip_link=tip_link,
                 tau_max=tau_max, damping=damping, q_lower=lower, q_upper=upper,
                 qd_max=vmax, coulomb=coulomb,
                 locked=tuple(sorted((k, float(v)) for k, v in locked.items())))


def _lock_beyond_tip(tree, tip_link: str, locked: dict) -> dict:
    """``locked`` plus every moving joint at or below the tip link (a gripper's fingers).

    Such a joint that ``locked`` does not name is locked at 0, moved into its position
    limits if 0 is outside them (its lower limit, or its upper one if that is below 0).
    """
    out = dict(locked)
    stack = [tip_link]
    while stack:
        lk = stack.pop()
        for j in tree.children[lk]:
            if j.type in MOVING_TYPES and j.name not in out:
                lim = j.limit
                lo = -math.inf if lim is None or lim.lower is None else float(lim.lower)
                hi = math.inf if lim is None or lim.upper is None else float(lim.upper)
                out[j.name] = float(min(max(0.0, lo), hi))
            stack.append(j.child)
    return out


def _leaves_below(base: str, children: dict) -> list[str]:
    leaves, stack = [], [base]
    while stack:
        lk = stack.pop()
        if not children[lk]:
            leaves.append(lk)
        stack.extend(j.child for j in children[lk])
    return sorted(leaves)


def _joint_axis(j) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=float)
    norm = np.linalg.norm(axis)
    if axis.shape != (3,) or not np.isfinite(norm) or norm < 1e-12:
        raise ModelError(f"joint {j.name!r}: <axis xyz> must be a non-zero 3-vector, got "
                         f"{j.axis!r}")
    return axis / norm


def _joint_limits(j) -> tuple[float, float, float, float]:
    lim = j.limit
    if lim is None or lim.effort is None:
        raise ModelError(f"joint {j.name!r}: <limit effort> is missing; the torque limit is "
                         f"the control bound")
    effort = float(lim.effort)
    if not effort > 0 or not math.isfinite(effort):
        raise ModelError(f"joint {j.name!r}: <limit effort> must be positive and finite, "
                         f"got {lim.effort}")
    velocity = math.inf if lim.velocity is None else float(lim.velocity)
    if not velocity > 0:
        raise ModelError(f"joint {j.name!r}: <limit velocity> must be positive, got "
                         f"{lim.velocity}")
    if j.type == "continuous":
        return effort, -math.inf, math.inf, velocity
    lo = -math.inf if lim.lower is None else float(lim.lower)
    hi = math.inf if lim.upper is None else float(lim.upper)
    if not lo < hi:
        raise ModelError(f"joint {j.name!r}: position limits must satisfy lower < upper, got "
                         f"lower={lim.lower} upper={lim.upper}")
    return effort, lo, hi, velocity


def _lump_inertia(poses: dict, links: dict) -> tuple[float, np.ndarray, np.ndarray]:
    """Total mass (kg), centre of mass (3,) and inertia about it (3, 3) of rigid links."""
    masses, coms, inertias = [], [], []
    for name, (rot_l, pos_l) in poses.items():
        inertial = links[name].inertial
        if inertial is None or inertial.mass is None:
            continue
        mass = float(inertial.mass)
        if mass < 0:
            raise ModelError(f"link {name!r}: <mass> must be >= 0, got {mass}")
        rot_i, pos_i = _origin(inertial.origin)
        ine = inertial.inertia
        tensor = np.zeros((3, 3)) if ine is None else np.array([
            [ine.ixx, ine.ixy, ine.ixz], [ine.ixy, ine.iyy, ine.iyz],
            [ine.ixz, ine.iyz, ine.izz]], dtype=float)
        if np.any(np.linalg.eigvalsh(tensor) < -1e-12 * max(1.0, np.abs(tensor).max())):
            raise ModelError(f"link {name!r}: <inertia> is not positive semi-definite")
        rot = rot_l @ rot_i
        masses.append(mass)
        coms.append(pos_l + rot_l @ pos_i)
        inertias.append(rot @ tensor @ rot.T)
    total = float(sum(masses))
    if total < MIN_MASS:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(mi * ci for mi, ci in zip(masses, coms, strict=True)) / total
    inertia = np.zeros((3, 3))
    for mi, ci, ii in zip(masses, coms, inertias, strict=True):
        d = ci - com
        inertia += ii + mi * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return total, com, inertia


def link_placements(robot, label: str, chain: Chain) -> dict[str, tuple[int, np.ndarray,
                                                                        np.ndarray]]:
    """Where every link of ``chain`` sits: the body that carries it and its pose there.

    The same walk as :func:`chain_from_urdf`'s (links rigidly attached, locked joints at
    their locked positions), so that a link's geometry moves with the body whose inertia
    holds its mass.

    Parameters
    ----------
    robot : urdf_parser_py.urdf.Robot
        The URDF the chain was read from (:func:`read_urdf`).
    label : str
        Names the URDF in errors.
    chain : Chain

    Returns
    -------
    dict of str to (int, ndarray (3, 3), ndarray (3,))
        Link name -> body index (-1: the base, fixed to the world; ``i``: moved by
        ``chain.bodies[i]``), rotation and translation (m) in that body's frame.
    """
    tree = _Tree(robot, label)
    locked = dict(chain.locked)
    path = tree.path(chain.base_link, chain.tip_link)
    on_path = {j.name for j in path}
    moving = [j for j in path if j.type in MOVING_TYPES and j.name not in locked]
    ends = (chain.base_link, chain.tip_link)
    out = {}
    root, joints = chain.base_link, [None] + moving
    for idx, j in enumerate(joints):
        root = chain.base_link if j is None else j.child
        nxt = joints[idx + 1] if idx + 1 < len(joints) else None
        for link, (rot, pos) in tree.rigid_group(root, nxt, locked, on_path, ends).items():
            out[link] = (idx - 1, rot, pos)
    return out
