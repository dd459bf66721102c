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
    """

    breaks: np.ndarray
    P: np.ndarray
    T: float
    lam_g: np.ndarray | None = None
    lam_x: np.ndarray | None = None
    rows_added: bool = False
