"""The planner's scene as ``visualization_msgs/MarkerArray``: read from ``~/scene``, drawn back.

:func:`scene_from_markers` applies a message to the scene in use: ``ADD`` (and ``MODIFY``,
its alias) puts or replaces the obstacle ``ns/id``; ``DELETE`` removes it; ``DELETEALL``
removes all (then the later markers of the same message apply). ``CUBE`` (``scale`` = edge
lengths), ``SPHERE`` (``scale.x`` = diameter, all three equal), ``CYLINDER`` (``scale.x`` =
``scale.y`` = diameter, ``scale.z`` = length, along the marker's z axis), in the planner's
frame (or an empty ``frame_id``). The whole message is refused when one marker is wrong
(:class:`~tocontrol_ros.core.errors.ProblemError` naming it): the previous scene stays.
:func:`scene_marker_list` draws a scene (namespace ``scene``), what RViz and Foxglove show.
"""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.geometry.scene import Obstacle, Scene, quaternion_matrix
from tocontrol_ros.core.robot.kinematics import quaternion_from_matrix

__all__ = ["scene_from_markers", "scene_marker_list"]

_KINDS = {Marker.CUBE: "box", Marker.SPHERE: "sphere", Marker.CYLINDER: "cylinder"}
_TYPES = {kind: marker_type for marker_type, kind in _KINDS.items()}


def _name(marker: Marker) -> str:
    return f"{marker.ns}/{marker.id}" if marker.ns else str(marker.id)


def _obstacle(marker: Marker, name: str) -> Obstacle:
    if marker.type not in _KINDS:
        raise ProblemError(f"~/scene marker {name!r}: type {marker.type} is not CUBE (1), "
                           f"SPHERE (2) or CYLINDER (3)")
    kind = _KINDS[marker.type]
    p, o, s = marker.pose.position, marker.pose.orientation, marker.scale
    values = [p.x, p.y, p.z, o.x, o.y, o.z, o.w, s.x, s.y, s.z]
    if not all(math.isfinite(v) for v in values):
        raise ProblemError(f"~/scene marker {name!r}: pose and scale must be finite, got "
                           f"position {[p.x, p.y, p.z]}, scale {[s.x, s.y, s.z]}")
    quat = np.array([o.x, o.y, o.z, o.w])
    if np.linalg.norm(quat) < 1e-9:
        raise ProblemError(f"~/scene marker {name!r}: zero orientation quaternion")
    scale = np.array([s.x, s.y, s.z])
    if np.any(scale <= 0):
        raise ProblemError(f"~/scene marker {name!r}: scale must be > 0 m, got {scale.tolist()}")
    if kind == "box":
        size = tuple(float(v) for v in scale)
    elif kind == "sphere":
        if not np.allclose(scale, scale[0], rtol=1e-6):
            raise ProblemError(f"~/scene marker {name!r}: a SPHERE needs equal scales (an "
                               f"ellipsoid is not supported), got {scale.tolist()}")
        size = (float(scale[0]) / 2,)
    else:
        if not math.isclose(scale[0], scale[1], rel_tol=1e-6):
            raise ProblemError(f"~/scene marker {name!r}: a CYLINDER needs scale.x == scale.y "
                               f"(its diameter), got {scale.tolist()}")
        size = (float(scale[0]) / 2, float(scale[2]))
    return Obstacle(name, kind, size, quaternion_matrix(quat), np.array([p.x, p.y, p.z]))


def scene_from_markers(markers, current: Scene, frame_id: str) -> Scene:
    """``current`` with a ``MarkerArray``'s markers applied (see the module).

    Parameters
    ----------
    markers : visualization_msgs.msg.MarkerArray
    current : Scene
        The scene in use (its allowed pairs are kept).
    frame_id : str
        The planner's frame: a marker's ``header.frame_id`` must be it or empty.

    Raises
    ------
    ProblemError
        A marker of another frame or type, a non-finite or non-positive size, an action
        other than ADD, MODIFY, DELETE, DELETEALL, a DELETE of an unknown obstacle.
    """
    obstacles = {o.name: o for o in current.obstacles}
    for marker in markers.markers:
        name = _name(marker)
        if marker.action == Marker.DELETEALL:
            obstacles.clear()
            continue
        if marker.header.frame_id not in ("", frame_id):
            raise ProblemError(f"~/scene marker {name!r} is in frame "
                               f"{marker.header.frame_id!r}; obstacles are taken in the "
                               f"planner's frame {frame_id!r}")
        if marker.action == Marker.DELETE:
            if name not in obstacles:
                raise ProblemError(f"~/scene: DELETE of {name!r}, which is not in the scene "
                                   f"(obstacles: {sorted(obstacles)})")
            del obstacles[name]
        elif marker.action in (Marker.ADD, Marker.MODIFY):
            obstacles[name] = _obstacle(marker, name)
        else:
            raise ProblemError(f"~/scene marker {name!r}: action {marker.action} is not ADD "
                               f"(0), MODIFY (1), DELETE (2) or DELETEALL (3)")
    gone = set(current.names()) - set(obstacles)  # their allowed pairs go with them
    allowed = frozenset(p for p in current.allowed if not set(p) & gone)
    return Scene(tuple(obstacles.values()), allowed)


def scene_marker_list(scene: Scene, header: Header) -> list[Marker]:
    """The scene's obstacles as markers (namespace ``scene``, grey, half transparent)."""
    out = []
    for i, ob in enumerate(scene.obstacles):
        if ob.kind == "box":
            scale = Vector3(x=ob.size[0], y=ob.size[1], z=ob.size[2])
        elif ob.kind == "sphere":
            scale = Vector3(x=2 * ob.size[0], y=2 * ob.size[0], z=2 * ob.size[0])
        else:
            scale = Vector3(x=2 * ob.size[0], y=2 * ob.size[0], z=ob.size[1])
        qx, qy, qz, qw = (float(v) for v in quaternion_from_matrix(ob.rotation))
        pos = Point(x=float(ob.translation[0]), y=float(ob.translation[1]),
                    z=float(ob.translation[2]))
        out.append(Marker(header=header, ns="scene", id=i, type=_TYPES[ob.kind],
                          action=Marker.ADD, pose=Pose(position=pos, orientation=Quaternion(
                              x=qx, y=qy, z=qz, w=qw)),
                          scale=scale, color=ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.5),
                          text=ob.name))
    return out
