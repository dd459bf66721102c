"""The paper's example (Galicki, Section 5), used by the demo, the figures, benchmarks, tests.

The arm is the bundled URDF (:func:`~tocontrol_ros.core.robot.model.default_urdf_path`,
``config/galicki_3r.urdf``); its end effector moves between two points of the plane.
"""

from __future__ import annotations

__all__ = ["PAPER_START", "PAPER_TARGET"]

#: Start of the end effector, (x, y) in the base frame (m).
PAPER_START = (1.0, 1.0)
#: Target of the end effector, (x, y) in the base frame (m).
PAPER_TARGET = (2.2, 1.5)
