"""Whether a task-space point has a configuration clear of the scene (issue 51).

A point end of a problem leaves the configuration free on its self-motion manifold; with a
collision model the motion must also end (or begin) at a configuration whose every checked
pair (the arm's links against the scene's obstacles, and its own non-adjacent links) is at
least the margin apart. A point inside an obstacle, or reachable only through one (the hand
between the table and the base, say), has none, and no solve can succeed: such a point is
refused at the problem's input (:class:`~tocontrol_ros.core.types.problem.Problem`) rather
than left to the solver, whose failure would not say why.

:func:`clear_configuration` looks for one by a fixed amount of work: IK solutions spread
over the self-motion manifold (:func:`~tocontrol_ros.core.robot.ik.ik_family`, seeded, so
the same point gives the same verdict on any machine load), inside the joint limits, each
measured by the exact distances (:meth:`CollisionModel.clearance`, Coal on the URDF's
geometry); it stops at the first one clear by the margin. Sampled IK is no proof that none
exists: the verdict is "none found among N", and the message says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.geometry.collision import CollisionModel
from tocontrol_ros.core.memo import OwnedMemo
from tocontrol_ros.core.robot.ik import ik_family, ik_pose

__all__ = ["ClearReach", "clear_configuration", "clear_pose_configuration", "note_clear",
           "CLEAR_IK_ROUNDS", "CLEAR_POSE_ROUNDS"]

#: IK seeds of each round (``ik_family``'s ``count``) and the generator seed of each: a
#: target with room around it has a clear configuration among the first round's solutions
#: (checked one at a time, stopping at the first clear one); only a point with none found
#: pays for the later rounds. 8 + 48 + 96 = 152 seeds bound the work of a refusal.
CLEAR_IK_ROUNDS = ((8, 0), (48, 1), (96, 2))

#: The same for a pose (:func:`clear_pose_configuration`), asked only when none of a
#: planner's first IK solutions of the pose (``pose_ik_seeds``) is clear: 32 + 96 = 128 more
#: seeds bound the work of a refusal.
CLEAR_POSE_ROUNDS = ((32, 1), (96, 2))

#: Verdicts remembered per collision model (newest last): a replan makes several problems
#: to one target with one collision model, and each check is up to 152 IK solves and as many
#: exact distances.
_KNOWN = OwnedMemo(256)
#: Configurations shown clear at a point by :func:`note_clear` (a :class:`ClearReach` of
#: one), per collision model; the joint limits are checked when one is used.
_NOTED = OwnedMemo(256)


@dataclass(frozen=True)
class ClearReach:
    """What :func:`clear_configuration` found.

    Attributes
    ----------
    q : ndarray or None
        A configuration reaching the point, inside the limits and clear by the margin,
        shape (n,) (rad, m); None when none was found.
    clearance : float
        The exact clearance of ``q``, or (none found) of the clearest configuration tried
        (m; ``-inf`` when no IK solution was inside the limits).
    pair : tuple of str
        The closest pair at that configuration (empty when none was tried).
    tried : int
        IK solutions inside the limits whose clearance was measured.
    solutions : int
        IK solutions found (inside the limits or not).
    seeds : int
        IK seeds spent.
    """

    q: np.ndarray | None
    clearance: float
    pair: tuple[str, ...]
    tried: int
    solutions: int
    seeds: int

    @property
    def found(self) -> bool:
        """Whether a clear configuration was found."""
        return self.q is not None


def clear_configuration(collision: CollisionModel, p, lower, upper) -> ClearReach:
    """A configuration reaching ``p`` inside ``[lower, upper]``, clear by the margin.

    Parameters
    ----------
    collision : CollisionModel
        The arm's geometry, the scene and the margin (m).
    p : array_like, shape (m,)
        Task-space point (m).
    lower, upper : array_like, shape (n,)
        Joint position bounds (rad, m; infinite where unbounded).

    Returns
    -------
    ClearReach
        The first clear configuration of :data:`CLEAR_IK_ROUNDS`' solutions, in their
        order; or, when none is clear, the clearest tried and its closest pair.
    """
    model = collision.model
    p = np.asarray(p, dtype=float)
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    key = (p.tobytes(), lo.tobytes(), hi.tobytes())
    known = _KNOWN.get(collision, key)
    if known is not None:
        return known
    noted = _NOTED.get(collision, key[0])
    if noted is not None and np.all(noted.q >= lo) and np.all(noted.q <= hi):
        return noted
    best = _first_clear(collision, lo, hi, (
        (count, ik_family(model, p, count=count, rng=np.random.default_rng(seed)))
        for count, seed in CLEAR_IK_ROUNDS))
    _KNOWN.put(collision, key, best)
    return best


def clear_pose_configuration(collision: CollisionModel, position, rotation, lower, upper
                             ) -> ClearReach:
    """A configuration putting the tip at a pose inside ``[lower, upper]``, clear by the margin.

    A pose goal's IK solutions are joint-state targets, and those closer to the scene than
    the margin are refused; when none of a planner's first solutions is clear, this looks
    further: :func:`~tocontrol_ros.core.robot.ik.ik_pose` from the seeds of
    :data:`CLEAR_POSE_ROUNDS` (uniform within the bounds, continuous joints in
    ``[-pi, pi]``, fixed generators: the same pose gives the same verdict on any load),
    each solution measured as :func:`clear_configuration` measures a point's, stopping at
    the first clear one. Remembered per collision model, pose and bounds.

    Parameters
    ----------
    collision : CollisionModel
    position : array_like, shape (3,)
        The tip's position in the base frame (m).
    rotation : array_like, shape (3, 3)
        The tip's orientation in the base frame (rotation matrix).
    lower, upper : array_like, shape (n,)
        Joint position bounds (rad, m; infinite where unbounded).

    Returns
    -------
    ClearReach
        The first clear solution in the rounds' order; or, when none is clear, the clearest
        tried and its closest pair (``-inf`` and no pair when no solution was found).
    """
    model = collision.model
    position = np.asarray(position, dtype=float).reshape(3)
    rotation = np.asarray(rotation, dtype=float).reshape(3, 3)
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    key = ("pose", position.tobytes(), rotation.tobytes(), lo.tobytes(), hi.tobytes())
    known = _KNOWN.get(collision, key)
    if known is not None:
        return known
    low = np.where(np.isfinite(lo), lo, -np.pi)
    high = np.where(np.isfinite(hi), hi, np.pi)

    def rounds():
        for count, seed in CLEAR_POSE_ROUNDS:
            seeds = np.random.default_rng(seed).uniform(low, high, size=(count, model.n))
            yield count, ik_pose(model, position, rotation, seeds, lo, hi)[0]

    best = _first_clear(collision, lo, hi, rounds())
    _KNOWN.put(collision, key, best)
    return best


def _first_clear(collision: CollisionModel, lo: np.ndarray, hi: np.ndarray, rounds
                 ) -> ClearReach:
    """The first configuration of ``rounds`` inside ``[lo, hi]`` and clear by the margin.

    ``rounds`` yields ``(seeds spent, configurations found)``; each new configuration
    (a later round's repeat is skipped) is measured by the exact distances
    (:meth:`CollisionModel.clearance`), and the rounds stop at the first clear one.
    """
    best = ClearReach(None, -np.inf, (), 0, 0, 0)
    tried = solutions = seeds = 0
    seen: list[np.ndarray] = []
    for count, found in rounds:
        seeds += count
        solutions += len(found)
        for q in found:
            if not (np.all(q >= lo) and np.all(q <= hi)):
                continue
            if any(np.max(np.abs(q - s)) < 1e-6 for s in seen):  # a later round's repeat
                continue
            seen.append(q)
            tried += 1
            c = collision.clearance(q)
            if c.minimum >= collision.margin:
                return ClearReach(q, c.minimum, tuple(c.pair), tried, solutions, seeds)
            if c.minimum > best.clearance:
                best = ClearReach(None, c.minimum, tuple(c.pair), tried, solutions, seeds)
    return ClearReach(None, best.clearance, best.pair, tried, solutions, seeds)


def note_clear(collision: CollisionModel, p, q) -> bool:
    """Remember ``q`` as a configuration reaching ``p`` clear of the scene, if it is.

    One exact clearance (:meth:`CollisionModel.clearance`) instead of
    :func:`clear_configuration`'s search: a replan toward a moving target knows a
    configuration that reaches its new point (Gauss-Newton steps from the end of the motion
    it continues, :func:`~tocontrol_ros.core.types.problem.note_reachable`), mostly clear
    as that end was. When every checked pair keeps the margin, a later
    :func:`clear_configuration` of ``p`` with the same collision model returns ``q``
    (inside its joint limits, else it searches as always); otherwise nothing is remembered.

    Parameters
    ----------
    collision : CollisionModel
    p : array_like, shape (m,)
        Task-space point (m) that ``q`` reaches (the caller's claim, to the IK's tolerance).
    q : array_like, shape (n,)
        Configuration (rad, m).

    Returns
    -------
    bool
        Whether ``q`` is clear by the margin (and remembered), or a clear configuration
        of ``p`` was noted before (kept; ``q`` is then not checked).
    """
    p = np.asarray(p, dtype=float)
    if _NOTED.get(collision, p.tobytes()) is not None:  # a replan's goal noted again
        return True
    q = np.asarray(q, dtype=float).copy()
    found = collision.clearance(q)
    if not found.minimum >= collision.margin:
        return False
    _NOTED.put(collision, p.tobytes(),
               ClearReach(q, float(found.minimum), tuple(found.pair), 1, 0, 0))
    return True
