"""A hit's warm start predicted from several stored neighbours in one basin (issue 50).

The measurement's helper (``bench/memory_blend.py``), not used by the planner: on the small
cell's 20 hits neither a blend of the stored neighbours nor one of the nearest's neighbours
continued into its basin started IPOPT nearer than the nearest alone (docs/memory.md, "A hit
from a blend of its neighbours"), so ``recall`` was left as it was.

A hit re-solves the serving mesh's NLP warm from a stored motion a few centimetres away
(:mod:`~tocontrol_ros.core.memory.recall`). Every stored serving state is a point of the
same NLP (control points ``P``, ``T``, multipliers ``lam_g`` and ``lam_x``), a function of
the request's parameters (its start and target); so the request's solution can be predicted
from several neighbours of one basin rather than taken from the nearest: inverse-distance
weights (Lembono et al., RA-L 2020, use k nearest neighbours), or a local linear fit of the
solution against the parameters over the neighbours (the first-order version: exact for a
solution linear in the parameters, an error of second order in the grid spacing instead of
first order for a smooth one).

The parameters are the requests' own (:func:`features`): each end's point in units of
:data:`~tocontrol_ros.core.types.tuning.WARM_RADIUS`, or a joint state's positions and
velocities in units of the warm joint radius, so that the metric is the lookup's up to the
norm (Euclidean here). Pure numpy: no solve happens here.
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.types.tuning import WARM_RADIUS

__all__ = ["BLEND_KINDS", "MULTIPLIER_KINDS", "BlendError", "features", "basin_rows",
           "blend_states"]

#: How a prediction is made: ``linear`` (the local linear fit, uniform weights), ``idw``
#: (inverse squared distance weights).
BLEND_KINDS = ("linear", "idw")
#: The prediction's multipliers: ``blend`` (predicted as the solution is), ``nearest``
#: (the first state's), ``none``.
MULTIPLIER_KINDS = ("blend", "nearest", "none")
#: Spread (warm units) below which a parameter is the same for every neighbour and left
#: out of the fit (e.g. the start station they share).
SAME = 1e-9


class BlendError(TocontrolError, ValueError):
    """Stored states that cannot be blended (other meshes or sizes), or bad arguments."""


def _end_features(kind: str, value, joint_radius: float) -> np.ndarray:
    value = np.asarray(value, dtype=float).ravel()
    return value / (WARM_RADIUS if kind == "point" else joint_radius)


def features(keys: dict, rows, problem, joint_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The requests' parameters in warm units: ``(X (m, p) of the rows, x (p,) of problem)``.

    Parameters
    ----------
    keys : dict
        :meth:`~tocontrol_ros.core.memory.store.MotionStore.keys`.
    rows : sequence of int
        Rows of ``keys`` of the same end kinds and sizes as ``problem``'s.
    problem : Problem
    joint_radius : float
        ``SolverOptions.warm_joint_radius`` (rad).
    """
    x = np.concatenate([_end_features(problem.start.kind, problem.start.value, joint_radius),
                        _end_features(problem.target.kind, problem.target.value,
                                      joint_radius)])
    X = np.array([np.concatenate([
        _end_features(keys["start_kind"][i], keys["start"][i], joint_radius),
        _end_features(keys["target_kind"][i], keys["target"][i], joint_radius)])
        for i in rows]).reshape(len(rows), -1)
    if X.shape[1] != x.size:
        raise BlendError(f"rows: parameters of size {X.shape[1]}, the request's {x.size}")
    return X, x


def basin_rows(keys: dict, dist: np.ndarray, nearest: int, X: np.ndarray, x: np.ndarray,
               candidates, count: int, basin: float) -> list[int]:
    """The neighbours to blend: ``nearest`` first, then its basin's nearest, at most ``count``.

    Parameters
    ----------
    keys : dict
        As :func:`features`.
    dist : ndarray, shape (E,)
        The lookup's distances (``inf``: another kind of request).
    nearest : int
        The row the hit re-solves.
    X, x : ndarray
        :func:`features` of ``candidates`` and of the request.
    candidates : sequence of int
        Rows that may be blended (a serving state on the mesh, finite distance).
    count : int
        Most rows returned.
    basin : float
        End configurations at most this far from ``nearest``'s (max-norm, rad) are its basin.

    Returns
    -------
    list of int
        Rows of ``keys``: ``nearest``, then the others by Euclidean distance of parameters
        (ties by row), deterministic.
    """
    candidates = [int(i) for i in candidates]
    d = np.linalg.norm(X - x, axis=1)
    end = keys["end_q"][nearest]
    order = sorted((float(d[j]), i) for j, i in enumerate(candidates)
                   if i != nearest and np.isfinite(dist[i])
                   and np.max(np.abs(keys["end_q"][i] - end)) <= basin)
    return [int(nearest)] + [i for _, i in order[:max(int(count) - 1, 0)]]


def _weights(D: np.ndarray, how: str) -> np.ndarray:
    d2 = np.sum(D * D, axis=1)
    if how == "idw":
        return 1.0 / d2
    return np.ones(len(D))


def blend_states(states, X: np.ndarray, x: np.ndarray, how: str = "linear",
                 multipliers: str = "blend") -> PathWarmState:
    """The solution at ``x`` predicted from stored ``states`` at ``X``.

    Parameters
    ----------
    states : sequence of PathWarmState
        The neighbours' serving states on one mesh (equal ``breaks``, shapes), the nearest
        first.
    X : ndarray, shape (m, p)
        Their parameters (:func:`features`).
    x : ndarray, shape (p,)
        The request's.
    how : str
        One of :data:`BLEND_KINDS`. ``linear``: ``y(x) = a + (x - mean X) B`` fitted by
        least squares over the states (parameters the same for all left out; fewer states
        than parameters: the least-norm fit); ``idw``: weights ``1 / |x - X_j|^2``.
    multipliers : str
        One of :data:`MULTIPLIER_KINDS`.

    Returns
    -------
    PathWarmState
        On the states' mesh: ``P`` (L + degree, n) rad, ``T`` s (the least stored ``T``
        when a fit would give less than half of it), the multipliers as asked. A state
        exactly at ``x`` is returned unchanged.

    Raises
    ------
    BlendError
        No states, states on different meshes or of different sizes, a multiplier-less
        state when blended multipliers are asked, or an unknown ``how``/``multipliers``.
    """
    if how not in BLEND_KINDS:
        raise BlendError(f"how: {how!r} is not one of {BLEND_KINDS}")
    if multipliers not in MULTIPLIER_KINDS:
        raise BlendError(f"multipliers: {multipliers!r} is not one of {MULTIPLIER_KINDS}")
    states = list(states)
    if not states:
        raise BlendError("states: none to blend")
    X = np.asarray(X, dtype=float).reshape(len(states), -1)
    x = np.asarray(x, dtype=float).ravel()
    first = states[0]
    for j, st in enumerate(states):
        if st.breaks.shape != first.breaks.shape or not np.array_equal(st.breaks, first.breaks) \
                or st.P.shape != first.P.shape:
            raise BlendError(f"states[{j}]: another mesh or path size than states[0]'s")
        if multipliers == "blend" and (st.lam_g is None or st.lam_x is None
                                       or st.lam_g.shape != first.lam_g.shape
                                       or st.lam_x.shape != first.lam_x.shape):
            raise BlendError(f"states[{j}]: no multipliers of states[0]'s sizes to blend")
    D = X - x
    exact = np.flatnonzero(np.all(D == 0.0, axis=1))
    if exact.size:
        return _with_multipliers(states[int(exact[0])], first, multipliers)
    parts = [np.array([st.P.ravel() for st in states]), np.array([[st.T] for st in states])]
    if multipliers == "blend":
        parts += [np.array([st.lam_g for st in states]), np.array([st.lam_x for st in states])]
    Y = np.concatenate(parts, axis=1)
    if how == "idw" or len(states) == 1:
        w = _weights(D, "idw")
        y = w @ Y / np.sum(w)
    else:
        centre = np.mean(X, axis=0)
        A = X - centre
        A[:, np.ptp(X, axis=0) <= SAME] = 0.0  # a parameter they share: not fitted
        A = np.concatenate([np.ones((len(states), 1)), A], axis=1)
        beta = np.linalg.lstsq(A, Y, rcond=None)[0]
        z = x - centre
        z[np.ptp(X, axis=0) <= SAME] = 0.0
        y = beta[0] + z @ beta[1:]
    size = first.P.size
    T = float(y[size])
    least = min(st.T for st in states)
    if not np.isfinite(T) or T < 0.5 * least:
        T = least
    lam_g = lam_x = None
    if multipliers == "blend":
        g = len(first.lam_g)
        lam_g, lam_x = y[size + 1:size + 1 + g], y[size + 1 + g:]
    elif multipliers == "nearest":
        lam_g, lam_x = first.lam_g, first.lam_x
    return PathWarmState(breaks=first.breaks, P=y[:size].reshape(first.P.shape), T=T,
                         lam_g=lam_g, lam_x=lam_x)


def _with_multipliers(state: PathWarmState, first: PathWarmState,
                      multipliers: str) -> PathWarmState:
    if multipliers == "blend":
        return state
    source = first if multipliers == "nearest" else None
    return PathWarmState(breaks=state.breaks, P=state.P, T=state.T,
                         lam_g=None if source is None else source.lam_g,
                         lam_x=None if source is None else source.lam_x)
