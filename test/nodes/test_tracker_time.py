"""The tracker's time keeping and recent positions, without ROS (nodes/tracker_time.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tocontrol_ros.nodes.tracker_time import (
    MAX_TICK_PERIODS,
    PositionHistory,
    PublishSchedule,
    SimClock,
)


class FakeWall:
    """A wall clock that moves only when told."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_wall_clock_runs_the_simulation_at_time_scale():
    wall = FakeWall()
    clock = SimClock(time_scale=0.5, epoch=7.0, monotonic=wall)
    wall.t += 2.0
    assert clock.wall_target() == pytest.approx(1.0)
    assert clock.epoch == 7.0


def test_a_tick_too_far_behind_drops_time():
    clock = SimClock(1.0, 0.0, monotonic=FakeWall())
    h = 0.001
    assert clock.limit(0.5, 0.0, h) == (0.5, 0.0)  # within one tick's periods
    target, dropped = clock.limit(20.0, 0.0, h)
    assert target == pytest.approx(MAX_TICK_PERIODS * h)
    assert dropped == pytest.approx(20.0 - MAX_TICK_PERIODS * h)
    assert clock.offset == dropped  # the wall target is behind by as much from now on


def test_ros_time_sets_the_epoch_at_the_first_clock_and_when_it_goes_back():
    clock = SimClock(1.0, 0.0, monotonic=FakeWall())
    assert clock.follow(0.0, 0.0, 0.001) == (None, False)  # no /clock yet
    assert clock.ros_target(None) is None
    assert clock.follow(50.0, 0.2, 0.001) == (50.0, True)
    assert clock.epoch == pytest.approx(49.8)
    assert clock.follow(50.5, 0.2, 0.001) == (50.5, False)
    assert clock.ros_target(50.5) == pytest.approx(0.7)
    clock.follow(10.0, 0.7, 0.001)  # a looped replay: count from it
    assert clock.epoch == pytest.approx(9.3)


def test_the_schedule_publishes_the_first_instant_after_each_time():
    schedule = PublishSchedule(rate=10.0)
    t = np.arange(0.0, 0.35, 0.025)
    rows = schedule.rows(t)
    assert t[rows] == pytest.approx([0.1, 0.2, 0.3])
    assert schedule.rows(np.arange(0.35, 0.45, 0.025)).tolist() == [2]  # 0.4 next
    assert schedule.rows(np.zeros(0)).size == 0


def test_a_start_within_tolerance_of_a_recent_position_is_accepted():
    wall = FakeWall()
    history = PositionHistory(span=2.0, monotonic=wall)
    names = ["a", "b"]
    history.add(np.array([0.0, 0.0]))
    wall.t += 1.0
    history.add(np.array([0.5, 0.0]))
    now = np.array([1.0, 0.0])
    offset, refused = history.start_gap(np.array([0.01, 0.0]), now, 0.05, names)
    assert offset == pytest.approx(0.99) and refused is None
    wall.t += 1.5  # the first position is older than the span now
    history.add(now)
    offset, refused = history.start_gap(np.array([0.01, 0.0]), now, 0.05, names)
    assert refused.startswith("its first point is 0.99 rad from the current position (a)")
    history.clear()
    assert history.nearest(np.array([0.9, 0.0]), now) == pytest.approx(0.1)
