"""The tracker holds the end of a motion (issue 49): the README's Panda, joints 1 and 3 aligned.

After the issue's goal (0.5, -0.2, 0.4) the Panda ends with joint 2 near zero, so that the
axes of joints 1 and 3 nearly align. Their difference then moves only link 2: its inertia is
a small fraction of either diagonal entry of ``M``, and the README's per-joint gains (set from
that diagonal at the start) exceed the 1 kHz loop's stability bound there; the hold
chattered at full torque and wandered 10-20 mm from the goal. The model-derived gains
(``bandwidth``) close every mode, the aligned one included.
"""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.sim.gains import TrackingGains, hold_spectral_radius
from tocontrol_ros.core.sim.tracking import NominalTrajectory, PlantConfig, Tracker

#: The README's start configuration and per-joint gains (30 rad/s on M's diagonal there).
Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
README = TrackingGains(kp=(10.0, 20.0, 13.0, 10.0, 2.4, 4.0, 0.5),
                       kd=(0.47, 0.91, 0.6, 0.49, 0.11, 0.19, 0.023))
#: Where the planned motion to the issue's goal (0.5, -0.2, 0.4) ends: joint 2 near zero.
Q_ALIGNED = np.array([0.026, -0.03, -0.431, -2.24, 0.088, 2.415, 0.39])
DERIVED = TrackingGains(bandwidth=50.0)
H = 1e-3
#: The issue's perturbed plant: every body 10 % heavier, twice the friction.
HEAVIER = PlantConfig(mass_scale=1.1, inertia_scale=1.1, friction_scale=2.0)


def _motion(model, q0, q1, duration, dt=0.002) -> NominalTrajectory:
    """Rest-to-rest quintic ``q0 -> q1`` sampled every ``dt``, the model's torques."""
    t = np.linspace(0.0, duration, int(round(duration / dt)) + 1)
    s = t / duration
    d = q1 - q0
    q = q0 + (10 * s**3 - 15 * s**4 + 6 * s**5)[:, None] * d
    qd = ((30 * s**2 - 60 * s**3 + 30 * s**4) / duration)[:, None] * d
    qdd = ((60 * s - 180 * s**2 + 120 * s**3) / duration**2)[:, None] * d
    tau = np.array(model.function("id")(q.T, qd.T, qdd.T)).T
    return NominalTrajectory(t, q, qd, qdd, tau)


def test_per_joint_gains_from_the_diagonal_are_unstable_where_joints_1_and_3_align(panda):
    assert hold_spectral_radius(panda, README, Q0, H) < 1.0
    assert hold_spectral_radius(panda, README, Q_ALIGNED, H) > 1.2
    for q in (Q0, Q_ALIGNED):
        assert hold_spectral_radius(panda, DERIVED, q, H) < 0.99


@pytest.mark.parametrize("plant", [PlantConfig(), HEAVIER], ids=["identical", "heavier"])
def test_the_panda_holds_its_goal_where_joints_1_and_3_align(panda, plant):
    tracker = Tracker(panda, plant, DERIVED, q0=Q0)
    nominal = _motion(panda, Q0, Q_ALIGNED, 1.0)
    tracker.start(nominal)
    tracker.advance(nominal.duration + H)
    hold = tracker.advance(tracker.t + 5.0).log
    goal = panda.point(Q_ALIGNED)
    assert np.linalg.norm(panda.point(tracker.q) - goal) < 1e-4
    last = hold.q[-int(round(1.0 / H)):]
    assert np.max(np.abs(last - tracker.q)) < 1e-5
    assert not hold.saturated.any()


def test_the_derived_gains_are_bounded_by_the_control_rate(panda):
    TrackingGains(bandwidth=500.0)  # alone: no rate to check against
    with pytest.raises(ProblemError, match="at most 500 rad/s"):
        Tracker(panda, PlantConfig(), TrackingGains(bandwidth=600.0), q0=Q0)
    with pytest.raises(ProblemError, match="`damping_ratio` must be a number > 0"):
        TrackingGains(bandwidth=50.0, damping_ratio=0.0)
