"""The default Panda plan against a compiled direct-collocation peer (issue 32).

What is measured, in one run: the best-motion section's 20 Panda cases
(:func:`bench.limits.draw_cases`, seed of :mod:`bench.optimum_panda`: even cases from a
point at rest to a point, odd ones from a joint state, at rest or moving, to a point;
k = 4, the URDF limits enforced), planned by

- *ours*: ``plan(problem, SolverOptions(time_limit=600))``, the default options (one
  process), and the same with ``workers=0`` (one process per core), each after a warm-up
  plan;
- *the peer*: an independent direct transcription written here (not the project's
  ``DirectCollocation``, ``FlatTranscription`` or limited pipeline), the kind of solver a
  practitioner would write for this problem: separated Hermite-Simpson collocation on ``N``
  uniform intervals of the free final time ``T`` (states ``q, qd``, accelerations ``qdd``
  and normalised torques ``u`` as variables at the mesh points and the interval midpoints),
  the dynamics implicit (``ID(q, qd, qdd) / (tau_max torque_scale) = u`` by the model's
  recursive Newton-Euler expression at every collocation point), the control set
  ``sum u_i^(2k) <= 1`` and the padded planning limits
  (:func:`~tocontrol_ros.core.direct.limited.state_bounds`) at every collocation point,
  objective ``T``. Start (a point at rest, ``P(q_0) = p_0``, or a joint state) and target
  (a point at rest) are *parameters* of one NLP built once per mesh and kind of start; the
  stage functions are mapped over the mesh, and the NLP's functions with all their
  derivatives (constraint Jacobian, exact Lagrangian Hessian) are generated to C by CasADi
  and compiled with gcc (:data:`CFLAGS`) into a shared library that IPOPT (MUMPS, tol 1e-8,
  its other options default) loads: a request builds nothing. The build (symbolic NLP,
  code generation, gcc) is timed apart. One start: the planner's own first seed pair
  (``seed_pairs(problem, SolverOptions())[0]``) joined by ``initial_path`` and timed within
  the velocity limits; the peer's time is its IPOPT solve (the guess, seed pair and
  initial path, is timed apart and left out: in the peer's favour).

Accuracy in ``T``: every solution (ours, and the peer's at each ``N``) is measured in its
own basin, ``|T - T_ref| / T_ref`` with ``T_ref`` the peer's NLP on
:data:`REFERENCE_INTERVALS` intervals started from that solution (sampled at the reference
mesh's collocation points). *Same accuracy*: the coarsest ``N`` whose median error over the
cases is at most ours (and at least :data:`MATCH_FLOOR`); the ratio is the peer's median time
at that ``N`` over our median plan time (above 1: ours is faster). The peer's one start may
land in another basin than our multistart: how often its ``T_ref`` is worse than ours by
more than :data:`BASIN_TOL` is counted.

The peer is checked independently of its own equations: each of its solutions' torques
(quadratic on each interval through the mesh point, midpoint and mesh point values, as
Hermite-Simpson implies) are re-integrated through the model's numeric forward dynamics
(``M(q)^-1 (tau - b(q, qd))``, scipy's DOP853), over the whole motion from the start state
(the end point's distance from the target) and over each interval from the solution's state
at its first mesh point (the state's error at the next, and the joint speeds between the
points against the limits); and the limits at the collocation points are reported.

Run alone: ``scripts/dev run python -P bench/peer_compiled.py [CASES] [--cache DIR]``
(prints the section; ``--cache`` keeps the compiled peers between runs).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.interpolate import CubicHermiteSpline, make_interp_spline  # noqa: E402

from bench.common import Section, log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED, K  # noqa: E402
from tocontrol_ros.core import Problem, SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.direct.collocation import initial_path  # noqa: E402
from tocontrol_ros.core.direct.limited import state_bounds  # noqa: E402
from tocontrol_ros.core.direct.tuning import PAD, SET_PAD  # noqa: E402
from tocontrol_ros.core.methods.seeding import seed_pairs  # noqa: E402
from tocontrol_ros.core.robot import compiled  # noqa: E402
from tocontrol_ros.core.robot.model import RobotModel  # noqa: E402
from tocontrol_ros.core.types.problem import joint_state, point  # noqa: E402

#: The peer's meshes (uniform intervals).
MESHES = (25, 50, 100, 200)
#: Intervals of the reference solves (the peer's NLP, started from each solution): 300, not
#: 400, to keep the run within about 25 minutes on two shared cores (a reference solve on
#: 400 intervals took 5-9 s, about 45 warm IPOPT iterations).
REFERENCE_INTERVALS = 300
#: Accuracy floor of the match (relative T), as in bench/panda_peer.py.
MATCH_FLOOR = 1e-4
#: The peer's basin is worse than ours when its T_ref is above ours by more than this.
BASIN_TOL = 1e-3
#: IPOPT's options: its tolerance as our solves', MUMPS, the rest default.
IPOPT = {"ipopt.tol": 1e-8, "ipopt.linear_solver": "mumps", "ipopt.print_level": 0,
         "ipopt.sb": "yes", "print_time": False}
#: gcc's flags for the generated NLP (-O1: most of -O2's speed here at a fraction of its
#: compile time on these large generated files).
CFLAGS = ("-O1", "-fPIC", "-shared")
#: Bounds of the peer's final time (s).
T_RANGE = (1e-3, 100.0)
#: The reference solves start from a solution: IPOPT's warm start from its primal point
#: (its default barrier start wanders off to another local optimum from there).
WARM = {"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-6,
        "ipopt.warm_start_bound_push": 1e-9, "ipopt.warm_start_mult_bound_push": 1e-9,
        "ipopt.bound_push": 1e-9, "ipopt.bound_frac": 1e-9}
#: A coarser peer solution whose joint path is within this (rad, at the same fractions of
#: T) of the finest one's shares its reference (the coarsest mesh always has its own).
BASIN_PATH = 0.1
#: Our plan's time limit (s): long enough never to cut a plan short.
TIME_LIMIT = 600.0


@dataclass(frozen=True)
class PeerSolution:
    """One solve of the peer.

    Attributes
    ----------
    success : bool
        IPOPT reported a solution (``Solve_Succeeded`` or ``Solved_To_Acceptable_Level``).
    status : str
        IPOPT's return status.
    T : float
        Final time (s).
    t : ndarray, shape (2N + 1,)
        Collocation times (s): mesh points and midpoints in turn.
    q, qd, qdd : ndarray, shape (2N + 1, n)
        Joint positions (rad), velocities (rad/s), accelerations (rad/s^2) at ``t``.
    u : ndarray, shape (2N + 1, n)
        Normalised torques at ``t``.
    iterations : int
        IPOPT iterations.
    seconds : float
        Wall time of the IPOPT call (s).
    """

    success: bool
    status: str
    T: float
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    u: np.ndarray
    iterations: int
    seconds: float


def _stage_functions(model: RobotModel, k: float, scale: np.ndarray):
    """The per-point and per-interval SX functions the NLP maps over its mesh.

    Returns ``dyn`` (z -> ID(q, qd, qdd) / scale - u, (n,)), ``cset`` (z -> sum u^(2k),
    scalar) and ``defect`` ((z_a, z_m, z_b, h) -> Hermite-Simpson defects, (4n,)), with
    ``z = (q, qd, qdd, u)`` (4n,) one collocation point.
    """
    n = model.n
    z = ca.SX.sym("z", 4 * n)
    q, qd, qdd, u = z[:n], z[n:2 * n], z[2 * n:3 * n], z[3 * n:]
    dyn = ca.Function("dyn", [z], [model.rnea_sym(q, qd, qdd) / ca.DM(scale) - u])
    cset = ca.Function("cset", [z], [ca.sum1(u ** (2 * int(k)))])
    za, zm, zb = (ca.SX.sym(s, 4 * n) for s in ("za", "zm", "zb"))
    h = ca.SX.sym("h")

    def state(v):
        return v[:2 * n]

    def rate(v):
        return v[n:3 * n]

    mid = state(zm) - 0.5 * (state(za) + state(zb)) - h / 8 * (rate(za) - rate(zb))
    simpson = state(zb) - state(za) - h / 6 * (rate(za) + 4 * rate(zm) + rate(zb))
    defect = ca.Function("defect", [za, zm, zb, h], [ca.vertcat(mid, simpson)])
    return dyn, cset, defect


def between_fractions(between: int) -> list[float]:
    """Fractions of an interval at which :class:`Peer` bounds the speeds besides its points.

    ``between`` evenly spaced fractions ``j / (between + 1)``, without 1/2 (a collocation
    point, bounded already).
    """
    return [j / (between + 1) for j in range(1, between + 1) if 2 * j != between + 1]


def _speeds_between(n: int, between: int) -> ca.Function:
    """(z_a, z_m, z_b, h) -> the interval's joint speeds at :func:`between_fractions`, (n f,).

    Hermite-Simpson's velocity on an interval is the integral of the quadratic through the
    accelerations at its ends and midpoint (its two defects say so at the midpoint and the
    end): ``qd(s h) = qd_a + h (c_a(s) qdd_a + c_m(s) qdd_m + c_b(s) qdd_b)``.
    """
    za, zm, zb = (ca.SX.sym(s, 4 * n) for s in ("za", "zm", "zb"))
    h = ca.SX.sym("h")
    qdd = [z[2 * n:3 * n] for z in (za, zm, zb)]
    speeds = []
    for s in between_fractions(between):
        c = (2 * s**3 / 3 - 1.5 * s**2 + s, 2 * s**2 - 4 * s**3 / 3, 2 * s**3 / 3 - s**2 / 2)
        speeds.append(za[n:2 * n] + h * (c[0] * qdd[0] + c[1] * qdd[1] + c[2] * qdd[2]))
    return ca.Function("between", [za, zm, zb, h], [ca.vertcat(*speeds)])


def _nlp(model: RobotModel, intervals: int, start_kind: str, k: float, scale: np.ndarray,
         between: int = 0):
    """The peer's NLP as CasADi MX expressions: ``{x, p, f, g}`` and the sizes of ``g``."""
    n, N = model.n, intervals
    points = 2 * N + 1
    dyn, cset, defect = _stage_functions(model, k, scale)
    z = ca.MX.sym("z", 4 * n, points)
    T = ca.MX.sym("T")
    p0 = ca.MX.sym("p0", model.m if start_kind == "point" else 2 * n)
    pT = ca.MX.sym("pT", model.m)
    q = z[:n, :]
    qd = z[n:2 * n, :]
    qs = ca.SX.sym("q", n)
    fk = ca.Function("P", [qs], [model.point_sym(qs)])
    if start_kind == "point":
        start = ca.vertcat(fk(q[:, 0]) - p0, qd[:, 0])
    else:
        start = ca.vertcat(q[:, 0], qd[:, 0]) - p0
    end = ca.vertcat(fk(q[:, -1]) - pT, qd[:, -1])
    h = ca.repmat(T / N, 1, N)
    g_dyn = dyn.map(points)(z)
    g_def = defect.map(N)(z[:, 0:-1:2], z[:, 1::2], z[:, 2::2], h)
    g_set = cset.map(points)(z)
    g = ca.vertcat(ca.vec(g_dyn), ca.vec(g_def), ca.vec(g_set), start, end)
    n_between = 0
    if between:
        g_between = _speeds_between(n, between).map(N)(z[:, 0:-1:2], z[:, 1::2], z[:, 2::2], h)
        g = ca.vertcat(g, ca.vec(g_between))
        n_between = g_between.numel()
    nlp = {"x": ca.vertcat(ca.vec(z), T), "p": ca.vertcat(p0, pT), "f": T, "g": g}
    return (nlp, g_dyn.numel() + g_def.numel(), g_set.numel(), start.numel() + end.numel(),
            n_between)


class Peer:
    """The peer for one model, mesh and kind of start: built once, solved per request.

    Parameters
    ----------
    model : RobotModel
    intervals : int
        Uniform intervals ``N`` of the mesh.
    start_kind : {"point", "state"}
    k : float
        Convexification exponent (an integer).
    torque_scale : float
        Fraction of ``tau_max`` planned against (:attr:`Problem.torque_scale`).
    cache : Path, optional
        Directory of the compiled libraries (keyed by the generated source's hash); without
        it the NLP is not compiled (CasADi's virtual machine evaluates it: for tests).
    options : dict, optional
        IPOPT options over :data:`IPOPT` (the reference solves' warm start).
    between : int
        Also bound the joint speeds at this many evenly spaced instants inside every
        interval (:func:`between_fractions`; 0: at the collocation points only).
    """

    def __init__(self, model: RobotModel, intervals: int, start_kind: str, k: float,
                 torque_scale: float = 1.0, cache: Path | None = None,
                 options: dict | None = None, between: int = 0) -> None:
        if start_kind not in ("point", "state"):
            raise ValueError(f"`start_kind` must be 'point' or 'state', got {start_kind!r}")
        if float(k) != int(k) or k < 1:
            raise ValueError(f"`k` must be a positive integer, got {k!r}")
        t0 = time.perf_counter()
        self.model, self.intervals, self.start_kind = model, intervals, start_kind
        self.scale = model.tau_max * torque_scale
        nlp, n_eq, n_set, n_bc, self.n_between = _nlp(model, intervals, start_kind, k,
                                                      self.scale, between)
        self.lbg = np.concatenate([np.zeros(n_eq), np.full(n_set, -np.inf), np.zeros(n_bc)])
        self.ubg = np.concatenate([np.zeros(n_eq), np.ones(n_set), np.zeros(n_bc)])
        self.options = dict(IPOPT, **(options or {}))
        solver = ca.nlpsol("peer", "ipopt", nlp, self.options)
        self.gcc_seconds = None
        if cache is not None:
            solver = self._compiled(solver, Path(cache))
        self.solver = solver
        self.build_seconds = time.perf_counter() - t0

    def _compiled(self, solver, cache: Path):
        """The same solver on its NLP functions generated to C and compiled (or cached)."""
        cache.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=cache) as work:
            base = f"peer_{self.start_kind}_{self.intervals}"
            cwd = os.getcwd()
            os.chdir(work)
            try:
                solver.generate_dependencies(base + ".c")
            finally:
                os.chdir(cwd)
            source = Path(work) / (base + ".c")
            key = hashlib.sha256(source.read_bytes() + " ".join(CFLAGS).encode()).hexdigest()
            library = cache / f"{base}_{key[:16]}.so"
            if not library.exists():
                t0 = time.perf_counter()
                tmp = Path(work) / (base + ".so")
                subprocess.run(["gcc", *CFLAGS, str(source), "-o", str(tmp), "-lm"],
                               check=True)
                shutil.move(tmp, library)
                self.gcc_seconds = time.perf_counter() - t0
        return ca.nlpsol("peer", "ipopt", str(library), self.options)

    def bounds(self, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on the variables from the state bounds (2n,) at every collocation point."""
        n, points = self.model.n, 2 * self.intervals + 1
        inf = np.full(n, np.inf)
        lo = np.concatenate([lower, -inf, -np.ones(n)])
        hi = np.concatenate([upper, inf, np.ones(n)])
        return (np.concatenate([np.tile(lo, points), [T_RANGE[0]]]),
                np.concatenate([np.tile(hi, points), [T_RANGE[1]]]))

    def solve(self, start: np.ndarray, target: np.ndarray, lower: np.ndarray,
              upper: np.ndarray, T: float, z: np.ndarray) -> PeerSolution:
        """One IPOPT solve.

        Parameters
        ----------
        start : ndarray, shape (m,) or (2n,)
            The start point (m) or joint state (rad, rad/s), as the peer's kind.
        target : ndarray, shape (m,)
            The target point (m).
        lower, upper : ndarray, shape (2n,)
            State bounds (rad, rad/s).
        T : float
            Initial guess of the final time (s).
        z : ndarray, shape (2N + 1, 4n)
            Initial guess ``(q, qd, qdd, u)`` at the collocation points.
        """
        n, points = self.model.n, 2 * self.intervals + 1
        if z.shape != (points, 4 * n):
            raise ValueError(f"`z` must have shape {(points, 4 * n)}, got {z.shape}")
        lbx, ubx = self.bounds(lower, upper)
        # The speeds between the points: the state bounds' velocity part, per instant.
        reps = self.n_between // n
        lbg = np.concatenate([self.lbg, np.tile(lower[n:], reps)])
        ubg = np.concatenate([self.ubg, np.tile(upper[n:], reps)])
        t0 = time.perf_counter()
        out = self.solver(x0=np.concatenate([z.ravel(), [T]]), p=np.concatenate([start, target]),
                          lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        seconds = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.array(out["x"]).ravel()
        zs = w[:-1].reshape(points, 4 * n)
        T_out = float(w[-1])
        status = str(stats.get("return_status", "unknown"))
        return PeerSolution(
            success=status in ("Solve_Succeeded", "Solved_To_Acceptable_Level"), status=status,
            T=T_out, t=np.linspace(0.0, T_out, points), q=zs[:, :n], qd=zs[:, n:2 * n],
            qdd=zs[:, 2 * n:3 * n], u=zs[:, 3 * n:], iterations=int(stats.get("iter_count", 0)),
            seconds=seconds)


# ------------------------------------------------------------------ starts and samples
def guess(model: RobotModel, problem: Problem, pair: tuple[np.ndarray, np.ndarray],
          intervals: int) -> tuple[float, np.ndarray]:
    """The peer's start: ``initial_path`` between a seed pair, at the collocation points.

    Returns
    -------
    T : float
        The path's time (s).
    z : ndarray, shape (2N + 1, 4n)
        ``(q, qd, qdd, u)`` at the mesh points and midpoints; ``qdd`` by differences of
        ``qd``.
    """
    n = model.n
    T, x, u = initial_path(model, pair[0], pair[1], 2 * intervals, problem.torque_scale,
                           problem.limits.plan_velocity)
    t = np.linspace(0.0, T, 2 * intervals + 1)
    return T, np.hstack([x, np.gradient(x[:, n:], t, axis=0), u])


def resampled(sol: PeerSolution, intervals: int) -> np.ndarray:
    """A peer solution at the collocation points of ``intervals`` intervals, (2N' + 1, 4n).

    ``q`` and ``qd`` by cubic Hermite interpolation (with ``qd`` and ``qdd`` as slopes),
    ``qdd`` and ``u`` linearly.
    """
    t = np.linspace(0.0, sol.T, 2 * intervals + 1)
    return np.hstack([CubicHermiteSpline(sol.t, sol.q, sol.qd)(t),
                      CubicHermiteSpline(sol.t, sol.qd, sol.qdd)(t),
                      make_interp_spline(sol.t, sol.qdd, k=1)(t),
                      make_interp_spline(sol.t, sol.u, k=1)(t)])


def sampled(trajectory, T: float, intervals: int) -> np.ndarray:
    """Our trajectory at the collocation points of ``intervals`` intervals, (2N + 1, 4n)."""
    s = trajectory.evaluate(np.linspace(0.0, T, 2 * intervals + 1))
    return np.hstack([s.q, s.qd, s.qdd, np.clip(s.u, -1.0, 1.0)])


def path_distance(a: PeerSolution, b: PeerSolution, samples: int = 201) -> float:
    """Largest joint difference (rad) of two solutions' paths at the same fractions of T."""
    s = np.linspace(0.0, 1.0, samples)
    qa = CubicHermiteSpline(a.t / a.T, a.q, a.qd * a.T)(s)
    qb = CubicHermiteSpline(b.t / b.T, b.q, b.qd * b.T)(s)
    return float(np.max(np.abs(qa - qb)))


# ------------------------------------------------------------------------ the check
def reintegrate(model: RobotModel, sol: PeerSolution, scale: np.ndarray, reset: bool = False,
                per_interval: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The peer's torques re-integrated through the model, interval by interval.

    The torques are quadratic on each interval through the values at its mesh points and
    midpoint (Hermite-Simpson's control), ``tau = scale u``; the accelerations are
    ``M(q)^-1 (tau - b(q, qd))`` from the model's numeric mass matrix and bias forces
    (scipy's DOP853, rtol 1e-10).

    Parameters
    ----------
    reset : bool
        Start each interval from the solution's state at its first mesh point (the
        transcription's error on one interval) instead of from the previous interval's end
        (the motion the torques make from the start state).

    Returns
    -------
    t : ndarray, shape (N per_interval + 1,)
        Sample times (s).
    x : ndarray, shape (N per_interval + 1, 2n)
        The re-integrated states at ``t``; row ``j per_interval`` at mesh point ``j`` (with
        ``reset``, the end of interval ``j - 1``), the last row at ``T``.
    """
    n = model.n
    N = (len(sol.t) - 1) // 2
    h = sol.T / N
    mesh = np.hstack([sol.q, sol.qd])[::2]
    times, states = [0.0], [mesh[0]]
    for j in range(N):
        ua, um, ub = sol.u[2 * j], sol.u[2 * j + 1], sol.u[2 * j + 2]
        ta = j * h

        def rhs(t, y, ua=ua, um=um, ub=ub, ta=ta):
            s = (t - ta) / h
            u = ua * (2 * s - 1) * (s - 1) + um * 4 * s * (1 - s) + ub * s * (2 * s - 1)
            q, qd = y[:n], y[n:]
            qdd = np.linalg.solve(model.mass_matrix(q), scale * u - model.bias(q, qd))
            return np.concatenate([qd, qdd])

        span = np.linspace(ta, ta + h, per_interval + 1)
        out = solve_ivp(rhs, (ta, ta + h), mesh[j] if reset else states[-1], method="DOP853",
                        t_eval=span[1:], rtol=1e-10, atol=1e-12)
        times += list(out.t)
        states += list(out.y.T)
    return np.array(times), np.array(states)


def check(model: RobotModel, problem: Problem, sol: PeerSolution,
          bounds: tuple[np.ndarray, np.ndarray], per_interval: int = 8) -> dict:
    """What the peer's solution does outside its own equations.

    Returns
    -------
    dict
        ``end``: the distance of the tip from the target at ``T`` when the torques are
        re-integrated from the start state (m); ``speed``: the largest joint speed there
        (rad/s); ``q_step``, ``qd_step``: the largest difference between the solution's
        state at a mesh point and its torques re-integrated over one interval from the
        previous one (rad, rad/s); ``velocity``: the largest joint speed on those
        one-interval motions over the (unpadded) planning limit, as a fraction of the limit;
        ``bounds``: the solution's largest excess over the padded state bounds at its
        collocation points (rad, rad/s).
    """
    n = model.n
    scale = model.tau_max * problem.torque_scale
    _, x = reintegrate(model, sol, scale, per_interval=per_interval)
    _, steps = reintegrate(model, sol, scale, reset=True, per_interval=per_interval)
    mesh = np.hstack([sol.q, sol.qd])[::2]
    error = np.abs(steps[per_interval::per_interval] - mesh[1:])
    lower, upper = bounds
    state = np.hstack([sol.q, sol.qd])
    return {"end": float(np.linalg.norm(model.point(x[-1, :n]) - problem.target.value)),
            "speed": float(np.max(np.abs(x[-1, n:]))),
            "q_step": float(np.max(error[:, :n])), "qd_step": float(np.max(error[:, n:])),
            "velocity": max(float(np.max(np.abs(steps[:, n:]) / problem.limits.plan_velocity))
                            - 1.0, 0.0),
            "bounds": max(float(np.max(state - upper)), float(np.max(lower - state)), 0.0)}


# ---------------------------------------------------------------------------- the run
def _problems(model: RobotModel, limits, count: int) -> list[Problem]:
    """The best-motion section's Panda cases, as ``bench/profile_panda.py`` builds them."""
    return [Problem(model, point(model.point(q0)) if i % 2 == 0 else joint_state(q0, qd0),
                    point(target), k=K, limits=limits)
            for i, (q0, qd0, target) in enumerate(draw_cases(model, limits, count, seed=SEED))]


#: Our two configurations: the default, and one process per core.
OURS = {"default": SolverOptions(time_limit=TIME_LIMIT),
        "workers=0": SolverOptions(time_limit=TIME_LIMIT, workers=0)}


def _warm_up(problem: Problem) -> None:
    """Our warm-up plans: compile cache filled, optimised libraries loaded, workers started."""
    plan(problem, OURS["default"])
    compiled.wait_for_builds()  # the optimised libraries, loaded by the next plans
    plan(problem, OURS["default"])
    plan(problem, OURS["workers=0"])


def _ours(problem: Problem, i: int) -> dict:
    """One case planned with each of :data:`OURS`, the first in turn by case: (s, result)."""
    rec = {}
    for name in (("default", "workers=0") if i % 2 == 0 else ("workers=0", "default")):
        t0 = time.perf_counter()
        res = plan(problem, OURS[name])
        rec[name] = (time.perf_counter() - t0, res)
    log(f"peer compiled: case {i + 1}: ours {rec['default'][1].status.name} T "
        f"{rec['default'][1].T:.6f} in {rec['default'][0]:.2f} s, workers=0 "
        f"{rec['workers=0'][1].status.name} T {rec['workers=0'][1].T:.6f} in "
        f"{rec['workers=0'][0]:.2f} s")
    return rec


def _build(model: RobotModel, kinds: list[str], torque_scale: float, cache: Path) -> tuple:
    """The peers (mesh, kind) -> Peer and the references kind -> Peer, with their builds."""
    peers, refs = {}, {}
    for kind in kinds:
        for N in MESHES:
            peers[N, kind] = Peer(model, N, kind, K, torque_scale, cache)
            log(f"peer compiled: built N = {N} ({kind}) in "
                f"{peers[N, kind].build_seconds:.1f} s")
        refs[kind] = Peer(model, REFERENCE_INTERVALS, kind, K, torque_scale, cache,
                          options=WARM)
    return peers, refs


def _reference(ref: Peer, problem: Problem, bounds, T: float, z: np.ndarray) -> float:
    sol = ref.solve(problem.start.value, problem.target.value, *bounds, T, z)
    return sol.T if sol.success else float("nan")


def _peer_case(model, problem, peers, refs, i) -> dict:
    """The peer on one case at every mesh, each solution's reference and check."""
    kind = problem.start.kind
    bounds = state_bounds(problem, PAD)
    t0 = time.perf_counter()
    pair = seed_pairs(problem, SolverOptions())[0]
    seed_time = time.perf_counter() - t0
    sols, guess_times = {}, {}
    for N in MESHES:
        t0 = time.perf_counter()
        T, z = guess(model, problem, pair, N)
        guess_times[N] = seed_time + time.perf_counter() - t0
        sols[N] = peers[N, kind].solve(problem.start.value, problem.target.value, *bounds, T, z)
    ok = [N for N in MESHES if sols[N].success]
    T_ref, shared, coarsest = {}, set(), None
    if ok:
        finest = sols[ok[-1]]
        T_ref[ok[-1]] = _reference(refs[kind], problem, bounds, finest.T,
                                   resampled(finest, REFERENCE_INTERVALS))
        for N in ok[:-1]:
            distance = path_distance(sols[N], finest)
            if N != MESHES[0] and distance <= BASIN_PATH:
                T_ref[N] = T_ref[ok[-1]]
                shared.add(N)
                continue
            T_ref[N] = _reference(refs[kind], problem, bounds, sols[N].T,
                                  resampled(sols[N], REFERENCE_INTERVALS))
            if N == MESHES[0]:
                # The coarsest always has its own reference: a check of the sharing rule.
                coarsest = (distance, T_ref[N], T_ref[ok[-1]])
    checks = {N: check(model, problem, sols[N], bounds) for N in ok}
    log(f"peer compiled: case {i + 1} ({kind}): " + ", ".join(
        f"N = {N} {sols[N].T:.6f} err {abs(sols[N].T - T_ref[N]) / T_ref[N]:.1e} "
        f"{sols[N].seconds:.2f} s" if N in ok else f"N = {N} {sols[N].status}"
        for N in MESHES))
    return {"sols": sols, "T_ref": T_ref, "shared": shared, "coarsest": coarsest,
            "checks": checks, "guess": guess_times}


def run(count: int = 20, cache: Path | None = None) -> Section:
    """The section: ``count`` Panda cases, ours against the compiled peer (see the module).

    Parameters
    ----------
    count : int
        Cases of the best-motion section.
    cache : Path, optional
        Where the compiled peers are kept; default: a fresh temporary directory, removed
        afterwards (the builds are then measured in full).
    """
    title = f"The Panda against a compiled direct-collocation peer ({count} cases)"
    found = robots().get("Panda")
    if found is None:
        return Section(title, ["example-robot-data is not installed: section skipped."])
    model, limits = found
    problems = _problems(model, limits, count)
    _warm_up(problems[0])
    own_cache = cache is None
    cache = Path(tempfile.mkdtemp(prefix="tocontrol-peer-")) if own_cache else Path(cache)
    try:
        kinds = sorted({p.start.kind for p in problems})
        t0 = time.perf_counter()
        peers, refs = _build(model, kinds, problems[0].torque_scale, cache)
        build_total = time.perf_counter() - t0
        ours, recs = [], []
        # Case by case, ours then the peer: a change of the machine's load over the run
        # falls on both.
        for i, problem in enumerate(problems):
            ours.append(_ours(problem, i))
            rec = _peer_case(model, problem, peers, refs, i)
            res = ours[i]["default"][1]
            rec["ours_ref"] = float("nan")
            if res.success:
                rec["ours_ref"] = _reference(
                    refs[problem.start.kind], problem, state_bounds(problem, PAD), res.T,
                    sampled(res.trajectory, res.T, REFERENCE_INTERVALS))
            log(f"peer compiled: case {i + 1}: our T_ref {rec['ours_ref']:.6f}, error "
                f"{_error(res.T, rec['ours_ref']):.1e}")
            recs.append(rec)
    finally:
        if own_cache:
            shutil.rmtree(cache, ignore_errors=True)
    return _section(title, problems, ours, recs, peers, refs, build_total)


def _error(T: float, T_ref: float) -> float:
    """``|T - T_ref| / T_ref``; infinite when either is missing (a failed solve)."""
    if not (np.isfinite(T) and np.isfinite(T_ref)):
        return float("inf")
    return abs(T - T_ref) / T_ref


def _med(values) -> float:
    values = list(values)
    return float(statistics.median(values)) if values else float("nan")


def _section(title, problems, ours, recs, peers, refs, build_total) -> Section:
    n_cases = len(problems)
    t_def = [o["default"][0] for o in ours]
    t_all = [o["workers=0"][0] for o in ours]
    ours_err = [_error(o["default"][1].T if o["default"][1].success else np.nan, r["ours_ref"])
                for o, r in zip(ours, recs, strict=True)]
    med_def, med_all, med_ours_err = _med(t_def), _med(t_all), _med(ours_err)
    differ = [str(i + 1) for i, o in enumerate(ours) if o["default"][1].T != o["workers=0"][1].T]
    errs = {N: [_error(r["sols"][N].T if r["sols"][N].success else np.nan,
                       r["T_ref"].get(N, np.nan)) for r in recs] for N in MESHES}
    times = {N: [r["sols"][N].seconds for r in recs] for N in MESHES}
    per_case = []
    for i, (problem, o, r) in enumerate(zip(problems, ours, recs, strict=True)):
        res = o["default"][1]
        cells = []
        for N in MESHES:
            sol = r["sols"][N]
            cells.append(f"{sol.T:.6f} / {errs[N][i]:.1e} / {sol.seconds:.2f}"
                         + (" (shared)" if N in r["shared"] else "")
                         if sol.success else f"**{sol.status}** / {sol.seconds:.2f}")
        peer_ref = r["T_ref"].get(max(r["T_ref"], default=None), np.nan)
        basin = (peer_ref - r["ours_ref"]) / r["ours_ref"]
        per_case.append([str(i + 1), problem.start.kind,
                         f"{res.T:.6f}" if res.success else f"**{res.status.name}**",
                         f"{ours_err[i]:.1e}", f"{o['default'][0]:.2f}",
                         f"{o['workers=0'][0]:.2f}", *cells,
                         f"{100 * basin:+.2f} %" if np.isfinite(basin) else "—"])
    summary, checked, match = [], [], None
    for N in MESHES:
        solved = [r["sols"][N].success for r in recs]
        checks = [r["checks"][N] for r in recs if N in r["checks"]]
        shared = sum(N in r["shared"] for r in recs)
        med_t, med_e = _med(times[N]), _med(errs[N])
        build = " / ".join(f"{peers[N, kind].build_seconds:.0f}"
                           for kind in ("point", "state") if (N, kind) in peers)
        summary.append([
            str(N), build, f"{sum(solved)}/{n_cases}", f"{med_t:.2f}",
            f"{_med(r['sols'][N].iterations for r in recs):.0f}", f"{med_e:.1e}",
            f"{max(errs[N]):.1e}", f"{med_t / med_def:.2f}", f"{med_t / med_all:.2f}",
            f"{sum(solved) - shared} / {shared}"])
        checked.append([
            str(N), *(f"{scale * _med(c[key] for c in checks):.{digits}} / "
                      f"{scale * max((c[key] for c in checks), default=np.nan):.{digits}}"
                      for key, scale, digits in (("end", 1e3, "3g"), ("q_step", 1.0, "1e"),
                                                 ("qd_step", 1.0, "1e"))),
            f"{100 * _med(c['velocity'] for c in checks):.0f} % / "
            f"{100 * max((c['velocity'] for c in checks), default=np.nan):.0f} %",
            f"{max((c['bounds'] for c in checks), default=np.nan):.0e}"])
        if match is None and med_e <= max(med_ours_err, MATCH_FLOOR):
            match = (N, med_t, med_e)
    order = []
    for a, b in zip(MESHES[:-1], MESHES[1:], strict=False):
        ea, eb = _med(errs[a]), _med(errs[b])
        order.append(f"{a} -> {b}: {np.log2(ea / eb):.1f}" if 0 < eb < np.inf
                     else f"{a} -> {b}: —")
    worse = better = 0
    gaps = []
    for r in recs:
        peer_ref = r["T_ref"].get(max(r["T_ref"], default=None), np.nan)
        worse += bool(peer_ref > r["ours_ref"] * (1 + BASIN_TOL))
        better += bool(peer_ref < r["ours_ref"] * (1 - BASIN_TOL))
        gap = (peer_ref - r["ours_ref"]) / r["ours_ref"]
        if np.isfinite(gap):
            gaps.append(gap)
    coarse = [r["coarsest"] for r in recs if r["coarsest"] is not None
              and r["coarsest"][0] <= BASIN_PATH]
    coarse_text = (f"{len(coarse)} of them within {BASIN_PATH:g} rad of the finest, where "
                   "sharing would have changed their T_ref by at most "
                   f"{max(abs(c[1] - c[2]) / c[1] for c in coarse):.1e}"
                   if coarse else f"none within {BASIN_PATH:g} rad of the finest")
    guess_med = _med(r["guess"][MESHES[0]] for r in recs)
    ref_builds = ", ".join(f"{kind} {refs[kind].build_seconds:.0f} s" for kind in refs)
    lines = [
        f"{n_cases} Panda cases of the best-motion section (seed {SEED}; even ones from a "
        f"point at rest, odd ones from a joint state, to a point; k = {K:g}, URDF limits "
        "enforced), planned case by case in this one process by ours, then by an "
        "independent peer. "
        f"*Ours*: `plan(problem, SolverOptions(time_limit={TIME_LIMIT:g}))`, the default "
        "options (one process), and the same with `workers=0` (one process per core), "
        "which of the two first alternating by case, after warm-up plans (compile cache "
        "filled, optimised libraries loaded, workers started). *Peer* "
        "(`bench/peer_compiled.py`): separated Hermite-Simpson collocation on N uniform "
        "intervals of the free T, variables q, qd, qdd and the normalised torques u at the "
        "mesh points and midpoints, the dynamics implicit (RNEA(q, qd, qdd) / tau_max = u "
        f"at every collocation point), the control set sum u_i^{2 * int(K)} <= 1 and the "
        "padded planning limits (`state_bounds(problem, PAD)`) at every collocation point, "
        "objective T; start and target are parameters of one NLP per mesh and kind of "
        "start, its functions and all their derivatives (exact Hessian) generated to C and "
        f"compiled with `gcc {CFLAGS[0]}` (builds apart: {build_total:.0f} s in all for "
        f"{len(peers) + len(refs)} libraries); IPOPT with MUMPS, tol 1e-8, its other "
        "options default; one start, the planner's first seed pair joined by "
        "`initial_path` (its cost, the seeding and the path, median "
        f"{1e3 * guess_med:.0f} ms, is left out of the peer's time: in the peer's favour). "
        "*Error*: |T - T_ref| / T_ref against the peer's NLP on "
        f"{REFERENCE_INTERVALS} intervals started from the solution itself (IPOPT warm "
        f"start from it; builds {ref_builds}), so that each is measured in its own basin; "
        "ours from its trajectory sampled at the reference's collocation points. A peer "
        f"solution on 50 or 100 intervals whose path is within {BASIN_PATH:g} rad of its "
        f"finest solution's (at the same fractions of T) shares that one's T_ref; the "
        f"{MESHES[0]}-interval solution always has its own ({coarse_text}). "
        "The two solve different discretisations of one problem: ours keeps the limits at "
        f"every time and the control set {SET_PAD:g} inside at its sample times, the peer "
        "both at its collocation points only, so part of our error against the peer's "
        "reference is the price of that margin (the set's alone: it scales the torques by "
        f"(1 - {SET_PAD:g})^(1/{2 * int(K)}), and T by about {SET_PAD / (4 * K):.1e} where "
        "the torques bind). "
        f"Command: `scripts/dev run python -P bench/peer_compiled.py {n_cases}`.",
        "",
        *table(["case", "start", "ours T (s)", "ours error", "ours (s)", "workers=0 (s)",
                *(f"peer N = {N}: T / error / s" for N in MESHES),
                "peer's basin (T_ref) against ours"], per_case),
        "",
        f"Ours: median plan time {med_def:.2f} s (default), {med_all:.2f} s (`workers=0`; "
        f"the same T in {n_cases - len(differ)}/{n_cases}"
        + (f", not in case {', '.join(differ)}" if differ else "") + "); "
        f"{sum(o['default'][1].success for o in ours)}/{n_cases} succeeded; median error "
        f"{med_ours_err:.1e} (max {max(ours_err):.1e}).",
        "",
        *table(["N", "build (s): point / state", "solved", "median solve (s)",
                "median iterations", "median error", "max error", "ratio to ours (default)",
                "ratio to ours (workers=0)", "own / shared T_ref"], summary),
        "",
        "Ratio: the peer's median solve time over our median plan time (above 1: ours is "
        "faster). A failed solve counts with its time and an infinite error. Order of "
        "convergence of the peer's median error (log2 of its ratio between meshes): "
        f"{', '.join(order)}.",
        "",
        "The peer checked outside its own equations: each solution's torques (quadratic on "
        "each interval through its three values, as Hermite-Simpson implies) re-integrated "
        "through the model's numeric forward dynamics M(q)^-1 (tau - b(q, qd)) (scipy "
        "DOP853, rtol 1e-10). *From the start*: the whole motion from the start state, the "
        "tip's distance from the target at T. *One interval*: each interval from the "
        "solution's state at its first mesh point, the state's difference from the "
        "solution's at the next (the transcription's own error, without the drift of an "
        "open-loop motion, which grows fast on the light wrist), and the largest joint speed "
        "on those motions over its (unpadded) planning limit, which the peer bounds at its "
        "collocation points only (ours at every time). Medians / maxima over the cases.",
        "",
        *table(["N", "from the start: end point (mm)", "one interval: q (rad)",
                "one interval: qd (rad/s)", "one interval: speed over the limit",
                "bounds at the collocation points: max excess"], checked),
        "",
    ]
    if match is not None:
        N, med_t, med_e = match
        verdict = (f"{med_t / med_def:.2f}x (default), {med_t / med_all:.2f}x (workers=0): "
                   f"peer N = {N}, median {med_t:.2f} s, median error {med_e:.1e}, against "
                   f"ours {med_def:.2f} s / {med_all:.2f} s, median error {med_ours_err:.1e}")
        ok = med_t / med_def >= 3
    else:
        verdict = (f"no mesh up to N = {MESHES[-1]} reaches our median error "
                   f"({med_ours_err:.1e}); at N = {MESHES[-1]} the peer's median time is "
                   f"{_med(times[MESHES[-1]]) / med_def:.2f}x ours")
        ok = False
    lines += [f"Same accuracy in T (the coarsest N whose median error is at most ours, "
              f"floor {MATCH_FLOOR:g}): {verdict}.",
              "",
              f"Basins: from its one start the peer's T_ref is worse than ours by more than "
              f"{BASIN_TOL:g} (relative) in {worse}/{n_cases} cases (median "
              f"{100 * _med(gaps):+.1f} % over all cases, max "
              f"{100 * max(gaps, default=np.nan):+.1f} %) and "
              f"better in {better}/{n_cases} (its finest solution's T_ref against our "
              "plan's: the accuracy above is each one's in its own basin)."]
    target = (f"issue 32: the default Panda plan's median time at least 3x below a compiled "
              f"direct-collocation peer's at the same accuracy in T ({n_cases} cases, one "
              "start)", f"{'yes' if ok else '**no**'}: {verdict}")
    return Section(title, lines, [target])


def main(argv=None) -> int:
    """Print the section: ``peer_compiled.py [CASES] [--cache DIR]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("count", nargs="?", type=int, default=20, help="cases (20)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="keep the compiled peers here (default: a fresh temporary "
                             "directory, removed afterwards)")
    args = parser.parse_args(argv)
    section = run(args.count, args.cache)
    section.print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
