"""A warm start predicted from several stored neighbours (bench/neighbour_blend.py), numpy.

The local linear fit reproduces a solution that is linear in the request's parameters
exactly (control points, ``T``, multipliers), at a new request and at the stored ones; the
inverse-distance blend is a convex combination that reproduces a stored state at its own
point; the neighbours kept are the nearest's basin, nearest first; bad input is refused
naming the argument.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench.neighbour_blend import BlendError, basin_rows, blend_states, features  # noqa: E402
from tocontrol_ros.core.direct.warm import PathWarmState  # noqa: E402
from tocontrol_ros.core.types.problem import point  # noqa: E402
from tocontrol_ros.core.types.tuning import WARM_RADIUS  # noqa: E402

BREAKS = np.linspace(0.0, 1.0, 5)
RNG = np.random.default_rng(34)
P0, PB = RNG.normal(size=(7, 3)), RNG.normal(size=(6, 7, 3))
G0, GB = RNG.normal(size=11), RNG.normal(size=(6, 11))
X0, XB = RNG.normal(size=22), RNG.normal(size=(6, 22))


def _linear(x) -> PathWarmState:
    """A state linear in the parameters ``x`` (shape (6,))."""
    x = np.asarray(x, dtype=float)
    return PathWarmState(BREAKS, P0 + np.tensordot(x, PB, axes=1), 1.0 + 0.1 * x.sum(),
                         G0 + x @ GB, X0 + x @ XB)


def _grid(start=(3.0, 0.0, 6.5)) -> np.ndarray:
    """Parameters of a 2 x 2 x 2 grid of targets from one start (warm units)."""
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    return np.concatenate([np.tile(start, (8, 1)), corners + [4.0, -1.0, 2.5]], axis=1)


def test_the_linear_fit_reproduces_a_linear_solution():
    X = _grid()
    states = [_linear(x) for x in X]
    x = np.array([3.0, 0.0, 6.5, 4.3, -0.4, 3.2])
    got = blend_states(states, X, x, "linear", "blend")
    want = _linear(x)
    np.testing.assert_allclose(got.P, want.P, atol=1e-10)
    assert got.T == pytest.approx(want.T, abs=1e-12)
    np.testing.assert_allclose(got.lam_g, want.lam_g, atol=1e-10)
    np.testing.assert_allclose(got.lam_x, want.lam_x, atol=1e-10)
    np.testing.assert_array_equal(got.breaks, BREAKS)
    # ... and at each stored point, its own state (by the fit, not only by the shortcut).
    for j in range(len(X)):
        again = blend_states(states, X, X[j] + 1e-13, "linear", "blend")
        np.testing.assert_allclose(again.P, states[j].P, atol=1e-9)
        assert again.T == pytest.approx(states[j].T, abs=1e-12)


def test_a_stored_point_gives_its_own_state_and_multipliers_as_asked():
    X = _grid()
    states = [_linear(x) for x in X]
    for how in ("linear", "idw"):
        got = blend_states(states, X, X[3], how, "blend")
        assert got is states[3]
        near = blend_states(states, X, X[3], how, "nearest")
        np.testing.assert_array_equal(near.P, states[3].P)
        assert near.lam_g is states[0].lam_g and near.lam_x is states[0].lam_x
        alone = blend_states(states, X, X[3], how, "none")
        assert alone.lam_g is None and alone.lam_x is None and alone.T == states[3].T


def test_inverse_distance_weights_are_a_convex_combination():
    X = _grid()
    states = [_linear(x) for x in X]
    centre = X.mean(axis=0)  # equidistant from every corner: the plain average
    got = blend_states(states, X, centre, "idw", "blend")
    np.testing.assert_allclose(got.P, np.mean([s.P for s in states], axis=0), atol=1e-12)
    x = np.array([3.0, 0.0, 6.5, 4.1, -0.8, 2.6])
    got = blend_states(states, X, x, "idw", "blend")
    Ts = [s.T for s in states]
    assert min(Ts) <= got.T <= max(Ts)
    assert np.linalg.norm(got.P - states[0].P) < np.linalg.norm(got.P - states[7].P)


def test_features_are_the_requests_parameters_in_warm_units():
    problem = SimpleNamespace(start=point([0.3, 0.0, 0.0]), target=point([0.5, 0.1, 0.0]))
    keys = {"start_kind": ["point", "point"], "target_kind": ["point", "point"],
            "start": [np.array([0.3, 0.0, 0.0]), np.array([0.3, 0.0, 0.0])],
            "target": [np.array([0.4, 0.1, 0.0]), np.array([0.6, 0.1, 0.0])]}
    X, x = features(keys, [0, 1], problem, 0.05)
    np.testing.assert_allclose(x, np.array([0.3, 0.0, 0.0, 0.5, 0.1, 0.0]) / WARM_RADIUS)
    np.testing.assert_allclose(X[1, 3:], np.array([0.6, 0.1, 0.0]) / WARM_RADIUS)


def test_the_neighbours_are_the_nearests_basin_nearest_first():
    X = _grid()
    keys = {"end_q": np.array([[0.0, 0.0]] * 7 + [[1.0, 0.0]])}  # the last: another basin
    dist = np.array([0.5] * 7 + [0.6])
    dist[2] = np.inf  # another kind of request
    x = X[0] + [0, 0, 0, 0.1, 0.2, 0.3]
    rows = basin_rows(keys, dist, 5, X, x, range(8), 4, 0.3)
    assert rows[0] == 5 and len(rows) == 4 and 7 not in rows and 2 not in rows
    d = np.linalg.norm(X - x, axis=1)
    assert list(d[rows[1:]]) == sorted(d[rows[1:]])
    assert basin_rows(keys, dist, 5, X, x, range(8), 1, 0.3) == [5]


@pytest.mark.parametrize("kwargs, match", [
    ({"how": "kriging"}, "how"),
    ({"multipliers": "some"}, "multipliers"),
    ({"states": []}, "states"),
    ({"states": "other mesh"}, r"states\[1\]"),
    ({"states": "no multipliers"}, r"states\[1\]"),
])
def test_bad_input_is_refused_naming_it(kwargs, match):
    X = _grid()[:2]
    states = [_linear(x) for x in X]
    if kwargs.get("states") == "other mesh":
        kwargs["states"] = [states[0], PathWarmState(np.linspace(0, 1, 6), P0, 1.0)]
    elif kwargs.get("states") == "no multipliers":
        kwargs["states"] = [states[0], PathWarmState(BREAKS, P0, 1.0)]
    args = {"states": states, "X": X, "x": X[0] + 0.5, "how": "linear",
            "multipliers": "blend", **kwargs}
    with pytest.raises(BlendError, match=match):
        blend_states(**args)
