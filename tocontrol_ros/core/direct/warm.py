"""What a bounded B-spline solve leaves for a warm start: its mesh, path and multipliers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PathWarmState"]


@dataclass(frozen=True, eq=False)
class PathWarmState:
    """The final B-spline mesh and path of a ``"direct"`` solve: what its warm start uses.

    Attributes
    ----------
    breaks : ndarray, shape (L + 1,)
        Breakpoints of the spline in normalised time ``s = t / T`` (from 0 to 1).
    P : ndarray, shape (L + degree, n)
        Control points (rad, m).
    T : float
        Final time (s).
    lam_g, lam_x : ndarray or None
        The NLP's multipliers at that solution (rows, then variables' bounds): a warm
        re-solve on the same mesh starts from them too (docs/limits.md).
    rows_added : bool
        The path solves a problem with fewer clearance rows than the one it starts (the
        planner's self rows after a refused motion): it breaks the new rows, so a warm
        solve that fails is tried once more from IPOPT's default start (docs/collision.md,
        session 34: case 1 table of bench/collision.py).
    set_values : ndarray or None
        The control set's values ``sum_i |u_i|^(2k)`` along this path at
        :data:`~tocontrol_ros.core.direct.flat_trajectory.SET_POINTS` times a span (L 32,),
        as the plan's check between the samples evaluated them (for its ``k`` and torque
        scale): a warm re-solve on this mesh with the same two reads its pads per sample
        off them (:func:`~tocontrol_ros.core.direct.set_pads.row_pads`) instead of
        evaluating them again (issue 47). None where not known (a stored motion's).
    k, torque_scale : float or None
        The exponent and the torque scale (fraction of ``tau_max``) of ``set_values``.
    """

    breaks: np.ndarray
    P: np.ndarray
    T: float
    lam_g: np.ndarray | None = None
    lam_x: np.ndarray | None = None
    rows_added: bool = False
    set_values: np.ndarray | None = None
    k: float | None = None
    torque_scale: float | None = None
