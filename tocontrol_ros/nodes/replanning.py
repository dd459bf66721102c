"""The planner's replanning state: what it published last, where a new plan takes over.

A goal that arrives while a published motion runs is planned from the state that motion
will be in at the hand-off: now plus the expected latency (:class:`LatencyEstimate`, per
kind of solve, with ``replan_margin`` and ``replan_min_lead``), put on the tracker's control
grid (the latest joint state's stamp plus a multiple of ``handoff_grid``). The published
trajectory is stamped with that time; the tracker splices it in there
(:mod:`tocontrol_ros.nodes.splice`). A goal within ``replan_radius`` of the running motion's
target is re-solved warm from the running motion's tail
(:func:`~tocontrol_ros.core.planning.replan.tail_warm_start`). No ROS here.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np

from tocontrol_ros.core.planning.replan import LatencyEstimate, tail_warm_start
from tocontrol_ros.core.planning.tuning import TAIL_MIN_REMAINING
from tocontrol_ros.core.sim.nominal import NominalTrajectory
from tocontrol_ros.core.types.problem import REST_SPEED, note_reachable
from tocontrol_ros.nodes.planner_config import PlannerConfig

__all__ = ["Handoff", "Replanner", "GoalStream", "align", "REPLAN_TRIES", "WARM", "COLD", "REST",
           "REST_RESERVE", "REST_TAIL", "AHEAD_KEEP", "keeps_ahead", "QUICK",
           "IMPROVE", "STREAM_RATIO", "STREAM_PERIOD", "FOLLOWING", "FOLLOW_LAG", "lag_start",
           "Executing", "CHAIN_KEPT", "continues"]

#: Solves of one goal at most: a plan that would arrive after its hand-off is solved again
#: from a later one (the lead at least twice the late solve's time), then given up.
REPLAN_TRIES = 4
#: Kinds of replan: the running motion's tail continued; a multistart from the hand-off
#: state; from the end of a motion that is over by the hand-off (the arm at rest there).
WARM, COLD, REST = "warm", "cold", "rest"
#: A quick motion's hand-off is at least this many ``replan_min_lead`` ahead of its
#: decision. Its solve takes milliseconds, so its lead from its latencies alone was about
#: 0.1 s; in full test runs beside other work, trajectories that reached the tracker after
#: their stamp started there at once, from a state the arm had left: command jumps of
#: 0.02-0.05 rad at 3 splices in about 10 runs of the moving-target test.
QUICK_LEAD_FACTOR = 3.0
#: The latency estimates of the quick motions published first (``replan_quick``) and of
#: the optimum solved after one, from a later hand-off on it.
QUICK, IMPROVE = "quick", "improve"
#: The arm follows a published motion when its measured positions are this close (rad, m;
#: any joint) to the command at their stamp: tracking error plus a control period's motion.
FOLLOWING = 0.05
#: A published motion the arm follows late (or early) is still followed: the measured arm
#: within :data:`FOLLOWING` of its command up to this long (s) before or after the time its
#: recorded start says (:func:`lag_start`). A holding tracker starts a motion delivered after
#: its stamp at once from its beginning (as a JTC holding its position would): under load a
#: quick motion's publication took 266 ms, its stamp passed, the tracker ran it that late,
#: and the next goal, its hand-off refused, became a cold multistart (8.4 s of IPOPT on the
#: Panda) while the stream's goals waited behind it.
FOLLOW_LAG = 0.5
#: Latency assumed before any was measured (s). A warm replan at 0.05 was often late at a
#: stream's first goals (its solve and publication took 60-180 ms): solved again from a later
#: hand-off, it held up the goals behind it, and the backlog kept the goal solved ahead from
#: running for 20-30 goals (paper's arm, 10 Hz circle, bench/replan.py: median latency 57-299
#: ms in five runs; with 0.1, 12-39 ms in eight).
INITIAL_LATENCY = {WARM: 0.1, COLD: 0.5, REST: 0.1, QUICK: 0.03, IMPROVE: 0.15}
#: The delivery reserve of a rest replan after its publication is at most ``replan_min_lead``
#: plus this (s). It grows with the recent rest solves' latencies (a loaded machine), but a
#: published trajectory's delivery does not take as long as a slow solve: on the Panda with
#: its limits (1-35 s per queued goal) the uncapped reserve stamped replans up to 70 s after
#: their publication, and every later replan was chained behind them.
REST_RESERVE = 0.2
#: A near goal is replanned from the running motion's end, at rest (kind ``"rest"``), when
#: less than this (s) of the motion is left at its warm hand-off: the arm finishes a short
#: tail first. A rest replan is never late and starts where the goal solved ahead started
#: (4-6 Newton iterations from it); a warm one from a short tail starts where the solve ahead
#: did not, and was late now and then, a backlog behind it. Paper's arm, 10 Hz circle
#: (bench/replan.py, 8 runs each): median latency 10.8-17.2 ms, p95 53-108 ms, 92-100 %
#: within 100 ms, against 11.8-262 ms, p95 122-839 ms, 38-90 % with the tail continued.
REST_TAIL = 0.1
#: A goal solved ahead (``replan_predict``) goes on when the goal that arrives is within
#: this fraction of the predicted step (the predicted goal's distance from the running
#: motion's target) of the prediction: its result is that goal's best warm start, closer
#: than any other. Stopped, its work was lost and the goal was solved from a step away
#: (27-42 Newton iterations against 4-6 on the paper's arm's circle), after which the next
#: solve ahead had too little time before its goal too: measured on the moving target,
#: 29 goals in a row solved from a step away.
AHEAD_KEEP = 0.5


def keeps_ahead(pending: list, predicted: np.ndarray, step: float) -> bool:
    """Whether a solve ahead for ``predicted`` goes on while ``pending`` requests wait.

    Parameters
    ----------
    pending : list of PlanRequest
        The requests waiting for the worker (none: it goes on).
    predicted : ndarray, shape (m,)
        The goal solved ahead (m).
    step : float
        Its distance from the running motion's target (m).

    Returns
    -------
    bool
        True when every waiting request is a goal (it queues) within :data:`AHEAD_KEEP`
        ``* step`` of ``predicted``: the goal it predicted, which it serves best.
    """
    tol = AHEAD_KEEP * step
    return all(r.queue and float(np.linalg.norm(np.asarray(r.target) - predicted)) <= tol
               for r in pending)


class Handoff(NamedTuple):
    """Where a replan takes over the running motion.

    Attributes
    ----------
    stamp_ns : int
        The take-over time (ns, the trajectory's ``header.stamp``).
    q, qd : ndarray, shape (n,)
        The running motion's state then (rad, rad/s).
    warm : PlanResult or None
        Its tail from then on, as a warm start (a goal within ``replan_radius``), or None.
    kind : {"warm", "cold", "rest"}
    lag_ns : int
        How much later (ns; negative: earlier) than its stamp the arm started the running
        motion, as its joint states show (:func:`lag_start`); 0 when it follows it in time.
    """

    stamp_ns: int
    q: np.ndarray
    qd: np.ndarray
    warm: object
    kind: str
    lag_ns: int = 0


class Executing(NamedTuple):
    """The last published motion as the replanner keeps it."""

    result: object  # the PlanResult published
    start_ns: int  # when it started or is expected to (its stamp, or a late start found)
    nominal: object  # NominalTrajectory of the published samples, or None
    guessed: bool  # the start a guess (sent after its stamp to a holding tracker)
    stamp_ns: int  # its trajectory's header stamp
    #: The motions it continues, the latest first (each without its own ``before``): a
    #: motion continues the last published one when it starts at that one's command at its
    #: take-over (:func:`continues`); at most :data:`CHAIN_KEPT` of them.
    before: tuple = ()


#: How many motions of a chain of replans are kept behind the last one: a tracker's
#: rejection of any of them (heard after the next ones were published on it) is traced back.
CHAIN_KEPT = 16
#: A motion continues the last one when its start is within these of that one's command at
#: its stamp (rad, rad/s): a hand-off is that command to the bit, or to the samples'
#: interpolation; a start measured on the arm is off it by the tracking error.
CONTINUES_Q, CONTINUES_QD = 1e-9, 1e-6


def continues(executing: Executing, result, stamp_ns: int) -> bool:
    """Whether ``result``, stamped ``stamp_ns`` (ns), starts from ``executing``'s command then.

    The command of the published samples at the stamp (their end after the motion's end,
    at rest), or the trajectory's state when no samples were kept; ``result``'s problem
    start must be a state (a plan from a point or a measured state starts elsewhere).
    """
    problem = getattr(result, "problem", None)
    if problem is None or executing.result.problem is None or problem.start.kind != "state":
        return False
    n = problem.model.n
    start = np.asarray(problem.start.value, dtype=float)
    t = (int(stamp_ns) - executing.start_ns) * 1e-9
    if t < 0.0:
        return False
    previous = executing.result
    if executing.nominal is not None and t <= float(executing.nominal.t[-1]):
        des = executing.nominal.evaluate(t)
        q, qd = des.q[0], des.qd[0]
    elif previous.trajectory is not None:
        z = previous.trajectory.state(min(t, previous.T))[0]
        q, qd = z[:n], z[n:2 * n] if t < previous.T else np.zeros(n)
    else:
        return False
    return bool(np.max(np.abs(start[:n] - q)) <= CONTINUES_Q
                and np.max(np.abs(start[n:2 * n] - qd)) <= CONTINUES_QD)


def lag_start(nominal: NominalTrajectory, start_ns: int, q: np.ndarray, stamp_ns: int,
              grid: float) -> int | None:
    """The start (ns) from which a motion runs that puts the arm at ``q`` at ``stamp_ns``.

    The published motion's own times within :data:`FOLLOW_LAG` of the one its stamp
    ``start_ns`` gives, on the control grid (a tracker starts a motion at a control instant,
    and the joint states are stamped on those instants): the one whose command is nearest to
    ``q`` (max-norm over the joints; of equally near ones, the nearest to the recorded
    start), when within :data:`FOLLOWING`. The arm still at the motion's start (not taken
    over yet) gives ``stamp_ns``: the earliest it can start. The window is around the stamp,
    not around a start found before: a motion never taken over (a tracker that refused it)
    is not followed once its stamp is :data:`FOLLOW_LAG` past.

    Parameters
    ----------
    nominal : NominalTrajectory
        The published samples' interpolant (what the tracker commands).
    start_ns : int
        The trajectory's stamp (ns).
    q : ndarray, shape (n,)
        The measured positions (rad, m).
    stamp_ns : int
        Their stamp (ns).
    grid : float
        The control period (s, ``handoff_grid``).

    Returns
    -------
    int or None
        The start (ns), ``start_ns`` plus a whole number of ``grid``; None when no time
        within :data:`FOLLOW_LAG` puts the command within :data:`FOLLOWING` of ``q``.
    """
    step = max(int(round(grid * 1e9)), 1)
    t_ns = stamp_ns - start_ns
    k_max = int(FOLLOW_LAG * 1e9) // step
    lags = np.arange(-k_max, k_max + 1)  # start later by lags * step
    own = (t_ns - lags * step) * 1e-9  # the motion's own time at the measurement
    keep = own >= 0.0  # before its start the arm is where it starts: the latest such is own 0
    if not np.any(keep):
        return None
    lags, own = lags[keep], own[keep]
    errors = np.max(np.abs(nominal.evaluate(own).q - np.asarray(q, dtype=float)), axis=1)
    best = float(np.min(errors))
    if best > FOLLOWING:
        return None
    # Of the equally near ones (within rounding), the nearest to the recorded start.
    tied = np.flatnonzero(errors <= best + 1e-12)
    k = int(lags[tied[np.argmin(np.abs(lags[tied]))]])
    return start_ns + k * step


def align(t_ns: int, origin_ns: int, grid: float) -> int:
    """The first time at or after ``t_ns`` that is ``origin_ns`` plus a multiple of ``grid``."""
    step = max(int(round(grid * 1e9)), 1)
    return origin_ns + math.ceil((t_ns - origin_ns) / step) * step


#: A stream of goals: the last three arrived at intervals within this factor of each other,
#: each at most :data:`STREAM_PERIOD` s after the one before.
STREAM_RATIO, STREAM_PERIOD = 1.5, 1.0


class GoalStream:
    """The recent goals (targets and arrival times) and the next one they predict.

    A target that moves smoothly and is sent at a steady rate (a tracked object, a
    teleoperation device) is predicted by the quadratic through its last three goals
    (:meth:`predict`): the planner solves that goal ahead while it waits for the real one
    (``replan_predict``). Thread-safe.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._recent: list[tuple[np.ndarray, float]] = []

    def record(self, target: np.ndarray, t: float) -> None:
        """A goal ``target`` (m, shape (m,)) arrived at ``t`` (s, monotonic)."""
        with self._lock:
            self._recent = (self._recent + [(np.array(target, dtype=float), float(t))])[-3:]

    def interval(self) -> float:
        """The last interval between two goals (s), 0 before two came."""
        with self._lock:
            recent = list(self._recent)
        return recent[-1][1] - recent[-2][1] if len(recent) >= 2 else 0.0

    def predict(self, radius: float) -> tuple[np.ndarray, float] | None:
        """The next goal (m) and when it is due (s, monotonic), or None: no steady stream.

        Parameters
        ----------
        radius : float
            The last three goals lie within this of each other (m), as replans do.
        """
        with self._lock:
            recent = list(self._recent)
        if len(recent) < 3:
            return None
        (p1, t1), (p2, t2), (p3, t3) = recent
        d1, d2 = t2 - t1, t3 - t2
        if not (0 < d1 <= STREAM_PERIOD and 0 < d2 <= STREAM_PERIOD
                and max(d1, d2) <= STREAM_RATIO * min(d1, d2)):
            return None
        if max(np.linalg.norm(p3 - p2), np.linalg.norm(p2 - p1)) > radius:
            return None
        return 3.0 * p3 - 3.0 * p2 + p1, t3 + d2  # the quadratic, one interval on


class Replanner:
    """The last published motion and the latencies of replans (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._executing: Executing | None = None
        self._from_rest = None  # the last published PlanResult that started at rest
        self._ahead = None  # (PlanResult solved ahead, the running PlanResult it continues)
        self._latency: dict[str, LatencyEstimate] = {}
        self.goals = GoalStream()

    def solved_ahead(self, result, running) -> None:
        """``result`` was solved ahead for a predicted goal, from the ``running`` motion."""
        with self._lock:
            self._ahead = (result, running)

    def not_executing(self, result) -> bool:
        """``result`` is not executing (the controller refused or aborted it): forget it.

        Replans then no longer continue it (no hand-off on it, no warm start from its tail);
        the next goal is planned from the arm's measured state. Nothing happens when another
        motion was published since (returns False).
        """
        with self._lock:
            if self._executing is None or self._executing.result is not result:
                return False
            self._executing = None
            self._ahead = None
            return True

    def rejected(self, stamp_ns: int, slack_ns: int = 1000) -> tuple[bool, int | None]:
        """The tracker rejected the trajectory stamped ``stamp_ns`` (ns, within ``slack_ns``).

        When it is the last published motion or one that the last continues (a replan
        chained on it, published before the rejection was heard: the tracker rejects a
        motion at its take-over, after the next replan of a stream is published), the
        replans no longer continue it nor what was chained on it: they continue the motion
        it was to take over (the one before it in the chain, which the tracker goes on
        with, or holds the end of), checked like any against the measured arm
        (:meth:`handoff`); when none is known, nothing (the measured state).

        Returns
        -------
        (bool, int or None)
            Whether anything changed, and the stamp (ns) of the motion continued from now
            on (None: none).
        """
        with self._lock:
            executing = self._executing
            if executing is None:
                return False, None
            chain = (executing._replace(before=()),) + executing.before
            i = next((j for j, motion in enumerate(chain)
                      if abs(motion.stamp_ns - int(stamp_ns)) <= slack_ns), None)
            if i is None:
                return False, None
            self._ahead = None
            # The one it was to take over: stamped before it (one stamped the same was
            # replaced by it in the tracker, never run).
            j = next((j for j in range(i + 1, len(chain))
                      if chain[j].stamp_ns < int(stamp_ns) - slack_ns), None)
            if j is not None:
                self._executing = chain[j]._replace(before=chain[j + 1:])
                return True, self._executing.stamp_ns
            self._executing = None
            return True, None

    def running(self):
        """The last published motion (a PlanResult), or None."""
        with self._lock:
            return self._executing.result if self._executing is not None else None

    def estimate(self, config: PlannerConfig, kind: str) -> LatencyEstimate:
        """The latency estimate of one kind of solve (made with the config's margins)."""
        with self._lock:
            est = self._latency.get(kind)
            if est is None or (est.margin, est.floor) != (config.replan_margin,
                                                          config.replan_min_lead):
                est = LatencyEstimate(config.replan_margin, config.replan_min_lead,
                                      initial=INITIAL_LATENCY[kind])
                self._latency[kind] = est
            return est

    def replan_time(self) -> float:
        """The near replans' recent median solve time (s), the warm or the rest one's.

        Solve start to publication; the larger of the two kinds; 0 before any.
        """
        with self._lock:
            return max((self._latency[kind].typical() for kind in (WARM, REST)
                        if kind in self._latency), default=0.0)

    def published(self, result, stamp_ns: int, sample=None, sent_ns: int | None = None
                  ) -> None:
        """``result`` was published, taking over at ``stamp_ns`` (ns), as ``sample``.

        The hand-off state is the published samples' interpolant (what the tracker
        commands), so that the splice does not jump by the interpolation error.

        ``sent_ns``: when its publication ended (ns), for a tracker that starts a motion
        delivered after its stamp at once from its beginning while it holds (the topic; not
        a JTC, which drops the points past: None). Sent after its stamp while nothing runs
        then (the motion before it over), it is expected to start when sent, not at its
        stamp: a guess that the next measured joint states correct (:meth:`handoff`).
        """
        nominal = None
        if sample is not None:
            nominal = NominalTrajectory(sample.t, sample.q, sample.qd, sample.qdd, sample.tau)
        with self._lock:
            start, guessed = int(stamp_ns), False
            if sent_ns is not None and sent_ns > start:
                before = self._executing
                holds = before is None or before.result.trajectory is None or \
                    before.start_ns + math.ceil(before.result.T * 1e9) <= sent_ns
                if holds:
                    start, guessed = int(sent_ns), True
            before = ()
            last = self._executing
            if last is not None and result.trajectory is not None and \
                    continues(last, result, stamp_ns):
                before = ((last._replace(before=()),) + last.before)[:CHAIN_KEPT]
            self._executing = Executing(result, start, nominal, guessed, int(stamp_ns),
                                        before) if result.trajectory is not None else None
            problem = result.problem
            if result.warm_state is not None and problem is not None and \
                    problem.start.kind == "state" and \
                    np.max(np.abs(problem.start.value[problem.model.n:])) <= REST_SPEED:
                self._from_rest = result

    def executing_start(self) -> int | None:
        """When the last published motion started, or is expected to (ns); None: none.

        Its stamp, or where a late start was seen (or expected) the start found
        (:func:`lag_start`).
        """
        with self._lock:
            return self._executing.start_ns if self._executing is not None else None

    def warm_starts(self, tail=None) -> list:
        """The warm starts of a near goal's replan, in the order to try them.

        The plan solved ahead for the goal a stream predicted
        (:class:`GoalStream`), when it continues the motion that still runs; the running
        motion's ``tail`` (:func:`~tocontrol_ros.core.planning.replan.tail_warm_start`), when there
        is one; the last published motion itself (along a stream of goals the
        next problem is much like the last: a similar move from a start nearby); the last
        published motion that started at rest (a target that moves slowly is caught: each
        replan then starts at rest at the last target). Which apply is
        :func:`~tocontrol_ros.core.planning.replan.warm_replan`'s to say.
        """
        with self._lock:
            executing, from_rest, ahead = self._executing, self._from_rest, self._ahead
        last = executing.result if executing is not None else None
        # Solved ahead from the motion that still runs: a prediction error from this goal.
        first = ahead[0] if ahead is not None and last is not None and ahead[1] is last \
            else None
        return [w for w in (first, tail, last, from_rest)
                if w is not None and w.warm_state is not None]

    def note_reachable(self, model, target: np.ndarray, collision=None) -> bool:
        """Show ``target`` (m) reachable from the end of the motion that ends nearest it.

        The motion solved ahead or the last published one
        (:func:`~tocontrol_ros.core.types.problem.note_reachable`): a goal of a stream is then not
        checked by a full inverse kinematics when its problem is made, nor (``collision``,
        the collision model in use) searched for a clear configuration when that end's
        steps reach one. Returns whether it was shown.
        """
        with self._lock:
            ends = [r for r in (self._ahead[0] if self._ahead else None,
                                self._executing.result if self._executing else None)
                    if r is not None and r.trajectory is not None and r.problem is not None]
        if not ends:
            return False
        r = min(ends, key=lambda r: float(np.linalg.norm(r.problem.target_point - target)))
        return note_reachable(model, target, r.trajectory.state(r.T)[0][:model.n], collision)

    def has_motion(self) -> bool:
        """Whether a motion was published that a replan could continue."""
        with self._lock:
            return self._executing is not None

    def near(self, config: PlannerConfig, target: np.ndarray) -> bool:
        """Whether ``target`` is within ``replan_radius`` of the last published motion's."""
        with self._lock:
            executing = self._executing
        if executing is None or executing.result.problem is None:
            return False
        gap = np.linalg.norm(np.asarray(target) - executing.result.problem.target_point)
        return bool(gap <= config.replan_radius)

    def _follow_start(self, executing: Executing, measured, grid: float) -> int | None:
        """When the measured arm shows the published motion started (ns), or None.

        Its recorded start when the arm is within :data:`FOLLOWING` of the command then
        (or the measurement is from before it), unless that start is a guess (sent after
        its stamp to a holding tracker: :meth:`published`); else, and for a guess, the start
        the measured positions give (:func:`lag_start`: the motion followed late or early),
        kept for the next hand-offs; None when the arm does not follow it at all (no
        executor, a rejected trajectory, a reset).
        """
        if measured is None:
            return None
        result, start_ns, nominal, guessed, stamp = executing[:5]
        q, measured_ns = measured
        t = (measured_ns - start_ns) * 1e-9
        if t < 0.0:  # before the motion takes over: the previous command (not kept) runs
            return start_ns
        if not guessed:
            n = result.problem.model.n
            if nominal is not None:
                q_cmd = nominal.evaluate(t).q[0]
            else:
                q_cmd = result.trajectory.state(min(t, result.T))[0][:n]
            if np.max(np.abs(np.asarray(q, dtype=float) - q_cmd)) <= FOLLOWING:
                return start_ns
        if nominal is None:
            return None
        start = lag_start(nominal, stamp, q, measured_ns, grid)
        if start is None:
            return None
        # Found from a moving arm (it left the start): no longer a guess; the arm still at
        # the start: the earliest it can start, refined by the next measurements.
        guess = start >= measured_ns
        with self._lock:
            if self._executing is executing:
                self._executing = executing._replace(start_ns=start, guessed=guess)
        return start

    def rest_lead(self, config: PlannerConfig) -> float:
        """The lead (s) of a motion that starts at rest.

        ``replan_min_lead`` plus ``replan_margin`` times the recent rest solves' latencies,
        at most :data:`REST_RESERVE` more than ``replan_min_lead``. A delivery reserve that
        grows with a loaded machine: a motion from rest delivered
        after its stamp starts late on a holding controller, from its start, and a replan
        planned from where its planner expected it then jumps by the speed times that
        lateness (a goal's first motion stamped ``replan_min_lead`` ahead: 5e-3 rad at the
        next splice in a loaded CI run).
        """
        return min(self.estimate(config, REST).lead(), config.replan_min_lead + REST_RESERVE)

    def rest_stamp(self, config: PlannerConfig, handoff: Handoff, now_ns: int,
                   origin_ns: int) -> int:
        """The stamp of a ``"rest"`` replan published at ``now_ns`` (ns).

        Its hand-off or, when that is nearer, ``now_ns`` plus the lead of rest replans
        (``replan_min_lead`` plus ``replan_margin`` times their recent latencies: a delivery
        reserve that grows with a loaded machine, at most :data:`REST_RESERVE` more than
        ``replan_min_lead``), on the control grid. The arm rests at the
        running motion's end from the hand-off on, so a later take-over starts from the same
        state: a rest replan is never late, however long its solve took.
        """
        stamp = max(handoff.stamp_ns, now_ns + int(self.rest_lead(config) * 1e9))
        return align(stamp, origin_ns or handoff.stamp_ns, config.handoff_grid)

    def forget(self) -> None:
        """Nothing runs any more that a replan could continue (e.g. the model changed)."""
        with self._lock:
            self._executing = self._from_rest = None

    def handoff(self, config: PlannerConfig, target: np.ndarray, now_ns: int,
                origin_ns: int, min_lead: float = 0.0, measured=None,
                quick: bool = False, lead_kind: str | None = None) -> Handoff | None:
        """The hand-off of a replan to ``target`` decided now, or None.

        Parameters
        ----------
        config : PlannerConfig
        target : ndarray, shape (m,)
            The goal (m).
        now_ns : int
            Now (ns, the clock of the stamps).
        origin_ns : int
            A time on the tracker's control grid (the latest joint state's stamp), or 0.
        min_lead : float
            Lead at least this (s): a solve again after a late one.
        measured : (ndarray, int), optional
            The arm's latest measured positions (rad) and their stamp (ns): the published
            motion counts as executing only when they are within :data:`FOLLOWING` of its
            command then, or of its command up to :data:`FOLLOW_LAG` earlier or later (a
            motion started late: the hand-off is then on the motion shifted by that lag,
            :func:`lag_start`); no executor, a rejected trajectory or a reset: not followed.

        quick : bool
            For a quick motion (``replan_quick``): the lead of the quick motions, and a
            moving hand-off whatever the tail left (a quick motion starts from any state;
            :data:`REST_TAIL` is the warm continuation's rule); kind ``"rest"`` only when
            the motion is over by then.
        lead_kind : str, optional
            The kind whose latency estimate sets the lead (default: the hand-off's own
            kind; :data:`QUICK` with ``quick``).

        Returns
        -------
        Handoff or None
            None when nothing was published, or the arm does not follow it (the goal is
            then planned from the arm's measured state). A motion over by the hand-off, or
            for a near goal with less than :data:`REST_TAIL` of it left then, gives kind
            ``"rest"``: from its end, at rest, stamped with that end or ``now_ns``
            (the later): the arm rests there from then on, so the publication may stamp it
            later (:meth:`rest_stamp`).
        """
        with self._lock:
            executing = self._executing
        if executing is None:
            return None
        result, nominal = executing.result, executing.nominal
        start_ns = self._follow_start(executing, measured, config.handoff_grid)
        if start_ns is None:
            return None
        near = float(np.linalg.norm(np.asarray(target) - result.problem.target_point)) \
            <= config.replan_radius
        # A near goal is re-solved warm, with the warm lead, when the running motion still
        # has a tail then; otherwise (or farther) the multistart's lead applies.
        for kind in (WARM, REST) if near else (COLD,):
            lead_of = lead_kind or (QUICK if quick else kind)
            lead = max(self.estimate(config, lead_of).lead(), min_lead)
            if quick:  # its solve is short, its delivery to the tracker under load is not
                lead = max(lead, QUICK_LEAD_FACTOR * config.replan_min_lead)
            stamp = max(now_ns + int(lead * 1e9), start_ns + 1)
            stamp = align(stamp, origin_ns or start_ns, config.handoff_grid)
            t = (stamp - start_ns) * 1e-9
            n = result.problem.model.n
            if t >= result.T * (1.0 - TAIL_MIN_REMAINING) or \
                    (near and not quick and result.T - t < REST_TAIL):
                # The motion is over by then, or a near goal's tail is under REST_TAIL
                # (a tail too short to continue is waited out:
                # the command is at rest only after the end): the arm holds its end. Any
                # instant from the end on serves, so no lead: the end, or now (the
                # publication puts it replan_min_lead after itself: never late).
                end = start_ns + math.ceil(result.T * 1e9)
                stamp = align(max(now_ns, end), origin_ns or start_ns, config.handoff_grid)
                q_end = result.trajectory.state(result.T)[0][:n]
                return Handoff(stamp, q_end.copy(), np.zeros(n), None, REST,
                               start_ns - executing.stamp_ns)
            warm = tail_warm_start(result, t) if kind == WARM else None
            if kind == WARM and warm is None and not quick:
                continue
            if nominal is not None:  # the command the tracker gives then
                des = nominal.evaluate(t)
                q, qd = des.q[0], des.qd[0]
            else:
                z = result.trajectory.state(t)[0]
                q, qd = z[:n].copy(), z[n:2 * n].copy()
            return Handoff(stamp, q, qd, warm, WARM if warm is not None else COLD,
                           start_ns - executing.stamp_ns)
        return None
