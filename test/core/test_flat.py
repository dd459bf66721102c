"""The bounded B-spline transcription (core/flat.py): real arms within their URDF limits."""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import BSpline

from tocontrol_ros.core.checks.certificate import CertificateOptions, certify_open_loop
from tocontrol_ros.core.direct.bspline import basis, breakpoints
from tocontrol_ros.core.direct.collocation import DirectCollocation
from tocontrol_ros.core.direct.flat import _sample_functions
from tocontrol_ros.core.direct.flat_trajectory import refined_breaks
from tocontrol_ros.core.direct.limited import NEAR_MAX_ITER, PAD, SPANS, state_bounds
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: The issue's Panda state at rest, and the configuration whose hand point is the target.
PANDA_Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
PANDA_Q1 = np.array([0.9, 0.3, -0.4, -1.5, 0.5, 1.5, -0.2])
#: A first bounded solve compiles the per-sample functions of the model (tens of seconds on
#: a loaded machine): not a time the solver's budget should be judged on here.
SLOW_OK = 900.0
OPTIONS = SolverOptions(starts=4, candidates=1, time_limit=SLOW_OK)


# ----------------------------------------------------------------- the spline basis
def test_basis_sums_to_one_and_its_derivatives_match_differences():
    br = np.array([0.0, 0.1, 0.15, 0.5, 0.55, 1.0])
    s = np.linspace(0.0, 1.0, 101)
    _, b = basis(br, 3, s)
    assert np.allclose(b[:, 0].sum(axis=1), 1.0)
    assert np.allclose(b[:, 1].sum(axis=1), 0.0, atol=1e-9)
    coef = np.random.default_rng(3).normal(size=len(br) - 1 + 3)

    def path(x, order):
        span, bb = basis(br, 3, x)
        idx = span[:, None] + np.arange(4)[None, :]
        return np.sum(bb[:, order] * coef[idx], axis=1)

    x = np.array([0.05, 0.3, 0.7, 0.9])  # inside spans, away from the breakpoints
    h = 1e-6
    for order in (1, 2):
        fd = (path(x + h, order - 1) - path(x - h, order - 1)) / (2 * h)
        assert np.allclose(path(x, order), fd, rtol=1e-5, atol=1e-5)


def test_breakpoints_must_increase_from_zero_to_one():
    assert np.allclose(breakpoints(4), [0, 0.25, 0.5, 0.75, 1.0])
    with pytest.raises(ValueError, match="increase from 0 to 1"):
        breakpoints(np.array([0.0, 0.5, 0.4, 1.0]))


# ----------------------------------------------------------------- the per-sample functions
@pytest.mark.parametrize("robot", ["galicki", "panda"])
def test_sample_functions_are_the_derivatives_of_the_set(request, robot):
    """The structured gradient and Hessian equal CasADi's of the composite ``c(z)``."""
    model = request.getfixturevalue(robot)
    n, d1 = model.n, 4
    set_, set_grad, set_hess, _ = _sample_functions(model, 3)
    P, T, b = ca.SX.sym("P", n, d1), ca.SX.sym("T"), ca.SX.sym("b", 3, d1)
    k, scale = ca.SX.sym("k"), ca.SX.sym("scale", n)
    z = ca.vertcat(ca.vec(P), T)
    c = set_(P, T, b, k, scale)
    ref = ca.Function("ref", [P, T, b, k, scale],
                      [ca.gradient(c, z), ca.hessian(c, z)[0]])
    rng = np.random.default_rng(7)
    for _ in range(3):
        args = [rng.normal(size=(n, d1)), rng.uniform(0.3, 2.0), rng.normal(size=(3, d1)),
                4.0, model.tau_max * rng.uniform(0.02, 0.1)]
        mu = rng.uniform(0.5, 2.0)
        grad, hess = (np.array(v) for v in ref(*args))
        value, grad_s = set_grad(*args)
        assert float(value) == pytest.approx(float(set_(*args)), rel=1e-12)
        assert np.allclose(np.array(grad_s).ravel(), grad.ravel(),
                           rtol=1e-9, atol=1e-9 * np.max(np.abs(grad)))
        upper = np.array(set_hess(*args, mu)).ravel()
        dz = n * d1 + 1
        rows, cols = zip(*[(r, col) for col in range(dz) for r in range(col + 1)], strict=True)
        expected = mu * hess[list(rows), list(cols)]
        assert np.allclose(upper, expected, rtol=1e-9, atol=1e-9 * np.max(np.abs(expected)))


@pytest.mark.parametrize("robot", ["galicki", pytest.param("panda", marks=pytest.mark.slow)])
def test_approximate_hessians_leave_out_the_torques_curvature(request, robot):
    """``ggn`` is ``mu Ju^T diag(c'') Ju`` (u's Jacobian taken by CasADi from the torques);
    the exact Hessian less it is the torques' curvature weighted by ``mu c'(u)``, and
    ``id_linear`` less it is the same for the path's ``y(z)`` alone (the inverse dynamics
    linear): each term from its own graph, not from the library's."""
    model = request.getfixturevalue(robot)
    n, d1 = model.n, 4
    exact, gn_id, ggn = (_sample_functions(model, 3, kind)[2]
                         for kind in ("exact", "id_linear", "ggn"))
    flat_id = _sample_functions(model, 3, "ggn")[3]
    P, T, b = ca.SX.sym("P", n, d1), ca.SX.sym("T"), ca.SX.sym("b", 3, d1)
    z = ca.vertcat(ca.vec(P), T)
    y = ca.vertcat(ca.mtimes(P, b[0, :].T), ca.mtimes(P, b[1, :].T) / T,
                   ca.mtimes(P, b[2, :].T) / T ** 2)
    scale = ca.SX.sym("scale", n)
    u = flat_id(y[:n], y[n:2 * n], y[2 * n:], scale)
    wu, wy, ys = ca.SX.sym("wu", n), ca.SX.sym("wy", 3 * n), ca.SX.sym("y", 3 * n)
    u_y = ca.Function("u_y", [ys, scale], [ca.jacobian(
        flat_id(ys[:n], ys[n:2 * n], ys[2 * n:], scale), ys)])
    parts = ca.Function("parts", [P, T, b, scale, wu, wy], [
        u, ca.jacobian(u, z), u_y(y, scale), ca.hessian(ca.dot(wu, u), z)[0],
        ca.hessian(ca.dot(wy, y), z)[0]])
    rng = np.random.default_rng(11)
    dz = n * d1 + 1
    rows, cols = (list(v) for v in zip(*[(r, c) for c in range(dz) for r in range(c + 1)],
                                       strict=True))
    with pytest.raises(ValueError, match="`hessian` must be one of"):
        _sample_functions(model, 3, "bfgs")
    for _ in range(2):
        args = [rng.normal(size=(n, d1)), rng.uniform(0.3, 2.0), rng.normal(size=(3, d1)),
                4.0, model.tau_max * rng.uniform(0.02, 0.1)]
        mu = rng.uniform(0.5, 2.0)
        P0, T0, b0, k, sc = args
        u0 = np.array(flat_id(*(np.array(v).ravel() for v in ca.vertsplit(
            ca.Function("y", [P, T, b], [y])(P0, T0, b0), n)), sc)).ravel()
        w = mu * 2 * k * np.sign(u0) * np.abs(u0) ** (2 * k - 1)
        curv = mu * 2 * k * (2 * k - 1) * np.abs(u0) ** (2 * k - 2)
        _, jz, jyu, _, _ = (np.array(v) for v in parts(P0, T0, b0, sc, w, np.zeros(3 * n)))
        _, _, _, hu, hy = (np.array(v) for v in parts(P0, T0, b0, sc, w, jyu.T @ w))
        ref_ggn = (jz.T * curv) @ jz
        got = {name: np.array(f(*args, mu)).ravel()
               for name, f in (("exact", exact), ("id_linear", gn_id), ("ggn", ggn))}
        big = np.max(np.abs(got["exact"]))
        for name, ref in (("ggn", ref_ggn[rows, cols]),
                          ("exact", (ref_ggn + hu)[rows, cols]),
                          ("id_linear", (ref_ggn + hy)[rows, cols])):
            assert np.allclose(got[name], ref, rtol=1e-9, atol=1e-9 * big), name
        assert np.min(np.linalg.eigvalsh(ref_ggn)) >= -1e-9 * big  # the set is convex in u
        assert not np.allclose(got["exact"], got["id_linear"], rtol=1e-6, atol=1e-6 * big)


# ----------------------------------------------------------------- the Panda
@pytest.fixture(scope="module")
def panda_limited(panda):
    problem = Problem(panda, joint_state(PANDA_Q0), point(panda.point(PANDA_Q1)), k=4.0)
    return plan(problem, OPTIONS)


def test_panda_from_rest_keeps_its_urdf_limits(panda_limited):
    res = panda_limited
    assert res.success, res.message
    assert res.method == "direct"
    assert res.verification["position_limits"] <= 1e-6
    assert res.verification["velocity_limits"] <= 1e-6
    assert res.verification["point_error"] <= 1e-4
    lim = res.problem.limits
    fine = res.trajectory.evaluate(np.linspace(0.0, res.T, 8001))
    assert np.all(np.abs(fine.qd) <= lim.plan_velocity * (1 + 1e-9))
    assert np.all((fine.q >= lim.plan_lower) & (fine.q <= lim.plan_upper))
    assert np.max(np.sum(fine.u ** 8, axis=1)) <= 1 + 1e-9
    # The velocity limits bind (the unconstrained optimum runs 15-35 times over them).
    assert np.max(np.abs(fine.qd) / lim.plan_velocity) > 0.99
    # The spans were halved where the acceleration jumps.
    assert res.intervals > SPANS


@pytest.mark.slow  # 12 s loaded; the default run keeps the Panda's other flat-path checks
def test_panda_time_agrees_with_hermite_simpson_on_192_intervals(panda, panda_limited):
    """Another transcription of the same bounded problem, started from the solution."""
    res = panda_limited
    problem = res.problem
    N = 192
    dc = DirectCollocation(panda, N, "state", "point")
    s = res.trajectory.evaluate(np.linspace(0.0, res.T, N + 1))
    ref = dc.solve(problem.start.value, problem.target.value, 4.0, res.T,
                   np.hstack([s.q, s.qd]), np.clip(s.u, -1, 1),
                   x_bounds=state_bounds(problem, PAD))
    assert ref.success, ref.message
    assert abs(res.T - ref.T) <= 1e-3 * ref.T, (res.T, ref.T)


@pytest.mark.parametrize("stiff", [False, True], ids=["adams", "bdf"])
def test_open_loop_agrees_with_dop853(panda, panda_limited, stiff):
    """The certificate's re-integration (CVODES span by span: Adams, and BDF, its fallback)
    against scipy's DOP853 through the published torques and the model's state function:
    the same end state."""
    res = panda_limited
    traj = res.trajectory
    n = panda.n
    _, x_cvodes, ok = traj.open_loop(1e-10, 1e-11, stiff=stiff)
    assert ok
    f = panda.function("f")
    scale = res.problem.torque_scale

    def rhs(t, x):
        return np.array(f(x, traj.control(t) * scale)).ravel()

    # Span by span, as the torques' third derivative jumps at the breakpoints.
    x = traj.state(0.0)[0, :2 * n]
    for a, b in zip(traj.breaks[:-1] * res.T, traj.breaks[1:] * res.T, strict=True):
        sol = solve_ivp(rhs, (a, b), x, method="DOP853", rtol=1e-10, atol=1e-11)
        assert sol.success
        x = sol.y[:, -1]
    assert np.max(np.abs(x - x_cvodes[-1])) < 1e-5
    assert np.max(np.abs(x - traj.state(res.T)[0, :2 * n])) < 1e-5


def test_open_loop_in_one_buffered_call_is_the_span_by_span_integration(panda_limited):
    """The certificate's open loop (every span in one buffered call, the Taylor coefficients
    from the trajectory's own derivative splines) gives the states of CVODES span by span
    from Python with each derivative's spline made from the path: to the bit."""
    from tocontrol_ros.core.direct import flat_trajectory as ft

    traj = panda_limited.trajectory
    t, x, ok = traj.open_loop(1e-10, 1e-11)
    assert ok
    integ = ft._open_loop_integrator(traj._model, traj._degree, 1e-10, 1e-11)
    br, T, d1 = traj.breaks, traj.T, traj._degree + 1
    ds = np.diff(br)
    fact = np.array([np.prod(np.arange(1, i + 1)) for i in range(d1)], dtype=float)
    grid = np.linspace(0, 1, ft.OPEN_LOOP_POINTS + 1)[1:]
    spans = []
    for j in range(len(ds)):
        derivs = np.stack([traj._spl.derivative(i)(br[j]) if i else traj._spl(br[j])
                           for i in range(d1)], axis=1)
        spans.append((derivs * ds[j] ** np.arange(d1) / fact, ds[j] * T,
                      T * (br[j] + ds[j] * grid)))
    t_ref, x_ref, ok_ref = ft.integrate_segments(integ, traj.state(0.0)[0, :2 * traj.n],
                                                 spans)
    assert ok_ref
    assert np.array_equal(t, t_ref)
    assert np.array_equal(x, x_ref)


def test_certificate_fails_a_faster_or_displaced_motion(panda_limited):
    """The same path run 2 % faster leaves the control set and the velocity limits; the
    last control points moved by 1 mrad miss the target: each check can fail."""
    res = panda_limited
    traj = res.trajectory
    options = CertificateOptions()
    faster = replace(traj.result, T=0.98 * res.T)
    cert = certify_open_loop(res.problem, traj.with_result(faster), options)
    failed = {item.name for item in cert.failures}
    assert {"control_set", "velocity_limits"} <= failed, cert.summary()
    P = traj.result.P.copy()
    P[-2:] += 1e-3
    moved = replace(traj.result, P=P)
    cert = certify_open_loop(res.problem, traj.with_result(moved), options)
    assert "end_point" in {item.name for item in cert.failures}, cert.summary()


def test_an_open_loop_that_drifts_by_its_integrator_is_integrated_again_tighter(panda_limited):
    """The end items judged on the integration at ``rtol``, else once more at
    ``OPEN_LOOP_TIGHTER`` times it: an open loop whose end velocity error is the integrator's
    (here 1e7 times ``rtol``: 1e-3 rad/s at 1e-10, over the tolerance) passes at the tighter
    one, figure ``rtol`` saying which; a motion that misses its end fails at both."""
    from tocontrol_ros.core.checks import certificate

    res = panda_limited
    traj = res.trajectory
    n, calls = traj.n, []

    class Drifting:  # the motion, its open loop off by an integrator-like error
        def __init__(self, inner, drift=1e7):
            self.inner, self.drift = inner, drift

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def open_loop(self, rtol, atol):
            calls.append((rtol, atol))
            t, x, ok = self.inner.open_loop(rtol, atol)
            x = x.copy()
            x[-1, n:] += self.drift * rtol * 1.01
            return t, x, ok

    options = CertificateOptions()
    assert certificate.OPEN_LOOP_TIGHTER <= 1e-2
    cert = certify_open_loop(res.problem, Drifting(traj), options)
    assert cert.passed, cert.summary()
    tight = options.rtol * certificate.OPEN_LOOP_TIGHTER
    assert cert.figures["rtol"] == tight
    assert calls == [(options.rtol, options.atol),
                     (tight, options.atol * certificate.OPEN_LOOP_TIGHTER)]
    calls.clear()
    cert = certify_open_loop(res.problem, Drifting(traj, 0.0), options)  # one integration
    assert cert.passed and cert.figures["rtol"] == options.rtol and len(calls) == 1
    calls.clear()
    P = traj.result.P.copy()
    P[-2:] += 1e-3
    cert = certify_open_loop(res.problem, Drifting(traj.with_result(replace(traj.result, P=P))),
                             options)
    assert "end_point" in {item.name for item in cert.failures} and len(calls) == 2


def test_refined_breaks_keep_the_old_ones(panda_limited):
    traj = panda_limited.trajectory
    new = refined_breaks(traj)
    assert np.all(np.isin(traj.breaks, new))
    assert new[0] == 0.0 and new[-1] == 1.0 and np.all(np.diff(new) > 0)


def test_control_points_on_finer_breaks_keep_the_path_exactly(panda_limited):
    traj = panda_limited.trajectory
    new = refined_breaks(traj, threshold=0.0)  # every span halved
    P = traj.control_points_on(new)
    assert P.shape == (len(new) - 1 + 3, traj.n)
    finer = BSpline(np.concatenate([[0.0] * 3, new, [1.0] * 3]), P, 3)
    s = np.linspace(0.0, 1.0, 997)
    for order in range(3):  # positions, velocities, accelerations: the same torques
        old = traj._spl.derivative(order)(s) if order else traj._spl(s)
        got = finer.derivative(order)(s) if order else finer(s)
        assert np.max(np.abs(got - old)) <= 1e-9 * max(1.0, np.max(np.abs(old)))
    with pytest.raises(ValueError, match="own breakpoints"):
        traj.control_points_on(np.linspace(0.0, 1.0, 7))


def test_a_transcription_on_other_breakpoints_solves_as_one_built_for_them(panda_limited):
    """``on(breaks)`` (the solver built once per number of spans, the mesh a parameter)
    solves the refined mesh as a transcription built for those breakpoints: the same
    iterations, T and control points to rounding."""
    from tocontrol_ros.core.direct.flat import FlatTranscription

    res = panda_limited
    problem, traj = res.problem, res.trajectory
    breaks = refined_breaks(traj, threshold=0.0)[::2]  # another mesh, as many spans
    breaks[-1] = 1.0
    breaks = np.unique(np.concatenate([breaks, traj.breaks[:1]]))
    kinds = (problem.start.kind, problem.target.kind)
    built = FlatTranscription(problem.model, breaks, *kinds,
                              torque_scale=problem.torque_scale, warm=True)
    uniform = FlatTranscription(problem.model, len(breaks) - 1, *kinds,
                                torque_scale=problem.torque_scale, warm=True)
    view = uniform.on(breaks)
    assert np.array_equal(view.breaks, breaks) and view.solver is uniform.solver
    assert np.array_equal(uniform.breaks, np.linspace(0.0, 1.0, len(breaks)))
    values = (problem.start.value, problem.target.value, problem.k)
    bounds = state_bounds(problem, PAD)
    P0 = built.fit(res.T, *(lambda s: (s.t, s.q, s.qd))(traj.evaluate(
        np.linspace(0.0, res.T, 200))))
    a = built.solve(*values, res.T, P0, *bounds)
    b = view.solve(*values, res.T, P0, *bounds)
    assert a.success and b.success, (a.message, b.message)
    assert a.iterations == b.iterations
    assert b.T == pytest.approx(a.T, rel=1e-9)
    assert np.max(np.abs(b.P - a.P)) <= 1e-7
    with pytest.raises(ValueError, match="spans"):
        uniform.on(np.linspace(0.0, 1.0, len(breaks) + 1))
    # Views on breakpoints asked for before reuse their geometry (kept per transcription):
    # the same parameters as the first view's and the built transcription's, others not.
    par = built.parameters(*values)
    again, other = uniform.on(breaks.copy()), uniform.on(np.linspace(0.0, 1.0, len(breaks)))
    assert np.array_equal(again.parameters(*values), par)
    assert np.array_equal(view.parameters(*values), par)
    assert not np.array_equal(other.parameters(*values), par)
    assert np.array_equal(uniform.on(breaks).parameters(*values), par)
    # The samples (the clearance allowance's fade) are a view's own, its geometry cached.
    np.testing.assert_array_equal(uniform.on(breaks).samples, built.samples)
    assert not np.array_equal(built.samples, uniform.samples)


def test_refined_meshes_are_built_once_per_number_of_spans(panda_limited, monkeypatch):
    """The planner's refined meshes have a multiple of SPAN_BUCKET spans and a second plan
    of the same motion builds no transcription."""
    from tocontrol_ros.core.direct import flat
    from tocontrol_ros.core.direct.limited import SPAN_BUCKET, _bucketed

    br = _bucketed(np.array([0.0, 0.1, 0.15, 0.5, 1.0]))
    assert len(br) - 1 == SPAN_BUCKET and np.all(np.isin([0.0, 0.1, 0.15, 0.5, 1.0], br))
    assert np.max(np.diff(br)) <= 0.25 + 1e-12  # the longest spans were the ones halved
    problem = panda_limited.problem
    options = SolverOptions(starts=1, candidates=1, verify=False, time_limit=SLOW_OK)
    plan(problem, options)
    built, spans = [], []
    init, solve = flat.FlatTranscription.__init__, flat.FlatTranscription.solve

    def counted(self, *args, **kwargs):
        built.append(args)
        init(self, *args, **kwargs)

    def recorded(self, *args, **kwargs):
        spans.append(self.spans)
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(flat.FlatTranscription, "__init__", counted)
    monkeypatch.setattr(flat.FlatTranscription, "solve", recorded)
    res = plan(problem, options)
    assert res.success, res.message
    assert not built
    assert len(spans) >= 2 and spans[0] == SPANS
    assert all(count % SPAN_BUCKET == 0 for count in spans[1:]), spans


def test_a_planner_keeps_the_most_recently_used_transcriptions(galicki, monkeypatch):
    from tocontrol_ros.core.planning import prepared, solver

    monkeypatch.setattr(prepared, "FLAT_CACHE", 2)
    planner = solver.Planner(galicki)
    problem = Problem(galicki, point(galicki.point(np.array([0.3, 0.4, 0.2]))),
                      point(galicki.point(np.array([1.0, -0.5, 0.6]))), k=4.0)
    first = planner.flat(problem, 4)
    planner.flat(problem, 5)
    assert planner.flat(problem, 4) is first  # used again: the most recent
    planner.flat(problem, 6)  # drops 5, the least recently used
    kept = sorted(key[4] for key in planner._direct if key[0] == "flat")
    assert kept == [4, 6]
    assert planner.flat(problem, 4) is first


def test_refined_meshes_stay_in_the_basin_of_the_coarse_solution(panda, monkeypatch):
    """Each refinement level lowers T (or keeps it): solved warm from the coarser path.

    A Panda problem (points, k = 4, its limits) whose first refinement, solved with IPOPT's
    defaults from a least-squares fit of the coarse path, rose 0.9 % in T (another basin)
    and whose next level left the solution (T 0.54 s) and crawled at 1.5 s per iteration.
    """
    from tocontrol_ros.core.direct import flat

    qa = np.array([0.223, -0.589, 0.124, -2.499, 0.002, 1.962, 0.622])
    qb = np.array([0.695, 0.384, 0.19, -1.811, 0.319, 1.769, 0.679])
    problem = Problem(panda, point(panda.point(qa)), point(panda.point(qb)), k=4.0)
    solves = []
    original = flat.FlatTranscription.solve

    def recorded(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        solves.append((self.spans, out.T, out.success))
        return out

    monkeypatch.setattr(flat.FlatTranscription, "solve", recorded)
    res = plan(problem, SolverOptions(starts=1, candidates=1, verify=False,
                                      time_limit=SLOW_OK))
    assert res.success and res.method == "direct", res.message
    assert len(solves) >= 3 and all(ok for _, _, ok in solves), solves
    for (_, before, _), (_, after, _) in zip(solves, solves[1:], strict=False):
        assert after <= before * (1 + 1e-4), solves
    assert res.T == pytest.approx(solves[-1][1], rel=1e-12)


def test_a_path_slowed_down_brings_its_torques_inside_the_set(panda_limited):
    """The certified plan run 1e-4 faster leaves the set between its samples; the same
    path slowed down by the least of STRETCHES that suffices is back inside it, meets the
    NLP's constraints, and costs at most 3e-4 of T."""
    from tocontrol_ros.core.direct.checked import stretched
    from tocontrol_ros.core.direct.flat import FlatTranscription
    from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL, SET_MARGIN, STRETCHES

    res = panda_limited
    problem, traj = res.problem, res.trajectory
    fast = replace(traj.result, T=res.T * (1 - 1e-4))
    fast_traj = traj.with_result(fast)
    assert np.max(fast_traj.set_values()) > 1.0 - SET_MARGIN  # the premise
    flat = FlatTranscription(problem.model, traj.breaks, problem.start.kind, problem.target.kind,
                             torque_scale=problem.torque_scale)
    values = (problem.start.value, problem.target.value, problem.k)
    bounds = state_bounds(problem, PAD)
    out, slower = stretched(flat, fast, fast_traj, values, bounds)
    assert fast.T < out.T <= fast.T * (1 + STRETCHES[-1])
    assert np.array_equal(out.P, fast.P) and slower.T == out.T
    assert np.max(slower.set_values()) <= 1.0 - SET_MARGIN
    assert out.residual <= RESIDUAL_TOL
    assert out.residual == flat.residual(*values, out.T, out.P, *bounds)
    # Much faster, no stretch in STRETCHES suffices: None (the pad re-solves take over).
    faster = replace(traj.result, T=res.T * 0.98)
    assert stretched(flat, faster, traj.with_result(faster), values, bounds) is None
    # The stretches checked in one call: the same set values to the bit as one by one,
    # so the same stretch is chosen (the least that suffices, checked above).
    durations = [fast.T * (1.0 + e) for e in STRETCHES]
    together = fast_traj.slower_set_values(durations)
    one_by_one = [fast_traj.with_result(replace(fast, T=T)).set_values() for T in durations]
    assert together.shape == (len(STRETCHES), len(one_by_one[0]))
    assert np.array_equal(together, np.array(one_by_one))
    first_inside = next(T for T, v in zip(durations, one_by_one, strict=True)
                        if np.max(v) <= 1.0 - SET_MARGIN
                        and flat.residual(*values, T, fast.P, *bounds) <= RESIDUAL_TOL)
    assert out.T == first_inside


def _plan_recording_pad_solves(problem: Problem, options: SolverOptions) -> tuple:
    """``plan(problem, options)`` and its re-solves with a widened set pad, each as
    ``(spans, warm, FlatResult)``."""
    from tocontrol_ros.core.direct import flat

    padded = []
    original = flat.FlatTranscription.solve

    def recorded(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        if kwargs.get("set_pad", flat.SET_PAD) > flat.SET_PAD:
            padded.append((self.spans, self.warm, out))
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(flat.FlatTranscription, "solve", recorded)
        res = plan(problem, options)
    return res, padded


def test_torques_between_samples_are_brought_inside_the_set(panda):
    """Case 34 of bench/limits.py's Panda: the refined solution's torques leave the set
    between its samples by 1.7e-3; the re-solves with a wider pad, from the warm start of
    the refined mesh, all failed and the plan failed its certificate. The path is now
    slowed down first (``checked.stretched``), and a re-solve with a wider pad, if one is still
    needed, starts its barrier higher (``warm="resume"``): the plan is certified."""

    q0 = np.array([-0.5338229825970606, 0.30773567715355116, 0.7863894957580588,
                   -1.2204077330213567, -0.8281207701729179, 1.6282500082433669,
                   -2.552027336517661])
    target = np.array([0.5091020144428229, 0.23647708130297732, 0.14495267618112728])
    from tocontrol_ros.core.direct import limited

    problem = Problem(panda, joint_state(q0, np.zeros(7)), point(target), k=4.0)
    stretched = []
    real_stretched = limited.stretched

    def recorded(*args, **kwargs):
        out = real_stretched(*args, **kwargs)
        stretched.append(out is not None)
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(limited, "stretched", recorded)
        res, padded = _plan_recording_pad_solves(problem, replace(OPTIONS, starts=4,
                                                                  candidates=1))
    assert res.success, res.message
    assert res.certificate.passed and res.method == "direct"
    # Here the slowed-down path suffices (the solver is deterministic): no re-solve with a
    # wider pad. (That those start from the higher barrier, warm="resume", and converge is
    # test_a_moving_start_pads_its_set_without_crawling's case.)
    assert True in stretched, stretched
    assert padded == [], [(spans, warm, out.success) for spans, warm, out in padded]


# A Panda plan with the default 16 starts (half a minute under load): with the slow tests.
# The default run keeps a set's pad widened on a moving start, a resumed re-solve (made to
# fail) and the one from the default start after it
# (test_a_failed_resumed_pad_solve_is_tried_from_the_default_start). Here (session 36) this
# plan's one padded re-solve, resumed at 96 spans, converged (73 iterations), with 16
# starts as with 4.
@pytest.mark.slow
def test_a_moving_start_pads_its_set_without_crawling(panda):
    """Case 2 of bench/optimum_panda.py (a Panda joint state moving at up to 0.57 rad/s, to
    a point): the path cannot be slowed down (its start velocity is given), so the set's
    pad is widened on refined meshes of 96 and 112 spans. From IPOPT's default start those
    re-solves began with the set's value at 1e10 and crawled (0.5 s per iteration, stopped
    at their 5 s cap, 33 s of a 40 s plan); from the higher barrier of ``warm="resume"``
    they converge, and the one from the default start (``warm="restart"``) that follows a
    failed one stops at its work limit instead of crawling (its regularisation capped)."""

    q0 = np.array([1.9268194592204666, 0.2726961563769517, 2.4945844444649157,
                   -2.4758281071942108, 1.3860301854540757, 3.0090742029781934,
                   0.6549474875532748])
    qd0 = np.array([-0.25592801466175397, -0.47654804271104534, -0.02735942550538036,
                    0.2960193805721647, 0.5724326688463768, -0.4751628495257425,
                    -0.03227972939634192])
    target = np.array([0.4604369079400326, -0.5986279880560181, 0.2576997629737329])
    problem = Problem(panda, joint_state(q0, qd0), point(target), k=4.0)
    res, padded = _plan_recording_pad_solves(problem, SolverOptions(time_limit=SLOW_OK))
    assert res.success and res.certificate.passed, res.message
    assert padded, "the premise: the set's pad is widened"
    # The resumed re-solves converge (here after one that fails at 96 spans, then one from
    # the default start stopped at its work limit); none crawls past it.
    assert any(warm == "resume" and out.success for _, warm, out in padded), padded
    assert all(out.success or out.iterations <= NEAR_MAX_ITER for _, _, out in padded), padded


def test_a_failed_resumed_pad_solve_is_tried_from_the_default_start(panda):
    """Case 29 of bench/limits.py's Panda (a joint state moving at up to 0.61 rad/s): its
    set's pad is widened. In the benchmark (on the machine of the time) the resumed re-solves
    with a wider pad failed (Error_In_Step_Computation) and the plan failed its certificate
    (control set 5e-4 over); a failed resumed re-solve is now tried from IPOPT's default
    start, and the plan is certified. Whether the resumed re-solve fails of itself depends
    on the CPU's last bits (it converges on some), so here it is made to fail."""
    from tocontrol_ros.core.direct import flat

    q0 = np.array([2.060047545209286, 0.03540634871715286, -1.4304923464752393,
                   -2.7567648347898004, -1.1248762997545216, 2.49681585764533,
                   -1.276495966667083])
    qd0 = np.array([0.6076981433501105, -0.24188417318093552, 0.40098709030160384,
                    0.45675917483722384, -0.127518733422558, -0.06849733678296112,
                    0.04908453210717684])
    target = np.array([-0.08358199286036902, 0.565856099938681, 0.5908179553312848])
    problem = Problem(panda, joint_state(q0, qd0), point(target), k=4.0)
    original = flat.FlatTranscription.solve

    def resumed_fails(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        if self.warm == "resume" and kwargs.get("set_pad", flat.SET_PAD) > flat.SET_PAD:
            return replace(out, success=False, message="Error_In_Step_Computation (made to)")
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(flat.FlatTranscription, "solve", resumed_fails)
        # One start: the re-solves this test is about come after any start's solve (4 starts
        # cost three times as long for the same checks).
        res, padded = _plan_recording_pad_solves(problem, replace(OPTIONS, starts=1))
    assert res.success and res.certificate.passed, res.message
    solves = [(warm, out.success) for _, warm, out in padded]
    # A resumed re-solve failed; then one from the default start succeeded.
    assert ("resume", False) in solves, solves
    assert ("restart", True) in solves, solves
    assert solves.index(("resume", False)) < solves.index(("restart", True)), solves


def test_a_uniform_solve_at_its_iteration_limit_is_finished_warm(ur5):
    """Case 40 of bench/limits.py's UR5 (4 starts, one basin): in the benchmark the
    uniform-mesh solve stopped at its 300 iterations at the solution's T (residual 1e-5)
    and the plan was LIMITS_INFEASIBLE. Here the cold solve is stopped at 15 iterations;
    continued warm from where it stopped, the plan converges and is certified."""
    from tocontrol_ros.core.direct import flat
    from tocontrol_ros.core.planning import solver

    q0 = np.array([-0.7974811845879118, -5.534415029278804, 0.1507150029737384,
                   4.834252918102076, 1.5310195967278124, 2.554346643521837])
    target = np.array([0.23567566147669725, -0.45870454611599043, -0.4348003926129555])
    problem = Problem(ur5, joint_state(q0, np.zeros(6)), point(target), k=4.0)
    solves = []
    init, solve = flat.FlatTranscription.__init__, flat.FlatTranscription.solve

    def short(self, *args, warm=False, **kwargs):
        init(self, *args, warm=warm, **{**kwargs, "max_iter": 300 if warm else 15})

    def recorded(self, *args, **kwargs):
        out = solve(self, *args, **kwargs)
        solves.append((self.spans, self.warm, out.message))
        return out

    plan(problem, replace(OPTIONS, starts=1, candidates=1, verify=False))  # the planner
    planner = solver._PLANNERS[id(ur5)]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(flat.FlatTranscription, "__init__", short)
        mp.setattr(flat.FlatTranscription, "solve", recorded)
        mp.setattr(planner, "_direct", {key: value for key, value in planner._direct.items()
                                        if key[0] != "flat"})
        res = plan(problem, replace(OPTIONS, starts=1, candidates=1))
    assert len(solves) >= 2 and solves[0] == (SPANS, False, "Maximum_Iterations_Exceeded"), \
        solves
    assert solves[1] == (SPANS, True, "Solve_Succeeded"), solves
    assert res.success and res.certificate.passed, res.message


@pytest.mark.slow
def test_panda_point_to_point_keeps_its_limits(panda):
    problem = Problem(panda, point(panda.point(PANDA_Q0)), point(panda.point(PANDA_Q1)), k=4.0)
    res = plan(problem, OPTIONS)
    assert res.success, res.message
    assert res.method == "direct"
    assert max(res.verification["position_limits"], res.verification["velocity_limits"]) <= 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("robot,q0,q1", [
    ("ur5", [0.3, -1.2, 1.4, -1.0, 1.2, 0.4], [1.4, -0.8, 0.9, -1.6, 0.7, -0.5]),
    ("xarm7", [0.2, 0.1, -0.3, 1.2, 0.2, 0.8, 0.0], [1.1, 0.5, 0.4, 1.8, -0.4, 1.2, 0.6]),
])
def test_other_arms_from_rest_keep_their_limits(request, robot, q0, q1):
    model = request.getfixturevalue(robot)
    problem = Problem(model, joint_state(np.array(q0)), point(model.point(np.array(q1))),
                      k=4.0)
    res = plan(problem, OPTIONS)
    assert res.success, res.message
    assert max(res.verification["position_limits"], res.verification["velocity_limits"]) <= 1e-6


@pytest.mark.slow
def test_leaving_candidates_behind_keeps_the_best_motion(panda, monkeypatch):
    """The race ends on the T of refining every candidate to the end; a window leaves some.

    The Panda point to point of bench/scaling.py, 16 starts and 6 candidates: three
    distinct candidates within 2 % after the uniform mesh, within 0.3 % of each other.
    """
    from tocontrol_ros.core.direct import flat
    from tocontrol_ros.core.direct import limited as lim

    a = panda.point(np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]))
    b = panda.point(np.array([0.8, 0.2, 0.3, -1.6, 0.2, 1.8, 0.5]))
    problem = Problem(panda, point(a), point(b), k=4.0)
    options = SolverOptions(starts=16, candidates=6, verify=False, time_limit=600.0)
    solves = []
    original = flat.FlatTranscription.solve

    def counted(self, *args, **kwargs):
        solves.append(len(self.breaks))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(flat.FlatTranscription, "solve", counted)
    runs = {}
    for name, windows in [("default", lim.LEVEL_WINDOWS), ("none", (np.inf,)),
                          ("narrow", (1e-4,))]:
        monkeypatch.setattr(lim, "LEVEL_WINDOWS", windows)
        solves.clear()
        res = plan(problem, options)
        assert res.success and res.method == "direct", (name, res.message)
        runs[name] = (res.T, len(solves))
    assert runs["default"][0] == pytest.approx(runs["none"][0], rel=1e-4)
    # Narrow: only the best after the first level goes on (fewer solves), T still near.
    assert runs["narrow"][1] < runs["none"][1]
    assert runs["narrow"][0] == pytest.approx(runs["none"][0], rel=2e-3)


def test_mapped_controls_are_kept_for_the_most_recent_counts(panda):
    """The buffered maps of the inverse dynamics (one per number of times) are reused for
    a count asked for again, equal the map called with DM, and only the MAPPED_KEEP most
    recently used are kept (sampled motions have any length: no growth without bound)."""
    import casadi as ca

    from tocontrol_ros.core.direct import flat_trajectory as ft

    q, qd, qdd, sc = (ca.SX.sym(name, 2) for name in ("q", "qd", "qdd", "scale"))
    fun = ca.Function("toy_id", [q, qd, qdd, sc], [(ca.sin(q) * qd + qdd) / sc])
    rng = np.random.default_rng(3)
    args = [rng.normal(size=(2, 5)) for _ in range(3)] + [np.array([2.0, 4.0])]
    first = ft.mapped_controls(panda, fun, 5)
    np.testing.assert_array_equal(first(*args)[0], np.array(fun.map(5)(*args)))
    assert ft.mapped_controls(panda, fun, 5) is first
    for count in range(6, 6 + ft.MAPPED_KEEP):
        ft.mapped_controls(panda, fun, count)
    again = ft.mapped_controls(panda, fun, 5)
    assert again is not first  # evicted, made again: the same values
    np.testing.assert_array_equal(again(*args)[0], first(*args)[0])
    assert ft.mapped_controls(panda, fun, 6 + ft.MAPPED_KEEP - 1) is \
        ft.mapped_controls(panda, fun, 6 + ft.MAPPED_KEEP - 1)
