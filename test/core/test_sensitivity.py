"""The parametric warm re-solve of the bounded B-spline solve (issue 47).

A converged bounded solution and its multipliers, carried to a moved target by Newton steps
on the barrier KKT system (core/direct/sensitivity.py), checked against IPOPT converged on
the same NLP from the same point (a second method), the KKT residuals at the result, and
the certificate every plan passes; where it does not converge within its work budget the
plan falls back to IPOPT and says why.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import tocontrol_ros.core.direct.sensitivity as sensitivity
from tocontrol_ros.core.direct.limited import state_bounds
from tocontrol_ros.core.direct.tuning import PAD, SET_PAD
from tocontrol_ros.core.planning.replan import replan_options, warm_replan
from tocontrol_ros.core.planning.solver import Planner, SolverOptions
from tocontrol_ros.core.robot.limits import JointLimits
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: A Panda case of bench/limits.py's draw (its fourth: a moving start, T about 0.5 s).
Q0 = np.array([2.5512619944661235, 0.74807590184881, 0.12099829150782057,
               -0.8557750326951699, 1.5780551453177782, 2.432919206131414,
               -0.7755753537417155])
QD0 = np.array([0.004050834032597764, 0.35271556399532705, 0.5949327185797754,
                -0.5367953855773556, -0.531040538866643, 0.4016965309861664,
                -0.23068248354473017])
TARGET = np.array([-0.4583765715363754, -0.10868277489498916, 0.46580382199599213])
#: The 2 cm move (m) in a fixed direction.
_D = np.random.default_rng(1003).normal(size=3)
MOVE = 0.02 * _D / np.linalg.norm(_D)
#: The first bounded solve of a kind compiles its NLP: not a time to judge the solver on.
SLOW_OK = 600.0
#: The replans' options: warm alone, 24 uniform spans (the serving mesh).
SERVE = replan_options(SolverOptions(time_limit=SLOW_OK), 0.0, 24)


def _moved(problem: Problem, by) -> Problem:
    return Problem(problem.model, problem.start,
                   point(problem.target.value + np.asarray(by, dtype=float)), k=problem.k,
                   limits=problem.limits)


def _route(result) -> str:
    text = " ".join(result.warnings)
    return "parametric" if "(route: parametric)" in text else \
        "ipopt" if "(route: ipopt)" in text else "none"


@pytest.fixture(scope="module")
def panda_case(panda):
    """The Panda with its URDF limits: the default plan, then its serving solution (the
    same problem re-solved warm on the replans' 24 spans, converged, with multipliers:
    what a previous replan leaves)."""
    planner = Planner(panda)
    limits = JointLimits.from_model(panda)
    problem = Problem(panda, joint_state(Q0, QD0), point(TARGET), k=4.0, limits=limits)
    base = planner.plan(problem, SolverOptions(time_limit=SLOW_OK))
    assert base.success, base.message
    serving = warm_replan(planner, problem, [base], SERVE)
    assert serving.success and serving.intervals == 24, serving.message
    assert serving.warm_state.lam_g is not None
    return planner, problem, serving


def _step_args(planner, serving, moved) -> tuple:
    """``(flat, args)``: the serving mesh's NLP of ``moved`` and :func:`sensitivity_solve`'s
    arguments from the serving solution (its control points, T and multipliers), the
    problem's padded limits and set pad."""
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    return flat, (flat, np.concatenate([ws.P.ravel(), [ws.T]]), ws.lam_g, ws.lam_x,
                  moved.start.value, moved.target.value, moved.k, *state_bounds(moved, PAD),
                  SET_PAD)


def _kkt_residuals(planner, problem, result) -> tuple[float, float]:
    """Stationarity and primal infeasibility of the result on its NLP, evaluated here."""
    ws = result.warm_state
    flat = planner.flat(problem, ws.breaks, warm="dual")
    lower, upper = state_bounds(problem, PAD)
    lbg, ubg, lbx, ubx = flat.bounds(lower, upper, SET_PAD)
    par = flat.parameters(problem.start.value, problem.target.value, problem.k)
    w = np.concatenate([ws.P.ravel(), [ws.T]])
    jac_fun, _ = flat.kkt_functions
    g, jac = jac_fun(w, par)
    g = np.array(g).ravel()
    grad = np.zeros(len(w))
    grad[-1] = 1.0
    stat = grad + np.array(jac.T @ ws.lam_g).ravel() + ws.lam_x
    primal = max(np.max(lbg - g), np.max(g - ubg), np.max(lbx - w), np.max(w - ubx), 0.0)
    return float(np.max(np.abs(stat))), float(primal)


def test_a_2cm_move_is_re_solved_by_the_parametric_step(panda_case):
    """A 2 cm move of the target: the parametric route converges, the plan is certified,
    T within 1e-6 of IPOPT's converged re-solve of the same NLP from the same point (the
    issue's bar is 1e-3), its KKT residuals small, and fewer Newton steps than IPOPT's
    iterations."""
    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    assert abs(np.linalg.norm(moved.target.value - problem.target.value) - 0.02) < 1e-3
    par = planner.plan(moved, SERVE, warm_start=serving)
    ipopt = planner.plan(moved, replace(SERVE, warm_parametric=False), warm_start=serving)
    assert par.success and ipopt.success, (par.message, ipopt.message)
    assert _route(par) == "parametric", par.warnings
    assert _route(ipopt) == "none"
    assert par.certificate is not None and par.certificate.passed
    assert par.method == "direct" and par.intervals == 24
    assert par.T != serving.T
    assert abs(par.T / ipopt.T - 1.0) <= 1e-6
    stat, primal = _kkt_residuals(planner, moved, par)
    assert stat <= 1e-5 and primal <= 1e-8, (stat, primal)
    assert par.iterations < ipopt.iterations
    # The result carries its multipliers: the next move continues from it.
    again = planner.plan(_moved(moved, (0.0, 0.01, -0.01)), SERVE, warm_start=par)
    assert again.success and again.certificate.passed, again.message
    assert _route(again) in ("parametric", "ipopt")


def test_a_move_that_changes_the_active_set_converges_or_falls_back_saying_why(panda_case):
    """A 10 cm move: the active set changes. Either the parametric steps converge (rows
    changed activity, T that of IPOPT's re-solve) or the plan says that they failed and
    why, and IPOPT's re-solve is published; both certified, never a silent wrong answer."""
    planner, problem, serving = panda_case
    moved = _moved(problem, (0.06, -0.05, 0.06))
    par = planner.plan(moved, SERVE, warm_start=serving)
    ipopt = planner.plan(moved, replace(SERVE, warm_parametric=False), warm_start=serving)
    assert par.success and ipopt.success, (par.message, ipopt.message)
    assert par.certificate.passed
    route = _route(par)
    text = " ".join(par.warnings)
    if route == "parametric":
        assert "rows changed activity" in text
        assert abs(par.T / ipopt.T - 1.0) <= 1e-6
    else:
        assert route == "ipopt", par.warnings
        assert "parametric step:" in text and "failed" in text and "IPOPT instead" in text
        assert par.T == pytest.approx(ipopt.T, rel=1e-6)


#: bench/warm_resolve.py's case 2 (a moving start) and its 2 cm move: the move makes two
#: rows block the barrier's steps (the active set changes).
HOLD_Q0 = np.array([2.3918396377373012, 1.538876765530094, 0.8516076787069186,
                    -2.4797175030377803, -0.5480556869667632, 1.1142377565041506,
                    2.3763812546418017])
HOLD_QD0 = np.array([0.23400553637193297, 0.10681930882760937, -0.5526385562529377,
                     0.299999739750907, 0.27244649958753814, 0.4728266786776917,
                     -0.5497733414936288])
HOLD_TARGET = np.array([0.0363844797615219, -0.45428216747540395, 0.20757390108044987])
HOLD_MOVED = np.array([0.02104013966431273, -0.4654382020789454, 0.20124190937911562])


def test_rows_that_block_the_step_are_held_and_the_answer_is_the_optimum(panda):
    """Where the move changes the active set (rows 1e-3 below their bounds become
    active), the blocking rows are held at their bounds: the parametric route converges,
    the plan is certified, its T within 1e-3 (here 1e-6) of IPOPT's converged re-solve of
    the same NLP from the same point, its KKT residuals small; the barrier alone (``hold
    =False``) needs more Newton steps there (measured 9 against 5), or fails saying why."""
    planner = Planner(panda)
    limits = JointLimits.from_model(panda)
    problem = Problem(panda, joint_state(HOLD_Q0, HOLD_QD0), point(HOLD_TARGET), k=4.0,
                      limits=limits)
    base = planner.plan(problem, SolverOptions(time_limit=SLOW_OK))
    assert base.success, base.message
    serving = warm_replan(planner, problem, [base], SERVE)
    assert serving.success and serving.intervals == 24, serving.message
    moved = _moved(problem, HOLD_MOVED - HOLD_TARGET)
    _, args = _step_args(planner, serving, moved)
    res, outcome = sensitivity.sensitivity_solve(*args)
    assert res.success and outcome.reason == "converged", res.message
    assert outcome.holds >= 1 and outcome.changed >= 1, outcome
    assert f"{outcome.holds} held at their bounds" in res.message
    par = planner.plan(moved, SERVE, warm_start=serving)
    ipopt = planner.plan(moved, replace(SERVE, warm_parametric=False), warm_start=serving)
    assert par.success and ipopt.success, (par.message, ipopt.message)
    assert _route(par) == "parametric", par.warnings
    assert par.certificate is not None and par.certificate.passed
    assert abs(par.T / ipopt.T - 1.0) <= 1e-6, (par.T, ipopt.T)
    stat, primal = _kkt_residuals(planner, moved, par)
    assert stat <= 1e-5 and primal <= 1e-8, (stat, primal)
    alone, out_alone = sensitivity.sensitivity_solve(*args, hold=False)
    assert out_alone.holds == 0
    if alone.success:
        assert out_alone.steps > outcome.steps, (out_alone, outcome)
        assert alone.T == pytest.approx(res.T, rel=1e-6)
    else:
        assert alone.residual == np.inf and "failed" in alone.message


def test_a_parametric_step_out_of_work_falls_back_to_ipopt(panda_case, monkeypatch):
    """With a budget of one Newton step the parametric solve stops unconverged: a failure
    with its reason (never a result); the plan (without the sub-moves that would follow)
    falls back to IPOPT, says so, certified."""
    import tocontrol_ros.core.direct.limited as limited

    planner, problem, serving = panda_case
    monkeypatch.setattr(limited, "PATH_SUBMOVES", 1)
    moved = _moved(problem, MOVE)
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    values = (moved.start.value, moved.target.value, moved.k)
    w0 = np.concatenate([ws.P.ravel(), [ws.T]])
    monkeypatch.setattr(sensitivity, "MAX_STEPS", 1)
    res, outcome = sensitivity.sensitivity_solve(flat, w0, ws.lam_g, ws.lam_x, *values,
                                                 *state_bounds(moved, PAD), SET_PAD)
    assert not res.success and res.residual == np.inf
    assert outcome.steps == 1 and outcome.reason == "not converged in 1 steps"
    assert "not converged in 1 steps" in res.message
    out = planner.plan(moved, SERVE, warm_start=serving)
    assert out.success and out.certificate.passed, out.message
    assert _route(out) == "ipopt"
    assert any("not converged in 1 steps" in w and "solved by IPOPT instead" in w
               for w in out.warnings), out.warnings


def test_cancel_stops_the_parametric_step(panda_case):
    planner, problem, serving = panda_case
    _, args = _step_args(planner, serving, _moved(problem, MOVE))
    res, outcome = sensitivity.sensitivity_solve(*args, should_stop=lambda: True)
    assert not res.success and outcome.reason == "cancelled" and outcome.steps == 0


@pytest.mark.parametrize("value", [1, "yes", None])
def test_warm_parametric_is_validated(value):
    from tocontrol_ros.core.errors import ProblemError

    with pytest.raises(ProblemError, match="warm_parametric"):
        SolverOptions(warm_parametric=value)


def _moved_nlp(panda_case):
    """The serving mesh's NLP of the Panda case moved by MOVE: ``(moved problem, flat,
    parameters, w, warm state)``, ``w`` the serving solution (control points and T)."""
    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    par = flat.parameters(moved.start.value, moved.target.value, moved.k)
    return moved, flat, par, np.concatenate([ws.P.ravel(), [ws.T]]), ws


def test_the_barrier_start_keeps_a_slack_on_either_side_of_a_two_sided_bound(monkeypatch):
    """IPOPT's point carried into the barrier: a value on (or just outside) its lower or
    upper bound, with a multiplier there, starts inside it by MU over that multiplier (the
    product MU); an inactive one stays. Before, a two-sided value on its lower bound was
    pulled back onto it by the upper side's room (a zero slack: the first KKT step of
    bench/warm_resolve.py's case 20's pad round was not finite)."""
    mu = sensitivity.MU
    value = np.array([-1.0, 1.0, 0.25, -1.0 - 1e-14])
    lam = np.array([-1e-3, 1e-3, 0.0, -1e-3])
    lower, upper, has = -np.ones(4), np.ones(4), np.ones(4, dtype=bool)
    start, z_l, z_u = sensitivity._barrier_start(value, lower, upper, lam, has, has)
    room_l, room_u = start - lower, upper - start
    assert np.all(room_l > 0.0) and np.all(room_u > 0.0)
    assert room_l[0] == pytest.approx(mu / 1e-3) and room_l[3] == pytest.approx(mu / 1e-3)
    assert room_u[1] == pytest.approx(mu / 1e-3) and start[2] == 0.25
    assert z_l[0] * room_l[0] == pytest.approx(mu) and z_u[1] * room_u[1] == pytest.approx(mu)
    monkeypatch.setattr(sensitivity, "FAR_SIDE_LEAST_ROOM", False)
    before, _, _ = sensitivity._barrier_start(value, lower, upper, lam, has, has)
    assert before[0] == -1.0 and before[1] == start[1]  # the lower side's slack lost


def test_the_banded_kkt_solve_equals_a_dense_solve(panda_case):
    """The banded LU with T's Schur complement (BandedKKT, shared with the active-set
    experiment in bench/) solves the Panda's KKT matrix as a dense LU of the same matrix,
    assembled here from the Hessian's upper triangle and the Jacobian's triplets."""
    moved, flat, par, w, ws = _moved_nlp(panda_case)
    jac_fun, hess_fun = flat.kkt_functions
    _, jac = jac_fun(w, par)
    hess = hess_fun(w, par, 1.0, ws.lam_g)
    banded = sensitivity.banded_kkt(flat, jac, hess)
    assert sensitivity.banded_kkt(flat, jac, hess) is banded  # built once per sparsity
    nw, ng = len(w), flat.rows
    hv, jv = np.array(hess.nonzeros()), np.array(jac.nonzeros())
    rng = np.random.default_rng(5)
    diag = np.concatenate([rng.uniform(0.0, 1.0, nw), -rng.uniform(1e-3, 1.0, ng)])
    fact = banded.factor(hv, diag, jv)
    assert fact is not None
    dense = np.zeros((nw + ng, nw + ng))
    np.add.at(dense, (banded.hr, banded.hc), hv)
    off = banded.hr != banded.hc
    np.add.at(dense, (banded.hc[off], banded.hr[off]), hv[off])
    dense[np.arange(nw + ng), np.arange(nw + ng)] += diag
    np.add.at(dense, (nw + banded.jr, banded.jc), jv)
    np.add.at(dense, (banded.jc, nw + banded.jr), jv)
    rhs = rng.normal(size=nw + ng)
    x = banded.solve(fact, rhs)
    ref = np.linalg.solve(dense, rhs)
    assert np.max(np.abs(x - ref)) <= 1e-8 * max(1.0, np.max(np.abs(ref)))
    assert np.max(np.abs(dense @ x - rhs)) <= 1e-8 * max(1.0, np.max(np.abs(rhs)))


def _called_as_functions(monkeypatch) -> None:
    """The step's derivatives called as the transcription's CasADi functions (DM in and
    out, the sparse results' nonzeros copied out): the route before KKTDerivatives."""
    from tocontrol_ros.core.direct import kkt_step

    def rows(self, w, p):
        g, jac = self.functions[0](w, p)
        return np.array(g).ravel(), np.array(jac.nonzeros())

    def hessian(self, w, p, lam_g):
        return np.array(self.functions[1](w, p, 1.0, lam_g).nonzeros())

    monkeypatch.setattr(kkt_step.KKTDerivatives, "rows", rows)
    monkeypatch.setattr(kkt_step.KKTDerivatives, "hessian", hessian)


def test_the_buffered_derivatives_and_steps_equal_the_functions_calls(panda_case,
                                                                       monkeypatch):
    """The rows, Jacobian and Hessian through NumPy buffers (KKTDerivatives) are the
    transcription's own functions' values; the parametric solve through them takes the
    same steps to the same answer (T, control points, multipliers to 1e-9) as through the
    functions called with DM conversions (the route before)."""
    from tocontrol_ros.core.direct.kkt_step import kkt_derivatives

    moved, flat, par, w, ws = _moved_nlp(panda_case)
    der = kkt_derivatives(flat)
    assert kkt_derivatives(flat) is der  # built once per transcription
    jac_fun, hess_fun = flat.kkt_functions
    g_ref, jac_ref = jac_fun(w, par)
    g, jv = der.rows(w, par)
    np.testing.assert_allclose(g, np.array(g_ref).ravel(), rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(jv, np.array(jac_ref.nonzeros()), rtol=0.0, atol=1e-12)
    hv = der.hessian(w, par, ws.lam_g)
    np.testing.assert_allclose(hv, np.array(hess_fun(w, par, 1.0, ws.lam_g).nonzeros()),
                               rtol=0.0, atol=1e-9 * np.max(np.abs(hv)))
    args = (flat, w, ws.lam_g, ws.lam_x, moved.start.value, moved.target.value, moved.k,
            *state_bounds(moved, PAD), SET_PAD)
    new, out_new = sensitivity.sensitivity_solve(*args)
    with monkeypatch.context() as m:
        _called_as_functions(m)
        old, out_old = sensitivity.sensitivity_solve(*args)
    assert new.success and old.success, (new.message, old.message)
    assert (out_new.steps, out_new.solves, out_new.hessians, out_new.holds) == \
        (out_old.steps, out_old.solves, out_old.hessians, out_old.holds)
    assert abs(new.T - old.T) <= 1e-9 * old.T
    np.testing.assert_allclose(new.P, old.P, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(new.lam_g, old.lam_g, rtol=0.0,
                               atol=1e-9 * max(1.0, np.max(np.abs(old.lam_g))))


def test_a_warm_state_keeps_its_set_values_and_the_pads_read_off_them(panda_case):
    """A plan's warm state keeps the set's values between the samples that its check
    evaluated (the serving solution's and a parametric answer's): equal to the bit to the
    values of its path evaluated again, and the next re-solve's pads per sample read off
    them are the pads evaluated from the path; another k or mesh evaluates them."""
    from tocontrol_ros.core.direct import set_pads
    from tocontrol_ros.core.direct.flat import FlatResult
    from tocontrol_ros.core.direct.flat_trajectory import SET_POINTS, FlatTrajectory

    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    par = planner.plan(moved, SERVE, warm_start=serving)
    assert par.success and _route(par) == "parametric", par.warnings
    for ws in (serving.warm_state, par.warm_state):
        assert ws.set_values is not None and ws.k == moved.k
        assert ws.torque_scale == moved.torque_scale
        assert not ws.set_values.flags.writeable
        flat = planner.flat(moved, ws.breaks, warm="dual")
        path = FlatResult(success=True, message="", T=float(ws.T), iterations=0,
                          solve_time=0.0, P=np.asarray(ws.P, dtype=float), residual=0.0)
        fresh = FlatTrajectory(flat, path, moved.k)
        assert fresh.known_set_values() is None
        again = fresh.set_values()
        assert len(again) == (len(ws.breaks) - 1) * SET_POINTS
        assert np.array_equal(ws.set_values, again)
        evaluated = set_pads.warm_row_pads(flat, replace(ws, set_values=None), moved.k)
        assert np.array_equal(set_pads.warm_row_pads(flat, ws, moved.k), evaluated)
        # Kept values of another exponent or torque scale are not read (a planted wrong
        # value shows where they are).
        planted = replace(ws, set_values=np.full_like(again, 2.0))
        assert not np.array_equal(set_pads.warm_row_pads(flat, planted, moved.k), evaluated)
        for other in (replace(planted, k=moved.k + 1.0),
                      replace(planted, torque_scale=0.9 * ws.torque_scale)):
            assert np.array_equal(set_pads.warm_row_pads(flat, other, moved.k), evaluated)


def test_the_buffered_rows_are_the_row_function_to_the_bit(panda_case):
    """The NLP's rows through NumPy buffers (the residual of every solve and time stretch)
    equal the row function called with DM, at the serving solution, a parametric answer and
    that answer slowed down; so do the residuals."""
    from tocontrol_ros.core.direct.flat import violation
    from tocontrol_ros.core.direct.kkt_step import buffered_rows

    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    par = planner.plan(moved, SERVE, warm_start=serving)
    assert par.success, par.message
    flat = planner.flat(moved, serving.warm_state.breaks, warm="dual")
    values = (moved.start.value, moved.target.value, moved.k)
    p = flat.parameters(*values)
    bounds = state_bounds(moved, PAD)
    for P, T in ((serving.warm_state.P, serving.T), (par.trajectory.result.P, par.T),
                 (par.trajectory.result.P, par.T * (1.0 + 3e-4))):
        w = np.concatenate([np.ravel(P), [T]])
        plain = np.array(flat.row_function(w, p)).ravel()
        assert np.array_equal(buffered_rows(flat)(w, p)[0], plain)
        assert flat.residual(*values, T, P, *bounds) == violation(
            w, plain, *flat.bounds(*bounds, SET_PAD, values[:2]))


def test_the_certificate_in_one_compiled_call_equals_span_by_span(panda_case, monkeypatch):
    """The bounded motion's re-integration in one call on the compiled right-hand side
    equals CVODES span by span on the symbolic one (the route before) to 1e-12, and the
    between-samples check through the buffered map equals the map called with DM; the
    plan through both routes has the same T, certificate and set values."""
    import casadi as ca

    import tocontrol_ros.core.direct.flat_trajectory as ft

    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    par = planner.plan(moved, SERVE, warm_start=serving)
    assert par.success and _route(par) == "parametric", par.warnings
    traj = par.trajectory
    assert isinstance(traj, ft.FlatTrajectory)
    t, x, ok = traj.open_loop(1e-8, 1e-10)
    u = traj.set_values()
    symbolic: dict = {}

    def compile_open_loop(model, degree=3):
        if not symbolic:
            sig, xs, c, h, ode = ft.polynomial_segment_ode(model, degree)
            symbolic["dae"] = {"x": xs, "p": ca.vertcat(ca.vec(c), h), "t": sig, "ode": ode}
        return symbolic["dae"], "cached (the test's symbolic)"

    def span_by_span(model, integ, segments):
        def fail(*_):
            raise RuntimeError("span by span")
        return fail

    with monkeypatch.context() as m:
        m.setattr(ft, "compile_open_loop", compile_open_loop)
        m.setattr(ft, "open_loop_sweep", span_by_span)
        m.setattr(ft, "open_loop_sweep_buffered", span_by_span)
        m.setattr(ft, "mapped_controls",
                  lambda model, fun, count: lambda *a: [np.array(fun.map(count)(*a))])
        t_old, x_old, ok_old = traj.open_loop(1e-8, 1e-10)
        u_old = traj.with_result(traj.result).set_values()  # not the values kept
        before = planner.plan(moved, SERVE, warm_start=serving)
    assert ok and ok_old
    np.testing.assert_array_equal(t, t_old)
    np.testing.assert_allclose(x, x_old, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(u, u_old, rtol=0.0, atol=1e-12)
    assert before.success and before.certificate.passed
    assert abs(before.T - par.T) <= 1e-12 * par.T
    assert before.certificate.passed == par.certificate.passed


#: bench/warm_resolve.py's case 11 (a start at rest, T about 0.35 s) and its 2 cm move: the
#: whole move's steps hold 81 rows and do not converge within their budget; followed in
#: sub-moves they do (measured: 17 Newton steps in 2 sub-moves).
PATH_Q0 = np.array([-1.1742763114692718, 1.0107897399553536, 1.6684353899250255,
                    -1.5668126401648266, -1.1222968863705987, 2.3766565048871007,
                    -2.138492659095167])
PATH_TARGET = np.array([0.26702422914005974, -0.3556075299390175, 0.18870281698592256])
PATH_MOVED = np.array([0.27940271925408733, -0.3655689775058824, 0.17655610776615763])


@pytest.fixture(scope="module")
def path_case(panda):
    """Case 11's default plan, its serving solution and the moved problem."""
    planner = Planner(panda)
    limits = JointLimits.from_model(panda)
    problem = Problem(panda, joint_state(PATH_Q0, np.zeros(7)), point(PATH_TARGET), k=4.0,
                      limits=limits)
    base = planner.plan(problem, SolverOptions(time_limit=SLOW_OK))
    assert base.success, base.message
    serving = warm_replan(planner, problem, [base], SERVE)
    assert serving.success and serving.intervals == 24, serving.message
    return planner, serving, _moved(problem, PATH_MOVED - PATH_TARGET)


def test_a_move_whose_whole_steps_fail_is_followed_in_sub_moves(path_case):
    """Where the whole move's steps do not converge, the move followed in sub-moves does
    (the path-following in the parameter: a Newton homotopy from the old point): the
    answer is a KKT point of the moved NLP (its residuals evaluated here), T within 1e-6 of
    IPOPT converged on the same NLP from the same point (a second method; the bar is
    1e-3); one sub-move is the whole move, the same steps to the bit."""
    planner, serving, moved = path_case
    ws = serving.warm_state
    flat, args = _step_args(planner, serving, moved)
    bounds = state_bounds(moved, PAD)
    values = (moved.start.value, moved.target.value, moved.k)
    whole, out_whole = sensitivity.sensitivity_solve(*args)
    assert not whole.success and out_whole.reason != "converged", whole.message
    same, out_same = sensitivity.sensitivity_solve(*args, submoves=1)
    assert same.T == whole.T and np.array_equal(same.P, whole.P)
    assert out_same == out_whole
    path, out_path = sensitivity.sensitivity_solve(
        *args, submoves=sensitivity.PATH_SUBMOVES, max_steps=sensitivity.PATH_STEPS,
        max_solves=sensitivity.PATH_SOLVES, sub_budget=sensitivity.PATH_SUB_BUDGET)
    assert path.success and out_path.reason == "converged", path.message
    assert f"in {sensitivity.PATH_SUBMOVES} sub-moves: converged" in path.message
    assert out_path.steps <= sensitivity.PATH_STEPS
    assert out_path.solves <= sensitivity.PATH_SOLVES
    stopped, out_stopped = sensitivity.sensitivity_solve(
        *args, submoves=sensitivity.PATH_SUBMOVES, sub_budget=(2, 40))
    assert not stopped.success and out_stopped.steps == 2, out_stopped
    assert out_stopped.reason == "sub-move 1 not done within its budget (2 steps, 40 KKT solves)"
    ref = flat.solve(*values, ws.T, ws.P, *bounds, lam_g0=ws.lam_g, lam_x0=ws.lam_x)
    assert ref.success, ref.message
    assert abs(path.T / ref.T - 1.0) <= 1e-6, (path.T, ref.T)
    assert path.T != ws.T
    answer = replace(serving, warm_state=replace(ws, P=path.P, T=path.T, lam_g=path.lam_g,
                                                 lam_x=path.lam_x))
    stat, primal = _kkt_residuals(planner, moved, answer)
    assert stat <= 1e-6 and primal <= 1e-9, (stat, primal)


def test_a_step_whose_held_rows_keep_growing_stops_the_solve(path_case, monkeypatch):
    """A step still blocked after HOLD_ROUNDS re-solves with rows held stops the solve
    there, a failure that says so, after fewer factorisations than the budget; where no
    step needs that many (this whole move holds rows at most twice within a step), the
    cap changes nothing: the same steps to the bit as without it."""
    planner, serving, moved = path_case
    _, args = _step_args(planner, serving, moved)
    whole, out_whole = sensitivity.sensitivity_solve(*args)
    with monkeypatch.context() as m:
        m.setattr(sensitivity, "HOLD_ROUNDS", 10 ** 6)
        uncapped, out_uncapped = sensitivity.sensitivity_solve(*args)
    assert out_uncapped == out_whole and uncapped.T == whole.T
    assert np.array_equal(uncapped.P, whole.P) and uncapped.message == whole.message
    with monkeypatch.context() as m:
        m.setattr(sensitivity, "HOLD_ROUNDS", 1)
        capped, out_capped = sensitivity.sensitivity_solve(*args)
    assert not capped.success and np.isinf(capped.residual)
    assert out_capped.reason == ("a step still blocked after 1 re-solves with rows held (the "
                                 "rows that block it keep growing)"), out_capped
    assert capped.message.endswith(": failed") and out_capped.reason in capped.message
    assert out_capped.holds >= 1
    assert out_capped.solves < out_whole.solves <= sensitivity.MAX_SOLVES


def test_the_plan_takes_the_sub_moves_where_the_whole_move_fails(path_case, monkeypatch):
    """The plan: the whole move's failure, then the sub-moves' convergence, in its warnings
    (route: parametric), certified, T within 1e-6 of the IPOPT route's (both slowed down
    by the same time stretch to hold the set between the samples); without the sub-moves
    (the route before) IPOPT answers the same T; sub-moves out of work fall back to IPOPT
    and say why."""
    import tocontrol_ros.core.direct.limited as limited

    planner, serving, moved = path_case
    par = planner.plan(moved, SERVE, warm_start=serving)
    ipopt = planner.plan(moved, replace(SERVE, warm_parametric=False), warm_start=serving)
    assert par.success and ipopt.success, (par.message, ipopt.message)
    assert _route(par) == "parametric", par.warnings
    text = " ".join(par.warnings)
    assert f"failed; parametric step in {sensitivity.PATH_SUBMOVES} sub-moves: converged" \
        in text, par.warnings
    assert par.certificate is not None and par.certificate.passed
    assert abs(par.T / ipopt.T - 1.0) <= 1e-6, (par.T, ipopt.T)
    with monkeypatch.context() as m:
        m.setattr(limited, "PATH_SUBMOVES", 1)
        before = planner.plan(moved, SERVE, warm_start=serving)
    assert before.success and _route(before) == "ipopt", before.warnings
    assert "sub-moves" not in " ".join(before.warnings)
    assert before.T == pytest.approx(par.T, rel=1e-6)
    with monkeypatch.context() as m:
        m.setattr(limited, "PATH_STEPS", 2)
        short = planner.plan(moved, SERVE, warm_start=serving)
    assert short.success and short.certificate.passed, short.message
    assert _route(short) == "ipopt", short.warnings
    assert any(f"in {sensitivity.PATH_SUBMOVES} sub-moves: not converged in 2 steps" in w
               and "solved by IPOPT instead" in w for w in short.warnings), short.warnings


def _with_iterates(planner, moved, serving, on_first):
    """The plan with ``on_first``, and every iterate its parametric steps showed
    (``on_step``): ``(result, [FlatResult, ...])``."""
    from tocontrol_ros.core.direct import limited

    seen = []
    original = limited.sensitivity_solve

    def watched(*args, on_step=None, **kwargs):
        def both(it):
            seen.append(it)
            if on_step is not None:
                on_step(it)
        return original(*args, on_step=both, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(limited, "sensitivity_solve", watched)
        result = planner.plan(moved, SERVE, warm_start=serving, on_first=on_first)
    return result, seen


def test_the_first_feasible_iterate_is_given_certified_before_the_optimum(panda_case):
    """Real-time iterations (issue 47): the 2 cm move's Newton iterates that are not the
    answer are watched, and the first one whose rows hold to the tolerance, inside the set
    between the samples and certified goes to ``on_first`` once, before the answer; the
    answer is the one without ``on_first``, to the bit. The first motion is checked here
    independently: its certificate, its violation of the NLP's rows re-evaluated on the
    moved problem, its start state, and T no shorter than the optimum's by more than the
    tolerances allow (a feasible point of the same NLP) and within the bar's 1e-3."""
    from tocontrol_ros.core.direct.checked import FIRST_TRIES
    from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL

    planner, problem, serving = panda_case
    moved = _moved(problem, MOVE)
    plain = planner.plan(moved, SERVE, warm_start=serving)
    firsts = []
    result, seen = _with_iterates(planner, moved, serving, firsts.append)
    assert result.success and _route(result) == "parametric", result.message
    assert result.T == plain.T
    assert np.array_equal(result.trajectory.result.P, plain.trajectory.result.P)
    assert len(firsts) == 1
    first = firsts[0]
    assert first.success and first.certificate is not None and first.certificate.passed
    assert "(route: first iterate)" in " ".join(first.warnings)
    # Before the answer: fewer Newton steps, and an iterate the steps showed.
    assert first.iterations < result.iterations
    shown = [it for it in seen if it.iterations == first.iterations]
    assert shown and shown[0].residual <= RESIDUAL_TOL
    # The earlier iterates were not feasible to the tolerance, or failed their checks
    # (fewer of those than the tries).
    earlier = [it for it in seen if it.iterations < first.iterations]
    assert sum(it.residual <= RESIDUAL_TOL for it in earlier) < FIRST_TRIES
    # Re-evaluated here: the first motion meets the moved problem's rows and starts where
    # the problem does.
    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    resid = flat.residual(moved.start.value, moved.target.value, moved.k, first.T,
                          first.trajectory.result.P, *state_bounds(moved, PAD))
    assert resid <= RESIDUAL_TOL
    at0 = first.trajectory.evaluate(np.array([0.0]))
    assert np.allclose(at0.q[0], Q0, atol=1e-6) and np.allclose(at0.qd[0], QD0, atol=1e-6)
    assert result.T * (1.0 - 1e-6) <= first.T <= result.T * (1.0 + 1e-3)


def test_a_move_whose_iterates_are_infeasible_gives_no_first_motion(panda_case):
    """The 10 cm move: every iterate of the parametric steps violates the NLP's rows by
    far more than the tolerance (the steps fail and IPOPT answers): the steps give nothing
    to ``on_first``; IPOPT's fallback may give its own first certified iterate
    (:mod:`~tocontrol_ros.core.direct.early`, the same receiver), at most one; the answer is
    the one without it."""
    from tocontrol_ros.core.direct.tuning import RESIDUAL_TOL

    planner, problem, serving = panda_case
    moved = _moved(problem, (0.06, -0.05, 0.06))
    plain = planner.plan(moved, SERVE, warm_start=serving)
    firsts = []
    result, seen = _with_iterates(planner, moved, serving, firsts.append)
    assert seen and all(it.residual > RESIDUAL_TOL for it in seen), \
        [it.residual for it in seen]
    assert len(firsts) <= 1
    for first in firsts:  # IPOPT's iterate, not the steps'
        text = " ".join(first.warnings)
        assert "(route: first iterate)" not in text and "IPOPT's iterate" in text, text
        assert first.success and first.certificate.passed
        assert first.T >= result.T * (1.0 - 1e-6)
    assert result.success == plain.success and result.T == plain.T
