"""Replanning in the nodes without spinning: splice instants, the goal queue, hand-offs."""

import numpy as np
import pytest

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point
from tocontrol_ros.nodes.planner_config import config_from_values
from tocontrol_ros.nodes.replanning import COLD, REST, WARM, Replanner, align
from tocontrol_ros.nodes.requests import LatestSlot
from tocontrol_ros.nodes.splice import (
    SPLICE_HORIZON,
    Splice,
    is_late,
    joins_late,
    jumps,
    schedule,
    splice_instant,
    take_over_elapsed,
    take_over_instant,
)


def test_a_stamp_just_passed_joins_late_and_other_clocks_do_not():
    # epoch 100 s, simulation time 5 s: the tracker's clock reads 105 s.
    assert joins_late(104.98, 100.0, 5.0)  # 20 ms past: delivered after its hand-off
    assert joins_late(105.0, 100.0, 5.0)
    assert not joins_late(105.01, 100.0, 5.0)  # ahead: a splice, not late
    assert not joins_late(0.0, 100.0, 5.0)  # stamp 0: "now"
    assert not joins_late(105.0 - SPLICE_HORIZON - 1.0, 100.0, 5.0)  # another clock
    assert not joins_late(float("nan"), 100.0, 5.0)
    # The tracker's rule: a topic trajectory joins late only while one runs; a goal always.
    h = 1e-3
    at, elapsed = take_over_instant(104.98, 100.0, 5.0, h, running=True, goal=False)
    assert at == pytest.approx(5.001) and elapsed == pytest.approx(0.021)  # next instant
    assert take_over_instant(104.98, 100.0, 5.0, h, running=False, goal=False) is None
    assert take_over_instant(104.98, 100.0, 5.0, h, running=False, goal=True) is not None


def test_splice_instant_on_the_control_grid():
    h = 1e-3
    assert splice_instant(0.0, 100.0, 5.0, h) is None  # stamp 0: now
    assert splice_instant(104.0, 100.0, 5.0, h) is None  # past: now
    assert splice_instant(100.0 + 5.0 + SPLICE_HORIZON + 1, 100.0, 5.0, h) is None
    at, elapsed = splice_instant(100.0 + 5.0105, 100.0, 5.0, h)
    assert at == pytest.approx(5.011) and elapsed == pytest.approx(0.0005)
    at, elapsed = splice_instant(100.0 + 5.02, 100.0, 5.0, h)
    assert at == pytest.approx(5.02) and elapsed == pytest.approx(0.0, abs=1e-6)


def test_schedule_replaces_later_pending_splices():
    a, b, c = (Splice(None, t, 0.0, t) for t in (1.0, 2.0, 1.5))
    pending, dropped = schedule([a, b], c)
    assert pending == [a, c] and dropped == [b]
    assert jumps((np.zeros(2), np.zeros(2)), (np.array([0.0, -2e-3]), np.ones(2))) == \
        pytest.approx((2e-3, 1.0))


class _Item:
    def __init__(self, queue, received=0.0):
        self.queue = queue
        self.received = received


def test_goals_queue_and_services_supersede():
    slot = LatestSlot()
    goals = [_Item(True) for _ in range(4)]
    for g in goals[:3]:
        assert slot.put(g, 3) == ([], None)
    replaced, _ = slot.put(goals[3], 3)
    assert replaced == [goals[0]]  # the oldest beyond the queue
    assert slot.take(0.0) == (goals[1], [])
    service = _Item(False)
    replaced, running = slot.put(service, 3)
    assert replaced == goals[2:] and running is goals[1]
    assert slot.close() == [service]


def test_goals_behind_a_backlog_too_long_to_solve_are_superseded():
    slot = LatestSlot()
    goals = [_Item(True, received=0.1 * i) for i in range(4)]  # a 10 Hz stream
    for g in goals:
        slot.put(g, 50)
    # Solves of 0.2 s fall behind goals 0.1 s apart: 4 waiting (0.8 s) over a 0.5 s backlog,
    # the two oldest give way, the two left (0.4 s) are taken in turn.
    assert slot.take(0.0, 0.5, 0.2) == (goals[2], [(goals[0], goals[1]),
                                                    (goals[1], goals[2])])
    assert slot.take(0.0, 0.0, 9.0) == (goals[3], [])  # the newest is never dropped
    slot.finished(goals[3])
    for g in goals:
        slot.put(g, 50)
    assert slot.take(0.0, 0.5, 0.0) == (goals[0], [])  # no solve time measured yet
    # Solves of 0.09 s keep up with the stream: 3 waiting (0.27 s) over a 0.1 s backlog
    # drain by themselves, none is dropped.
    assert slot.take(0.0, 0.1, 0.09) == (goals[1], [])
    service = _Item(False)
    slot.put(service, 50)  # a service request replaces the pending goals; never stale
    assert slot.take(0.0, 0.0, 5.0) == (service, [])


def test_replan_time_is_the_slower_kind_s_recent_median():
    # What a queued goal costs the worker (LatestSlot.take's per_item): unknown (0) before
    # any near replan was timed, then the larger of the warm and rest replans' medians.
    replans = Replanner()
    config = config_from_values({})
    assert replans.replan_time() == 0.0
    for seconds in (0.01, 0.02, 0.5):  # one slow solve does not set it
        replans.estimate(config, REST).record(seconds)
    assert replans.replan_time() == pytest.approx(0.02)
    for seconds in (0.04, 0.05):
        replans.estimate(config, WARM).record(seconds)
    assert replans.replan_time() == pytest.approx(0.045)
    replans.estimate(config, COLD).record(9.0)  # new motions are not replans
    assert replans.replan_time() == pytest.approx(0.045)


def test_align():
    assert align(1_000_400, 0, 1e-3) == 2_000_000
    assert align(1_000_400, 400, 1e-3) == 1_000_400
    assert align(1_000_401, 400, 1e-3) == 2_000_400
    assert align(999_999, 0, 1e-3) == 1_000_000


@pytest.fixture(scope="module")
def motion():
    model = load_robot(default_urdf_path())
    q0 = np.array([0.3, 0.9, 0.6])
    problem = Problem(model, joint_state(q0), point(PAPER_TARGET), k=4.0)
    return plan(problem, SolverOptions(starts=1, candidates=1))


def test_handoff_kinds(motion):
    config = config_from_values({})
    replans = Replanner()
    target = np.asarray(PAPER_TARGET)
    start = 10**9
    at_start = (motion.trajectory.state(0.0)[0][:3], start)
    assert replans.handoff(config, target, start, 0, measured=at_start) is None  # nothing yet
    replans.published(motion, start, motion.trajectory.sample(0.01))
    near = target + np.array([0.02, 0.0])
    # Not followed (no executor, a reset): planned from the measured state as before.
    assert replans.handoff(config, near, start, 0, measured=(at_start[0] + 0.1, start)) is None
    assert replans.handoff(config, near, start, 0) is None
    h = replans.handoff(config, near, start, 0, measured=at_start)
    assert h.kind == WARM and h.warm is not None and h.stamp_ns > start
    assert h.stamp_ns % 10**6 == 0  # on the 1 ms grid from 0
    z = motion.trajectory.state((h.stamp_ns - start) * 1e-9)[0]
    np.testing.assert_allclose(h.q, z[:3], atol=1e-6)
    far = np.asarray(PAPER_START)
    replans.estimate(config, COLD).record(0.01)  # a lead shorter than the motion
    assert replans.handoff(config, far, start, 0, measured=at_start).kind == COLD
    after = start + int(2 * motion.T * 1e9)
    h = replans.handoff(config, near, after, 0, measured=at_start)
    assert h.kind == REST and not np.any(h.qd)
    np.testing.assert_allclose(h.q, motion.trajectory.state(motion.T)[0][:3])


def test_a_near_goal_waits_out_a_short_tail(motion):
    """Less than REST_TAIL of the motion left at the warm hand-off: a rest replan from its
    end; more: the tail continued (warm). A far goal is not affected."""
    from tocontrol_ros.nodes.replanning import INITIAL_LATENCY, REST_TAIL

    config = config_from_values({})
    start = 10**9
    at_start = (motion.trajectory.state(0.0)[0][:3], start)
    near = np.asarray(PAPER_TARGET) + np.array([0.02, 0.0])
    lead = config.replan_min_lead + config.replan_margin * INITIAL_LATENCY[WARM]
    assert motion.T > lead + REST_TAIL + 0.05  # the premise: a tail either side of it
    for left, kind in ((REST_TAIL + 0.02, WARM), (REST_TAIL - 0.02, REST)):
        replans = Replanner()
        replans.published(motion, start, motion.trajectory.sample(0.01))
        now = start + int((motion.T - left - lead) * 1e9)
        h = replans.handoff(config, near, now, 0, measured=at_start)
        assert h.kind == kind, (left, h.kind)
        if kind == REST:
            assert h.stamp_ns >= start + int(motion.T * 1e9) and not np.any(h.qd)


def test_a_rest_replan_is_never_late(motion):
    # The running motion is over by the hand-off: the replan starts at its end, at rest,
    # stamped with that end (no lead); published after it, it is stamped replan_min_lead
    # after its publication on the control grid, from the same state.
    config = config_from_values({})
    replans = Replanner()
    start = 10**9
    at_start = (motion.trajectory.state(0.0)[0][:3], start)
    replans.published(motion, start, motion.trajectory.sample(0.01))
    near = np.asarray(PAPER_TARGET) + np.array([0.02, 0.0])
    end = start + int(np.ceil(motion.T * 1e9))
    before_end = end - 10**6  # 1 ms before the end, with a lead of 50 ms or more
    h = replans.handoff(config, near, before_end, 0, measured=at_start)
    assert h.kind == REST and h.stamp_ns == align(end, 0, config.handoff_grid)
    lead = replans.estimate(config, REST).lead()  # the delivery reserve of rest replans
    assert lead >= config.replan_min_lead
    in_time = h.stamp_ns - int(lead * 1e9) - 10**6  # published before it by more: as is
    assert replans.rest_stamp(config, h, in_time, 0) == h.stamp_ns
    soon = replans.rest_stamp(config, h, before_end, 0)  # 1 ms before it: the lead
    assert soon == align(before_end + int(lead * 1e9), 0, config.handoff_grid)
    late = h.stamp_ns + 3 * 10**8  # published 0.3 s after the hand-off
    stamp = replans.rest_stamp(config, h, late, 0)
    assert stamp == align(late + int(lead * 1e9), 0, config.handoff_grid) > late
    assert stamp % int(config.handoff_grid * 1e9) == 0


def test_a_slow_solve_does_not_push_a_rest_replan_far_ahead(motion):
    # Rest replans whose solves took 35 s each (the Panda's queued goals): their delivery
    # reserve stays replan_min_lead + REST_RESERVE after publication, not 70 s.
    from tocontrol_ros.nodes.replanning import REST_RESERVE

    config = config_from_values({})
    replans = Replanner()
    start = 10**9
    replans.published(motion, start, motion.trajectory.sample(0.01))
    near = np.asarray(PAPER_TARGET) + np.array([0.02, 0.0])
    end = start + int(np.ceil(motion.T * 1e9))
    h = replans.handoff(config, near, end, 0,
                        measured=(motion.trajectory.state(0.0)[0][:3], start))
    assert h.kind == REST
    for _ in range(5):
        replans.estimate(config, REST).record(35.0)
    assert replans.estimate(config, REST).lead() > 35.0  # the estimate itself is kept
    now = end + 10**8
    stamp = replans.rest_stamp(config, h, now, 0)
    cap = config.replan_min_lead + REST_RESERVE
    assert now + int(config.replan_min_lead * 1e9) < stamp
    assert stamp == align(now + int(cap * 1e9), 0, config.handoff_grid)


def test_a_handoff_velocity_a_little_over_a_limit_is_planned_from_the_limit():
    # The published samples' interpolant can pass a velocity limit between samples; a replan
    # from that hand-off starts at the limit (up to 10 % over), beyond that it is refused.
    from tocontrol_ros.core.errors import ProblemError
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.nodes.planner_config import plan_problem
    from tocontrol_ros.nodes.replanning import Handoff

    model = load_robot(default_urdf_path())
    limits = JointLimits(tuple(model.joint_names), np.full(3, -10.0), np.full(3, 10.0),
                         np.array([2.0, 2.0, 2.0]))
    config = config_from_values({})
    q = np.array([0.3, 0.9, 0.6])
    over = Handoff(0, q, np.array([2.1, -0.5, 0.0]), None, WARM)
    problem = plan_problem(config, model, limits, ("state", over.q, over.qd), PAPER_TARGET)
    qd = problem.start.value[3:]
    assert qd[0] == pytest.approx(2.0) and qd[0] < 2.0 and qd[1] == -0.5
    far = Handoff(0, q, np.array([2.5, 0.0, 0.0]), None, WARM)
    with pytest.raises(ProblemError, match="velocity 2.5 is not below its limit 2"):
        plan_problem(config, model, limits, ("state", far.q, far.qd), PAPER_TARGET)


def test_goal_stream_predicts_a_steady_stream_only():
    from tocontrol_ros.nodes.replanning import GoalStream

    stream = GoalStream()
    centre, r, period = np.array([1.5, 1.2]), 0.15, 0.1
    a = 2 * np.pi * np.arange(4) / 50  # bench/replan.py's circle at 10 Hz

    def on_circle(i):
        return centre + r * np.array([np.cos(a[i]), np.sin(a[i])])

    for i in range(2):
        stream.record(on_circle(i), 10.0 + i * period)
        assert stream.predict(0.1) is None  # fewer than three
    stream.record(on_circle(2), 10.0 + 2 * period)
    target, due = stream.predict(0.1)
    assert due == pytest.approx(10.0 + 3 * period)
    # The quadratic through three points of a circle, one step on: r * step^3 off.
    assert np.linalg.norm(target - on_circle(3)) < r * (a[1] ** 3)
    assert stream.predict(0.01) is None  # goals farther apart than the radius
    stream.record(on_circle(3), 10.0 + 3 * period + 0.5)  # an irregular interval
    assert stream.predict(0.1) is None


def test_a_solve_ahead_goes_on_for_the_goal_it_predicted_only():
    from types import SimpleNamespace

    from tocontrol_ros.nodes.replanning import AHEAD_KEEP, keeps_ahead

    predicted, step = np.array([1.0, 2.0]), 0.04

    def goal(offset, queue=True):
        return SimpleNamespace(target=predicted + np.array([offset, 0.0]), queue=queue)

    assert keeps_ahead([], predicted, step)  # nothing waits
    # The goal predicted, a prediction error away: its best warm start goes on.
    assert keeps_ahead([goal(1e-4)], predicted, step)
    assert keeps_ahead([goal(0.99 * AHEAD_KEEP * step)], predicted, step)
    # Another goal, a service request (it does not queue), or one more goal behind: stop.
    assert not keeps_ahead([goal(1.01 * AHEAD_KEEP * step)], predicted, step)
    assert not keeps_ahead([goal(1e-4, queue=False)], predicted, step)
    assert not keeps_ahead([goal(1e-4), goal(step)], predicted, step)


def test_a_late_goal_joins_as_far_along_as_its_stamp_says():
    """FollowJointTrajectory goals (``late``): a stamp already past takes over at the next
    control instant with the time since the stamp, as a JTC drops the points already past;
    without ``late`` (the topic) it starts at once from its beginning (None)."""
    h = 0.001
    assert splice_instant(104.0, 100.0, 5.0, h) is None
    at, elapsed = splice_instant(104.9995, 100.0, 5.0, h, late=True)
    assert at == pytest.approx(5.001) and elapsed == pytest.approx(0.0015)
    at, elapsed = splice_instant(104.0, 100.0, 5.0004, h, late=True)
    assert at == pytest.approx(5.001) and elapsed == pytest.approx(1.001)
    assert splice_instant(0.0, 100.0, 5.0, h, late=True) is None  # stamp 0: now


def test_a_late_splice_keeps_its_stamps_timeline_when_the_motion_it_joins_has_ended():
    """A replan delivered after its hand-off is scheduled to join the running motion at the
    next control instant, as far along as its stamp says. When that motion ends before the
    instant (a rest replan stamped at its end, delivered a little late), the tracker used to
    start the replan from its beginning: a lag its planner did not know, and the next
    replan's splice, on time, jumped (1.1e-2 rad/s, 5.3e-3 rad in loaded CI runs). It keeps
    the stamp's timeline now; only an on-time splice onto a holding arm starts from 0."""
    h = 0.002
    at, elapsed = splice_instant(100.0 + 4.992, 100.0, 5.0004, h, late=True)
    late = Splice(None, at, elapsed, 104.992)
    assert is_late(late, h) and elapsed == pytest.approx(0.010)
    assert take_over_elapsed(late, running=True, h=h) == pytest.approx(0.010)
    assert take_over_elapsed(late, running=False, h=h) == pytest.approx(0.010)
    at, elapsed = splice_instant(100.0 + 5.1, 100.0, 5.0, h)  # ahead: on time
    on_time = Splice(None, at, elapsed, 105.1)
    assert not is_late(on_time, h)
    assert take_over_elapsed(on_time, running=False, h=h) == 0.0
    # A stamp between two control instants: on time, within a period of it.
    at, elapsed = splice_instant(100.0 + 5.1005, 100.0, 5.0, h)
    grid = Splice(None, at, elapsed, 105.1005)
    assert not is_late(grid, h) and take_over_elapsed(grid, False, h) == 0.0
    assert take_over_elapsed(grid, True, h) == pytest.approx(0.0015)


def _nominal(sample):
    from tocontrol_ros.core.sim.nominal import NominalTrajectory

    return NominalTrajectory(sample.t, sample.q, sample.qd, sample.qdd, sample.tau)


def test_a_motion_followed_late_is_followed_from_where_the_arm_is(motion):
    """A tracker that started the motion 0.2 s after its stamp (a holding tracker starts a
    late delivery from its beginning): the hand-off is on the motion shifted by that lag,
    found from the measured positions on the control grid, and kept for the next goal. A lag
    beyond FOLLOW_LAG, or an arm off the motion, is not followed (planned from the measured
    state, as before)."""
    from tocontrol_ros.nodes.replanning import FOLLOW_LAG, FOLLOWING, lag_start

    config = config_from_values({})
    sample = motion.trajectory.sample(0.01)
    nominal = _nominal(sample)
    start = 10**9
    near = np.asarray(PAPER_TARGET) + np.array([0.02, 0.0])
    own, lag = 0.3 * motion.T, 0.2
    measured_ns = start + int(round((own + lag) * 1e3)) * 10**6  # on the 1 ms grid
    q = nominal.evaluate(own).q[0]
    # The premise: at its stamp's time the command is far from the arm (not followed so).
    assert np.max(np.abs(nominal.evaluate(own + lag).q[0] - q)) > FOLLOWING
    shifted = start + int(round(lag * 1e3)) * 10**6
    assert lag_start(nominal, start, q, measured_ns, config.handoff_grid) == shifted
    replans = Replanner()
    replans.published(motion, start, sample)
    h = replans.handoff(config, near, measured_ns, 0, measured=(q, measured_ns))
    assert h is not None and h.kind in (WARM, COLD)
    assert replans.executing_start() == shifted
    expect = nominal.evaluate((h.stamp_ns - shifted) * 1e-9)
    np.testing.assert_allclose(h.q, expect.q[0], atol=1e-12)
    np.testing.assert_allclose(h.qd, expect.qd[0], atol=1e-12)
    # The next goal, the arm on the shifted motion: followed as it is, same start.
    later = measured_ns + 20 * 10**6
    q2 = nominal.evaluate((later - shifted) * 1e-9).q[0]
    assert replans.handoff(config, near, later, 0, measured=(q2, later)) is not None
    assert replans.executing_start() == shifted
    # Too late to count as this motion's, or off it: not followed.
    too_late = Replanner()
    too_late.published(motion, start, sample)
    far_ns = start + int(round((own + FOLLOW_LAG + 0.05) * 1e3)) * 10**6
    assert too_late.handoff(config, near, far_ns, 0, measured=(q, far_ns)) is None
    assert too_late.handoff(config, near, measured_ns, 0,
                            measured=(q + 2 * FOLLOWING, measured_ns)) is None
    assert lag_start(nominal, start, q + 2 * FOLLOWING, measured_ns, 1e-3) is None


def test_a_late_publication_to_a_holding_tracker_is_expected_to_start_when_sent(motion):
    """Sent after its stamp while nothing runs (the tracker holds and starts it on arrival):
    its start is expected when it was sent, a guess that the measured arm corrects (still at
    the start: the measurement's stamp at the earliest; moving: where it is on the motion).
    Sent late while the motion before it still runs (the tracker joins it as far along as
    its stamp says), or through a JTC (no sent time), it starts at its stamp."""
    config = config_from_values({})
    sample = motion.trajectory.sample(0.01)
    nominal = _nominal(sample)
    stamp = 10**9
    sent = stamp + 3 * 10**8
    near = np.asarray(PAPER_TARGET) + np.array([0.02, 0.0])
    q0 = nominal.evaluate(0.0).q[0]
    replans = Replanner()
    replans.published(motion, stamp, sample, sent_ns=sent)
    assert replans.executing_start() == sent
    # Measured before it was sent, at its start: the guess stands.
    assert replans.handoff(config, near, sent, 0, measured=(q0, sent - 10**7)) is not None
    assert replans.executing_start() == sent
    # Still at its start after it was sent: not taken over yet, no earlier than then.
    at = sent + 4 * 10**6
    assert replans.handoff(config, near, at, 0, measured=(q0, at)) is not None
    assert replans.executing_start() == at
    # Moving: taken over 12 ms after it was sent; found and no longer a guess.
    own = 0.25 * motion.T
    moving = sent + 12 * 10**6 + int(round(own * 1e3)) * 10**6
    h = replans.handoff(config, near, moving, 0,
                        measured=(nominal.evaluate(own).q[0], moving))
    assert h is not None and replans.executing_start() == sent + 12 * 10**6
    # In time, or late behind a motion that still runs, or to a JTC: its stamp.
    for before, sent_ns in ((None, stamp - 10**7), (motion, sent), (None, None)):
        replans = Replanner()
        if before is not None:
            replans.published(before, stamp - 10**8, sample)  # runs until after `sent`
        replans.published(motion, stamp, sample, sent_ns=sent_ns)
        assert replans.executing_start() == stamp


def _line_motion(q0: float, stamp_s: float, start_offset: float = 0.0):
    """A one-joint motion at 1 rad/s from ``q0`` for 1 s, stamped ``stamp_s``; its problem
    starts at ``(q0 + start_offset, 1)`` (an offset: a start measured off the command)."""
    from types import SimpleNamespace

    t = np.linspace(0.0, 1.0, 11)
    sample = SimpleNamespace(t=t, q=(q0 + t)[:, None], qd=np.ones((11, 1)),
                             qdd=np.zeros((11, 1)), tau=np.zeros((11, 1)))
    start = SimpleNamespace(kind="state", value=np.array([q0 + start_offset, 1.0]))
    trajectory = SimpleNamespace(state=lambda s: (np.array([q0 + s, 1.0]),))
    result = SimpleNamespace(problem=SimpleNamespace(start=start, model=SimpleNamespace(n=1)),
                             trajectory=trajectory, T=1.0, warm_state=None)
    return result, int(round(stamp_s * 1e9)), sample


def test_a_rejection_of_a_motion_the_last_continues_restores_the_one_before_it():
    """The chain: B starts at A's command at its stamp, C at B's; a rejection of B (heard
    after C was published) makes A the running motion again; D, planned from a start off
    A's command (measured), continues nothing: a rejection of B then changes nothing."""
    a, b, c = _line_motion(0.0, 0.0), _line_motion(0.5, 0.5), _line_motion(0.8, 0.8)
    replans = Replanner()
    for result, stamp, sample in (a, b, c):
        replans.published(result, stamp, sample)
    assert replans.rejected(b[1] + 10**6) == (False, None)  # another stamp
    assert replans.running() is c[0]
    assert replans.rejected(b[1] + 100) == (True, a[1])  # within 1 us
    assert replans.running() is a[0]
    assert replans.rejected(a[1]) == (True, None)  # the first of the chain: nothing known
    assert replans.running() is None
    replans = Replanner()
    d = _line_motion(0.8, 0.8, start_offset=1e-3)
    for result, stamp, sample in (a, b, d):
        replans.published(result, stamp, sample)
    assert replans.rejected(b[1]) == (False, None) and replans.running() is d[0]


def test_a_rejected_motion_is_not_replaced_by_one_stamped_the_same():
    """B stamped with A's stamp replaced A in the tracker (never run): rejected, nothing
    is continued."""
    a, b = _line_motion(0.0, 0.2), _line_motion(0.0, 0.2)
    replans = Replanner()
    for result, stamp, sample in (a, b):
        replans.published(result, stamp, sample)
    assert replans.rejected(a[1]) == (True, None) and replans.running() is None
