"""A base link's convex hull as support planes: a tighter cover than spheres for the rows.

A link on the base (body -1: it does not move) is, for the optimiser's self rows, a fixed
convex set like an obstacle. Its geometry's convex hull is held by support planes
``u . x - h(u)`` (``u`` a unit direction, ``h(u)`` the largest ``u . p`` over the link's
surface points): each is at most the distance of ``x`` to the hull, hence to the geometry,
so their largest is a lower bound of the exact distance (exact on the faces' regions, short
near edges and corners, where it is the distance along the nearest direction held). The
directions: the hull's face normals, thinned by area to one within :data:`THIN_ANGLE` of
another, then :data:`DIRECTIONS` spread evenly over the sphere (thinned the same way),
which hold the edges' and corners' regions. The row takes their smooth maximum
``log(sum exp(beta v_f)) / beta - log(F) / beta`` (``beta`` = :data:`SHARPNESS`): never
above the largest, so still a lower bound, and twice differentiable.

Measured on the Panda's ``panda_link0`` (a convex mesh of 102 vertices): 102 planes, the
smooth bound at most 4.7 mm below Coal's exact distance for points up to 2 cm away and
8.4 mm up to 5 cm away (4000 random points), where the base's spheres stand 5-6 cm off its
mesh (docs/collision.md, session 34). The gap recorded (:attr:`LinkHull.gap`) is the worst
shortfall below Coal's exact distance at points :data:`PROBE_DEPTHS` out of the hull along
200 directions (a concave link's hollows count where a probe faces them); the collision
model uses the hull in the rows only where this gap is below the spheres'.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from tocontrol_ros.core.geometry.shapes import LinkShape
from tocontrol_ros.core.geometry.spheres import sphere_probes
from tocontrol_ros.core.geometry.tuning import COVER_PAD

__all__ = ["LinkHull", "fit_hull", "DIRECTIONS", "SHARPNESS", "THIN_ANGLE"]

#: Face normals (and the even directions) closer than this angle (degrees) to one kept are
#: left out: on ``panda_link0`` 8 degrees keeps 51 of its 200 faces' normals, and the
#: bound's worst shortfall up to 2 cm is the same as with all of them (4.7 mm).
THIN_ANGLE = 8.0
#: Directions spread over the sphere added to the faces' (the edges' and corners' regions):
#: on ``panda_link0``, without them 15.9 mm short up to 5 cm, with 64 8.4 mm, 128 6.4 mm.
DIRECTIONS = 64
#: The smooth maximum's sharpness (1/m): it stands at most ``log(F) / SHARPNESS`` below
#: the largest plane (1.5 mm for 102 planes); 1000 doubled the shortfall on the faces.
SHARPNESS = 3000.0
#: Where the gap is measured: this far (m) out of the hull along each probe direction.
PROBE_DEPTHS = (0.01, 0.05)


@dataclass(frozen=True)
class LinkHull:
    """Support planes of a link's convex hull, in the frame of the body that moves it.

    Attributes
    ----------
    link : str
    body : int
        -1 for the base.
    planes : ndarray, shape (F, 4)
        Unit normals (F, 3) and offsets (F,): ``planes[:, :3] @ x + planes[:, 3]`` is at most
        the distance of ``x`` to the link's geometry for every plane (m).
    gap : float
        The worst shortfall of :meth:`distance` below Coal's exact distance at points
        :data:`PROBE_DEPTHS` out of the hull (m).
    """

    link: str
    body: int
    planes: np.ndarray
    gap: float

    def distance(self, x: np.ndarray) -> np.ndarray:
        """The smooth lower bound of the distance to the link at points ``x`` (K, 3) (m)."""
        v = np.atleast_2d(x) @ self.planes[:, :3].T + self.planes[:, 3]
        top = np.max(v, axis=1)
        soft = top + np.log(np.sum(np.exp(SHARPNESS * (v - top[:, None])), axis=1)) / SHARPNESS
        return soft - np.log(len(self.planes)) / SHARPNESS


def _thinned(directions: np.ndarray, cos: float) -> np.ndarray:
    kept: list[np.ndarray] = []
    for u in directions:
        if all(float(u @ k) < cos for k in kept):
            kept.append(u)
    return np.array(kept)


def fit_hull(shapes: Sequence[LinkShape], points: np.ndarray) -> LinkHull:
    """The support planes of one link's shapes (see the module).

    Parameters
    ----------
    shapes : sequence of LinkShape
        The link's collision elements (one body); Coal measures the gap on them.
    points : ndarray, shape (N, 3)
        Their surface points in the body's frame (m): a mesh's include its vertices, so
        the planes hold it exactly; a primitive's are padded by
        :data:`~.tuning.COVER_PAD` (its surface lies within that of its points).
    """
    import coal

    points = np.asarray(points, dtype=float)
    hull = ConvexHull(points)
    tri = points[hull.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cos = float(np.cos(np.radians(THIN_ANGLE)))
    faces = _thinned(hull.equations[np.argsort(-area, kind="stable"), :3], cos)
    normals = _thinned(np.vstack([faces, sphere_probes(DIRECTIONS)]), cos)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pad = 0.0 if all(s.kind == "mesh" for s in shapes) else COVER_PAD
    support = np.max(points @ normals.T, axis=0) + pad
    fitted = LinkHull(shapes[0].link, shapes[0].body,
                      np.column_stack([normals, -support]), 0.0)
    probes = sphere_probes()
    far = points[np.argmax(points @ probes.T, axis=0)]
    request = coal.DistanceRequest()
    point = coal.Sphere(1e-9)
    worst = 0.0
    for depth in PROBE_DEPTHS:
        x = far + depth * probes
        exact = np.array([min(coal.distance(s.geometry(), coal.Transform3s(s.rotation,
                                                                             s.translation),
                                            point, coal.Transform3s(np.eye(3), xi), request,
                                            coal.DistanceResult()) for s in shapes)
                          for xi in x])
        worst = max(worst, float(np.max(exact - fitted.distance(x))))
    return LinkHull(fitted.link, fitted.body, fitted.planes, worst)
