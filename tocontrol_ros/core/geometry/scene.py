"""The cell around the arm: boxes, spheres and cylinders in the base frame, and allowed pairs.

A scene comes from a YAML file (``scene_file``; the format: ``msg_docs/scene_file.md``), a
mapping of the same shape, or the planner's ``~/scene`` markers (the nodes convert them).
Every obstacle has a unique name; an allowed pair names a link and an obstacle (or two
links) that may touch, as MoveIt's allowed-collision matrix does (the base link and the
table it stands on). Bad input raises :class:`~tocontrol_ros.core.errors.ProblemError`
naming the obstacle and field.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import ProblemError

__all__ = ["Obstacle", "Scene", "load_scene", "scene_from_dict", "quaternion_matrix",
           "signed_distance"]

#: Obstacle kinds and the sizes each takes (m).
OBSTACLE_SIZES = {"box": ("size",), "sphere": ("radius",), "cylinder": ("radius", "length")}


def quaternion_matrix(quat: Sequence[float]) -> np.ndarray:
    """Rotation (3, 3) of a unit quaternion ``(x, y, z, w)`` (normalised first)."""
    x, y, z, w = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A fixed shape in the base frame.

    Attributes
    ----------
    name : str
    kind : {"box", "sphere", "cylinder"}
    size : tuple of float
        Box: full edge lengths (x, y, z); sphere: (radius,); cylinder: (radius, length)
        along its z axis. In m.
    rotation : ndarray, shape (3, 3)
    translation : ndarray, shape (3,)
        Its centre in the base frame (m).
    """

    name: str
    kind: str
    size: tuple[float, ...]
    rotation: np.ndarray
    translation: np.ndarray
    _coal: list = field(default_factory=list, repr=False)

    def geometry(self):
        """The Coal geometry (built once)."""
        if not self._coal:
            from tocontrol_ros.core.geometry.shapes import coal_geometry
            self._coal.append(coal_geometry(self.kind, self.size))
        return self._coal[0]

    def key(self) -> tuple:
        """Everything that defines it, rounded to the bit (for equality and caches)."""
        return (self.name, self.kind, tuple(self.size), tuple(self.rotation.ravel()),
                tuple(self.translation))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (K,) of points (K, 3) in the base frame to it (m; < 0 inside)."""
        return signed_distance(self.kind, self.size, (np.asarray(points) - self.translation)
                               @ self.rotation)


def signed_distance(kind: str, size: Sequence[float], local: np.ndarray) -> np.ndarray:
    """Exact signed distance (K,) of points (K, 3) in a shape's own frame (m)."""
    if kind == "sphere":
        return np.linalg.norm(local, axis=1) - size[0]
    if kind == "cylinder":
        d = np.column_stack([np.linalg.norm(local[:, :2], axis=1) - size[0],
                             np.abs(local[:, 2]) - size[1] / 2])
    else:
        d = np.abs(local) - np.asarray(size, dtype=float) / 2
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
    return outside + np.minimum(np.max(d, axis=1), 0.0)


@dataclass(frozen=True)
class Scene:
    """Obstacles and the pairs allowed to touch.

    Attributes
    ----------
    obstacles : tuple of Obstacle
    allowed : frozenset of frozenset of str
        Pairs of names (a link and an obstacle, or two links) not checked.
    """

    obstacles: tuple[Obstacle, ...] = ()
    allowed: frozenset = frozenset()

    def key(self) -> tuple:
        """The scene's content, hashable (two equal keys: the same scene)."""
        return (tuple(o.key() for o in self.obstacles),
                tuple(sorted(tuple(sorted(p)) for p in self.allowed)))

    def __eq__(self, other) -> bool:
        return isinstance(other, Scene) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())

    def names(self) -> tuple[str, ...]:
        """The obstacles' names."""
        return tuple(o.name for o in self.obstacles)

    def allows(self, a: str, b: str) -> bool:
        """Whether the pair ``a``, ``b`` may touch."""
        return frozenset((a, b)) in self.allowed


def _vector(label: str, value, size: int) -> np.ndarray:
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"{label} must be {size} numbers, got {value!r}") from exc
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        raise ProblemError(f"{label} must be {size} finite numbers, got {value!r}")
    return out


def _obstacle(entry, index: int, label: str) -> Obstacle:
    if not isinstance(entry, Mapping):
        raise ProblemError(f"{label}: obstacle {index} must be a mapping, got {entry!r}")
    name = entry.get("name")
    if not isinstance(name, str) or not name:
        raise ProblemError(f"{label}: obstacle {index} needs a `name` (a non-empty string)")
    kind = entry.get("type")
    if kind not in OBSTACLE_SIZES:
        raise ProblemError(f"{label}: obstacle {name!r}: `type` must be one of "
                           f"{sorted(OBSTACLE_SIZES)}, got {kind!r}")
    known = {"name", "type", "position", "orientation", *OBSTACLE_SIZES[kind]}
    extra = sorted(set(entry) - known)
    if extra:
        raise ProblemError(f"{label}: obstacle {name!r} ({kind}): unknown fields {extra} "
                           f"(known: {sorted(known)})")
    if kind == "box":
        size = tuple(_vector(f"{label}: obstacle {name!r}: `size`", entry.get("size"), 3))
    else:
        size = tuple(float(_vector(f"{label}: obstacle {name!r}: `{key}`", [entry.get(key)],
                                   1)[0]) for key in OBSTACLE_SIZES[kind])
    if not all(s > 0 for s in size):
        raise ProblemError(f"{label}: obstacle {name!r}: sizes must be > 0 m, got {size}")
    pos = _vector(f"{label}: obstacle {name!r}: `position`", entry.get("position", [0, 0, 0]),
                  3)
    quat = _vector(f"{label}: obstacle {name!r}: `orientation` (x, y, z, w)",
                   entry.get("orientation", [0, 0, 0, 1]), 4)
    if np.linalg.norm(quat) < 1e-9:
        raise ProblemError(f"{label}: obstacle {name!r}: `orientation` is a zero quaternion")
    return Obstacle(name, kind, tuple(float(s) for s in size), quaternion_matrix(quat), pos)


def scene_from_dict(data, label: str = "scene", frame: str | None = None) -> Scene:
    """A scene from a mapping (a parsed YAML file, see ``msg_docs/scene_file.md``).

    Parameters
    ----------
    data : mapping
        ``obstacles`` (a list) and optionally ``allowed`` (a list of name pairs) and
        ``frame``.
    label : str
        Names the source in errors.
    frame : str, optional
        The base link: a ``frame`` given in ``data`` must be it.

    Raises
    ------
    ProblemError
        Anything malformed, naming the obstacle and field.
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ProblemError(f"{label}: a scene is a mapping with `obstacles`, got "
                           f"{type(data).__name__}")
    extra = sorted(set(data) - {"frame", "obstacles", "allowed"})
    if extra:
        raise ProblemError(f"{label}: unknown keys {extra} (known: frame, obstacles, allowed)")
    given = data.get("frame")
    if given is not None and frame is not None and given != frame:
        raise ProblemError(f"{label}: `frame` is {given!r}, but obstacles are given in the "
                           f"base frame {frame!r}")
    entries = data.get("obstacles")
    entries = [] if entries is None else entries
    if not isinstance(entries, list):
        raise ProblemError(f"{label}: `obstacles` must be a list, got {entries!r}")
    obstacles = tuple(_obstacle(e, i, label) for i, e in enumerate(entries))
    names = [o.name for o in obstacles]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ProblemError(f"{label}: obstacle names must be unique, repeated: {twice}")
    allowed = []
    pairs = data.get("allowed")
    if pairs is not None and not isinstance(pairs, list):
        raise ProblemError(f"{label}: `allowed` must be a list of name pairs, got {pairs!r}")
    for pair in pairs or []:
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2
                and all(isinstance(p, str) for p in pair)):
            raise ProblemError(f"{label}: each `allowed` entry is a pair of names, got "
                               f"{pair!r}")
        allowed.append(frozenset(pair))
    return Scene(obstacles, frozenset(allowed))


def load_scene(path: str | os.PathLike, frame: str | None = None) -> Scene:
    """A scene from a YAML file (``msg_docs/scene_file.md``).

    Raises
    ------
    ProblemError
        A missing or unreadable file, malformed YAML, or a malformed scene; the message
        names the file.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"scene file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ProblemError(f"scene file {path} could not be read: {exc}") from exc
    return scene_from_dict(data, f"scene file {path}", frame)
