"""Clearance rows of the bounded transcription: each link sphere against each obstacle.

With a collision model (:class:`~tocontrol_ros.core.geometry.collision.CollisionModel`) the
B-spline transcription (:mod:`~tocontrol_ros.core.direct.flat`) gets, at each of its sample
times, one row per moving body and obstacle: the smooth minimum (:func:`_grouped`) over the
body's link spheres (less the allowed pairs) of

    sdf_o(c(q)) - r - margin - v T ds / 2 >= 0,

``sdf_o`` the obstacle's exact signed distance function, ``c(q)`` the sphere's centre, ``r``
its radius, ``v`` a bound of how fast the sphere moves under the joint velocity limits
(:meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.speed_bounds`, held at every
time by the velocity rows) and ``T ds`` the largest time between two samples: between the
samples the distance cannot fall below the margin, and the spheres cover the link's
geometry, so the exact clearance is at least the margin at every time. The certificate
checks it independently (Coal on the URDF's own geometry).

The arm's own pairs are not rows (hundreds of sphere pairs per sample on the Panda): the
certificate checks them, and a motion whose links come closer than the margin fails it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import casadi as ca
import numpy as np

from tocontrol_ros.core.geometry.collision import CollisionModel
from tocontrol_ros.core.robot.compiled import compile_owned
from tocontrol_ros.core.robot.model import RobotModel

__all__ = ["ClearanceRows", "clearance_rows", "clearance_functions", "compile_clearance"]

#: The smoothing of the box's and cylinder's distance function at its edges (m): the
#: outside distance is ``sqrt(|max(d, 0)|^2 + SDF_EPS^2) - SDF_EPS``, differentiable where
#: a sphere's centre touches a face (it is always at least ``r`` outside in a solution).
SDF_EPS = 1e-6


#: The sharpness of the smooth minimum over one body's spheres (1/m): it stands at most
#: ``log(spheres) / SOFTMIN_SHARPNESS`` below the true minimum (2.7 mm for fifteen), a
#: conservative error; sharper makes the rows' curvature larger.
SOFTMIN_SHARPNESS = 1000.0


@dataclass(frozen=True)
class ClearanceRows:
    """The rows' data: one per (moving link sphere, obstacle).

    Attributes
    ----------
    body : ndarray of int, shape (R,)
    center : ndarray, shape (R, 3)
        Sphere centres in their body's frame (m).
    radius : ndarray, shape (R,)
    rate : ndarray, shape (R,)
        Speed bounds of the spheres' links (m/s).
    obstacle : tuple of (kind, size, rotation, translation), length R
    margin : float
    names : tuple of (str, str), length R
        (link, obstacle) of each row.
    """

    body: np.ndarray
    center: np.ndarray
    radius: np.ndarray
    rate: np.ndarray
    obstacle: tuple
    margin: float
    names: tuple

    def digest(self) -> str:
        """A short hash of everything the rows compute (names a compiled library)."""
        h = hashlib.sha1()
        for arr in (self.body, self.center, self.radius, self.rate):
            h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
        for kind, size, rot, pos in self.obstacle:
            h.update(kind.encode())
            h.update(np.array([*size, *np.ravel(rot), *pos], dtype=float).tobytes())
        h.update(np.array([self.margin]).tobytes())
        return h.hexdigest()[:16]

    @property
    def count(self) -> int:
        """Spheres against obstacles (the rows are :meth:`groups`)."""
        return len(self.radius)

    def groups(self) -> list[np.ndarray]:
        """The NLP's rows: the sphere pairs of one body and one obstacle, each an index array.

        In order of first appearance.
        """
        keys = [(int(b), n[1]) for b, n in zip(self.body, self.names, strict=True)]
        order = list(dict.fromkeys(keys))
        return [np.flatnonzero([k == key for k in keys]) for key in order]


def clearance_rows(collision: CollisionModel, velocity: np.ndarray) -> ClearanceRows:
    """The rows of ``collision``'s scene under joint speed limits ``velocity`` (n,) (rad/s).

    Links on the base (body -1) do not move: their pairs are constant and left to the
    certificate (a start in collision is refused before).
    """
    speeds = collision.speed_bounds(velocity)
    obstacles = {o.name: o for o in collision.scene.obstacles}
    rows = []
    for link, name in collision.obstacle_pairs():
        spheres = next(s for s in collision.spheres if s.link == link)
        if spheres.body < 0:
            continue
        ob = obstacles[name]
        for c, r in zip(spheres.centers, spheres.radii, strict=True):
            rows.append((spheres.body, c, r, speeds[link],
                         (ob.kind, tuple(ob.size), ob.rotation, ob.translation), (link, name)))
    if not rows:
        return ClearanceRows(np.zeros(0, int), np.zeros((0, 3)), np.zeros(0), np.zeros(0), (),
                             collision.margin, ())
    body, center, radius, rate, obstacle, names = zip(*rows, strict=True)
    return ClearanceRows(np.array(body), np.array(center), np.array(radius), np.array(rate),
                         tuple(obstacle), collision.margin, tuple(names))


def _grouped(g, rows: ClearanceRows):
    """One row per body and obstacle: the smooth minimum of its spheres' rows.

    ``-log(sum exp(-beta g_i)) / beta`` is below ``min g_i`` by at most ``log(count) /
    beta``: a row that holds makes every sphere's hold (conservative). One row instead of up
    to fifteen (the Panda's last body): on a Panda case 32 rows a sample made each IPOPT
    iteration seven times as long as without a scene.
    """
    out = []
    for idx in rows.groups():
        gi = g[idx.tolist()]
        if len(idx) == 1:
            out.append(gi)
            continue
        low = ca.mmin(gi)  # any shift gives the same value; this one keeps exp() in range
        out.append(low - ca.log(ca.sum1(ca.exp(-SOFTMIN_SHARPNESS * (gi - low))))
                   / SOFTMIN_SHARPNESS)
    return ca.vertcat(*out)


def _sdf(kind: str, size, local):
    """The signed distance (SX) of a point ``local`` (3, 1) in an obstacle's frame."""
    if kind == "sphere":
        return ca.sqrt(ca.sumsqr(local) + SDF_EPS ** 2) - size[0]
    if kind == "cylinder":
        radial = ca.sqrt(local[0] ** 2 + local[1] ** 2 + SDF_EPS ** 2)
        d = ca.vertcat(radial - size[0], ca.fabs(local[2]) - size[1] / 2)
    else:
        d = ca.fabs(local) - ca.DM(np.asarray(size, dtype=float) / 2)
    outside = ca.sqrt(ca.sumsqr(ca.fmax(d, 0)) + SDF_EPS ** 2) - SDF_EPS
    return outside + ca.fmin(ca.mmax(d), 0)


def clearance_functions(model: RobotModel, rows: ClearanceRows, degree: int
                        ) -> list[ca.Function]:
    """Per-sample functions (SX) of the rows: values, with their gradient, the weighted Hessian.

    Inputs ``P`` (n, degree + 1) (the span's control points), ``T`` (s), ``b`` (1,
    degree + 1) (the sample's basis values), ``ds`` (the largest normalised time between
    samples); the Hessian also ``lam`` (R,). The variables ``z = (vec P, T)``.
    """
    n, d1 = model.n, degree + 1
    P = ca.SX.sym("P", n, d1)
    T = ca.SX.sym("T")
    b = ca.SX.sym("b", 1, d1)
    ds = ca.SX.sym("ds")
    lam = ca.SX.sym("lam", len(rows.groups()))
    z = ca.vertcat(ca.vec(P), T)
    q = ca.mtimes(P, b.T)
    frames = model.body_frames_sym(q)
    g = []
    for i in range(rows.count):
        rot, pos = frames[int(rows.body[i])]
        c = pos + ca.mtimes(rot, ca.DM(rows.center[i]))
        kind, size, o_rot, o_pos = rows.obstacle[i]
        local = ca.mtimes(ca.DM(o_rot).T, c - ca.DM(o_pos))
        g.append(_sdf(kind, size, local) - float(rows.radius[i]) - rows.margin
                 - float(rows.rate[i]) * T * ds / 2)
    g = _grouped(ca.vertcat(*g), rows)
    hess = ca.hessian(ca.dot(lam, g), z)[0]
    dz = z.numel()
    upper = ca.vertcat(*[hess[r, col] for col in range(dz) for r in range(col + 1)])
    return [ca.Function("clear", [P, T, b, ds], [g]),
            ca.Function("clear_grad", [P, T, b, ds], [g, ca.densify(ca.jacobian(g, z))]),
            ca.Function("clear_hess", [P, T, b, ds, lam], [ca.densify(ca.cse(upper))])]


def compile_clearance(model: RobotModel, rows: ClearanceRows, degree: int = 3
                      ) -> tuple[list[ca.Function], str]:
    """:func:`clearance_functions` compiled, once per model, rows and degree.

    The rows' values are constants of the library (a scene's content names it): a new scene
    builds one more library; the same scene again reuses it.
    """
    digest = rows.digest()
    return compile_owned(model, ("clearance", degree, digest), f"clear{model.n}p{degree}_{digest}",
                         lambda: clearance_functions(model, rows, degree))
