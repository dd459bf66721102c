"""Exceptions of the numerical core.

Numerical outcomes (a solve that does not converge) are reported in result objects, never
raised. Exceptions are for invalid input and programming errors; every one the core raises
on purpose derives from :class:`TocontrolError`.
"""

from __future__ import annotations

__all__ = ["TocontrolError", "ModelError", "ProblemError"]


class TocontrolError(Exception):
    """Root of the exceptions raised by tocontrol_ros on purpose."""


class ModelError(TocontrolError, ValueError):
    """A robot description (URDF) that cannot be turned into a dynamic model."""


class ProblemError(TocontrolError, ValueError):
    """An invalid planning problem: bad shapes, NaN, unreachable points, bad options."""
