"""Clearance rows of the bounded transcription: each link sphere against each obstacle.

With a collision model (:class:`~tocontrol_ros.core.geometry.collision.CollisionModel`) the
B-spline transcription (:mod:`~tocontrol_ros.core.direct.flat`) gets, at each of its sample
times, one row per moving body and obstacle: the smooth minimum (:func:`_grouped`) over the
body's link spheres (less the allowed pairs) of

    sdf_o(c(q(s))) - r - margin - h sum_j rho_j max_k |Q'_jk| >= 0,

``sdf_o`` the obstacle's exact signed distance function, ``c(q)`` the sphere's centre, ``r``
its radius. The last term bounds how far the distance can fall between two samples, from
the motion itself: on a span of the B-spline ``q(s)`` (``s`` in [0, 1], ``t = T s``) the
path derivative ``q_j'(s)`` (rad per unit ``s``) lies in the convex hull of the span's
derivative control points ``Q'_jk`` (the span's ``p`` of them), so the centre moves at most
``sum_j rho_j max_k |Q'_jk|`` (m per unit ``s``; ``rho_j`` (m/rad) the lever arms of
:meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.lever_arms` at the centre's
distance from its body's origin). In time that is a speed of ``sum_j rho_j max_k |Q'_jk| /
T`` over a time step ``T ds``: ``T`` cancels, the term is ``ds sum_j rho_j max_k |Q'_jk|``
in metres, with no ``T`` in it. The distance of the sphere is 1-Lipschitz in its centre,
so between samples ``a`` and ``b`` of one span (``ds`` apart) it is at least the mean of
the two ends less half that term: ``h = ds / 2`` at every sample whose two neighbouring
steps lie in its span; the last sample of a span before the next one's first protects its
step forward alone, with ``h = ds`` (the next span's bound may be smaller). Between the
samples the distance cannot fall below the margin, and the spheres cover the link's
geometry, so the exact clearance is at least the margin at every time. The certificate
checks it independently (Coal on the URDF's own geometry).

``max_k |x_k|`` is bounded above by the smooth ``sqrt(sum_k x_k^2 + eps^2)`` (at most
``sqrt(p)`` times the maximum, 1.73 for a cubic, plus ``eps`` = :data:`SPEED_EPS`): the
bound stays a bound, and the rows stay twice differentiable. Measured on the bench's case
0, shelf (one solve warm from the obstacle-free optimum): the fourth-power norm with
``eps`` 1e-3 rad ended in IPOPT's restoration failure after 50 iterations, with ``eps``
0.05 at 300 iterations unconverged; the Euclidean norm with 0.05 converged (276).

Before issue 51's session 29 the term was ``v T ds / 2`` with ``v`` the link's speed bound
under the joint velocity limits (9.8 m/s for the Panda's hand: 2.9 cm at every sample, the
start's included): a start 1-3.9 cm from an obstacle made the NLP infeasible.

The arm's own pairs (:attr:`~tocontrol_ros.core.geometry.collision.CollisionModel.
self_pairs`) are rows only for the model's ``row_pairs`` (all of them would be 285 sphere
pairs a sample on the Panda): one row per pair of bodies, the smooth minimum of

    |c_a - c_b| - r_a - r_b - margin - h sum_{j > a} rho_bj max_k |Q'_jk| >= 0

over their sphere pairs (``a`` the earlier body: the joints up to it move both centres
alike, the later ones move ``c_b`` relative to body ``a`` with its lever arms). A pair with a
link on the base whose convex hull is tighter than its spheres (the Panda's ``panda_link0``:
spheres 5-6 cm off its mesh, the hull's planes at most 8.4 mm short up to 5 cm out;
:mod:`~tocontrol_ros.core.geometry.hull`) holds the other link's spheres against the hull
instead: ``d_H(c_b) - r_b - margin - h sum_j rho_bj max_k |Q'_jk|``, ``d_H`` the smooth
maximum of the hull's support planes (a lower bound of the exact distance). The planner
adds the pairs a motion refused by the certificate brought within
``SELF_ROW_BAND`` of the margin and plans again (``core/planning/solver.py``); the
certificate checks every self pair.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from tocontrol_ros.core.geometry.collision import CollisionModel
from tocontrol_ros.core.geometry.hull import SHARPNESS as HULL_SHARPNESS
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

#: The smoothing of the speed term's ``max_k |Q'_jk|`` (rad per unit ``s``): it adds at
#: most ``SPEED_EPS`` to each joint's bound (conservative; with the Panda's lever arms
#: and ``ds / 2`` about 1/200, about 1 mm); smaller made IPOPT's steps fail.
SPEED_EPS = 0.05

#: The room above its spheres' clearance that a row group close to a start (or joint state
#: target) is given at it (m): the speed term of the first span's samples, when the ends'
#: allowance (``FlatTranscription.clearance_allowance``) lowers the row.
END_ROOM = 0.005

#: The share of the motion (in ``s``) over which an end's allowance fades to none: the
#: allowance is ``shortfall (1 - (s / END_SPAN)^2)`` near the start (``1 - s`` for a
#: joint-state target's), zero beyond (``FlatTranscription.clearance_allowance``).
END_SPAN = 0.25

#: The power of the smooth maximum of ``|Q'_jk|`` (an even integer): ``(sum x^p)^(1/p)``
#: is at most ``degree^(1/p)`` times the maximum; 4 made IPOPT's steps fail (see above).
SPEED_NORM = 2

#: The version of the rows' formula (part of the compiled library's name).
ROWS_VERSION = 3

#: A self pair that a motion refused by the certificate brings closer than the margin
#: plus this (m, Coal's exact distance) becomes rows of the next solve
#: (``core/planning/solver.py``).
SELF_ROW_BAND = 0.005


@dataclass(frozen=True)
class ClearanceRows:
    """The rows' data: one per (moving link sphere, obstacle).

    Attributes
    ----------
    body : ndarray of int, shape (R,)
    center : ndarray, shape (R, 3)
        Sphere centres in their body's frame (m).
    radius : ndarray, shape (R,)
    lever : ndarray, shape (R, n)
        Lever arms of the spheres' centres per joint (m/rad,
        :meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.lever_arms`).
    obstacle : tuple of (kind, size, rotation, translation), length R
    margin : float
    names : tuple of (str, str), length R
        (link, obstacle) of each row.
    pair_body : ndarray of int, shape (Q, 2)
        The two bodies of each self sphere pair (-1: the base).
    pair_center : ndarray, shape (Q, 2, 3)
    pair_radius : ndarray, shape (Q, 2)
    pair_lever : ndarray, shape (Q, n)
        How fast the distance of each sphere pair changes per joint (m/rad): the lever
        arms of the later body's centre for the joints after the earlier body (the joints
        before move both centres alike).
    pair_names : tuple of (str, str), length Q
        (link, link) of each sphere pair.
    hull_body : ndarray of int, shape (H,)
        The body of each sphere held against a base link's hull (self rows where
        :meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.row_hull` gives one).
    hull_center : ndarray, shape (H, 3)
    hull_radius : ndarray, shape (H,)
    hull_lever : ndarray, shape (H, n)
    hull_planes : tuple of ndarray, length H
        Each row's hull as support planes (F, 4) in the base frame
        (:class:`~tocontrol_ros.core.geometry.hull.LinkHull`).
    hull_names : tuple of (str, str), length H
        (base link, link) of each row.
    """

    body: np.ndarray
    center: np.ndarray
    radius: np.ndarray
    lever: np.ndarray
    obstacle: tuple
    margin: float
    names: tuple
    pair_body: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), int))
    pair_center: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    pair_radius: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pair_lever: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    pair_names: tuple = ()
    hull_body: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    hull_center: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hull_radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hull_lever: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    hull_planes: tuple = ()
    hull_names: tuple = ()

    def digest(self) -> str:
        """A short hash of everything the rows compute (names a compiled library)."""
        h = hashlib.sha1(f"rows{ROWS_VERSION} {SOFTMIN_SHARPNESS!r} {SPEED_EPS!r} "
                         f"{SPEED_NORM}".encode())
        for arr in (self.body, self.center, self.radius, self.lever, self.pair_body,
                    self.pair_center, self.pair_radius, self.pair_lever):
            h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
        for kind, size, rot, pos in self.obstacle:
            h.update(kind.encode())
            h.update(np.array([*size, *np.ravel(rot), *pos], dtype=float).tobytes())
        h.update(np.array([self.margin]).tobytes())
        if len(self.hull_radius):  # rows without a hull keep their former names
            h.update(f"hull {HULL_SHARPNESS!r}".encode())
            for arr in (self.hull_body, self.hull_center, self.hull_radius, self.hull_lever,
                        *self.hull_planes):
                h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
        return h.hexdigest()[:16]

    @property
    def count(self) -> int:
        """Spheres against obstacles and self sphere pairs (the rows are :meth:`groups`)."""
        return len(self.radius) + len(self.pair_radius) + len(self.hull_radius)

    def groups(self) -> list[np.ndarray]:
        """The NLP's rows: the sphere pairs of one body and one obstacle, each an index array.

        In order of first appearance; then the self sphere pairs of two bodies (indices
        after the obstacles' ``R``), then the spheres held against a base link's hull (one
        group with any sphere pairs of the same two bodies).
        """
        keys = [(int(b), n[1]) for b, n in zip(self.body, self.names, strict=True)]
        keys += [("self", int(a), int(b)) for a, b in self.pair_body]
        keys += [("self", -1, int(b)) for b in self.hull_body]
        order = list(dict.fromkeys(keys))
        return [np.flatnonzero([k == key for k in keys]) for key in order]


def clearance_rows(collision: CollisionModel) -> ClearanceRows:
    """The rows of ``collision``'s scene and of its ``row_pairs``.

    Links on the base (body -1) do not move: their obstacle pairs are constant and left to
    the certificate (a start in collision is refused before).
    """
    n = collision.model.n
    obstacles = {o.name: o for o in collision.scene.obstacles}
    rows = []
    for link, name in collision.obstacle_pairs():
        spheres = next(s for s in collision.spheres if s.link == link)
        if spheres.body < 0:
            continue
        ob = obstacles[name]
        for c, r in zip(spheres.centers, spheres.radii, strict=True):
            lever = collision.lever_arms(spheres.body, float(np.linalg.norm(c)))
            rows.append((spheres.body, c, r, lever,
                         (ob.kind, tuple(ob.size), ob.rotation, ob.translation), (link, name)))
    pairs = _self_rows(collision)
    if not rows:
        return ClearanceRows(np.zeros(0, int), np.zeros((0, 3)), np.zeros(0), np.zeros((0, n)),
                             (), collision.margin, (), **pairs)
    body, center, radius, lever, obstacle, names = zip(*rows, strict=True)
    return ClearanceRows(np.array(body), np.array(center), np.array(radius), np.array(lever),
                         tuple(obstacle), collision.margin, tuple(names), **pairs)


def _self_rows(collision: CollisionModel) -> dict:
    """The rows of ``collision.row_pairs`` (:class:`ClearanceRows`' ``pair_*`` and ``hull_*``).

    A pair with a base link whose hull is tighter than its spheres
    (:meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.row_hull`) holds the
    other link's spheres against the hull's planes; any other pair, sphere against sphere.
    """
    n = collision.model.n
    by_link = {s.link: s for s in collision.spheres}
    rows, hulls = [], []
    for a, b in collision.row_pairs:
        sa, sb = by_link[a], by_link[b]
        if sa.body > sb.body:
            sa, sb = sb, sa
        hull = collision.row_hull(sa.link) if sa.body < 0 else None
        for cb, rb in zip(sb.centers, sb.radii, strict=True):
            # joints up to sa's body move both centres alike: only those after it
            # change the distance, moving sb's centre relative to sa's body
            lever = collision.lever_arms(sb.body, float(np.linalg.norm(cb)))
            lever[:sa.body + 1] = 0.0
            if hull is not None:
                hulls.append((sb.body, cb, rb, lever, hull.planes, (sa.link, sb.link)))
                continue
            for ca_, ra in zip(sa.centers, sa.radii, strict=True):
                rows.append(((sa.body, sb.body), (ca_, cb), (ra, rb), lever,
                             (sa.link, sb.link)))
    out: dict = {"pair_lever": np.zeros((0, n)), "hull_lever": np.zeros((0, n))}
    if rows:
        body, center, radius, lever, names = zip(*rows, strict=True)
        out.update(pair_body=np.array(body, int), pair_center=np.array(center),
                   pair_radius=np.array(radius), pair_lever=np.array(lever),
                   pair_names=tuple(names))
    if hulls:
        body, center, radius, lever, planes, names = zip(*hulls, strict=True)
        out.update(hull_body=np.array(body, int), hull_center=np.array(center),
                   hull_radius=np.array(radius), hull_lever=np.array(lever),
                   hull_planes=tuple(planes), hull_names=tuple(names))
    return out


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


def _hull_distance(planes: np.ndarray, c) -> tuple:
    """The smooth lower bound (SX) of a point's distance ``c`` (3, 1) to a hull's planes (F, 4).

    As :meth:`~tocontrol_ros.core.geometry.hull.LinkHull.distance`: the smooth maximum of
    the planes' values less ``log(F) / sharpness``, never above the largest. Returns the
    value and ``(gradient (3, 1), Hessian (3, 3))`` in ``c``, written out (softmax weights
    ``w_f``: gradient ``sum w_f a_f``, Hessian ``beta (sum w_f a_f a_f^T - grad grad^T)``).
    """
    normals = ca.DM(planes[:, :3])
    v = ca.mtimes(normals, c) + ca.DM(planes[:, 3])
    top = ca.mmax(v)  # any shift gives the same value; this one keeps exp() in range
    e = ca.exp(HULL_SHARPNESS * (v - top))
    total = ca.sum1(e)
    value = top + (ca.log(total) - np.log(len(planes))) / HULL_SHARPNESS
    w = e / total
    grad = ca.mtimes(normals.T, w)
    hess = HULL_SHARPNESS * (ca.mtimes(normals.T, ca.mtimes(ca.diag(w), normals))
                             - ca.mtimes(grad, grad.T))
    return value, (grad, hess)


def _span_speed(P, coef):
    """Smooth upper bounds (n,) of ``max_k |Q'_jk|`` on a span (rad per unit ``s``).

    ``P`` (n, p + 1) the span's control points, ``coef`` (p,) the derivative's coefficients
    (``Q'_k = coef_k (P_{k+1} - P_k)``).
    """
    p = P.shape[1] - 1
    total = SPEED_EPS ** SPEED_NORM
    for k in range(p):
        total = total + (coef[k] * (P[:, k + 1] - P[:, k])) ** SPEED_NORM
    return total ** (1.0 / SPEED_NORM)


def clearance_functions(model: RobotModel, rows: ClearanceRows, degree: int
                        ) -> list[ca.Function]:
    """Per-sample functions (SX) of the rows: values, with their gradient, the weighted Hessian.

    Inputs ``P`` (n, degree + 1) (the span's control points), ``T`` (s), ``b`` (1,
    degree + 1) (the sample's basis values), ``geo`` (degree + 1,): the sample's step
    weight ``h`` (``ds / 2`` or ``ds``, normalised time) then its span's derivative
    coefficients; the Hessian also ``lam`` (R,). The variables ``z = (vec P, T)`` (the rows
    do not depend on ``T``; it stays in ``z`` for the scatter's layout).
    """
    n, d1 = model.n, degree + 1
    P = ca.SX.sym("P", n, d1)
    T = ca.SX.sym("T")
    b = ca.SX.sym("b", 1, d1)
    geo = ca.SX.sym("geo", d1)
    lam = ca.SX.sym("lam", len(rows.groups()))
    z = ca.vertcat(ca.vec(P), T)
    q = ca.mtimes(P, b.T)
    frames = model.body_frames_sym(q)
    speed = _span_speed(P, geo[1:])
    g = []
    for i in range(len(rows.radius)):
        rot, pos = frames[int(rows.body[i])]
        c = pos + ca.mtimes(rot, ca.DM(rows.center[i]))
        kind, size, o_rot, o_pos = rows.obstacle[i]
        local = ca.mtimes(ca.DM(o_rot).T, c - ca.DM(o_pos))
        g.append(_sdf(kind, size, local) - float(rows.radius[i]) - rows.margin
                 - geo[0] * ca.dot(ca.DM(rows.lever[i]), speed))
    for i in range(len(rows.pair_radius)):
        ends = []
        for k in range(2):
            body = int(rows.pair_body[i, k])
            centre = ca.DM(rows.pair_center[i, k])
            if body < 0:  # the base
                ends.append(centre)
            else:
                rot, pos = frames[body]
                ends.append(pos + ca.mtimes(rot, centre))
        dist = ca.sqrt(ca.sumsqr(ends[0] - ends[1]) + SDF_EPS ** 2)
        g.append(dist - float(rows.pair_radius[i].sum()) - rows.margin
                 - geo[0] * ca.dot(ca.DM(rows.pair_lever[i]), speed))
    # A hull row's distance is a sum over its planes: differentiated through the sphere's
    # centre by the chain rule, it would repeat that sum for every variable (a 15 MB C
    # source for the Panda's hand, minutes of compiling). So it enters as its second-order
    # expansion about a stand-in point ``c0`` (value, gradient and Hessian in ``c0``: sums
    # over the planes, once each), which is then replaced by the centre: at ``c0 = c`` the
    # value, gradient and Hessian are the distance's own.
    stand, centres = [], []
    for i in range(len(rows.hull_radius)):
        rot, pos = frames[int(rows.hull_body[i])]
        c = pos + ca.mtimes(rot, ca.DM(rows.hull_center[i]))
        c0 = ca.SX.sym(f"c0_{i}", 3)
        value, (slope, curve) = _hull_distance(np.asarray(rows.hull_planes[i], dtype=float),
                                               c0)
        d = c - c0
        g.append(value + ca.dot(slope, d) + 0.5 * ca.dot(d, ca.mtimes(curve, d))
                 - float(rows.hull_radius[i]) - rows.margin
                 - geo[0] * ca.dot(ca.DM(rows.hull_lever[i]), speed))
        stand.append(c0)
        centres.append(c)
    g = _grouped(ca.vertcat(*g), rows)
    hess = ca.hessian(ca.dot(lam, g), z)[0]
    dz = z.numel()
    upper = ca.vertcat(*[hess[r, col] for col in range(dz) for r in range(col + 1)])
    jac = ca.densify(ca.jacobian(g, z))
    if stand:
        stand, centres = ca.vertcat(*stand), ca.vertcat(*centres)
        g, jac, upper = (ca.substitute(e, stand, centres) for e in (g, jac, upper))
    return [ca.Function("clear", [P, T, b, geo], [g]),
            ca.Function("clear_grad", [P, T, b, geo], [g, jac]),
            ca.Function("clear_hess", [P, T, b, geo, lam], [ca.densify(ca.cse(upper))])]


def compile_clearance(model: RobotModel, rows: ClearanceRows, degree: int = 3
                      ) -> tuple[list[ca.Function], str]:
    """:func:`clearance_functions` compiled, once per model, rows and degree.

    The rows' values are constants of the library (a scene's content names it): a new scene
    builds one more library; the same scene again reuses it.
    """
    digest = rows.digest()
    return compile_owned(model, ("clearance", degree, digest), f"clear{model.n}p{degree}_{digest}",
                         lambda: clearance_functions(model, rows, degree))
