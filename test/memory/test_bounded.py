"""The memory with the bounded solve's warm state: the paper's arm with limits that bind.

With its velocity limits at 0.4 and 1 rad/s (as the benchmark's ``3R-limited``), the paper's
arm is solved by the bounded B-spline transcription (``method`` ``direct``), whose warm state
(mesh, control points, multipliers) is what a memory of a real arm (the Panda) holds. Stored,
read back and re-solved warm for a request 3 cm away: certified, and its T within 1e-3 of
the cold multistart's (the issue's bar), checked by an independent re-integration too.
"""

from __future__ import annotations

import numpy as np
import pytest
from limited_arm import MODEL, OPTIONS, problem

from tocontrol_ros.core import Planner
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.memory.codec import decode_warm
from tocontrol_ros.core.memory.recall import open_memory, recall, remember


def test_a_bounded_motion_is_stored_and_recalled(tmp_path):
    planner = Planner(MODEL)
    stored = planner.plan(problem([2.2, 1.5]), OPTIONS)
    assert stored.success and stored.method == "direct", stored.message
    assert isinstance(stored.warm_state, PathWarmState)
    with open_memory(tmp_path / "m.sqlite", stored.problem, create=True) as store:
        assert remember(store, stored, "test", 0.0)
        entry = store.get(int(store.keys()["id"][0]))
        state, _ = decode_warm(entry.warm_kind, entry.warm)
        np.testing.assert_array_equal(state.P, stored.warm_state.P)
        np.testing.assert_array_equal(state.breaks, stored.warm_state.breaks)
        np.testing.assert_array_equal(state.lam_g, stored.warm_state.lam_g)
        near = problem([2.22, 1.53])
        found = recall(planner, near, OPTIONS, store)
    assert found.hit and found.result is not None, found.messages
    res = found.result
    assert res.success and res.method == "direct" and res.certificate.passed
    cert = certify_open_loop(near, res.trajectory, res.certificate.options)
    assert cert.passed, cert.summary()
    cold = planner.plan(near, OPTIONS)
    assert cold.success
    assert res.T <= cold.T * (1 + 1e-3), (res.T, cold.T)
    assert res.T == pytest.approx(cold.T, rel=1e-3)
