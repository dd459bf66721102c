"""The refinement's clearance rows as an active set (issue 51, ``core/direct/active_rows.py``).

A Panda move past a ball on a coarse mesh: the NLP with the clearance rows of the samples
near the ball only, solved from the full NLP's solution, gives that solution again (the
same ``T``, every row of the full NLP held, the multipliers mapped to the full rows); a set
that leaves out a row the solution needs is refused (the caller then solves the full NLP).
"""

from __future__ import annotations

import numpy as np
import pytest
from skip_policy import panda_srdf, panda_urdf

coal = pytest.importorskip("coal")

from tocontrol_ros.core.direct import active_rows  # noqa: E402
from tocontrol_ros.core.direct.active_rows import active_rows_solve  # noqa: E402
from tocontrol_ros.core.direct.limited import PAD, state_bounds  # noqa: E402
from tocontrol_ros.core.geometry.collision import collision_model  # noqa: E402
from tocontrol_ros.core.geometry.scene import scene_from_dict  # noqa: E402
from tocontrol_ros.core.planning.solver import Planner  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

LOCKED = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
Q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
Q1 = np.array([1.2, -0.2, 0.0, -1.8, 0.0, 1.6, 0.8])
SPANS = 10


@pytest.fixture(scope="module")
def solved():
    """The full NLP on SPANS spans solved from the straight joint path; its problem."""
    urdf = panda_urdf()
    model = load_robot(urdf, tip_link="panda_hand", locked_joints=LOCKED)
    mid = model.point(0.5 * (Q0 + Q1))
    ball = scene_from_dict({"obstacles": [{"name": "ball", "type": "sphere", "radius": 0.04,
                                           "position": [float(mid[0]), float(mid[1]),
                                                        float(mid[2]) + 0.12]}]})
    col = collision_model(model, urdf, panda_srdf()).with_scene(ball)
    problem = Problem(model, joint_state(Q0), point(model.point(Q1)),
                      limits=JointLimits.from_model(model), collision=col)
    flat = Planner(model).flat(problem, SPANS)
    values = (problem.start.value, problem.target.value, problem.k)
    bounds = state_bounds(problem, PAD)
    t = np.linspace(0.0, 1.5, 50)
    s = 0.5 - 0.5 * np.cos(np.pi * t / 1.5)
    q = Q0 + s[:, None] * (Q1 - Q0)
    qd = (0.5 * np.pi / 1.5 * np.sin(np.pi * t / 1.5))[:, None] * (Q1 - Q0)
    full = flat.solve(*values, 1.5, flat.fit(1.5, t, q, qd), *bounds)
    assert full.success, full.message
    return flat, values, bounds, full


def test_the_near_rows_alone_give_the_full_nlps_solution(solved):
    flat, values, bounds, full = solved
    slack = np.min(flat.clearance_slack(*values, full.T, full.P), axis=1)
    assert slack.min() < 1e-6  # the ball binds somewhere: a row is active
    assert np.any(slack >= active_rows.ROW_BAND)  # and some samples are far from it
    out = active_rows_solve(flat, values, full.T, full.P, bounds)
    assert out is not None and out.success
    assert abs(out.T - full.T) <= 1e-6 * full.T, (out.T, full.T)
    assert len(out.lam_g) == flat.rows
    assert out.residual <= 1e-6
    assert flat.residual(*values, out.T, out.P, *bounds) <= 1e-6
    assert np.min(flat.clearance_slack(*values, out.T, out.P)) >= -1e-6
    # the rows of the samples left out have no multiplier (inactive)
    far = np.flatnonzero(slack >= active_rows.ROW_BAND)
    lam = out.lam_g[flat.rows - len(flat.samples) * len(flat.clearance.groups()):]
    assert np.all(lam.reshape(len(flat.samples), -1)[far] == 0.0)


def test_a_set_that_leaves_out_a_needed_row_is_refused(solved, monkeypatch):
    """With only the closest sample's rows kept, the smaller NLP's optimum cuts the ball."""
    flat, values, bounds, full = solved
    slack = np.min(flat.clearance_slack(*values, full.T, full.P), axis=1)
    one = flat.with_clearance_samples([int(np.argmin(slack))])
    alone = one.solve(*values, full.T, full.P, *bounds)
    assert alone.success and alone.T < full.T * (1 - 1e-4)
    assert np.min(flat.clearance_slack(*values, alone.T, alone.P)) < 0.0
    monkeypatch.setattr(active_rows, "ROW_BAND", -1.0)  # keeps the closest sample alone
    assert active_rows_solve(flat, values, full.T, full.P, bounds) is None
