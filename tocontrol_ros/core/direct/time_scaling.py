"""A joint path timed optimally along it by TOPP-RA, inside the convexified torque set.

:func:`time_scaling` is step 2 and 3 of the first motion
(:mod:`~tocontrol_ros.core.direct.first_motion`): TOPP-RA (``toppra``: reachability
analysis, one small linear program per gridpoint) on :data:`GRIDPOINTS` segments with the
interpolation discretisation (each segment's constant path acceleration meets the
constraints at both its ends), under

- the joint velocity limits (``problem.limits.plan_velocity``; ``sd^2`` at a gridpoint
  bounded with the larger ``|q'|`` of its two segments, which keeps the speeds between the
  gridpoints within them too, ``|q'|`` and ``sd^2`` being linear in ``s`` on a segment);
- the torques inside the convexified set ``sum_i u_i^(2k) <= 1``,
  ``u = tau / (tau_max torque_scale)``, which is not a box, where TOPP-RA takes linear
  constraints: each gridpoint gets a box inside the set (:func:`_boxes`), first the
  inscribed cube ``|u_i| <= n^(-1/(2k))`` (its corners on the set's boundary), then, for
  :data:`ADAPT_PASSES` passes, the box whose corner lies on the boundary in the direction
  of the last pass's torques there (a box inside the set wherever it is put; the one along
  the torques the path needs lets the loaded joints nearer their limits). A polytope
  closer to the set, e.g. the hull of the cube and the points ``+-e_i``, needs many more
  rows (168 for 7 joints at k = 4, 840 at k = 1) and still keeps a loaded joint below its
  limit unless the others are idle; the adapted box costs one more pass and no more rows;
- viscous friction ``D qd = D q'(s) sd``, linear in ``sd``, which TOPP-RA's form
  ``a sdd + b sd^2 + c`` cannot hold: it is bounded on each side by a line in ``sd^2`` (a
  tangent of the concave ``sqrt`` above it, a chord below it, :func:`_friction_lines`), so
  that the rows stay inside the true constraint;
- the joint acceleration limits where ``joint_limits.yaml`` sets them
  (``qdd = q'(s) sdd + q''(s) sd^2``, linear rows), kept by :data:`ACCELERATION_PAD` at the
  gridpoints; the certificate checks them along the motion.

The torques between the gridpoints are then checked (:data:`CHECK_POINTS` per segment,
both sides of each acceleration jump); where they leave the set, the path is timed again
with the boxes shrunk (at most :data:`MARGIN_ROUNDS` times). Decided by work, never by the
clock.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from tocontrol_ros.core.direct.scaled_path import PolynomialPath, ScaledPath, rigid_body_terms
from tocontrol_ros.core.direct.sweeps import (
    controllable_and_forward,
    controllable_and_forward_many,
    sweeps_function,
)
from tocontrol_ros.core.direct.tuning import (
    ACCELERATION_PAD,
    ADAPT_FLOOR,
    ADAPT_PASSES,
    CHECK_POINTS,
    GRIDPOINTS,
    MARGIN_ROUNDS,
    QUICK_GRIDPOINTS,
    SCALING_SET_MARGIN,
    SPEED_CAP,
    TANGENT_FLOOR,
    VELOCITY_PAD,
    X_HUGE,
)
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import Status

__all__ = ["rest_time", "cube_time", "first_pass", "first_passes", "FirstPass", "time_scaling",
           "ENGINES", "DEFAULT_ENGINE", "compile_sweeps"]

#: TOPP-RA's drivers: ``"compiled"`` (the default: both sweeps in one compiled call, each
#: stage's LP in closed form, :mod:`~tocontrol_ros.core.direct.sweeps`; issue 47), ``"seidel"``
#: (toppra's compiled Seidel solver driven stage by stage from Python, its two sweeps as
#: toppra's own: the same numbers to rounding, 2-3 times the CPU time a pass) and
#: ``"toppra"`` (the library's ``TOPPRA`` algorithm object, built per pass: the same numbers,
#: about 1 ms a pass more than ``"seidel"``: it scans the installed packages for solvers on
#: every construction); the last two kept for the benchmark's comparison and the tests'.
ENGINES = ("compiled", "seidel", "toppra")
#: The driver used unless one is named.
DEFAULT_ENGINE = "compiled"


@functools.cache
def _grid_steps(gridpoints: int) -> tuple[np.ndarray, np.ndarray]:
    """``s = np.linspace(0, 1, gridpoints + 1)`` and ``2 diff(s)``, once per size (read-only)."""
    s = np.linspace(0.0, 1.0, gridpoints + 1)
    two_ds = 2.0 * np.diff(s)
    s.flags.writeable = two_ds.flags.writeable = False
    return s, two_ds


def _grid(gridpoints: int) -> np.ndarray:
    """``np.linspace(0, 1, gridpoints + 1)``, made once per size (read-only)."""
    return _grid_steps(gridpoints)[0]


@functools.cache
def _cube_of(gridpoints: int, n: int, k: float) -> np.ndarray:
    cube = np.full((gridpoints + 1, n), n ** (-1.0 / (2.0 * k)))
    cube.flags.writeable = False
    return cube


def _cube(problem: Problem, gridpoints: int) -> np.ndarray:
    """The inscribed cube ``|u_i| <= n^(-1/(2k))`` at every gridpoint, (N + 1, n), read-only."""
    return _cube_of(gridpoints, problem.model.n, problem.k)


def compile_sweeps(problem: Problem, grids: tuple = (QUICK_GRIDPOINTS, GRIDPOINTS)) -> None:
    """Build the compiled sweeps (:data:`DEFAULT_ENGINE`) that ``problem``'s passes use.

    One library per row count (the robot's joints; twice as many rows with acceleration
    limits) and grid size (``grids``: the quick replans' and the first motion's segments),
    so that no replan pays for generating or compiling it: the planner's warm-up calls this
    (inside :func:`~tocontrol_ros.core.robot.compiled.parallel_builds` it only starts the
    builds).
    """
    m = 2 * problem.model.n * (2 if problem.limits.has_acceleration else 1)
    for gridpoints in grids:
        sweeps_function(problem.model, 2 * m, gridpoints)


def rest_time(problem: Problem, path: PolynomialPath, gridpoints: int = GRIDPOINTS,
              peaks: bool = False, engine: str = DEFAULT_ENGINE) -> tuple:
    """The time (s) of ``path`` from rest to rest in the cube, friction left out (one pass).

    What ranks candidate paths and sets a moving start's time scale; ``(None, why)`` when
    TOPP-RA finds no timing. ``gridpoints``: TOPP-RA's segments along the path. With
    ``peaks``: ``(T, why, peak)``, ``peak`` (n,) each joint's largest speed on that timing
    at the gridpoints (rad/s; None without a timing). ``engine``: one of :data:`ENGINES`.
    """
    s = _grid(gridpoints)
    cube = _cube(problem, gridpoints)
    x, why = _toppra(_Coefficients(problem, path, s), s, 0.0, cube, None, engine)
    T = None if x is None else _duration(x, s)
    if not peaks:
        return (None, why) if x is None else (T, "")
    if x is None:
        return None, why, None
    return T, "", np.max(np.abs(path(s, 1)) * np.sqrt(np.maximum(x, 0.0))[:, None], axis=0)


def cube_time(problem: Problem, path: PolynomialPath, sd0: float,
              gridpoints: int = GRIDPOINTS, speed_cap: np.ndarray | None = None,
              engine: str = DEFAULT_ENGINE) -> float:
    """The time (s) of ``path`` from path speed ``sd0`` to rest in the cube (one pass).

    As :func:`rest_time`, from a moving start and with :func:`time_scaling`'s
    ``speed_cap``: what ranks a moving start's candidate paths before one is timed in full.
    ``inf`` when TOPP-RA finds no timing.
    """
    s = _grid(gridpoints)
    cube = _cube(problem, gridpoints)
    x, _ = _toppra(_Coefficients(problem, path, s, speed_cap), s, sd0, cube, None, engine)
    return np.inf if x is None else _duration(x, s)


@dataclass(frozen=True)
class FirstPass:
    """:func:`time_scaling`'s first pass of a path, done ahead (:func:`first_pass`).

    Attributes
    ----------
    T : float
        Its time (s); ``inf`` when TOPP-RA found no timing.
    why : str
        Why not, or "".
    """

    T: float
    why: str
    coef: object
    x: np.ndarray | None
    key: tuple


def first_pass(problem: Problem, path: PolynomialPath, sd0: float,
               gridpoints: int = GRIDPOINTS, speed_cap: np.ndarray | None = None,
               engine: str = DEFAULT_ENGINE) -> FirstPass:
    """The first pass :func:`time_scaling` would make of ``path``, ranked before it is run.

    The cube shrunk by :data:`SCALING_SET_MARGIN`, friction left out (one pass): what ranks
    a moving start's candidate paths (as :func:`cube_time`), and then, given to
    :func:`time_scaling` as ``first``, its first pass and coefficients, not computed twice.
    """
    s = _grid(gridpoints)
    cube = _cube(problem, gridpoints)
    coef = _Coefficients(problem, path, s, speed_cap)
    x, why = _toppra(coef, s, sd0, cube * (1.0 - SCALING_SET_MARGIN), None, engine)
    return FirstPass(np.inf if x is None else _duration(x, s), why, coef, x,
                     (id(path), sd0, gridpoints, engine))


def first_passes(problem: Problem, paths: list, sd0s: list,
                 gridpoints: int = GRIDPOINTS, speed_cap: np.ndarray | None = None,
                 engine: str = DEFAULT_ENGINE) -> list[FirstPass]:
    """:func:`first_pass` of each of ``paths`` from its ``sd0s`` (1/s), the same numbers.

    With the compiled engine the paths are timed together: their coefficients by one
    inverse-dynamics call, their rows stacked, their sweeps by one call of the compiled
    sweeps mapped over them (the library's code once per path); a path whose forward step
    toppra would retry is run by the Seidel driver, as :func:`_toppra` does. Other engines:
    one :func:`first_pass` after another. What a moving start's time scales are ranked by
    (:func:`~tocontrol_ros.core.direct.first_motion.quick_motion`): one call for all of
    them instead of one pass each.

    Parameters
    ----------
    problem : Problem
    paths : list of PolynomialPath
        P paths of one degree and joint count.
    sd0s : list of float
        Each path's start speed ``sd(0)`` (1/s), P of them.
    gridpoints, speed_cap, engine
        As :func:`first_pass`'s (``speed_cap`` (n,), rad/s, the same for every path).

    Returns
    -------
    list of FirstPass
        Each path's, as :func:`first_pass` gives it (its ``key`` that path's).
    """
    paths, sd0s = list(paths), [float(v) for v in sd0s]
    if len(paths) != len(sd0s):
        raise ValueError(f"`sd0s` must have one speed per path ({len(paths)}), got "
                         f"{len(sd0s)}")
    if engine != "compiled" or len(paths) < 2:
        return [first_pass(problem, path, sd0, gridpoints, speed_cap, engine)
                for path, sd0 in zip(paths, sd0s, strict=True)]
    s = _grid(gridpoints)
    box = _cube(problem, gridpoints) * (1.0 - SCALING_SET_MARGIN)
    stacked, coefs = _Coefficients.of_paths(problem, paths, s, speed_cap)
    a, b, c, x_max = _partners_ordered(problem.model, _rows(stacked, sd0s, box, None))
    swept = controllable_and_forward_many(problem.model, a, b, c, x_max, s,
                                          np.array([v ** 2 for v in sd0s]))
    out = []
    for path, sd0, coef, sweeps in zip(paths, sd0s, coefs, swept, strict=True):
        found = _verdict(*sweeps[:3], s)
        x, why = found if found is not None else _toppra(coef, s, sd0, box, None, "seidel")
        out.append(FirstPass(np.inf if x is None else _duration(x, s), why, coef, x,
                             (id(path), sd0, gridpoints, engine)))
    return out


class _Coefficients:
    """The torques along a path at the gridpoints: ``u = a sdd + b sd^2 + c + f sd``.

    All in normalised torque (``tau / (tau_max torque_scale)``), shapes (N + 1, n); ``xv``
    (N + 1,) bounds ``sd^2`` by the velocity limits. :meth:`of_paths` makes several paths'
    at once (stacked, (P, N + 1, n) and (P, N + 1): the same numbers, every operation
    elementwise or an exact min / max).
    """

    def __init__(self, problem: Problem, path: PolynomialPath | None, s: np.ndarray,
                 speed_cap: np.ndarray | None = None, derivatives: tuple | None = None
                 ) -> None:
        model = problem.model
        q, d1, d2 = derivatives if derivatives is not None else \
            (path(s), path(s, 1), path(s, 2))
        fn = rigid_body_terms(model, q.size // model.n)
        scale = model.tau_max * problem.torque_scale
        # one call (every path's gridpoints as columns, path after path): 1 ms on the Panda
        c, a, b = (np.asarray(v).T.reshape(q.shape)  # the call's own copies
                   for v in fn(*(d.reshape(-1, model.n).T for d in (q, d1, d2))))
        self.a = (a - c) / scale
        self.b = (b - c) / scale
        self.c = c / scale
        self.model = model
        self.f = model.damping * d1 / scale
        self.zero = np.zeros_like(self.f)  # friction lines without friction (_friction_lines)
        # |q'(s)| is linear on a segment and sd^2 too (sdd is constant there): bounding
        # sd^2 at a gridpoint by the larger |q'| of its two segments keeps the speeds
        # between the gridpoints within the limits as well.
        speed = np.abs(d1)
        seg = np.maximum(speed[..., :-1, :], speed[..., 1:, :])
        speed = np.maximum(np.concatenate([seg, seg[..., -1:, :]], axis=-2),
                           np.concatenate([seg[..., :1, :], seg], axis=-2))
        v = problem.limits.plan_velocity * (1.0 - VELOCITY_PAD)
        if speed_cap is not None:
            v = np.minimum(v, speed_cap)
        # A joint that does not move along the path has no bound (0/0 would be NaN).
        moving = speed > 0.0
        self.xv = np.min(np.where(moving, (v / np.where(moving, speed, 1.0)) ** 2, np.inf),
                         axis=-1)
        # joint_limits.yaml's accelerations: qdd = q'(s) sdd + q''(s) sd^2, linear in
        # (sdd, sd^2) as TOPP-RA's rows are.
        lim = problem.limits
        self.accel = None
        if lim.has_acceleration:
            a = np.where(np.isfinite(lim.plan_acceleration),
                         lim.plan_acceleration * (1.0 - ACCELERATION_PAD), np.inf)
            self.accel = (d1 / a, d2 / a)

    @classmethod
    def of_paths(cls, problem: Problem, paths: list, s: np.ndarray,
                 speed_cap: np.ndarray | None = None
                 ) -> tuple[_Coefficients, list[_Coefficients]]:
        """Each path's coefficients, computed stacked: one inverse-dynamics call for all.

        ``paths``: :class:`PolynomialPath` of one degree and joint count. Returns the stacked
        ones (what :func:`_rows` takes for all paths at once) and one per path (views).
        """
        stacked = cls(problem, None, s, speed_cap,
                      tuple(PolynomialPath.evaluate_many(paths, s, order) for order in range(3)))
        return stacked, [stacked._part(i) for i in range(len(paths))]

    def _part(self, i: int) -> _Coefficients:
        """Path ``i``'s coefficients of stacked ones (views)."""
        part = _Coefficients.__new__(_Coefficients)
        part.a, part.b, part.c, part.f = self.a[i], self.b[i], self.c[i], self.f[i]
        part.xv, part.zero, part.model = self.xv[i], self.zero[i], self.model
        part.accel = None if self.accel is None else (self.accel[0][i], self.accel[1][i])
        return part

    def torques(self, x: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``|u|`` at every gridpoint, the larger of both sides' (N + 1, n), for ``x``."""
        sdd = (x[1:] - x[:-1]) / (2.0 * np.diff(s))
        base = self.b * x[:, None] + self.c + self.f * np.sqrt(x)[:, None]
        after = np.abs(base[:-1] + self.a[:-1] * sdd[:, None])
        before = np.abs(base[1:] + self.a[1:] * sdd[:, None])
        return np.maximum(np.vstack([after, before[-1:]]), np.vstack([after[:1], before]))


def time_scaling(problem: Problem, path: PolynomialPath, sd0: float,
                 gridpoints: int = GRIDPOINTS, speed_cap: np.ndarray | None = None,
                 engine: str = DEFAULT_ENGINE, first: FirstPass | None = None):
    """``path`` timed from path speed ``sd0`` (1/s) to rest (see the module).

    ``gridpoints``: TOPP-RA's segments along the path (the quick replans' take fewer);
    ``speed_cap`` (n,): joint speeds held below it too (rad/s, m/s), as the velocity limits;
    ``engine``: one of :data:`ENGINES`; ``first``: :func:`first_pass` of this ``path`` with
    these arguments (it is not counted again in the passes).

    Returns
    -------
    (ScaledPath, int) or (Status, str)
        The timed path and the TOPP-RA passes it took, or ``SCALING_FAILED`` and why.
    """
    s = _grid(gridpoints)
    if first is not None and first.key != (id(path), sd0, gridpoints, engine):
        raise ValueError("`first` must be first_pass of the same path and arguments")
    coef = first.coef if first is not None else _Coefficients(problem, path, s, speed_cap)
    margin, passes = SCALING_SET_MARGIN, 0
    for _ in range(MARGIN_ROUNDS + 1):
        x, count = _best_scaling(problem, coef, s, sd0, margin, engine,
                                 first if margin == SCALING_SET_MARGIN else None)
        passes += count
        if isinstance(x, str):
            return Status.SCALING_FAILED, x
        traj = ScaledPath(problem.model, path, s, x, problem.k, problem.torque_scale)
        _, u, _ = traj.segment_samples(CHECK_POINTS)
        excess = float(np.max(np.sum(np.abs(u) ** (2 * problem.k), axis=1))) - 1.0
        if excess <= 0.0:
            return traj, passes
        margin += 2.0 * excess
    return Status.SCALING_FAILED, f"the torques between the gridpoints leave the set by " \
        f"{excess:.2g} after {MARGIN_ROUNDS} wider margins"


def _best_scaling(problem: Problem, coef: _Coefficients, s: np.ndarray, sd0: float,
                  margin: float, engine: str, first: FirstPass | None = None):
    """The fastest of the passes (squared path speeds (N + 1,)) and their count.

    Or a message when the first pass fails. ``first``: that pass, done already.
    """
    friction = bool(np.any(coef.f))
    cube = _cube(problem, len(s) - 1)
    # Without friction the first pass is exact; with it, its speeds only place the lines.
    if first is not None:
        x, why, passes = first.x, first.why, 0
    else:
        x, why = _toppra(coef, s, sd0, cube * (1.0 - margin), None, engine)
        passes = 1
    if x is None:
        return f"TOPP-RA found no timing inside the cube |u_i| <= n^(-1/(2k)) ({why})", passes
    if friction:
        x, why = _toppra(coef, s, sd0, cube * (1.0 - margin), x, engine)
        passes += 1
        if x is None:
            return f"TOPP-RA found no timing with friction bounded ({why})", passes
    best = x
    for _ in range(ADAPT_PASSES):
        boxes = _boxes(coef.torques(best, s), problem.k) * (1.0 - margin)
        x, _ = _toppra(coef, s, sd0, boxes, best if friction else None, engine)
        passes += 1
        if x is None or _duration(x, s) >= _duration(best, s):
            break
        best = x
    return best, passes


def _duration(x: np.ndarray, s: np.ndarray) -> float:
    """The time (s) of squared path speeds ``x`` (N + 1,) on gridpoints ``s`` (N + 1,)."""
    sd = np.sqrt(np.maximum(x, 0.0))
    grid, steps = _grid_steps(len(s) - 1)
    two_ds = steps if grid is s else 2.0 * np.diff(s)
    return float((two_ds / (sd[:-1] + sd[1:])).sum())


def _boxes(demand: np.ndarray, k: float) -> np.ndarray:
    """Boxes (N + 1, n) with their corner on the set's boundary along ``demand`` (N + 1, n).

    ``demand + ADAPT_FLOOR max(demand)`` per gridpoint, scaled so that its ``2k``-norm is
    1: then every ``u`` with ``|u_i| <= box_i`` has ``sum u_i^(2k) <= sum box_i^(2k) = 1``.
    """
    w = demand + ADAPT_FLOOR * np.max(demand, axis=1, keepdims=True) + 1e-12
    return w / np.sum(w ** (2.0 * k), axis=1, keepdims=True) ** (1.0 / (2.0 * k))


def _friction_lines(coef: _Coefficients, x_prev: np.ndarray | None):
    """Lines in ``x = sd^2`` around ``f sqrt(x)``: ``(U0, U1, L0, L1, x_cap)``.

    ``L0 + L1 x <= f sqrt(x) <= U0 + U1 x`` for ``0 <= x <= x_cap``: a tangent of the
    concave ``sqrt`` at the last pass's ``x`` (floored) bounds it above, the chord from 0 to
    ``x_cap`` below (for ``f < 0`` the two swap). Without ``x_prev``: no friction, no cap.
    """
    if x_prev is None:
        zero = coef.zero
        return zero, zero, zero, zero, np.full(coef.f.shape[:-1], np.inf)
    x_top = float(np.max(x_prev))
    x0 = np.maximum(x_prev, TANGENT_FLOOR * x_top)[:, None]
    cap = np.full(len(x_prev), SPEED_CAP * x_top)
    tangent0, tangent1 = 0.5 * np.sqrt(x0), 0.5 / np.sqrt(x0)
    chord1 = 1.0 / np.sqrt(cap)[:, None]
    pos = coef.f >= 0.0
    f = coef.f
    upper0 = np.where(pos, f * tangent0, 0.0)
    upper1 = np.where(pos, f * tangent1, f * chord1)
    lower0 = np.where(pos, 0.0, f * tangent0)
    lower1 = np.where(pos, f * chord1, f * tangent1)
    return upper0, upper1, lower0, lower1, cap


def _toppra(coef: _Coefficients, s: np.ndarray, sd0: float, boxes: np.ndarray,
            x_prev: np.ndarray | None, engine: str = DEFAULT_ENGINE):
    """One TOPP-RA pass: squared path speeds (N + 1,) to rest at ``s = 1``, or (None, why).

    The torque rows ``-box_i <= u_i <= box_i`` (friction by :func:`_friction_lines`),
    divided by the box so that TOPP-RA's ``F v <= g`` is the same at every gridpoint.
    ``engine``: one of :data:`ENGINES`.
    """
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {ENGINES}, got {engine!r}")
    rows_a, rows_b, rows_c, x_max = _rows(coef, sd0, boxes, x_prev)
    if engine == "compiled":
        out = _compiled(coef.model, s, sd0, (rows_a, rows_b, rows_c, x_max))
        if out is not None:
            return out
        engine = "seidel"  # a forward step toppra would retry (see _compiled)
    constraint = _constraint_class()(rows_a, rows_b, rows_c, x_max)
    if engine == "seidel":
        return _seidel(constraint, coef.a.shape[1], s, sd0, (rows_a, rows_b, rows_c, x_max))
    import toppra.algorithm

    algo = toppra.algorithm.TOPPRA([constraint], _path_class()(coef.a.shape[1]), gridpoints=s,
                                   solver_wrapper="seidel")
    _, sd, _ = algo.compute_parameterization(sd0, 0.0)
    if sd is None or not np.all(np.isfinite(sd)):
        return None, algo.problem_data.return_code.value
    return np.asarray(sd, dtype=float) ** 2, ""


def _rows(coef: _Coefficients, sd0, boxes: np.ndarray, x_prev: np.ndarray | None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A pass's rows ``a u + b x + c <= 1`` (N + 1, m) and bounds ``x_max`` (N + 1,).

    Columns: the torques' upper bounds, their lower bounds (then the accelerations' upper
    and lower bounds where set): see :func:`_toppra`. Stacked coefficients
    (:meth:`_Coefficients.of_paths`) without ``x_prev`` give every path's at once, (P, N + 1,
    m) and (P, N + 1), ``sd0`` then a list of P.
    """
    u0, u1, l0, l1, cap = _friction_lines(coef, x_prev)
    cat = np.concatenate
    rows_a = cat([coef.a / boxes, -coef.a / boxes], axis=-1)
    rows_b = cat([(coef.b + u1) / boxes, -(coef.b + l1) / boxes], axis=-1)
    rows_c = cat([(coef.c + u0) / boxes, -(coef.c + l0) / boxes], axis=-1)
    if coef.accel is not None:  # -a <= q' sdd + q'' sd^2 <= a
        d1, d2 = coef.accel
        rows_a = cat([rows_a, d1, -d1], axis=-1)
        rows_b = cat([rows_b, d2, -d2], axis=-1)
        rows_c = cat([rows_c, np.zeros_like(d1), np.zeros_like(d1)], axis=-1)
    x_max = np.minimum(np.minimum(coef.xv, cap), X_HUGE)
    # the start's own speed (inside its velocity limits)
    if isinstance(sd0, list):
        x_max[:, 0] = np.maximum(x_max[:, 0], [v ** 2 for v in sd0])
    else:
        x_max[0] = max(x_max[0], sd0 ** 2)
    return rows_a, rows_b, rows_c, x_max


def _compiled(model, s: np.ndarray, sd0: float, rows: tuple):
    """TOPP-RA's two sweeps in one compiled call: ``(x, "")``, (None, why) or None.

    :mod:`~tocontrol_ros.core.direct.sweeps` (each stage's LP in closed form): the same
    sets and timing as :func:`_seidel`, the same failures with the same messages. None
    when a forward step's greatest ``u`` is not feasible at the stage's ``x`` (rounding at
    a set's edge), where toppra lowers ``x`` and tries again: the caller then runs
    :func:`_seidel`, which does. ``rows``: :func:`_toppra`'s.
    """
    a, b, c, x_max = _partners_ordered(model, rows)
    return _verdict(*controllable_and_forward(model, a, b, c, x_max, s, sd0 ** 2)[:3], s)


def _partners_ordered(model, rows: tuple) -> tuple:
    """``rows`` with each row's partner half a row apart: [torque+, accel.+, torque-, accel.-].

    (The sweeps' pairing, :mod:`~tocontrol_ros.core.direct.sweeps`; on the last axis.)
    """
    a, b, c, x_max = rows
    m = a.shape[-1]
    if m != 2 * model.n:
        order = np.r_[0:model.n, 2 * model.n:3 * model.n, model.n:2 * model.n, 3 * model.n:m]
        a, b, c = a[..., order], b[..., order], c[..., order]
    return a, b, c, x_max


def _verdict(K: np.ndarray, x: np.ndarray, feasible: bool, s: np.ndarray):
    """:func:`_compiled`'s answer from a pass's sweeps (see there)."""
    last = len(s) - 1
    empty = ~(K[:last, 0] <= K[:last, 1])
    if empty.any():
        i = int(np.flatnonzero(empty)[-1])
        return None, f"the controllable set is empty at gridpoint {i} of {last}"
    small = _toppra_constant("SMALL")
    if x[0] + small < K[0, 0] or K[0, 1] + small < x[0]:
        return None, f"the start's path speed is not controllable (sd^2 = {x[0]:.6g} " \
            f"outside [{K[0, 0]:.6g}, {K[0, 1]:.6g}])"
    return (x, "") if feasible else None


@functools.cache
def _toppra_constant(name: str) -> float:
    """``toppra.constants.<name>``, imported on first use (toppra loads only when asked)."""
    import toppra.constants

    return getattr(toppra.constants, name)


def _seidel(constraint, dof: int, s: np.ndarray, sd0: float, rows: tuple):
    """TOPP-RA's two sweeps over toppra's compiled Seidel solver: ``(x, "")`` or (None, why).

    What ``toppra.algorithm.TOPPRA.compute_parameterization(sd0, 0)`` computes with
    ``solver_wrapper="seidel"`` (the same stage programs, objectives and safeguards: the
    controllable sets backward, then the greatest controllable ``x`` forward, each next
    ``x`` lowered by toppra's ``TINY`` or 0.01 % and a stage retried from a ``x`` 0.1 %
    lower when rounding makes it infeasible), without building the algorithm object per
    pass. Where Seidel's solver returns no answer for a stage's bound of ``x`` (it fails on
    rows nearly parallel to the ``u`` axis: a replan from a start moving at 1e-5 rad/s,
    whose parabola's tangent is 1e-8 at ``s = 0``), that bound is the stage program's exact
    one in closed form (:func:`_stage_interval`); ``rows``: :func:`_toppra`'s.
    """
    from toppra.constants import MAX_TRIES, SMALL, TINY
    from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

    wrapper = seidelWrapper([constraint], _path_class()(dof), s, solve_lp1d=True)
    solve = wrapper.solve_stagewise_optim
    deltas = wrapper.get_deltas()
    last = len(s) - 1
    K = np.zeros((last + 1, 2))
    g_upper, g_lower = np.array([1e-9, -1.0]), np.array([-1e-9, 1.0])
    wrapper.setup_solver()
    for i in range(last - 1, -1, -1):
        hi = solve(i, None, g_upper, np.nan, np.nan, K[i + 1, 0], K[i + 1, 1])[1]
        lo = solve(i, None, g_lower, np.nan, np.nan, K[i + 1, 0], K[i + 1, 1])[1]
        if np.isnan(hi) or np.isnan(lo):
            lo, hi = _stage_interval(rows, s, i, K[i + 1])
        if not lo <= hi:
            return None, f"the controllable set is empty at gridpoint {i} of {last}"
        K[i] = max(lo, 0.0), hi
    x = np.zeros(last + 1)
    x[0] = sd0 ** 2
    if x[0] + SMALL < K[0, 0] or K[0, 1] + SMALL < x[0]:
        return None, f"the start's path speed is not controllable (sd^2 = {x[0]:.6g} " \
            f"outside [{K[0, 0]:.6g}, {K[0, 1]:.6g}])"
    tries, i = 0, 0
    while i < last:
        g = np.array([-2.0 * deltas[i], -1.0])
        u = solve(i, None, g, x[i], x[i], K[i + 1, 0], K[i + 1, 1])[0]
        if np.isnan(u):
            if tries >= MAX_TRIES:
                return None, f"the forward sweep failed at gridpoint {i} of {last}"
            x[i] = max(x[i] - TINY, 0.999 * x[i])
            tries += 1
            continue
        tries = 0
        x_next = x[i] + 2.0 * deltas[i] * u
        x_next = max(x_next - TINY, 0.9999 * x_next)
        x[i + 1] = min(K[i + 1, 1], max(K[i + 1, 0], x_next))
        i += 1
    wrapper.close_solver()
    return x, ""


def _stage_interval(rows: tuple, s: np.ndarray, i: int, next_set: np.ndarray
                    ) -> tuple[float, float]:
    """Stage ``i``'s interval of ``x`` from which ``next_set`` is reachable, in closed form.

    Its rows ``alpha u + beta x <= gamma``: gridpoint ``i``'s, gridpoint ``i + 1``'s with
    ``x_{i+1} = x + 2 delta u`` put in, ``0 <= x <= x_max_i`` and ``lo <= x + 2 delta u <=
    hi``. Eliminating ``u`` (Fourier-Motzkin) is exact in two variables: every row bounding
    ``u`` above paired with every row bounding it below gives one linear bound of ``x``
    (multiplied through by ``-alpha_q alpha_p > 0``: no division by a small ``alpha``).
    ``(lo, hi)``; ``lo > hi`` when the stage has no ``x``.
    """
    a, b, c, x_max = rows
    two_d = 2.0 * (s[i + 1] - s[i])
    alpha = np.concatenate([a[i], a[i + 1] + two_d * b[i + 1], [two_d, -two_d]])
    beta = np.concatenate([b[i], b[i + 1], [1.0, -1.0]])
    gamma = np.concatenate([1.0 - c[i], 1.0 - c[i + 1], [next_set[1], -next_set[0]]])
    up, down = alpha > 0.0, alpha < 0.0
    coef = np.concatenate([(-alpha[down][None, :] * beta[up][:, None]
                            + alpha[up][:, None] * beta[down][None, :]).ravel(),
                           beta[~(up | down)]])
    rhs = np.concatenate([(-alpha[down][None, :] * gamma[up][:, None]
                           + alpha[up][:, None] * gamma[down][None, :]).ravel(),
                          gamma[~(up | down)]])
    if np.any((coef == 0.0) & (rhs < 0.0)):
        return np.inf, -np.inf
    pos, neg = coef > 0.0, coef < 0.0
    hi = min(float(np.min(rhs[pos] / coef[pos], initial=np.inf)), float(x_max[i]))
    lo = max(float(np.max(rhs[neg] / coef[neg], initial=-np.inf)), 0.0)
    return lo, hi


_CLASSES: dict = {}


def _constraint_class():
    """A TOPP-RA linear constraint with given rows.

    A class made on first use: toppra (and the matplotlib it imports) is loaded only when a
    first motion is asked for.
    """
    if "constraint" not in _CLASSES:
        from toppra.constraint import DiscretizationType, LinearConstraint
        from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate

        # Its failures are this module's results; its log lines would only repeat them.
        logging.getLogger("toppra").setLevel(logging.ERROR)

        class RowsConstraint(LinearConstraint):
            """``a u + b x + c <= 1`` row by row, ``0 <= x <= x_max``, per gridpoint."""

            def __init__(self, a, b, c, x_max):
                super().__init__()
                self.set_discretization_type(DiscretizationType.Interpolation)
                self.identical = True
                self.rows, self.x_max = (a, b, c), x_max

            def compute_constraint_params(self, path, gridpoints):
                a, b, c = self.rows
                m = a.shape[1]
                out = canlinear_colloc_to_interpolate(a, b, c, np.eye(m), np.ones(m), None,
                                                      None, gridpoints, identical=True)
                xbound = np.column_stack([np.zeros(len(gridpoints)), self.x_max])
                return (*out[:5], None, xbound)

        _CLASSES["constraint"] = RowsConstraint
    return _CLASSES["constraint"]


def _path_class():
    """A stand-in geometric path for TOPP-RA (the rows carry the path already)."""
    if "path" not in _CLASSES:
        from toppra.interpolator import AbstractGeometricPath

        class Unit(AbstractGeometricPath):
            def __init__(self, dof: int) -> None:
                self._dof = dof

            @property
            def dof(self) -> int:
                return self._dof

            @property
            def path_interval(self) -> np.ndarray:
                return np.array([0.0, 1.0])

        _CLASSES["path"] = Unit
    return _CLASSES["path"]
