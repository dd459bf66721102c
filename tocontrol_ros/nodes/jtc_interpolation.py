"""A JTC's interpolation of goal points that carry positions only, or no accelerations.

A Jazzy ``joint_trajectory_controller`` accepts points whose velocities and accelerations are
empty (``validate_trajectory_point_field(..., allow_empty=true)``) and interpolates each
segment with what both of its ends have: positions and velocities and accelerations, a
quintic polynomial; positions and velocities, a cubic; positions only, a straight line
(constant velocity, no acceleration). The tracker follows a nominal trajectory that is a
quintic Hermite spline through positions, velocities and accelerations at its points
(:class:`~tocontrol_ros.core.sim.nominal.NominalTrajectory`); :func:`jtc_samples` turns such a
goal into one: the quintic segments keep their two points, the others are sampled every
``period`` with the JTC's polynomial and its derivatives, so the nominal follows the JTC's
interpolation to within one sample period. Pure numpy, no ROS.
"""

from __future__ import annotations

import numpy as np

__all__ = ["segment_kinds", "jtc_samples"]

#: Kinds of a segment, by what both of its end points carry.
LINEAR, CUBIC, QUINTIC = "linear", "cubic", "quintic"


def segment_kinds(has_velocities, has_accelerations) -> list[str]:
    """The interpolation of each segment, as a JTC chooses it.

    Parameters
    ----------
    has_velocities, has_accelerations : sequence of bool, length K
        Whether each point carries velocities / accelerations.

    Returns
    -------
    list of str, length K - 1
        ``"quintic"``, ``"cubic"`` or ``"linear"``.
    """
    v, a = list(has_velocities), list(has_accelerations)
    kinds = []
    for i in range(len(v) - 1):
        if v[i] and v[i + 1] and a[i] and a[i + 1]:
            kinds.append(QUINTIC)
        elif v[i] and v[i + 1]:
            kinds.append(CUBIC)
        else:
            kinds.append(LINEAR)
    return kinds


def _segment(kind: str, qa, va, qb, vb, h: float, s: np.ndarray):
    """Positions, velocities and accelerations (each (len(s), n)) at times ``s`` in [0, h)."""
    s = s[:, None]
    if kind == LINEAR:
        slope = (qb - qa) / h
        return qa + slope * s, np.broadcast_to(slope, (len(s), len(qa))).copy(), \
            np.zeros((len(s), len(qa)))
    # Cubic Hermite through (qa, va) and (qb, vb) over h.
    c2 = (3 * (qb - qa) / h - 2 * va - vb) / h
    c3 = (2 * (qa - qb) / h + va + vb) / h**2
    return (qa + va * s + c2 * s**2 + c3 * s**3, va + 2 * c2 * s + 3 * c3 * s**2,
            2 * c2 + 6 * c3 * s)


def jtc_samples(t, q, qd, qdd, period: float):
    """The points of a nominal trajectory that follows a JTC's interpolation of a goal.

    Parameters
    ----------
    t : array_like, shape (K,)
        ``time_from_start`` of the points (s), strictly increasing.
    q : array_like, shape (K, n)
        Positions (rad, m).
    qd, qdd : sequence of (array_like, shape (n,)) or None, length K
        Each point's velocities (rad/s) and accelerations (rad/s^2), None where it has none.
    period : float
        Sample spacing (s) of the segments that are not quintic, > 0.

    Returns
    -------
    (t, q, qd, qdd) : ndarrays, shapes (M,), (M, n), (M, n), (M, n)
        The goal's own points where every segment is quintic; else its points with the
        samples of its linear and cubic segments between them. A point where two kinds of
        segment meet takes the values of the segment that starts there (a JTC at that instant
        evaluates that one); the last point, at rest as a goal ends, keeps its own.
    """
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    K, n = q.shape
    if not period > 0:
        raise ValueError(f"`period` must be > 0, got {period!r}")
    kinds = segment_kinds([v is not None for v in qd], [a is not None for a in qdd])
    vel = [np.zeros(n) if v is None else np.asarray(v, dtype=float) for v in qd]
    acc = [np.zeros(n) if a is None else np.asarray(a, dtype=float) for a in qdd]
    if all(kind == QUINTIC for kind in kinds):
        return t, q, np.array(vel).reshape(K, n), np.array(acc).reshape(K, n)
    out_t, out_q, out_v, out_a = [], [], [], []
    for i, kind in enumerate(kinds):
        h = t[i + 1] - t[i]
        if kind == QUINTIC:
            s = np.zeros(1)
            pos, v, a = q[i][None], vel[i][None], acc[i][None]
        else:
            s = np.arange(0.0, h, period)
            s = s[s < h - 1e-3 * period]
            pos, v, a = _segment(kind, q[i], vel[i], q[i + 1], vel[i + 1], h, s)
        out_t.append(t[i] + s)
        out_q.append(pos)
        out_v.append(v)
        out_a.append(a)
    last_v = vel[-1] if qd[-1] is not None else np.zeros(n)
    last_a = acc[-1] if qdd[-1] is not None else np.zeros(n)
    out_t.append(t[-1:])
    out_q.append(q[-1:])
    out_v.append(last_v[None])
    out_a.append(last_a[None])
    return (np.concatenate(out_t), np.vstack(out_q), np.vstack(out_v), np.vstack(out_a))
