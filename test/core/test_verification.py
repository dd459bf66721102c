"""The checks of a result: the sampling they share."""

from __future__ import annotations

import numpy as np
import pytest


def test_check_sampling_finds_the_extremes_of_a_fine_sampling(solved):
    """The result checks sample at the RK4 step points (filled in to T / SAMPLE_GAPS):
    max |u| and the joint extremes agree with a 100001-point sampling."""
    from tocontrol_ros.core.checks.verification import SAMPLE_GAPS, fine_sample

    traj = solved["nodes"].trajectory
    sample = fine_sample(traj)
    assert np.all(np.diff(sample.t) <= traj.T / SAMPLE_GAPS * (1 + 1e-12))
    fine = traj.evaluate(np.linspace(0.0, traj.T, 100001))
    assert np.max(np.abs(sample.u)) == pytest.approx(np.max(np.abs(fine.u)), abs=1e-6)
    for a, b in ((sample.q, fine.q), (sample.qd, fine.qd)):
        np.testing.assert_allclose(a.max(axis=0), b.max(axis=0), atol=1e-4)
        np.testing.assert_allclose(a.min(axis=0), b.min(axis=0), atol=1e-4)
    assert np.max(np.abs(sample.H)) == pytest.approx(np.max(np.abs(fine.H)), abs=1e-7)
