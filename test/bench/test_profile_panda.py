"""The profile's two-core estimate (bench/profile_panda.py) on pieces whose answer is known.

The estimate shares each ``Compiled.map`` call's pieces between two processes from one
queue, the first free process taking the next piece, and keeps the rest of a plan serial.
"""

import sys
from pathlib import Path

import pytest

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench.profile_panda import STAGES, makespan, two_core_path  # noqa: E402


def test_makespan_takes_pieces_in_order_from_one_queue():
    assert makespan([]) == 0.0
    assert makespan([3.0]) == 3.0
    # Two equal pieces side by side; a third waits for the first free process.
    assert makespan([1.0, 1.0, 1.0]) == 2.0
    # In order, not re-sorted: 4 goes to the process that finished 1 first (1 + 4 = 5),
    # where the longest-first order would give 4.
    assert makespan([1.0, 2.0, 4.0]) == 5.0
    assert makespan([1.0, 2.0, 4.0], processes=3) == 4.0
    assert makespan([1.0, 2.0, 4.0], processes=1) == 7.0


def test_two_core_path_keeps_the_rest_serial_and_attributes_groups_by_first_solve():
    solves = [{"stage": STAGES[0]}, {"stage": STAGES[0]}, {"stage": STAGES[1]},
              {"stage": STAGES[2]}]
    groups = [{"items": [1.0, 1.0, 1.0, 1.0], "first_solve": 0},  # the guesses
              {"items": [2.0, 1.0], "first_solve": 2},             # two uniform solves
              {"items": [0.5], "first_solve": 3},                  # one refinement
              {"items": [], "first_solve": 4}]                     # nothing shared
    path = two_core_path(11.0, groups, solves)
    assert path[STAGES[0]] == (4.0, 2.0)
    assert path[STAGES[1]] == (3.0, 2.0)
    assert path[STAGES[2]] == (0.5, 0.5)
    assert path["not shared"] == pytest.approx((3.5, 3.5))
    # One process: the estimate is the plan's own time.
    one = two_core_path(11.0, groups, solves, processes=1)
    assert sum(v[1] for v in one.values()) == pytest.approx(11.0)
    assert sum(v[1] for v in path.values()) == pytest.approx(8.0)
