"""When a stamped trajectory takes over in the tracker, and how far the command jumps there.

A ``trajectory_msgs/JointTrajectory`` whose ``header.stamp`` lies ahead of the tracker's
clock (by at most :data:`SPLICE_HORIZON`) is a splice: the running trajectory goes on up to
that instant and the new one takes over there (a replan from where the arm will be, see
``msg_docs/tracker_trajectory_input.md``). One whose stamp has just passed (by at most
:data:`SPLICE_HORIZON`: :func:`joins_late`) while a trajectory runs takes over at the next
control instant as far along as its stamp says, as a JTC does (also when the running one
ends before that instant: :func:`take_over_elapsed`): a replan delivered after its hand-off
then follows the motion its planner assumed, and the next replan's splice matches it. A
stamp of zero, one farther off (another clock), or one at or before the tracker's time while
it holds, starts the trajectory at once from its start. No ROS here.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["Splice", "SPLICE_HORIZON", "splice_instant", "joins_late", "take_over_instant",
           "is_late", "take_over_elapsed", "jumps", "schedule"]

#: A stamp at most this far (s) ahead of the tracker's time is a splice instant; farther,
#: the stamp is taken to be on another clock (a planner on wall time, a tracker on /clock:
#: decades apart) and the trajectory starts at once. Generous: a slow replan (seconds, the
#: Panda's bounded solve) is stamped that far ahead.
SPLICE_HORIZON = 60.0
#: Stamps within this (s) of a control instant are on it (float rounding of ns stamps).
GRID_SLACK = 1e-6


class Splice(NamedTuple):
    """A parsed trajectory waiting for its take-over instant.

    Attributes
    ----------
    nominal : NominalTrajectory
    at : float
        Simulation time of the first control instant at or after the stamp (s).
    elapsed : float
        The trajectory's own time at that instant (s, >= 0: ``at`` minus the stamp).
    stamp : float
        The take-over time as stamped (s, the tracker's clock).
    record : GoalRecord or None
        The ``FollowJointTrajectory`` goal it came in (None: the topic).
    """

    nominal: object
    at: float
    elapsed: float
    stamp: float
    record: object = None


def splice_instant(stamp: float, epoch: float, now: float, h: float, late: bool = False
                   ) -> tuple[float, float] | None:
    """The control instant at which a trajectory stamped ``stamp`` takes over, or None.

    Parameters
    ----------
    stamp : float
        The trajectory's ``header.stamp`` (s); 0 means "start now".
    epoch : float
        The tracker's stamp of simulation time 0 (s).
    now : float
        The tracker's simulation time (s).
    h : float
        Control period (s).
    late : bool
        A stamp already past takes over at the next control instant, as far along as the
        stamp says (a Jazzy JTC drops the points already past: a FollowJointTrajectory
        goal whose round trip outlasted its lead). False: it starts at once from its start.

    Returns
    -------
    (at, elapsed) or None
        Simulation time of the take-over and the trajectory's own time then; None when the
        trajectory starts at once (stamp 0, not ahead of ``now`` unless ``late``, or beyond
        the horizon).
    """
    if stamp <= 0.0 or not math.isfinite(stamp):
        return None
    t = stamp - epoch
    if late and t <= now + GRID_SLACK:
        at = math.ceil((now + GRID_SLACK) / h) * h
        return at, at - t
    if t <= now + GRID_SLACK or t > now + SPLICE_HORIZON:
        return None
    at = math.ceil(t / h - GRID_SLACK / h) * h
    return at, max(at - t, 0.0)


def joins_late(stamp: float, epoch: float, now: float) -> bool:
    """Whether a trajectory stamped ``stamp`` (s) joins a running one late.

    True when its stamp is on the tracker's clock and has passed by at most
    :data:`SPLICE_HORIZON` at simulation time ``now`` (s; ``epoch``: the stamp of time 0):
    the trajectory was meant to take over then and was delivered (or parsed) after it.
    Stamp 0 ("now") and stamps farther in the past (another clock) do not.
    """
    if stamp <= 0.0 or not math.isfinite(stamp):
        return False
    passed = now - (stamp - epoch)
    return 0.0 <= passed <= SPLICE_HORIZON


def take_over_instant(stamp: float, epoch: float, now: float, h: float, running: bool,
                      goal: bool) -> tuple[float, float] | None:
    """:func:`splice_instant` with the tracker's rule for a stamp already past.

    A ``FollowJointTrajectory`` goal's (``goal``) joins as far along as its stamp says, as a
    JTC drops the points past; a topic trajectory's the same while one runs (``running``)
    and its stamp has just passed (:func:`joins_late`: a replan delivered after its
    hand-off). Otherwise a past stamp starts the trajectory at once (None).
    """
    late = goal or (running and joins_late(stamp, epoch, now))
    return splice_instant(stamp, epoch, now, h, late)


def is_late(splice: Splice, h: float) -> bool:
    """Whether ``splice`` takes over a control period ``h`` (s) or more after its stamp."""
    return splice.elapsed >= h - GRID_SLACK


def take_over_elapsed(splice: Splice, running: bool, h: float) -> float:
    """The trajectory's own time (s) at which ``splice`` takes over.

    Joining a running trajectory (``running``), or late (:func:`is_late`: delivered after
    its hand-off): as far along as its stamp says, as a JTC drops the points past. So a late
    replan keeps the timeline its planner assumed, and the next replan's splice matches it,
    also when the motion it was to join ended between its delivery and its take-over (it
    used to start from its beginning then, a lag the planner did not know: the next splice
    jumped). Holding, on time: from its beginning (0).
    """
    return splice.elapsed if running or is_late(splice, h) else 0.0


def jumps(old: tuple[np.ndarray, np.ndarray], new: tuple[np.ndarray, np.ndarray]
          ) -> tuple[float, float]:
    """Largest position (rad, m) and velocity (rad/s, m/s) jump between two commands."""
    return (float(np.max(np.abs(np.asarray(new[0]) - np.asarray(old[0])))),
            float(np.max(np.abs(np.asarray(new[1]) - np.asarray(old[1])))))


def schedule(pending: list[Splice], splice: Splice) -> tuple[list[Splice], list[Splice]]:
    """Add ``splice`` to the pending ones; return ``(pending, dropped)``.

    A new trajectory replaces the pending ones that would take over at or after its own
    instant (they were planned before it); earlier ones stay and take over first.
    """
    keep = [s for s in pending if s.at < splice.at]
    dropped = [s for s in pending if s.at >= splice.at]
    return keep + [splice], dropped
