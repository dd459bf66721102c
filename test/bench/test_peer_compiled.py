"""The benchmark's direct-collocation peer (bench/peer_compiled.py) checked on its own.

Not compiled here (CasADi's virtual machine evaluates the same NLP): one Panda case from a
moving joint state, 50 intervals. Its torques, re-integrated through the model's numeric
forward dynamics, must bring the tip to the target and the arm to rest, and over one
interval from its own state reach its next one; its solution must keep the padded limits at
its collocation points.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one
# (test/packaging/test_install_layout.py checks that).
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench import peer_compiled as pc  # noqa: E402
from bench.limits import draw_cases  # noqa: E402
from tocontrol_ros.core import Problem, SolverOptions  # noqa: E402
from tocontrol_ros.core.direct.limited import state_bounds  # noqa: E402
from tocontrol_ros.core.direct.tuning import PAD  # noqa: E402
from tocontrol_ros.core.types.problem import joint_state, point  # noqa: E402


def test_peer_reaches_the_target_through_the_forward_dynamics(panda):
    model, limits = panda
    q0, qd0, target = draw_cases(model, limits, 2, seed=pc.SEED)[1]
    assert np.any(qd0 != 0)
    problem = Problem(model, joint_state(q0, qd0), point(target), k=pc.K, limits=limits)
    bounds = state_bounds(problem, PAD)
    peer = pc.Peer(model, 50, "state", pc.K, problem.torque_scale)
    T, z = pc.guess(model, problem, pc.seed_pairs(problem, SolverOptions())[0], 50)
    sol = peer.solve(problem.start.value, target, *bounds, T, z)
    assert sol.success, sol.status
    np.testing.assert_allclose(np.hstack([sol.q[0], sol.qd[0]]), problem.start.value,
                               atol=1e-8)
    result = pc.check(model, problem, sol, bounds)
    # The torques are only interpolated between collocation points: on 50 intervals the
    # re-integration drifts by about a millimetre and a few hundredths of a rad/s.
    assert result["end"] < 3e-3  # m
    assert result["speed"] < 0.15  # rad/s
    assert result["bounds"] < 1e-7
    assert result["q_step"] < 1e-3  # rad, one interval from the solution's own state


# Two more solves of the peer (half a minute under load): with the slow tests, as the
# benchmark option it checks (``between``). The default run keeps the peer's solve of the same
# case re-integrated to the target (test_peer_reaches_the_target_through_the_forward_dynamics).
@pytest.mark.slow
def test_speeds_bounded_between_the_points_keep_the_limits_when_re_integrated(panda):
    """With ``between``, the peer (the Panda's reference) keeps the velocity limits between
    its collocation points too: its torques re-integrated over each interval stay within
    them (bounded at the points only, this case passes a limit by about a third there)."""
    model, limits = panda
    q0, qd0, target = draw_cases(model, limits, 2, seed=pc.SEED)[1]
    problem = Problem(model, joint_state(q0, qd0), point(target), k=pc.K, limits=limits)
    bounds = state_bounds(problem, PAD)
    T, z = pc.guess(model, problem, pc.seed_pairs(problem, SolverOptions())[0], 50)
    assert pc.between_fractions(7) == [1 / 8, 2 / 8, 3 / 8, 5 / 8, 6 / 8, 7 / 8]
    results = {}
    for between in (0, 7):
        peer = pc.Peer(model, 50, "state", pc.K, problem.torque_scale, between=between)
        sol = peer.solve(problem.start.value, target, *bounds, T, z)
        assert sol.success, sol.status
        results[between] = (sol.T, pc.check(model, problem, sol, bounds))
    assert results[0][1]["velocity"] > 0.1
    assert results[7][1]["velocity"] < 0.01
    assert results[7][1]["bounds"] < 1e-7
    # Bounding more can only slow the motion down (the same basin here).
    assert results[0][0] <= results[7][0] < 1.01 * results[0][0]
