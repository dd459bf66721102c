"""Clamped B-splines in normalised time: breakpoints, knot vectors and basis functions.

The joint paths of the bounded solve (:mod:`tocontrol_ros.core.direct.flat`) are clamped
B-splines on ``[0, 1]``; these give their knots and the basis values and derivatives.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BSpline

__all__ = ["basis", "breakpoints", "knots"]


def breakpoints(spans: int | np.ndarray) -> np.ndarray:
    """Breakpoints on [0, 1] (L + 1,): ``spans`` uniform spans, or given increasing ones."""
    if np.ndim(spans) == 0:
        return np.linspace(0.0, 1.0, int(spans) + 1)
    br = np.asarray(spans, dtype=float)
    if br[0] != 0.0 or br[-1] != 1.0 or np.any(np.diff(br) <= 0):
        raise ValueError("breakpoints must increase from 0 to 1")
    return br


def knots(breaks: np.ndarray, degree: int) -> np.ndarray:
    """Clamped knot vector (L + 2 degree + 1,) on breakpoints ``breaks`` (L + 1,)."""
    return np.concatenate([np.zeros(degree), breaks, np.ones(degree)])


def basis(breaks: np.ndarray, degree: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Basis values and derivatives at normalised times ``s`` (S,).

    Returns
    -------
    span : ndarray of int, shape (S,)
        First control point of each sample's support (``span ... span + degree``).
    b : ndarray, shape (S, 3, degree + 1)
        Values, first and second derivatives (in ``s``) of those ``degree + 1`` basis
        functions.
    """
    s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, 1.0)
    L = len(breaks) - 1
    K = L + degree
    spl = BSpline(knots(breaks, degree), np.eye(K), degree, extrapolate=False)
    rows = [spl(s), spl.derivative(1)(s), spl.derivative(2)(s)]
    span = np.clip(np.searchsorted(breaks, s, side="right") - 1, 0, L - 1)
    idx = span[:, None] + np.arange(degree + 1)[None, :]
    b = np.stack([np.take_along_axis(np.nan_to_num(r), idx, axis=1) for r in rows], axis=1)
    return span, b
