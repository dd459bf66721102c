"""What a maximum-principle solve leaves for a warm start: its shooting mesh and unknowns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.indirect.pmp import CanonicalSystem
from tocontrol_ros.core.indirect.shooting import ShootingGrid

__all__ = ["WarmState"]


@dataclass(frozen=True, eq=False)
class WarmState:
    """The final shooting mesh and unknowns of a solve: what a warm start continues from.

    Attributes
    ----------
    lengths : ndarray, shape (N,)
        Interval lengths in normalised time (sum 1).
    w : ndarray, shape (size,)
        Unknowns of the shooting grid (:meth:`ShootingGrid.pack`).
    steps : int
        RK4 steps per interval.
    kinds : ndarray of int, shape (N,)
        Step grading of each interval (0 uniform, 1 towards its end, -1 towards its start).
    breaks : list of (int, int)
        Switch nodes: (node index, index of the switching function).
    factors : object or None
        LU factors of a Jacobian on this mesh (reused by chord Newton steps).
    """

    lengths: np.ndarray
    w: np.ndarray
    steps: int
    kinds: np.ndarray
    breaks: list
    factors: object = None

    def grid(self, system: CanonicalSystem, start_kind: str, target_kind: str
             ) -> ShootingGrid:
        """The shooting grid of this state for the given end kinds ("point" or "state")."""
        return ShootingGrid(system, self.lengths, self.steps, start_kind, target_kind,
                            kinds=self.kinds, breaks=self.breaks)
