"""A JTC's interpolation of goal points without velocities or accelerations
(nodes/jtc_interpolation.py): each segment by what both of its ends carry."""

import numpy as np
import pytest

from tocontrol_ros.nodes.jtc_interpolation import jtc_samples, segment_kinds

T = np.array([0.0, 0.5, 1.5, 2.0])
Q = np.array([[0.0, 1.0], [0.5, 0.5], [1.0, 0.0], [1.2, 0.1]])


def test_each_segment_takes_what_both_ends_carry():
    assert segment_kinds([True, True, False, True], [True, True, True, False]) == \
        ["quintic", "linear", "linear"]
    assert segment_kinds([True, True, True], [False, True, True]) == ["cubic", "quintic"]


def test_points_with_every_derivative_are_kept_as_they_are():
    qd = [np.ones(2) * i for i in range(4)]
    qdd = [np.ones(2) * -i for i in range(4)]
    t, q, v, a = jtc_samples(T, Q, qd, qdd, 0.01)
    assert np.array_equal(t, T) and np.array_equal(q, Q)
    assert np.array_equal(v, np.array(qd)) and np.array_equal(a, np.array(qdd))


def test_positions_only_are_straight_lines_at_constant_velocity():
    t, q, v, a = jtc_samples(T, Q, [None] * 4, [None] * 4, 0.01)
    assert t[0] == 0.0 and t[-1] == 2.0 and np.all(np.diff(t) > 0)
    assert np.max(np.diff(t)) <= 0.01 + 1e-12
    for i in range(3):
        inside = (t >= T[i]) & (t < T[i + 1])
        slope = (Q[i + 1] - Q[i]) / (T[i + 1] - T[i])
        np.testing.assert_allclose(q[inside], Q[i] + np.outer(t[inside] - T[i], slope),
                                   atol=1e-12)
        np.testing.assert_allclose(v[inside], np.broadcast_to(slope, v[inside].shape))
        assert not np.any(a[inside])
    np.testing.assert_array_equal(q[-1], Q[-1])
    assert not np.any(v[-1]) and not np.any(a[-1])  # the goal ends at rest


def test_positions_and_velocities_are_cubics_through_both():
    qd = [np.array([0.0, 0.0]), np.array([1.0, -1.0]), np.array([0.5, 0.0]), np.zeros(2)]
    t, q, v, a = jtc_samples(T, Q, qd, [None] * 4, 1e-3)
    for i in range(4):  # every point's own position and velocity
        j = int(np.argmin(np.abs(t - T[i])))
        np.testing.assert_allclose(q[j], Q[i], atol=1e-12)
        np.testing.assert_allclose(v[j], qd[i], atol=1e-12)
    # Velocity and acceleration are the position's derivatives (finite differences).
    np.testing.assert_allclose(np.gradient(q[:, 0], t)[1:400], v[1:400, 0], atol=2e-3)
    np.testing.assert_allclose(np.gradient(v[:, 0], t)[1:400], a[1:400, 0], atol=2e-2)


def test_a_bad_period_is_named():
    with pytest.raises(ValueError, match="`period`"):
        jtc_samples(T, Q, [None] * 4, [None] * 4, 0.0)
