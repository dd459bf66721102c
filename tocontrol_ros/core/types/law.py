"""The parameters of the torque set and of the paper's control law (15).

Below every method: the maximum principle's compiled functions take them as their ``par``
input, and the direct methods' trajectories evaluate the set with them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LawParams"]


@dataclass(frozen=True)
class LawParams:
    """Parameters of the control law, the ``par`` input of every compiled function.

    Attributes
    ----------
    k : float
        Convexification exponent of the torque set ``sum u_i^(2k) <= 1``.
    delta : float
        Smoothing of the law (0 = the paper's law).
    torque_scale : float
        Fraction of ``tau_max`` planned against: ``1 - reserve``.
    """

    k: float
    delta: float = 0.0
    torque_scale: float = 1.0

    def array(self) -> np.ndarray:
        """``(k, delta, torque_scale)``, shape (3,): the compiled functions' ``par``."""
        return np.array([self.k, self.delta, self.torque_scale])

    @classmethod
    def from_array(cls, par) -> LawParams:
        """The inverse of :meth:`array`."""
        k, delta, scale = (float(v) for v in np.asarray(par, dtype=float).ravel())
        return cls(k, delta, scale)
