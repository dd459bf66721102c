"""The stage-wise transcription (core/direct/stagewise*.py): closed form, and the Panda
re-integrated through its forward dynamics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.limited import PAD, state_bounds
from tocontrol_ros.core.direct.stagewise import StagewiseTranscription, inverse_dynamics
from tocontrol_ros.core.direct.stagewise_solve import StagewiseSolver
from tocontrol_ros.core.direct.stagewise_trajectory import StageTrajectory
from tocontrol_ros.core.direct.tuning import SET_PAD
from tocontrol_ros.core.robot.model import load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: One uniform rod (1 kg, 1 m) on a vertical axis: inertia 1/3 kg m^2 about the joint, no
#: friction, 10 N m: the double integrator qdd = 3 tau.
ONE_ROD = """<?xml version="1.0"?>
<robot name="rod"><link name="base_link"/>
  <joint name="j1" type="continuous"><parent link="base_link"/><child link="l1"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit effort="10" velocity="100.0"/><dynamics damping="0" friction="0.0"/></joint>
  <link name="l1"><inertial><origin xyz="0.5 0 0" rpy="0 0 0"/><mass value="1"/>
    <inertia ixx="0" ixy="0" ixz="0" iyy="0.0833333333333333"
     iyz="0" izz="0.0833333333333333"/></inertial></link>
  <joint name="tool_joint" type="fixed"><parent link="l1"/><child link="tool"/>
    <origin xyz="1 0 0" rpy="0 0 0"/></joint><link name="tool"/>
</robot>"""
PANDA_Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
PANDA_Q1 = np.array([0.9, 0.3, -0.4, -1.5, 0.5, 1.5, -0.2])


def _straight(tr: StagewiseTranscription, q0, q1, T):
    """A smoothstep joint path from q0 to q1 in T s, as the transcription's guess."""
    d = np.asarray(q1) - np.asarray(q0)

    def q(t):
        s = np.asarray(t)[:, None] / T
        return q0 + d * (3 * s ** 2 - 2 * s ** 3)

    def qd(t):
        s = np.asarray(t)[:, None] / T
        return d * (6 * s - 6 * s ** 2) / T

    def qdd(t):
        s = np.asarray(t)[:, None] / T
        return d * (6 - 12 * s) / T ** 2

    return tr.guess(T, q, qd, qdd)


@pytest.mark.parametrize("order", [1, 2])
def test_a_double_integrator_takes_the_bang_bang_time(order):
    """1 rad from rest to rest at |qdd| <= a: T = 2 sqrt(d / a), the set at its pad."""
    model = load_robot(ONE_ROD, task_axes=[0])
    d, k = 1.0, 4.0
    problem = Problem(model, joint_state([0.0], [0.0]), point([np.cos(d)]), k=k)
    lo, hi = state_bounds(problem, PAD)
    a = 10.0 * 3.0 * (1.0 - SET_PAD) ** (1.0 / (2 * k))
    N = 20
    tr = StagewiseTranscription(model, N, "state", order)
    S = StagewiseSolver(tr)
    r = S.solve([0.0, 0.0], [np.cos(d)], k, model.tau_max, lo, hi,
                _straight(tr, np.zeros(1), np.full(1, d), 1.0))
    assert r.success, r.message
    exact = 2.0 * np.sqrt(d / a)
    if order == 1:  # bang-bang with the switch on a node: exact on the mesh
        assert r.T == pytest.approx(exact, rel=1e-6)
        assert np.allclose(np.abs(r.qdd[:-1]), a, rtol=1e-5)
    else:  # a linear ramp between the arcs costs time, less on finer meshes
        assert exact < r.T < exact * 1.05
    assert r.q[-1, 0] == pytest.approx(d, abs=1e-7)


def _reintegrated(model, tr: StagewiseTranscription, w: np.ndarray, x0: np.ndarray):
    """The solution's torques (inverse dynamics of its polynomial, per interval) integrated
    through the model's forward dynamics from ``x0``; the end state."""
    T, X, U = tr.unpack(w)
    n, h = model.n, T / tr.N
    x = np.asarray(x0, dtype=float)
    for i in range(tr.N):
        def rhs(t, y, i=i):
            q, qd, qdd = tr.evaluate(w, np.array([i * h + min(t, h * (1 - 1e-12))]))
            tau = inverse_dynamics(model, q, qd, qdd)[0]
            return np.concatenate([y[n:], model.forward_dynamics(y[:n], y[n:], tau)])

        x = solve_ivp(rhs, (0.0, h), x, method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
    return x


@pytest.mark.slow
def test_a_panda_motion_holds_its_limits_and_reaches_the_target_when_reintegrated(panda):
    """From rest to a point with the URDF limits: the torques re-integrated reach the target
    at rest, positions and velocities within the padded limits and the torques inside the set
    on a fine sampling (after the pad is widened where the samples missed)."""
    model, k = panda, 4.0
    target = model.point(PANDA_Q1)
    problem = Problem(model, joint_state(PANDA_Q0), point(target), k=k)
    lo, hi = state_bounds(problem, PAD)
    tr = StagewiseTranscription(model, 20, "state", 1)
    S = StagewiseSolver(tr)
    scale = model.tau_max * problem.torque_scale
    x0 = np.concatenate([PANDA_Q0, np.zeros(model.n)])
    r = S.solve_within_set(x0, target, k, scale, lo, hi,
                           _straight(tr, PANDA_Q0, PANDA_Q1, 1.5))
    assert r.success, r.message
    assert r.set_max <= 1.0
    t = np.linspace(0.0, r.T, 4001)
    q, qd, _ = tr.evaluate(r.w, t)
    n = model.n
    assert np.all(q >= lo[:n] - 1e-9) and np.all(q <= hi[:n] + 1e-9)
    assert np.all(np.abs(qd) <= hi[n:] + 1e-9)
    assert np.max(np.abs(qd) / hi[n:]) > 0.999  # a velocity limit binds
    xT = _reintegrated(model, tr, r.w, x0)
    assert np.linalg.norm(model.point(xT[:n]) - target) < 1e-5
    assert np.max(np.abs(xT[n:])) < 1e-5
    # The project's certificate of a direct method's motion, through the adapter.
    cert = certify_open_loop(problem, StageTrajectory(tr, r.w, scale),
                             solver_residual=r.residual)
    assert cert.passed, [f"{i.name} {i.value:.3g}" for i in cert.failures]
