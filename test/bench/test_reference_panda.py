"""The seeds of the Panda's independent reference (bench/reference_panda.py).

Its seeds must lie on the start and target points and inside the padded bounds that the
peer's NLP enforces, spread over the self-motion manifold (not one configuration found
again and again), and a joint-state start must stay at its state.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench import reference_panda as rp  # noqa: E402
from bench.limits import draw_cases  # noqa: E402
from tocontrol_ros.core import Problem  # noqa: E402
from tocontrol_ros.core.direct.limited import state_bounds  # noqa: E402
from tocontrol_ros.core.direct.tuning import PAD  # noqa: E402
from tocontrol_ros.core.types.problem import joint_state, point  # noqa: E402


def test_seeds_reach_both_points_inside_the_bounds_and_spread(panda):
    model, limits = panda
    q0, _, target = draw_cases(model, limits, 1, seed=rp.SEED)[0]
    problem = Problem(model, point(model.point(q0)), point(target), k=rp.K, limits=limits)
    lower, upper = state_bounds(problem, PAD)
    pairs = rp.seed_configurations(problem, 6, seed=1)
    for qa, qb in pairs:
        np.testing.assert_allclose(model.point(qa), problem.start.value, atol=1e-9)
        np.testing.assert_allclose(model.point(qb), target, atol=1e-9)
        for q in (qa, qb):
            assert np.all(q >= lower[:model.n]) and np.all(q <= upper[:model.n])
    ends = np.array([qb for _, qb in pairs])
    gaps = np.abs(ends[:, None] - ends[None]).max(axis=2)[np.triu_indices(len(ends), 1)]
    assert gaps.min() > 0.1  # rad: distinct self-motion samples


def test_joint_state_start_is_kept_and_an_unreachable_point_raises(panda):
    model, limits = panda
    q0, _, target = draw_cases(model, limits, 1, seed=rp.SEED)[0]
    qd0 = 0.1 * limits.velocity
    problem = Problem(model, joint_state(q0, qd0), point(target), k=rp.K, limits=limits)
    for qa, _ in rp.seed_configurations(problem, 2, seed=2):
        np.testing.assert_array_equal(qa, q0)
    lower, upper = state_bounds(problem, PAD)
    with pytest.raises(RuntimeError, match="reaches"):
        rp.random_ik(model, np.array([5.0, 0.0, 0.0]), lower[:model.n], upper[:model.n],
                     np.random.default_rng(0), tries=2)
