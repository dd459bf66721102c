"""The refinement's clearance rows as an active set: only the samples near an obstacle.

A refinement level (``limited._refine_item``) solves the bounded NLP on a finer mesh from
the coarser level's path, which it changes by little. With a scene, every sample carries a
row per moving body and obstacle (and per self pair made a row): on a fine mesh thousands
of rows, almost all of them centimetres to metres from their bound, each paid for in every
IPOPT iteration (its value, gradient and Hessian block, and its row of the KKT system).
:func:`active_rows_solve` keeps the rows of the samples where some row of the full NLP is
within :data:`ROW_BAND` of its bound along the starting path, solves that smaller NLP, and
accepts its solution only if every row of the full NLP holds there with room
(:meth:`~.flat.FlatTranscription.clearance_slack`, the same rows, bounds and allowance):
then it is a solution of the full NLP too (the rows left out are inactive, their
multipliers zero, :meth:`~.flat.FlatTranscription.full_lam_g`), and its residual is the
full NLP's. Otherwise (a row left out came within its bound, or the smaller NLP failed)
the caller solves the full NLP as before, from the same start: nothing is lost but the
smaller solve. The choice of samples depends on the starting path only (work, not the
clock): the same request gives the same plan. The margin is still held at every sample by
the accepted motion, and the certificate checks the exact clearance independently.

This is the active-set outer loop of TrajOpt and MoveIt's planners (constraints from the
pairs near contact along the current path), cut to one round with a fallback.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription

__all__ = ["ACTIVE_ROWS", "ROW_BAND", "ACTIVE_SHARE", "active_rows_solve"]

#: Whether the refinement tries the active set first (a switch for the paired measurement
#: of bench/collision_profile.py; the plan is the same either way up to IPOPT's tolerance).
ACTIVE_ROWS = True

#: A sample keeps its clearance rows when some row is within this of its bound (m) along
#: the starting path: wider than a refinement level moves the path (docs/collision.md).
ROW_BAND = 0.05
#: When more than this share of the samples would keep their rows, the full NLP is solved
#: (the smaller build would save little).
ACTIVE_SHARE = 0.8


def active_rows_solve(flat: FlatTranscription, values: tuple, T: float, P0: np.ndarray,
                      bounds: tuple, **budget) -> FlatResult | None:
    """Solve ``flat`` from ``(T, P0)`` with the clearance rows of the near samples only.

    Parameters
    ----------
    flat : FlatTranscription
        The full NLP (every sample's clearance rows), on the refinement's breakpoints.
    values : tuple
        ``(start value, target value, k)``.
    T : float
        Starting final time (s).
    P0 : ndarray, shape (K, n)
        Starting control points (rad).
    bounds : tuple of ndarray
        ``(lower, upper)`` state bounds (2n,).
    **budget
        :meth:`~.flat.FlatTranscription.solve`'s ``deadline``, ``max_iter``,
        ``should_stop``.

    Returns
    -------
    FlatResult or None
        A solution of the full NLP (its multipliers and residual the full NLP's), or None:
        no scene, nearly every sample near, the smaller NLP failed, or a row left out does
        not hold at its solution (the caller then solves ``flat`` itself).
    """
    if flat.clearance is None:
        return None
    slack = np.min(flat.clearance_slack(*values, T, P0), axis=1)
    near = np.flatnonzero(slack < ROW_BAND)
    if len(near) > ACTIVE_SHARE * len(slack):
        return None
    keep = near if len(near) else np.array([int(np.argmin(slack))])
    small = flat.with_clearance_samples(keep)
    out = small.solve(*values, T, P0, *bounds, **budget)
    if not out.success:
        return None
    left = np.setdiff1d(np.arange(len(slack)), keep)
    after = np.min(flat.clearance_slack(*values, out.T, out.P), axis=1)
    if len(left) and float(np.min(after[left])) <= 0.0:
        return None
    return replace(out, lam_g=small.full_lam_g(out.lam_g),
                   residual=flat.residual(*values, out.T, out.P, *bounds))
