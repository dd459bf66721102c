"""The arm's collision model: its shapes, spheres and pairs, a scene, a margin; distances.

:func:`collision_model` reads a URDF's ``<collision>`` elements onto the chain of a
:class:`~tocontrol_ros.core.robot.model.RobotModel`, fits spheres to each link
(:mod:`~tocontrol_ros.core.geometry.spheres`), and lists the pairs to check: every link
against every obstacle, and every two links but those on one body, on consecutive bodies
(adjacent: one joint between them) and those an SRDF's ``disable_collisions`` names; less
the scene's allowed pairs. :meth:`CollisionModel.clearance` measures the exact distances
with Coal on the URDF's own geometry (meshes as they are, not the spheres);
:meth:`CollisionModel.speed_bounds` bounds how fast a distance can change under the joint
velocity limits, which bounds what happens between two sampled times.
"""

from __future__ import annotations

import functools
import os
import threading
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import ModelError, ProblemError
from tocontrol_ros.core.geometry.hull import LinkHull, fit_hull
from tocontrol_ros.core.geometry.scene import Scene
from tocontrol_ros.core.geometry.shapes import LinkShape, link_shapes
from tocontrol_ros.core.geometry.spheres import LinkSpheres, fit_spheres
from tocontrol_ros.core.geometry.tuning import (
    DEFAULT_MARGIN,
    EXACT_BAND,
    SURFACE_SPACING,
)
from tocontrol_ros.core.robot.kinematics import axis_rotation
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.robot.urdf import link_placements, read_urdf

__all__ = ["Clearance", "SweptClearance", "CollisionModel", "collision_model", "disabled_pairs",
           "body_frames"]


def disabled_pairs(srdf) -> frozenset:
    """The link pairs an SRDF's ``<disable_collisions>`` names.

    Parameters
    ----------
    srdf : str or os.PathLike
        The SRDF's XML text (as MoveIt's ``robot_description_semantic``) or a file path.

    Raises
    ------
    ModelError
        A missing file or malformed XML, naming it.
    """
    text, label = srdf, "robot_description_semantic"
    if isinstance(srdf, os.PathLike) or (isinstance(srdf, str)
                                         and not srdf.lstrip().startswith("<")):
        path = Path(srdf)
        if not path.is_file():
            raise ModelError(f"SRDF file not found: {path}")
        text, label = path.read_text(), str(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ModelError(f"malformed SRDF ({label}): {exc}") from exc
    pairs = set()
    for elem in root.iter("disable_collisions"):
        a, b = elem.get("link1"), elem.get("link2")
        if not a or not b:
            raise ModelError(f"SRDF ({label}): <disable_collisions> needs link1 and link2")
        pairs.add(frozenset((a, b)))
    return frozenset(pairs)


def body_frames(model: RobotModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The base's and every body's frame at many configurations.

    Parameters
    ----------
    model : RobotModel
    q : ndarray, shape (K, n)
        Joint positions (rad, m).

    Returns
    -------
    rotation : ndarray, shape (K, n + 1, 3, 3)
    position : ndarray, shape (K, n + 1, 3)
        Index 0 the base (identity), ``i + 1`` body ``i``; in the base frame (m).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    count = len(q)
    rots = np.empty((count, model.n + 1, 3, 3))
    poss = np.empty((count, model.n + 1, 3))
    rots[:, 0], poss[:, 0] = np.eye(3), 0.0
    for i, body in enumerate(model.bodies):
        if body.kind == "prismatic":
            r = np.broadcast_to(body.rotation, (count, 3, 3))
            p = body.translation + np.outer(q[:, i], body.rotation @ body.axis)
        else:
            r = np.array([body.rotation @ axis_rotation(body.axis, qi) for qi in q[:, i]])
            p = np.broadcast_to(body.translation, (count, 3))
        poss[:, i + 1] = poss[:, i] + np.einsum("kij,kj->ki", rots[:, i], p)
        rots[:, i + 1] = rots[:, i] @ r
    return rots, poss


@dataclass(frozen=True)
class Clearance:
    """Exact distances along configurations.

    Attributes
    ----------
    distance : ndarray, shape (K,)
        The smallest distance over the checked pairs at each configuration (m; < 0:
        penetration depth).
    pair : tuple of str
        The closest pair over all configurations.
    index : int
        Where it is closest.
    minimum : float
        ``distance[index]`` (m).
    pair_distances : dict
        Pair -> distances (K,) (m).
    """

    distance: np.ndarray
    pair: tuple[str, str]
    index: int
    minimum: float
    pair_distances: dict = field(repr=False)


@dataclass(frozen=True)
class SweptClearance:
    """The clearance of a whole motion: exact at the sampled times, bounded between them.

    Attributes
    ----------
    minimum : float
        The least exact distance at the sampled times (m): Coal's, over every checked pair
        (where the bounding spheres' bound of a pair lies below it, that pair and time too).
    pair : tuple of str
        The closest pair there.
    time : float
        When (s).
    lower_bound : float
        A distance no pair comes below at any time, between the samples included (m).
    exact_calls : int
        Coal distance queries made (the others were certified by bounding spheres).
    interval_bounds : ndarray, shape (K - 1,)
        A distance no pair comes below on each interval between two sampled times (m);
        ``lower_bound`` is their least (or the one sample's distance).
    """

    minimum: float
    pair: tuple[str, str]
    time: float
    lower_bound: float
    exact_calls: int
    interval_bounds: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)


@dataclass(frozen=True, eq=False)
class CollisionModel:
    """A model's collision geometry, a scene and a margin (build with :func:`collision_model`).

    Attributes
    ----------
    model : RobotModel
    shapes : tuple of LinkShape
        The URDF's collision elements (exact geometry).
    spheres : tuple of LinkSpheres
        The optimiser's spheres, one entry per link with geometry.
    self_pairs : tuple of (str, str)
        Link pairs checked against each other.
    scene : Scene
    margin : float
        The clearance every motion keeps (m).
    source : tuple
        ``(urdf, srdf, package_dirs)`` it was built from (pickled as these).
    row_pairs : tuple of (str, str)
        Self pairs that are also rows of the bounded solve (sphere pairs,
        :func:`~tocontrol_ros.core.direct.clearance.clearance_rows`); the others are
        checked by the certificate only. Default none: the planner adds the pairs a refused
        motion brought close (:meth:`with_row_pairs`).
    hulls : tuple of LinkHull
        The base links' convex hulls as support planes
        (:mod:`~tocontrol_ros.core.geometry.hull`): a self row against such a link uses
        them where their gap is below its spheres' (:meth:`row_hull`).
    """

    model: RobotModel
    shapes: tuple[LinkShape, ...]
    spheres: tuple[LinkSpheres, ...]
    self_pairs: tuple[tuple[str, str], ...]
    scene: Scene
    margin: float
    source: tuple = field(repr=False)
    row_pairs: tuple[tuple[str, str], ...] = ()
    hulls: tuple[LinkHull, ...] = field(default=(), repr=False)

    def __reduce__(self):
        urdf, srdf, dirs = self.source
        return (_rebuilt, (self.model, urdf, srdf, self.scene, self.margin, dirs,
                           self.row_pairs))

    def key(self) -> tuple:
        """What decides a plan: the geometry's source, the scene, the margin, the row pairs."""
        return (self.source, self.scene.key(), self.margin) + \
            ((self.row_pairs,) if self.row_pairs else ())

    def with_row_pairs(self, pairs) -> CollisionModel:
        """The same model with ``pairs`` (self pairs, any order) added to :attr:`row_pairs`.

        Raises
        ------
        ValueError
            A pair that is not one of :attr:`self_pairs`.
        """
        known = {frozenset(p): p for p in self.self_pairs}
        add = []
        for pair in pairs:
            if frozenset(pair) not in known:
                raise ValueError(f"{tuple(pair)} is not a checked self pair")
            add.append(known[frozenset(pair)])
        rows = tuple(p for p in self.self_pairs if p in set(self.row_pairs) | set(add))
        return replace(self, row_pairs=rows)

    def row_hull(self, link: str) -> LinkHull | None:
        """The hull a self row against ``link`` uses instead of its spheres, or None.

        A base link's hull (:attr:`hulls`) when its gap is below the link's spheres' gap.
        """
        spheres = next((s for s in self.spheres if s.link == link), None)
        for hull in self.hulls:
            if hull.link == link and spheres is not None and hull.gap < spheres.gap:
                return hull
        return None

    @property
    def links(self) -> tuple[str, ...]:
        """The links with geometry, in the URDF's order."""
        return tuple(s.link for s in self.spheres)

    def with_scene(self, scene: Scene | None = None, margin: float | None = None
                   ) -> CollisionModel:
        """The same geometry with another scene and/or margin (checked as at the build)."""
        scene = self.scene if scene is None else scene
        margin = self.margin if margin is None else _margin(margin)
        _check_allowed(scene, self.links)
        pairs = _self_pairs(self.spheres, frozenset(), scene)
        pairs = tuple(p for p in self.self_pairs if p in pairs)
        return replace(self, scene=scene, margin=margin, self_pairs=pairs,
                       row_pairs=tuple(p for p in self.row_pairs if p in pairs))

    def obstacle_pairs(self) -> tuple[tuple[str, str], ...]:
        """(link, obstacle) pairs checked: all but the scene's allowed ones."""
        return tuple((link, o.name) for link in self.links for o in self.scene.obstacles
                     if not self.scene.allows(link, o.name))

    def worst_gap(self) -> float:
        """The spheres' worst gap over the links (m)."""
        return max((s.gap for s in self.spheres), default=0.0)

    def lever_arms(self, body: int, reach: float) -> np.ndarray:
        """How fast a point of ``body`` at most ``reach`` (m) from its origin moves per joint.

        A point of body ``b`` at ``p`` moves at most ``sum_{j <= b} |qd_j| rho_jb``, with
        ``rho_jb`` the distance from joint ``j``'s axis bounded by the joint origins'
        offsets along the chain plus the point's distance from its body's origin (a
        prismatic joint adds its stroke to the offsets and moves the point at ``|qd_j|``).

        Returns
        -------
        ndarray, shape (n,)
            ``rho_jb`` (m/rad; 1 for a prismatic joint ``j``, 0 for ``j > b``).
        """
        model = self.model
        offsets = [float(np.linalg.norm(b.translation)) for b in model.bodies]
        stroke = [max(abs(lo), abs(hi)) if b.kind == "prismatic" else 0.0
                  for b, lo, hi in zip(model.bodies, model.q_lower, model.q_upper,
                                       strict=True)]
        out = np.zeros(model.n)
        for j in range(body + 1):
            rho = sum(offsets[j + 1:body + 1]) + sum(stroke[j:body + 1]) + reach
            out[j] = 1.0 if model.bodies[j].kind == "prismatic" else rho
        return out

    @functools.cached_property
    def link_levers(self) -> dict[str, np.ndarray]:
        """Each link's :meth:`lever_arms` (n,) (m/rad) out to its farthest surface point.

        The reach is :meth:`LinkShape.reach` (exact) over the link's shapes; computed once
        per model (read, not changed: the certificate's between-samples bound and the
        report's executed-motion bound both use it).
        """
        out = {}
        for link_spheres in self.spheres:
            reach = max((s.reach() for s in self.shapes if s.link == link_spheres.link),
                        default=0.0)
            out[link_spheres.link] = self.lever_arms(link_spheres.body, reach)
        return out

    def speed_bounds(self, velocity: np.ndarray) -> dict:
        """How fast any point of each link can move under joint speeds ``velocity``.

        ``sum_j |qd_j| rho_jb`` with :attr:`link_levers`. ``velocity`` (n,) gives link ->
        float (m/s; ``inf`` with an infinite joint speed that moves the link); (M, n), one
        row of joint speed bounds per interval of a motion, gives link -> ndarray (M,).
        """
        velocity = np.abs(np.asarray(velocity, dtype=float))
        out = {}
        with np.errstate(invalid="ignore"):
            for link, lever in self.link_levers.items():
                rate = np.sum(np.where(lever > 0, velocity * lever, 0.0), axis=-1)
                out[link] = float(rate) if velocity.ndim == 1 else rate
        return out

    def clearance(self, q: np.ndarray) -> Clearance:
        """Exact distances (Coal, the URDF's geometry) of every checked pair at ``q`` (K, n).

        Raises
        ------
        ProblemError
            Nothing to check (no obstacle and no self pair).
        """
        import coal

        q = np.atleast_2d(np.asarray(q, dtype=float))
        rots, poss = body_frames(self.model, q)
        by_link: dict[str, list[LinkShape]] = {}
        for s in self.shapes:
            by_link.setdefault(s.link, []).append(s)
        request = coal.DistanceRequest()
        request.enable_signed_distance = True

        def placed(shape, k):
            b = shape.body + 1
            return coal.Transform3s(rots[k, b] @ shape.rotation,
                                    poss[k, b] + rots[k, b] @ shape.translation)

        out = {}
        obstacles = {o.name: o for o in self.scene.obstacles}
        for a, b in self.obstacle_pairs() + self.self_pairs:
            d = np.full(len(q), np.inf)
            for k in range(len(q)):
                for sa in by_link[a]:
                    if b in obstacles:
                        ob = obstacles[b]
                        others = [(ob.geometry(), coal.Transform3s(ob.rotation,
                                                                   ob.translation))]
                    else:
                        others = [(sb.geometry(), placed(sb, k)) for sb in by_link[b]]
                    for geom, where in others:
                        res = coal.DistanceResult()
                        d[k] = min(d[k], coal.distance(sa.geometry(), placed(sa, k), geom,
                                                       where, request, res))
            out[(a, b)] = d
        if not out:
            raise ProblemError("the collision model checks no pair (no obstacle, no self pair)")
        stacked = np.array(list(out.values()))
        distance = stacked.min(axis=0)
        index = int(np.argmin(distance))
        pair = list(out)[int(np.argmin(stacked[:, index]))]
        return Clearance(distance, pair, index, float(distance[index]), out)


    def swept(self, t: np.ndarray, q: np.ndarray, velocity: np.ndarray,
              least_exact: bool = True) -> SweptClearance:
        """The clearance along a motion sampled at times ``t`` (K,) with positions ``q`` (K, n).

        At each time every checked pair gets a lower bound from bounding spheres
        (:meth:`LinkShape.bounding_sphere`, and the exact distance of its centre to an
        obstacle); Coal's exact distance replaces it where it is within
        :data:`~.tuning.EXACT_BAND` of the margin plus the between-samples bound. Between
        two times ``h`` apart a pair's distance falls at most ``v h / 2`` below the mean of
        its two ends (``v``: :meth:`speed_bounds` of both links under ``velocity``: (n,),
        joint speeds the motion never exceeds, e.g. the velocity limits it keeps; or
        (K - 1, n), a bound of the joint speeds on each interval, e.g.
        :meth:`~tocontrol_ros.core.direct.flat_trajectory.FlatTrajectory.joint_speed_bounds`):
        that is :attr:`SweptClearance.lower_bound`. :attr:`SweptClearance.minimum` is the
        least exact distance at the times: where a pair's spheres' bound (not made exact by
        the band) lies below the least exact distance found, Coal is asked there too,
        nearest bound first (:func:`_least_exact`). ``least_exact=False`` leaves that search
        out, for a caller that reads only the bounds (``lower_bound``, ``interval_bounds``):
        ``minimum``, ``pair`` and ``time`` are then the least of the distances made exact.
        """
        import coal

        t = np.asarray(t, dtype=float)
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rots, poss = body_frames(self.model, q)
        h = np.diff(t)
        velocity = np.asarray(velocity, dtype=float)
        if velocity.shape not in ((self.model.n,), (len(h), self.model.n)):
            raise ValueError(f"`velocity` must have shape ({self.model.n},) or ({len(h)}, "
                             f"{self.model.n}), got {velocity.shape}")
        speeds = self.speed_bounds(velocity)
        shapes: dict[str, list] = {}
        for s in self.shapes:
            c, r = s.bounding_sphere()
            world = poss[:, s.body + 1] + np.einsum("kij,j->ki", rots[:, s.body + 1], c)
            shapes.setdefault(s.link, []).append((s, world, r))
        obstacles = {o.name: o for o in self.scene.obstacles}
        request = coal.DistanceRequest()
        request.enable_signed_distance = True

        def placed(shape, k):
            b = shape.body + 1
            return coal.Transform3s(rots[k, b] @ shape.rotation,
                                    poss[k, b] + rots[k, b] @ shape.translation)

        best, lower, calls = (np.inf, ("", ""), 0.0), np.inf, 0
        per_interval = np.full(len(h), np.inf)
        loose: list = []  # per piece: its pair, shapes, placement and the bounds not made exact
        for a, b in self.obstacle_pairs() + self.self_pairs:
            rate = speeds[a] + (0.0 if b in obstacles else speeds[b])
            fall = np.concatenate([[0.0], rate * h / 2, [0.0]])  # on each side of a time
            need = self.margin + np.maximum(fall[:-1], fall[1:]) + EXACT_BAND
            d = np.full(len(t), np.inf)
            for sa, wa, ra in shapes[a]:
                if b in obstacles:
                    ob = obstacles[b]
                    pieces = [(ob.distance(wa) - ra, ob.geometry(),
                               lambda k, ob=ob: coal.Transform3s(ob.rotation, ob.translation))]
                else:
                    pieces = [(np.linalg.norm(wa - wb, axis=1) - ra - rb, sb.geometry(),
                               lambda k, sb=sb: placed(sb, k)) for sb, wb, rb in shapes[b]]
                for bound, geom, where in pieces:
                    exact = bound.copy()
                    near = bound < need
                    for k in np.flatnonzero(near):
                        calls += 1
                        exact[k] = coal.distance(sa.geometry(), placed(sa, k), geom,
                                                 where(k), request, coal.DistanceResult())
                    d = np.minimum(d, exact)
                    known = np.where(near, exact, np.inf)
                    k = int(np.argmin(known))
                    if known[k] < best[0]:
                        best = (float(known[k]), (a, b), float(t[k]))
                    if least_exact:
                        loose.append(((a, b), sa, geom, where,
                                      np.where(near, np.inf, bound)))
            if len(h):
                per_interval = np.minimum(per_interval, 0.5 * (d[:-1] + d[1:]) - rate * h / 2)
                lower = min(lower, float(np.min(per_interval)))
            else:
                lower = min(lower, float(d[0]))
        if loose:  # the least exact distance where a sphere bound lies below it
            best, more = _least_exact(best, loose, t, placed, request)
            calls += more
        return SweptClearance(best[0], best[1], best[2], lower, calls, per_interval)


def _least_exact(best: tuple, loose: list, t: np.ndarray, placed, request
                 ) -> tuple[tuple, int]:
    """``best`` made the least exact distance over every pair and time; and Coal's calls.

    ``best`` is ``(distance, pair, time)`` over the distances made exact (those near the
    check's need); ``placed(shape, k)`` a shape's placement at time ``k``; ``loose`` holds,
    per piece, the bounding spheres' lower bounds (shape (K,), ``t``'s) where no
    exact distance was taken. An exact distance is at least its bound, so Coal is asked at
    the loose entries whose bound lies below the least exact distance found, nearest bound
    first, until the next bound is not below it (a fixed amount of work: at most those
    entries). Far from every obstacle this is a few calls.
    """
    import coal

    bounds = np.concatenate([item[-1] for item in loose])
    todo = np.flatnonzero(bounds < best[0])
    calls = 0
    for j in todo[np.argsort(bounds[todo], kind="stable")]:
        if bounds[j] >= best[0]:
            break
        pair, sa, geom, where, _ = loose[j // len(t)]
        k = int(j % len(t))
        calls += 1
        dist = coal.distance(sa.geometry(), placed(sa, k), geom, where(k), request,
                             coal.DistanceResult())
        if dist < best[0]:
            best = (float(dist), pair, float(t[k]))
    return best, calls


def _margin(margin) -> float:
    value = float(margin)
    if not (np.isfinite(value) and value >= 0.0):
        raise ProblemError(f"`margin` must be a finite number >= 0 m, got {margin!r}")
    return value


def _check_allowed(scene: Scene, links: Sequence[str]) -> None:
    known = set(links) | set(scene.names())
    for pair in scene.allowed:
        unknown = sorted(set(pair) - known)
        if unknown:
            raise ProblemError(f"allowed pair {sorted(pair)} names {unknown}, neither a link "
                               f"with geometry nor an obstacle (links: {list(links)}; "
                               f"obstacles: {list(scene.names())})")


def _self_pairs(spheres: Sequence[LinkSpheres], disabled: frozenset, scene: Scene
                ) -> tuple[tuple[str, str], ...]:
    out = []
    for i, a in enumerate(spheres):
        for b in spheres[i + 1:]:
            if abs(a.body - b.body) <= 1:  # one body, or one joint between them
                continue
            pair = frozenset((a.link, b.link))
            if pair in disabled or pair in scene.allowed:
                continue
            out.append((a.link, b.link))
    return tuple(out)


def collision_model(model: RobotModel, urdf, srdf=None, scene: Scene | None = None,
                    margin: float = DEFAULT_MARGIN,
                    package_dirs: Sequence[str | os.PathLike] = ()) -> CollisionModel:
    """The collision model of ``model`` from its URDF (see the module).

    Parameters
    ----------
    model : RobotModel
        Loaded from the same URDF (:func:`~tocontrol_ros.core.robot.model.load_robot`).
    urdf : str or os.PathLike
        The URDF file or XML text (meshes relative to a file's directory).
    srdf : str or os.PathLike, optional
        SRDF text or file; its ``disable_collisions`` pairs are not checked.
    scene : Scene, optional
        Default: no obstacle.
    margin : float
        Clearance to keep (m).
    package_dirs : sequence of path
        Extra places for ``package://`` (see
        :func:`~tocontrol_ros.core.geometry.packages.share_directories`).

    Raises
    ------
    ModelError
        A mesh that cannot be found or read (named), a malformed SRDF, no geometry.
    ProblemError
        A negative margin, an allowed pair naming neither a link nor an obstacle.
    """
    scene = scene or Scene()
    margin = _margin(margin)
    robot, label = read_urdf(urdf)
    base_dir = Path(urdf).parent if label != "URDF string" else None
    placements = link_placements(robot, label, model)
    shapes = link_shapes(robot, label, placements, base_dir, package_dirs)
    if not shapes:
        raise ModelError(f"{label} has no <collision> element on the chain's links")
    spheres, hulls = [], []
    for link in dict.fromkeys(s.link for s in shapes):
        mine = [s for s in shapes if s.link == link]
        points = np.concatenate([s.points(SURFACE_SPACING) for s in mine])
        spheres.append(fit_spheres(link, mine[0].body, points))
        if mine[0].body < 0:  # fixed: its hull is a fixed convex set, as an obstacle
            hulls.append(fit_hull(mine, points))
    _check_allowed(scene, [s.link for s in spheres])
    disabled = disabled_pairs(srdf) if srdf is not None else frozenset()
    return CollisionModel(model, tuple(shapes), tuple(spheres),
                          _self_pairs(spheres, disabled, scene), scene, margin,
                          (str(urdf) if isinstance(urdf, os.PathLike) else urdf, srdf,
                           tuple(str(d) for d in package_dirs)), hulls=tuple(hulls))


#: Collision models rebuilt from a pickle (a worker process's problems), by what their
#: geometry comes from: read once per process, then given each problem's scene and margin.
_REBUILT: dict = {}
_REBUILT_LOCK = threading.Lock()


def _rebuilt(model, urdf, srdf, scene, margin, dirs, row_pairs=()) -> CollisionModel:
    key = (model.name, model.joint_names, model.base_link, model.tip_link, model.locked,
           urdf, srdf, dirs)
    with _REBUILT_LOCK:
        base = _REBUILT.get(key)
        if base is None:
            base = _REBUILT[key] = collision_model(model, urdf, srdf, None, margin, dirs)
    return replace(base, model=model).with_scene(scene, margin).with_row_pairs(row_pairs)
