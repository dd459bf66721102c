"""The profile's two-core estimate (bench/profile_panda.py) on pieces whose answer is known.

The estimate shares each ``Compiled.map`` call's pieces between two processes from one
queue, the first free process taking the next piece, and keeps the rest of a plan serial;
the refinement without its level barrier chains each candidate's levels instead.
"""

import sys
from pathlib import Path

import pytest

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench.profile_panda import (  # noqa: E402
    STAGES,
    chained_makespan,
    makespan,
    two_core_path,
    unbarred_refinement,
)


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


def test_chained_makespan_starts_a_candidates_next_level_when_its_own_ends():
    # Candidate a: 1 s then 3 s; candidate b: 3 s then 1 s (T in -> T out per level).
    levels = [[(1.0, 0.50, 0.40, True), (3.0, 0.52, 0.45, True)],
              [(3.0, 0.40, 0.39, True), (1.0, 0.45, 0.44, True)]]
    assert sum(makespan([p[0] for p in level]) for level in levels) == 6.0  # the barrier
    assert chained_makespan(levels) == 4.0  # a: 0-1, 1-4; b: 0-3, 3-4
    assert chained_makespan(levels, processes=1) == 8.0
    assert chained_makespan([]) == 0.0


def test_chained_makespan_counts_a_discarded_level_only_when_speculative():
    # b stops after the first level without settling (a window left it behind): a race
    # without the barrier would have started its next level (2 s) and discarded it.
    levels = [[(1.0, 0.50, 0.40, True), (2.0, 0.52, 0.45, True)],
              [(2.0, 0.40, 0.39, True)]]
    assert chained_makespan(levels) == 3.0
    assert chained_makespan(levels, speculative=True) == 4.0
    assert chained_makespan(levels, processes=1, speculative=True) == 7.0
    # A candidate that settled (T moved by less than T_SETTLED) or failed starts nothing.
    settled = [[(1.0, 0.50, 0.40, True), (2.0, 0.45, 0.45, True)],
               [(2.0, 0.40, 0.39, True)]]
    assert chained_makespan(settled, speculative=True) == 3.0


def test_unbarred_refinement_takes_each_run_of_levels_as_one_race():
    def level(*pieces):
        return {"items": [p[0] for p in pieces], "links": [p[1:] for p in pieces],
                "first_solve": 0}
    groups = [{"items": [1.0, 1.0], "first_solve": 0},  # the guesses: not a refinement
              level((1.0, 0.50, 0.40, True), (3.0, 0.52, 0.45, True)),
              level((3.0, 0.40, 0.39, True), (1.0, 0.45, 0.44, True)),
              {"items": [], "first_solve": 0},  # something between two races
              level((2.0, 0.39, 0.38, True))]
    assert unbarred_refinement(groups) == (8.0, 6.0)
