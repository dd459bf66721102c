"""The control set's pad per sample for a warm re-solve (core/direct/set_pads.py, issue 47).

A Panda move of bench/warm_resolve.py's draw (its ninth case) whose answer at the default pad
leaves the set between the samples (a pad round, a second parametric solve, before): at
the pads read off the serving solution it is answered in one parametric solve, inside the
set between the samples (checked on a denser grid here), certified, ``T`` equal to IPOPT's
converged re-solve of the same NLP (the same pads) from the same point.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from skip_policy import missing

from tocontrol_ros.core.direct import sensitivity, set_pads
from tocontrol_ros.core.direct.limited import state_bounds
from tocontrol_ros.core.direct.tuning import PAD, SET_MARGIN, SET_PAD
from tocontrol_ros.core.planning.replan import replan_options, warm_replan
from tocontrol_ros.core.planning.solver import Planner, SolverOptions
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: bench/warm_resolve.py's ninth case: a start at rest, and its 2 cm move.
Q0 = np.array([-2.322888655562322, 0.19706239608557058, -0.3328259448009854,
               -1.1614344426403809, -1.1381496004301386, 2.338023461196815,
               2.1659394922939934])
TARGET = np.array([0.7122472435425258, 0.1573235024504635, 0.6900124355539173])
MOVED = np.array([0.7142042827438061, 0.17143719440683353, 0.6759777037458155])
#: The first bounded solve of a kind compiles its NLP: not a time to judge the solver on.
SLOW_OK = 600.0
#: The replans' options: warm alone, 24 uniform spans (the serving mesh).
SERVE = replan_options(SolverOptions(time_limit=SLOW_OK), 0.0, 24)


@pytest.fixture(scope="module")
def pad_case(robot_specs):
    """The default plan, its serving solution on the replans' 24 spans, the moved problem
    (the Panda as bench/warm_resolve.py loads it: the URDF's own gravity)."""
    if "panda" not in robot_specs:
        missing("the panda URDF of example-robot-data (pip install '.[test]')")
    spec = robot_specs["panda"]
    panda = load_robot(spec["source"], tip_link="panda_hand",
                       locked_joints=spec["kwargs"]["locked_joints"])
    planner = Planner(panda)
    limits = JointLimits.from_model(panda)
    problem = Problem(panda, joint_state(Q0, np.zeros(7)), point(TARGET), k=4.0,
                      limits=limits)
    base = planner.plan(problem, SolverOptions(time_limit=SLOW_OK))
    assert base.success, base.message
    serving = warm_replan(planner, problem, [base], SERVE)
    assert serving.success and serving.intervals == 24, serving.message
    moved = Problem(panda, problem.start, point(MOVED), k=4.0, limits=limits)
    return planner, serving, moved


def _peaks(traj, samples, points):
    """Independently of set_pads: the set's values at the samples and, on a grid of
    ``points`` times per interval between two samples, each interval's peak."""
    k = traj.law.k
    at = np.sum(np.abs(traj.control_at(samples * traj.T)) ** (2 * k), axis=1)
    frac = (np.arange(points) + 0.5) / points
    times = samples[:-1, None] + frac[None, :] * np.diff(samples)[:, None]
    inner = np.sum(np.abs(traj.control_at(times.ravel() * traj.T)) ** (2 * k), axis=1)
    return at, inner.reshape(len(samples) - 1, points).max(axis=1)


def test_the_pads_are_the_serving_solutions_bulges_between_samples(pad_case):
    """Each sample's pad is at least the default and at most the cap; where an interval's
    peak comes near the set's boundary, the pads at its ends hold twice its bulge above its
    samples (measured here on a finer grid, within what the two grids' peaks differ); far
    from the boundary, the default pad."""
    planner, serving, moved = pad_case
    flat = planner.flat(moved, serving.warm_state.breaks, warm="dual")
    samples = flat.samples
    pads = set_pads.row_pads(serving.trajectory, samples)
    assert pads.shape == samples.shape
    assert np.all(pads >= SET_PAD) and np.all(pads <= set_pads.ROW_PAD_CAP)
    assert np.sum(pads > SET_PAD) >= 4  # this serving solution bulges somewhere
    at, peak = _peaks(serving.trajectory, samples, 200)
    bulge = peak - np.maximum(at[:-1], at[1:])
    near = peak >= 1.0 - set_pads.ROW_PAD_NEAR + 1e-3
    need = np.minimum(set_pads.ROW_PAD_FACTOR * bulge, set_pads.ROW_PAD_CAP)
    held = np.minimum(pads[:-1], pads[1:])
    assert np.all(held[near] >= need[near] - 2e-4), np.max(need[near] - held[near])
    far = ~np.convolve(peak >= 1.0 - set_pads.ROW_PAD_NEAR - 1e-3, [1, 1]).astype(bool)
    assert np.all(pads[far] == SET_PAD)


def test_one_pad_for_all_and_one_per_sample_give_the_same_bounds(pad_case):
    planner, serving, moved = pad_case
    flat = planner.flat(moved, serving.warm_state.breaks, warm="dual")
    bounds = state_bounds(moved, PAD)
    one = flat.bounds(*bounds, 0.0123)
    each = flat.bounds(*bounds, np.full(len(flat.samples), 0.0123))
    for a, b in zip(one, each, strict=True):
        assert np.array_equal(a, b)


def test_a_pad_round_widens_only_the_intervals_that_leave_the_set(pad_case):
    """widened: the samples at the ends of an interval whose peak exceeds ``1 - margin``
    get the larger of their pads plus twice the excess; every other sample keeps its pad."""
    planner, serving, moved = pad_case
    flat = planner.flat(moved, serving.warm_state.breaks, warm="dual")
    samples = flat.samples
    traj = serving.trajectory
    _, peak = _peaks(traj, samples, 200)
    margin = 1.0 - float(np.quantile(peak, 0.9))  # the top tenth of the intervals exceed
    pads = set_pads.row_pads(traj, samples)
    wide = set_pads.widened(pads, traj, samples, margin)
    over = np.zeros(len(samples), bool)
    check = traj.set_values()
    where = np.searchsorted(samples, traj.set_fractions(32), side="right") - 1
    bad = np.unique(where[check > 1.0 - margin])
    over[bad] = over[bad + 1] = True
    assert np.any(over) and not np.all(over)
    assert np.array_equal(wide[~over], pads[~over])
    assert np.all(wide[over] > pads[over])
    assert np.array_equal(set_pads.widened(pads, traj, samples, SET_MARGIN), pads)


def test_the_move_is_answered_in_one_solve_at_the_serving_solutions_pads(pad_case,
                                                                        monkeypatch):
    """At the default pad this move's answer leaves the set between the samples and a pad
    round follows (a second parametric solve); at the row pads one parametric solve, inside
    the set between the samples (a grid four times finer than the planner's check),
    certified, T within 1e-6 of IPOPT converged on the same NLP from the same point, and
    not above the route before's (its pad is wider where no sample needs it)."""
    planner, serving, moved = pad_case
    ws = serving.warm_state
    res = planner.plan(moved, SERVE, warm_start=serving)
    text = " ".join(res.warnings)
    assert res.success and "(route: parametric)" in text, res.warnings
    assert "; pad " not in text, text
    assert res.certificate is not None and res.certificate.passed
    assert float(np.max(res.trajectory.set_values(128))) <= 1.0 - SET_MARGIN
    flat = planner.flat(moved, ws.breaks, warm="dual")
    pads = set_pads.row_pads(serving.trajectory, flat.samples)
    ref = flat.solve(moved.start.value, moved.target.value, moved.k, ws.T, ws.P,
                     *state_bounds(moved, PAD), set_pad=pads, lam_g0=ws.lam_g,
                     lam_x0=ws.lam_x)
    assert ref.success, ref.message
    assert abs(res.T / ref.T - 1.0) <= 1e-6, (res.T, ref.T)
    monkeypatch.setattr(set_pads, "ROW_PADS", False)
    before = planner.plan(moved, SERVE, warm_start=serving)
    told = " ".join(before.warnings)
    assert before.success and "(route: parametric)" in told and "; pad " in told, told
    assert res.T <= before.T * (1.0 + 1e-6), (res.T, before.T)
    ipopt = planner.plan(moved, replace(SERVE, warm_parametric=False), warm_start=serving)
    assert ipopt.success and abs(before.T / ipopt.T - 1.0) <= 1e-6


def test_the_dual_reset_takes_fewer_steps_to_the_same_answer(pad_case, monkeypatch):
    """The whole move's steps with the multipliers reset onto the barrier
    (``sensitivity.DUAL_RESET``) and with the dual step cut by the fraction to the boundary
    converge to the same KKT point (T to 1e-9, the control points to 1e-6 rad), the reset
    in no more Newton steps; the sub-moves' steps are not reset (one sub-move of two takes
    the same steps either way)."""
    planner, serving, moved = pad_case
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    pads = set_pads.row_pads(serving.trajectory, flat.samples)
    args = (flat, np.concatenate([ws.P.ravel(), [ws.T]]), ws.lam_g, ws.lam_x,
            moved.start.value, moved.target.value, moved.k, *state_bounds(moved, PAD), pads)
    runs = {}
    for reset in (True, False):
        monkeypatch.setattr(sensitivity, "DUAL_RESET", reset)
        runs[reset] = (sensitivity.sensitivity_solve(*args),
                       sensitivity.sensitivity_solve(*args, submoves=2))
    (new, out_new), (sub_new, _) = runs[True]
    (old, out_old), (sub_old, _) = runs[False]
    assert new.success and old.success, (new.message, old.message)
    assert abs(new.T / old.T - 1.0) <= 1e-9
    assert np.max(np.abs(new.P - old.P)) <= 1e-6
    assert out_new.steps <= out_old.steps
    assert sub_new.T == sub_old.T and np.array_equal(sub_new.P, sub_old.P)
