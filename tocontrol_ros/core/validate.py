"""Argument checks shared by the core's public constructors."""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.errors import ProblemError

__all__ = ["finite_array"]


def finite_array(name: str, value, shape: tuple[int, ...] | None = None,
           ndim: int | None = None) -> np.ndarray:
    """A finite float array, with the argument named in every error."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"`{name}` must be numeric, got {value!r}") from exc
    if shape is not None and arr.shape != shape:
        raise ProblemError(f"`{name}` must have shape {shape}, got {arr.shape}")
    if ndim is not None and arr.ndim != ndim:
        raise ProblemError(f"`{name}` must be {ndim}-dimensional, got shape {arr.shape}")
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        raise ProblemError(f"`{name}` must be finite; element {tuple(int(i) for i in bad[0])} "
                           f"is {float(arr[tuple(bad[0])])}")
    return arr
