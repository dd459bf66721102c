"""The URDF's ``<collision>`` elements placed on the chain's bodies, as Coal objects and points.

Each element becomes a :class:`LinkShape`: its kind (box, cylinder, sphere, mesh), its size,
its pose in the frame of the body that moves it (:func:`~tocontrol_ros.core.robot.urdf.
link_placements`), its Coal geometry for exact distances, and points on its surface for the
spheres of the optimiser (:mod:`~tocontrol_ros.core.geometry.spheres`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import ModelError
from tocontrol_ros.core.geometry.packages import resolve_uri
from tocontrol_ros.core.robot.urdf import origin_pose

__all__ = ["LinkShape", "link_shapes", "coal_geometry", "surface_points"]

#: Kinds of shape a URDF ``<collision>`` may hold, and a scene's obstacles too.
KINDS = ("box", "cylinder", "sphere", "mesh")


@dataclass(frozen=True, eq=False)
class LinkShape:
    """One ``<collision>`` element of a link, placed on the body that moves the link.

    Attributes
    ----------
    link : str
    body : int
        -1: the base (fixed); ``i``: moved by the chain's body ``i``.
    kind : {"box", "cylinder", "sphere", "mesh"}
    size : tuple of float
        Box: full edge lengths (x, y, z); cylinder: (radius, length) along its z; sphere:
        (radius,); mesh: its scale (x, y, z). In m.
    rotation, translation : ndarray, shape (3, 3) and (3,)
        Pose of the shape's frame in the body's frame (m).
    mesh : Path or None
        The mesh file (resolved).
    """

    link: str
    body: int
    kind: str
    size: tuple[float, ...]
    rotation: np.ndarray
    translation: np.ndarray
    mesh: Path | None = None
    _coal: list = field(default_factory=list, repr=False)

    def geometry(self):
        """The Coal collision geometry (loaded once)."""
        if not self._coal:
            self._coal.append(coal_geometry(self.kind, self.size, self.mesh))
        return self._coal[0]

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """A sphere that holds the whole shape: centre (3,) in the body's frame, radius (m).

        A mesh's: about the middle of its vertices' box, out to the farthest vertex (the
        mesh is inside its vertices' hull); a primitive's from its size.
        """
        if self.kind == "mesh":
            v = np.asarray(self.geometry().vertices(), dtype=float)
            local = 0.5 * (v.min(axis=0) + v.max(axis=0))
            radius = float(np.max(np.linalg.norm(v - local, axis=1)))
        else:
            local = np.zeros(3)
            radius = {"box": 0.5 * float(np.linalg.norm(self.size)),
                      "cylinder": float(np.hypot(self.size[0], 0.5 * self.size[1])),
                      "sphere": float(self.size[0])}[self.kind]
        return self.rotation @ local + self.translation, radius

    def reach(self) -> float:
        """The farthest any point of the shape is from the body frame's origin (m).

        Exact, not sampled: a mesh's farthest vertex (the mesh is inside its vertices'
        hull), a box's farthest corner, a sphere's centre distance plus its radius, a
        cylinder's farthest point on its two rim circles. What a point of the link moves at
        most per unit joint speed is this distance's lever (:meth:`~tocontrol_ros.core.
        geometry.collision.CollisionModel.speed_bounds`), so it must not fall short.
        """
        rot, pos = self.rotation, self.translation
        if self.kind == "sphere":
            return float(np.linalg.norm(pos)) + float(self.size[0])
        if self.kind == "cylinder":
            r, half, axis = float(self.size[0]), 0.5 * float(self.size[1]), rot[:, 2]
            out = 0.0
            for end in (pos + half * axis, pos - half * axis):
                along = float(end @ axis)
                across = float(np.linalg.norm(end - along * axis))
                out = max(out, float(np.hypot(along, across + r)))
            return out
        if self.kind == "box":
            corners = np.array(np.meshgrid(*[(-0.5 * s, 0.5 * s) for s in self.size],
                                           indexing="ij")).reshape(3, -1).T
        else:
            corners = np.asarray(self.geometry().vertices(), dtype=float)
        return float(np.max(np.linalg.norm(corners @ rot.T + pos, axis=1)))

    def points(self, spacing: float) -> np.ndarray:
        """Points (N, 3) on the surface (and a mesh's vertices), in the body's frame (m)."""
        local = surface_points(self.kind, self.size, spacing, self.geometry())
        return local @ self.rotation.T + self.translation


def coal_geometry(kind: str, size: Sequence[float], mesh: Path | None = None):
    """A Coal geometry: ``Box``, ``Cylinder`` (along z), ``Sphere`` or a mesh's BVH model.

    Raises
    ------
    ModelError
        A mesh file Coal cannot read (the message names it).
    """
    import coal

    if kind == "box":
        return coal.Box(*[float(s) for s in size])
    if kind == "cylinder":
        return coal.Cylinder(float(size[0]), float(size[1]))
    if kind == "sphere":
        return coal.Sphere(float(size[0]))
    try:
        model = coal.MeshLoader().load(str(mesh), np.asarray(size, dtype=float))
    except Exception as exc:  # noqa: BLE001 - assimp's errors come as RuntimeError or others
        raise ModelError(f"mesh file {mesh} could not be read: {exc}") from exc
    if model.num_tris == 0:
        raise ModelError(f"mesh file {mesh} has no triangles")
    return model


def _mesh_points(model, spacing: float) -> np.ndarray:
    """A mesh's vertices and points on each triangle no further than ``spacing`` apart."""
    vertices = np.asarray(model.vertices(), dtype=float)
    tris = np.array([[t[0], t[1], t[2]] for t in (model.tri_indices(i)
                                                   for i in range(model.num_tris))])
    out = [vertices]
    a, b, c = vertices[tris[:, 0]], vertices[tris[:, 1]], vertices[tris[:, 2]]
    longest = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                               np.linalg.norm(a - c, axis=1)]), axis=0)
    parts = np.maximum(1, np.ceil(longest / spacing).astype(int))
    for m in np.unique(parts[parts > 1]):
        sel = parts == m
        i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
        keep = i + j <= m
        wa, wb = (i[keep] / m)[:, None], (j[keep] / m)[:, None]
        pts = (a[sel, None, :] * (1 - wa - wb)[None] + b[sel, None, :] * wa[None]
               + c[sel, None, :] * wb[None])
        out.append(pts.reshape(-1, 3))
    return np.concatenate(out)


def surface_points(kind: str, size: Sequence[float], spacing: float, geometry=None
                   ) -> np.ndarray:
    """Points (N, 3) on a shape's surface in its own frame, ``spacing`` apart or closer (m).

    A mesh gives its vertices too (``geometry``: its Coal model).
    """
    if kind == "mesh":
        return _mesh_points(geometry, spacing)
    if kind == "sphere":
        r = float(size[0])
        count = max(12, int(np.ceil(4 * np.pi * r ** 2 / spacing ** 2)))
        i = np.arange(count) + 0.5
        phi, theta = np.arccos(1 - 2 * i / count), np.pi * (1 + 5 ** 0.5) * i
        return r * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                    np.cos(phi)])
    if kind == "cylinder":
        r, length = float(size[0]), float(size[1])
        na = max(8, int(np.ceil(2 * np.pi * r / spacing)))
        nz = max(2, int(np.ceil(length / spacing)) + 1)
        ang = 2 * np.pi * np.arange(na) / na
        z = np.linspace(-length / 2, length / 2, nz)
        side = np.column_stack([np.repeat(r * np.cos(ang)[None], nz, 0).ravel(),
                                np.repeat(r * np.sin(ang)[None], nz, 0).ravel(),
                                np.repeat(z, na)])
        rings = [np.zeros((1, 2))] + [
            rr * np.column_stack([np.cos(ang), np.sin(ang)])
            for rr in np.linspace(0, r, max(2, int(np.ceil(r / spacing)) + 1))[1:]]
        cap = np.concatenate(rings)
        caps = [np.column_stack([cap, np.full(len(cap), zz)]) for zz in (-length / 2,
                                                                         length / 2)]
        return np.concatenate([side] + caps)
    half = np.asarray(size, dtype=float) / 2
    faces = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        u, v = (np.linspace(-half[a], half[a], max(2, int(np.ceil(2 * half[a] / spacing)) + 1))
                for a in others)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        for sign in (-1.0, 1.0):
            pts = np.zeros((uu.size, 3))
            pts[:, others[0]], pts[:, others[1]] = uu.ravel(), vv.ravel()
            pts[:, axis] = sign * half[axis]
            faces.append(pts)
    return np.concatenate(faces)


def _collision_shape(collision, label: str, link: str, base_dir: Path | None,
                     package_dirs: Sequence[str | os.PathLike]):
    """Kind, size and mesh path of one parsed ``<collision>`` element."""
    geom = collision.geometry
    name = type(geom).__name__.lower()
    if name == "box":
        size = tuple(float(s) for s in geom.size)
    elif name == "cylinder":
        size = (float(geom.radius), float(geom.length))
    elif name == "sphere":
        size = (float(geom.radius),)
    elif name == "mesh":
        scale = geom.scale if geom.scale is not None else (1.0, 1.0, 1.0)
        scale = (float(scale),) * 3 if np.isscalar(scale) else tuple(float(s) for s in scale)
        return "mesh", scale, resolve_uri(geom.filename, base_dir, package_dirs)
    else:
        raise ModelError(f"link {link!r} of {label}: unsupported <collision> geometry "
                         f"{name!r} (box, cylinder, sphere, mesh)")
    if not all(np.isfinite(s) and s > 0 for s in size):
        raise ModelError(f"link {link!r} of {label}: <collision> {name} needs positive "
                         f"sizes, got {size}")
    return name, size, None


def link_shapes(robot, label: str, placements: dict, base_dir: Path | None = None,
                package_dirs: Sequence[str | os.PathLike] = ()) -> list[LinkShape]:
    """Every ``<collision>`` of the links in ``placements``, placed on its body.

    Parameters
    ----------
    robot : urdf_parser_py.urdf.Robot
    label : str
        Names the URDF in errors.
    placements : dict
        :func:`~tocontrol_ros.core.robot.urdf.link_placements`.
    base_dir : Path, optional
        The URDF's directory (relative mesh paths).
    package_dirs : sequence of path
        See :func:`~tocontrol_ros.core.geometry.packages.share_directories`.

    Raises
    ------
    ModelError
        A mesh that cannot be found or read, an unsupported or degenerate shape.
    """
    shapes = []
    for link in robot.links:
        if link.name not in placements:
            continue
        body, rot_l, pos_l = placements[link.name]
        for collision in link.collisions:
            kind, size, mesh = _collision_shape(collision, label, link.name, base_dir,
                                                package_dirs)
            rot_o, pos_o = origin_pose(collision.origin)
            shape = LinkShape(link.name, body, kind, size, rot_l @ rot_o,
                              pos_l + rot_l @ pos_o, mesh)
            shape.geometry()  # a mesh that cannot be read fails here, naming its file
            shapes.append(shape)
    return shapes
