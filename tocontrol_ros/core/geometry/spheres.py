"""Spheres per link that cover its collision geometry: what the optimiser's rows see.

A link's surface points (:meth:`~tocontrol_ros.core.geometry.shapes.LinkShape.points`, the
mesh's vertices and its triangles filled to :data:`~.tuning.SURFACE_SPACING`) are grouped by a
deterministic k-means into ``m`` groups, each enclosed by a sphere (Badoiu-Clarkson: the
centre walks toward the farthest point, then the radius is the farthest point's distance,
plus :data:`~.tuning.COVER_PAD`, so every point of the surface
is inside, not only the points); ``m`` grows from 1 until the worst gap is at most
:data:`~.tuning.GAP_TARGET` or ``m`` reaches :data:`~.tuning.MAX_SPHERES`. The gap of a
sphere is how far its surface stands off the geometry: the largest distance from a point
of its surface (outside the other spheres and outside the link's convex hull) to the
link's surface points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from tocontrol_ros.core.geometry.tuning import (
    COVER_PAD,
    ENCLOSING_ITERATIONS,
    GAP_PROBES,
    GAP_TARGET,
    KMEANS_ITERATIONS,
    KMEANS_POINTS,
    MAX_SPHERES,
)

__all__ = ["LinkSpheres", "fit_spheres", "sphere_probes"]


@dataclass(frozen=True)
class LinkSpheres:
    """The spheres of one link, in the frame of the body that moves it.

    Attributes
    ----------
    link : str
    body : int
        -1 for the base, else the chain's body index.
    centers : ndarray, shape (m, 3)
        Centres in the body's frame (m).
    radii : ndarray, shape (m,)
        Radii (m).
    gap : float
        The worst gap of these spheres (m; see the module).
    """

    link: str
    body: int
    centers: np.ndarray
    radii: np.ndarray
    gap: float


def sphere_probes(count: int = GAP_PROBES) -> np.ndarray:
    """``count`` unit vectors spread evenly over the sphere (Fibonacci lattice), (count, 3)."""
    i = np.arange(count) + 0.5
    phi, theta = np.arccos(1 - 2 * i / count), np.pi * (1 + 5 ** 0.5) * i
    return np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                            np.cos(phi)])


def _enclosing(points: np.ndarray) -> tuple[np.ndarray, float]:
    """A small sphere enclosing ``points`` (K, 3): centre (3,), radius (covers every point)."""
    try:  # the same sphere encloses the points and their hull's vertices
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        pass
    c = points.mean(axis=0)
    for it in range(ENCLOSING_ITERATIONS):
        far = points[np.argmax(np.sum((points - c) ** 2, axis=1))]
        c = c + (far - c) / (it + 2)
    return c, float(np.sqrt(np.max(np.sum((points - c) ** 2, axis=1)))) + COVER_PAD


def _groups(points: np.ndarray, m: int) -> np.ndarray:
    """Deterministic k-means labels (K,) of ``points`` into ``m`` groups."""
    every = points
    points = points[::max(1, len(points) // KMEANS_POINTS)]
    centers = [points[np.argmin(np.sum((points - points.mean(axis=0)) ** 2, axis=1))]]
    d2 = np.sum((points - centers[0]) ** 2, axis=1)
    for _ in range(1, m):  # farthest-point start
        centers.append(points[np.argmax(d2)])
        d2 = np.minimum(d2, np.sum((points - centers[-1]) ** 2, axis=1))
    centers = np.array(centers)
    labels = np.zeros(len(points), dtype=int)
    for _ in range(KMEANS_ITERATIONS):
        labels = np.argmin(((points[:, None, :] - centers[None]) ** 2).sum(-1), axis=1)
        for j in range(m):
            if np.any(labels == j):
                centers[j] = points[labels == j].mean(axis=0)
    return np.argmin(((every[:, None, :] - centers[None]) ** 2).sum(-1), axis=1)


def _gap(points: np.ndarray, tree: cKDTree, hull, centers: np.ndarray, radii: np.ndarray
         ) -> float:
    """The worst gap of the spheres over ``points`` (see the module), m."""
    probes = sphere_probes()
    worst = 0.0
    for j, (c, r) in enumerate(zip(centers, radii, strict=True)):
        pts = c + r * probes
        others = [i for i in range(len(radii)) if i != j]
        if others:
            inside = np.any(np.linalg.norm(pts[:, None, :] - centers[None, others], axis=2)
                            < radii[others] - 1e-9, axis=1)
            pts = pts[~inside]
        if hull is not None and len(pts):
            pts = pts[np.any(pts @ hull[:, :3].T + hull[:, 3] > 1e-9, axis=1)]
        if len(pts):
            worst = max(worst, float(np.max(tree.query(pts)[0])))
    return worst


def fit_spheres(link: str, body: int, points: np.ndarray) -> LinkSpheres:
    """The spheres of one link from its surface points (N, 3) in its body's frame (m)."""
    points = np.asarray(points, dtype=float)
    tree = cKDTree(points)
    try:
        hull = ConvexHull(points).equations  # (F, 4): inside where every a.x + b <= 0
    except (QhullError, ValueError):  # flat or tiny geometry: no volume to be inside of
        hull = None
    best = None
    for m in range(1, min(MAX_SPHERES, len(points)) + 1):
        labels = _groups(points, m)
        balls = [_enclosing(points[labels == j]) for j in range(m) if np.any(labels == j)]
        centers = np.array([c for c, _ in balls])
        radii = np.array([r for _, r in balls])
        gap = _gap(points, tree, hull, centers, radii)
        if best is None or gap < best.gap:
            best = LinkSpheres(link, body, centers, radii, gap)
        if gap <= GAP_TARGET:
            break
    return best
