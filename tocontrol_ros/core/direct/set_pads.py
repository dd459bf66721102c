"""The control set's pad per sample, read off a solution's torques between the samples.

The bounded B-spline NLP (:class:`~tocontrol_ros.core.direct.flat.FlatTranscription`)
holds the control set ``sum_i u_i^(2k) <= 1 - pad`` at its sample times only; between two
samples the torques may bulge above their samples' values, and a solution whose bulge
crosses the set is re-solved at a wider pad (``limited._inside_set``: one pad for every
sample, widened by twice the excess). A warm re-solve by the parametric step started at the
default pad and, where the move's answer left the set between the samples, carried it to a
wider pad in a second solve: 6 of the 20 moves of ``bench/warm_resolve.py`` (issue 47).

:func:`row_pads` gives each sample its own pad from a nearby solution (the serving one of a
replan): the bulge of each interval between two samples above the larger of its samples'
values, times :data:`ROW_PAD_FACTOR` (room for the move to change it), for the samples at
either end of an interval whose torques come within :data:`ROW_PAD_NEAR` of the set's
boundary; the default pad elsewhere. The first solve on those pads then holds the set
between the samples where the move keeps the bulges, with no second solve; a pad where the
serving solution needed none costs nothing (docs/limits.md, "Pads per sample").
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.direct.flat import FlatResult, FlatTranscription
from tocontrol_ros.core.direct.flat_trajectory import FlatTrajectory
from tocontrol_ros.core.direct.tuning import SET_PAD
from tocontrol_ros.core.direct.warm import PathWarmState

__all__ = ["FALLBACK_PADS", "LOCAL_ROUNDS", "ROW_PADS", "ROW_PAD_CAP", "ROW_PAD_FACTOR",
           "ROW_PAD_NEAR", "row_pads", "warm_row_pads", "widened"]

#: A warm re-solve on its warm state's own mesh (``limited.plan_limited_warm``: the
#: parametric steps, and IPOPT's solve) starts at these pads, read off the warm state's
#: path; False: at :data:`~.tuning.SET_PAD` for every sample (the route before;
#: bench/warm_resolve.py's *before* column).
ROW_PADS = True
#: With :data:`ROW_PADS`, a pad round widens only the samples at the ends of the intervals
#: that leave the set (:func:`widened`); False: all alike, by twice the largest excess.
LOCAL_ROUNDS = True
#: With :data:`ROW_PADS`, IPOPT's warm re-solve (where the parametric step fails, or
#: without it) starts at the same pads (its pad rounds per sample too); False: at
#: :data:`~.tuning.SET_PAD` (bench/warm_pad_rows.py's variant).
FALLBACK_PADS = True

#: A sample's pad is its intervals' bulge times this (the move changes the bulge; 1: the
#: serving solution's own, with no room). On bench/warm_resolve.py's 20 moves one
#: parametric solve answered 11 at 2, 10 at 1.5, 8 at 3 (bench/warm_pad_rows.py).
ROW_PAD_FACTOR = 2.0
#: Only intervals whose largest set value comes within this of the set's boundary give a
#: pad (elsewhere the torques are far inside the set and the default pad holds).
ROW_PAD_NEAR = 0.1
#: At most this pad per sample (a pad this wide changes the motion more than a replan's
#: move; the between-samples check and its pad round decide there).
ROW_PAD_CAP = 0.05


def _intervals(trajectory, samples: np.ndarray, points: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """The set's value at the samples (S,) and its peak in each interval between (S - 1,)."""
    at_samples = np.sum(np.abs(trajectory.control_at(samples * trajectory.T))
                        ** (2 * trajectory.law.k), axis=1)
    # Each check time's interval: the samples before and after it (samples are sorted).
    where = np.searchsorted(samples, trajectory.set_fractions(points), side="right") - 1
    peak = np.full(len(samples) - 1, -np.inf)
    np.maximum.at(peak, np.clip(where, 0, len(samples) - 2), trajectory.set_values(points))
    return at_samples, peak


def _spread(pad: np.ndarray, need: np.ndarray) -> np.ndarray:
    """``pad`` (S,) raised to each interval's ``need`` (S - 1,) at the samples at its ends."""
    pad = np.array(pad, dtype=float)
    pad[:-1] = np.maximum(pad[:-1], need)
    pad[1:] = np.maximum(pad[1:], need)
    return pad


def widened(pad, trajectory, samples: np.ndarray, margin: float,
            points: int = 32) -> np.ndarray:
    """Pads per sample (S,) widened where ``trajectory`` leaves the set between samples.

    The samples at the ends of each interval whose peak exceeds ``1 - margin`` get their
    pad (``pad``: one for all, or (S,)) raised by twice that excess, as the global pad
    round (``limited._inside_set``) raises all; the others keep theirs.
    """
    samples = np.asarray(samples, dtype=float)
    pad = np.broadcast_to(np.asarray(pad, dtype=float), len(samples))
    _, peak = _intervals(trajectory, samples, points)
    excess = np.maximum(peak - (1.0 - margin), 0.0)
    need = np.where(excess > 0.0, np.maximum(pad[:-1], pad[1:]) + 2.0 * excess, 0.0)
    return _spread(pad, need)


def row_pads(trajectory, samples: np.ndarray, floor: float = SET_PAD,
             points: int = 32) -> np.ndarray:
    """The set's pad per sample (S,) for a solution near ``trajectory``'s (see the module).

    Parameters
    ----------
    trajectory : FlatTrajectory
        A solution on the mesh of the NLP whose pads these are (its ``breaks``, ``T`` in s).
    samples : ndarray, shape (S,)
        The NLP's sample times as fractions of ``T`` (:attr:`FlatTranscription.samples`:
        ``per_span`` a span, then 1).
    floor : float
        The pad where no interval asks for more (:data:`~.tuning.SET_PAD`).
    points : int
        Times per span of the check between the samples (as
        :meth:`FlatTrajectory.set_values`).

    Returns
    -------
    ndarray, shape (S,)
        Pads in ``[floor, max(floor, ROW_PAD_CAP)]``.
    """
    samples = np.asarray(samples, dtype=float)
    at_samples, peak = _intervals(trajectory, samples, points)
    ends = np.maximum(at_samples[:-1], at_samples[1:])
    bulge = np.where(peak >= 1.0 - ROW_PAD_NEAR, peak - ends, 0.0)
    pad = _spread(np.full(len(samples), float(floor)), ROW_PAD_FACTOR * np.maximum(bulge, 0.0))
    return np.minimum(pad, max(float(floor), ROW_PAD_CAP))


def warm_row_pads(flat: FlatTranscription, warm: PathWarmState, k: float
                  ) -> float | np.ndarray:
    """The set's pad per sample (S,) for a warm re-solve from ``warm`` on its mesh ``flat``.

    Read off the warm state's path and ``T`` as a trajectory of ``flat`` (its inverse
    dynamics, so that the mapped calls are the ones the answer's checks use)
    (:func:`row_pads`, with :data:`ROW_PADS`); else :data:`SET_PAD`. The set's values
    between the samples are the warm state's own where it has them for this ``k``, torque
    scale and mesh (its plan's check evaluated them: the same numbers), else evaluated.
    """
    if not ROW_PADS:
        return SET_PAD
    path = FlatResult(success=True, message="warm state", T=float(warm.T),
                      iterations=0, solve_time=0.0, P=np.asarray(warm.P, dtype=float),
                      residual=0.0)
    known = getattr(warm, "set_values", None)  # (a warm state pickled before it had them)
    if known is None or warm.k != k or warm.torque_scale != flat.torque_scale \
            or not np.array_equal(warm.breaks, flat.breaks):
        known = None
    return row_pads(FlatTrajectory(flat, path, k, set_values=known), flat.samples)
