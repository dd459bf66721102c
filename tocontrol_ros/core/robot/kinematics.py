"""Forward kinematics of a serial chain in plain numpy (no CasADi), for drawing and messages.

The solver uses the symbolic kinematics of :class:`~tocontrol_ros.core.robot.model.RobotModel`;
these numeric twins run on any thread without compiled functions (markers, paths, figures,
the locked joints of a URDF).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["axis_rotation", "joint_transform", "link_positions", "quaternion_from_matrix",
           "tip_pose", "tip_poses"]


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) by ``angle`` (rad) about the unit vector ``axis`` (3,)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def quaternion_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)``, shape (4,), of a rotation matrix, shape (3, 3).

    Shepperd's method (the largest of the four squared components first, so no division by
    a small number); ``w >= 0``.
    """
    m = np.asarray(rotation, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > max(m[0, 0], m[1, 1], m[2, 2]):
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s,
             0.25 * s]
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s,
             (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] >= m[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s,
             (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s,
             (m[1, 0] - m[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def joint_transform(body, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) (m) of a :class:`Body` in its parent's frame.

    Parameters
    ----------
    body : Body or JointFrame
        A fixed joint (``kind == "fixed"``) ignores `q`.
    q : float
        The joint's position (rad or m).
    """
    if body.kind == "fixed":
        return body.rotation, body.translation
    if body.kind == "prismatic":
        return body.rotation, body.translation + body.rotation @ body.axis * q
    return body.rotation @ axis_rotation(body.axis, q), body.translation


def _frames(model, q):
    """Yield the base frame, then each body's frame, in the base frame: (rotation, origin)."""
    q = np.asarray(q, dtype=float)
    rot = np.eye(3)
    pos = np.zeros(3)
    yield rot, pos
    for i, body in enumerate(model.bodies):
        r, p = joint_transform(body, q[i])
        pos = pos + rot @ p
        rot = rot @ r
        yield rot, pos


def link_positions(model, q) -> np.ndarray:
    """Base origin, each joint's origin and the tip, in the base frame.

    Parameters
    ----------
    model : RobotModel
    q : array_like, shape (n,)
        Joint positions (rad, m).

    Returns
    -------
    ndarray, shape (n + 2, 3)
        Positions (m): row 0 the base origin, rows 1..n the joint origins, row n+1 the tip.
    """
    frames = list(_frames(model, q))
    rot, pos = frames[-1]
    return np.array([p for _, p in frames] + [pos + rot @ model.tip_translation])


def tip_pose(model, q) -> tuple[np.ndarray, np.ndarray]:
    """Tip frame in the base frame: rotation, shape (3, 3), and position, shape (3,) (m).

    Parameters
    ----------
    model : RobotModel
    q : array_like, shape (n,)
        Joint positions (rad, m).
    """
    *_, (rot, pos) = _frames(model, q)
    return rot @ model.tip_rotation, pos + rot @ model.tip_translation


def tip_poses(model, q) -> tuple[np.ndarray, np.ndarray]:
    """:func:`tip_pose` at many configurations at once (one numpy pass per joint).

    Parameters
    ----------
    model : RobotModel
    q : array_like, shape (K, n)
        Joint positions (rad, m).

    Returns
    -------
    rotation : ndarray, shape (K, 3, 3)
    position : ndarray, shape (K, 3)
        Tip frames in the base frame (m).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    count = len(q)
    rot = np.broadcast_to(np.eye(3), (count, 3, 3)).copy()
    pos = np.zeros((count, 3))
    for i, body in enumerate(model.bodies):
        if body.kind == "prismatic":
            r = np.broadcast_to(body.rotation, (count, 3, 3))
            p = body.translation + np.outer(q[:, i], body.rotation @ body.axis)
        else:
            a = body.axis
            k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            s, c = np.sin(q[:, i])[:, None, None], np.cos(q[:, i])[:, None, None]
            r = body.rotation @ (np.eye(3) + s * k + (1.0 - c) * (k @ k))
            p = np.broadcast_to(body.translation, (count, 3))
        pos = pos + np.einsum("kij,kj->ki", rot, p)
        rot = rot @ r
    return rot @ model.tip_rotation, pos + rot @ model.tip_translation
