"""TOPP-RA's two sweeps in one compiled call: each stage's 2-variable LP in closed form.

A TOPP-RA pass (:mod:`~tocontrol_ros.core.direct.time_scaling`) is a backward sweep (the
controllable sets ``K_i = [lo_i, hi_i]`` of ``x = sd^2``) and a forward sweep (the greatest
controllable ``x``), each over the ``N`` stages of the path; a stage is a linear program in
two variables ``u = sdd`` and ``x``: its rows ``alpha u + beta x <= gamma`` (gridpoint
``i``'s, gridpoint ``i + 1``'s with ``x_{i+1} = x + 2 delta u`` put in, as toppra's
interpolation discretisation gives them), ``|u| <= U_BOUND`` and ``0 <= x <= x_max_i``
(toppra's Seidel solver's bounds), and the next stage's set ``K_{i+1}`` as two more rows.
Driven stage by stage from Python over toppra's Seidel solver, the per-stage calls are most
of a quick replan's scaling time; here both sweeps are one CasADi function compiled to C:

- a stage's ``x`` range is the projection of its polygon on ``x``, by Fourier-Motzkin
  elimination (exact in two variables): the rows with ``alpha = 0`` as they are, and every
  pair of rows with opposite signs of ``alpha`` combined into one bound of ``x`` (multiplied
  through by ``|alpha|``, no division by a small ``alpha``). Branch-free: a min / max over
  the pairs with ``if_else`` on the signs, vector operations that the generated C runs as
  loops; a stage without ``x`` (``lo > hi``, or a row ``0 <= rhs < 0``) gives
  ``(inf, -inf)``;
- the forward sweep's greedy ``u`` at the stage's ``x`` is the least upper bound of the rows
  with ``alpha > 0``; it reports whether that ``u`` is feasible (rounding can leave the
  start's ``x`` a hair outside its set, where toppra retries from a slightly lower ``x``:
  the caller then runs the Seidel driver, which does);
- the backward sweep is a ``mapaccum`` of the stage over the reversed stages, the forward
  sweep a ``mapaccum`` over the stages, both in one function whose inputs are the rows:
  one library per row count and grid size serves every problem of a robot, cached by
  :func:`~tocontrol_ros.core.robot.compiled.compile_owned` (without a compiler, CasADi's
  virtual machine: the same numbers).

Decided by work: a fixed number of stages and rows, no clock.
"""

from __future__ import annotations

import weakref

import casadi as ca
import numpy as np

from tocontrol_ros.core.robot.compiled import BufferedFunction, compile_owned

__all__ = ["U_BOUND", "sweeps_function", "controllable_and_forward",
           "controllable_and_forward_many"]

#: ``|u| = |sdd|`` bound of every stage: toppra's Seidel solver's ``VAR_MIN`` / ``VAR_MAX``
#: on its variables (kept so that a stage whose rows do not bound ``u`` gives its numbers).
U_BOUND = 1e8

def _stage_rows(a, b, g, two_d, k_next):
    """A stage's rows with the next set's two and the ``u`` bounds: (alpha, beta, gamma)."""
    one = ca.DM.ones(1, 1)
    alpha = ca.vertcat(a, two_d, -two_d, one, -one)
    beta = ca.vertcat(b, one, -one, 0.0, 0.0)
    gamma = ca.vertcat(g, k_next[1], -k_next[0], U_BOUND, U_BOUND)
    return alpha, beta, gamma


def _all_rows(total: int) -> ca.Function:
    """Every row both as an up row and as a down row (zeroed where it is not one).

    ``(alpha, beta, gamma (total,)) -> (up, down (3, total), singles (3,))``: an up row
    weighs ``max(alpha, 0)``, a down row ``max(-alpha, 0)``, and a row of weight 0 has its
    ``beta`` and ``gamma`` set to 0, so that a pair without a true up row and a true down
    row is ``0 x <= 0``; ``singles``: ``(hi, lo, flat)`` of the rows with ``alpha = 0``.
    """
    alpha, beta, gamma = (ca.SX.sym(name, total) for name in ("a", "b", "g"))
    up, down = alpha > 0.0, alpha < 0.0
    rows_up = ca.horzcat(ca.fmax(alpha, 0.0), ca.if_else(up, beta, 0.0),
                         ca.if_else(up, gamma, 0.0)).T
    rows_down = ca.horzcat(ca.fmax(-alpha, 0.0), ca.if_else(down, beta, 0.0),
                           ca.if_else(down, gamma, 0.0)).T
    return ca.Function("toppra_all_rows", [alpha, beta, gamma],
                       [rows_up, rows_down, ca.vertcat(*_bounds(beta, gamma, alpha == 0.0))])


def _backward_stage(rows: int) -> ca.Function:
    """``(K_{i+1} (2,), alpha, beta, gamma (rows,), x_max_i, 2 delta_i) -> K_i (2,)``.

    Every up row with every down row of the stage (the next set's and the ``u`` bounds
    included): Fourier-Motzkin for any signs of ``alpha``.
    """
    a, b, g = (ca.MX.sym(name, rows) for name in ("a", "b", "g"))
    k_next, x_max, two_d = ca.MX.sym("k_next", 2), ca.MX.sym("x_max"), ca.MX.sym("two_d")
    alpha, beta, gamma = _stage_rows(a, b, g, two_d, k_next)
    total = rows + 4
    up, down, singles = _all_rows(total)(alpha, beta, gamma)
    own = _own_pairs(total)(up, down, singles)
    hi, lo = ca.fmin(own[0], x_max), ca.fmax(own[1], 0.0)
    k = ca.if_else(own[2] > 0.0, ca.vertcat(ca.inf, -ca.inf), ca.vertcat(lo, hi))
    return ca.Function("toppra_back_stage", [k_next, a, b, g, x_max, two_d], [k])


def _forward_stage(rows: int, tiny: float) -> ca.Function:
    """``(x_i, alpha, beta, gamma, x_max_i, 2 delta_i, K_{i+1}) -> (x_{i+1}, feasible)``.

    ``x_{i+1}``: ``x_i + 2 delta_i u`` with the greatest feasible ``u``, lowered by
    ``tiny`` or 0.01 % and put into ``K_{i+1}`` (toppra's forward step).
    """
    a, b, g = (ca.SX.sym(name, rows) for name in ("a", "b", "g"))
    x, x_max, two_d = ca.SX.sym("x"), ca.SX.sym("x_max"), ca.SX.sym("two_d")
    k_next = ca.SX.sym("k_next", 2)
    alpha, beta, gamma = _stage_rows(a, b, g, two_d, k_next)
    r = gamma - beta * x
    u_hi = ca.mmin(ca.if_else(alpha > 0.0, r / alpha, ca.inf))
    u_lo = ca.mmax(ca.if_else(alpha < 0.0, r / alpha, -ca.inf))
    flat_bad = ca.mmax(ca.if_else(ca.logic_and(alpha == 0.0, r < 0.0), 1.0, 0.0))
    feasible = ca.logic_and(ca.logic_and(u_lo <= u_hi, flat_bad == 0.0),
                            ca.logic_and(x >= 0.0, x <= x_max))
    x_next = x + two_d * u_hi
    x_next = ca.fmax(x_next - tiny, 0.9999 * x_next)
    x_next = ca.fmin(k_next[1], ca.fmax(k_next[0], x_next))
    return ca.Function("toppra_fwd_stage", [x, a, b, g, x_max, two_d, k_next],
                       [x_next, feasible])


def _sweeps(rows: int, stages: int, tiny: float) -> ca.Function:
    """Both sweeps: ``(A, B, G (rows, N), x_max (1, N), 2 delta (1, N), x_0) -> (K, x, ok)``.

    ``K`` (2, N + 1): the controllable sets (``K_N = [0, 0]``: rest at the end); ``x``
    (1, N): ``x_1 ... x_N`` of the forward sweep from ``x_0``; ``ok`` (1, N): whether each
    stage's greedy ``u`` was feasible. Every pair of a stage's rows in the sequential sweep
    (what :func:`_paired_sweeps` falls back on).
    """
    A, B, G = (ca.MX.sym(name, rows, stages) for name in ("A", "B", "G"))
    x_max, two_d, x0 = ca.MX.sym("x_max", 1, stages), ca.MX.sym("two_d", 1, stages), \
        ca.MX.sym("x0")
    back = _backward_stage(rows).mapaccum("toppra_back", stages)
    rev = list(range(stages - 1, -1, -1))
    k_rev = back(ca.DM.zeros(2, 1), A[:, rev], B[:, rev], G[:, rev], x_max[:, rev],
                 two_d[:, rev])
    K = ca.horzcat(k_rev[:, rev], ca.DM.zeros(2, 1))
    fwd = _forward_stage(rows, tiny).mapaccum("toppra_fwd", stages)
    x, ok = fwd(x0, A, B, G, x_max, two_d, K[:, 1:])
    return ca.Function(f"toppra_sweeps_{rows}x{stages}", [A, B, G, x_max, two_d, x0],
                       [K, x, ok], ["A", "B", "G", "x_max", "two_d", "x0"],
                       ["K", "x", "ok"])


def _bounds(coef, rhs, valid=None):
    """``(hi, lo, contradiction)`` of the bounds ``coef x <= rhs`` (those ``valid``)."""
    up, down, flat = coef > 0.0, coef < 0.0, ca.logic_and(coef == 0.0, rhs < 0.0)
    if valid is not None:
        up, down, flat = (ca.logic_and(valid, v) for v in (up, down, flat))
    ratio = rhs / coef
    return (ca.mmin(ca.if_else(up, ratio, ca.inf)), ca.mmax(ca.if_else(down, ratio, -ca.inf)),
            ca.mmax(ca.if_else(flat, 1.0, 0.0)))


def _own_rows(rows: int) -> ca.Function:
    """A stage's own rows as up and down rows.

    ``(alpha, beta, gamma (rows,)) -> (up, down (3, rows / 2 + 1), singles (3,), exact)``.
    The rows come in partners (row ``j`` of each gridpoint's half and row ``j + h`` of the
    other half, ``h`` a quarter of ``rows``: a joint's upper and lower bound), which have
    opposite signs of ``alpha`` but where friction lines differ. Of each partner pair the
    row with the larger ``alpha`` is its *up* row, the other its *down* row, and the ``u``
    bounds one more pair; an up row weighs ``max(alpha, 0)`` and a down row
    ``max(-alpha, 0)``, a row of weight 0 has its ``beta`` and ``gamma`` set to 0, so that
    a pair without a true up row and a true down row is ``0 x <= 0`` (``up``, ``down``:
    rows of weight, beta, gamma). ``singles``: ``(hi, lo, flat)`` of the rows with
    ``alpha = 0``. ``exact``: no partner pair has two rows of one sign (else a row would be
    left unpaired: the caller then uses every pair).
    """
    alpha, beta, gamma = (ca.SX.sym(name, rows) for name in ("a", "b", "g"))
    h = rows // 4
    first = [*range(h), *range(2 * h, 3 * h)]
    second = [*range(h, 2 * h), *range(3 * h, 4 * h)]
    sel = alpha[first] >= alpha[second]
    pick = [(ca.if_else(sel, v[first], v[second]), ca.if_else(sel, v[second], v[first]))
            for v in (alpha, beta, gamma)]
    (a_up, a_dn), (b_up, b_dn), (g_up, g_dn) = pick
    a_up, b_up, g_up = (ca.vertcat(v, w) for v, w in zip((a_up, b_up, g_up),
                                                          (1.0, 0.0, U_BOUND), strict=True))
    a_dn, b_dn, g_dn = (ca.vertcat(v, w) for v, w in zip((a_dn, b_dn, g_dn),
                                                          (-1.0, 0.0, U_BOUND), strict=True))
    w_up, w_dn = ca.fmax(a_up, 0.0), ca.fmax(-a_dn, 0.0)
    b_up, g_up = ca.if_else(a_up > 0.0, b_up, 0.0), ca.if_else(a_up > 0.0, g_up, 0.0)
    b_dn, g_dn = ca.if_else(a_dn < 0.0, b_dn, 0.0), ca.if_else(a_dn < 0.0, g_dn, 0.0)
    singles = _bounds(beta, gamma, alpha == 0.0)
    exact = ca.logic_not(ca.logic_or(ca.mmax(a_dn) > 0.0, ca.mmin(a_up) < 0.0))
    return ca.Function("toppra_own_rows", [alpha, beta, gamma],
                       [ca.horzcat(w_up, b_up, g_up).T, ca.horzcat(w_dn, b_dn, g_dn).T,
                        ca.vertcat(*singles), exact])


def _up_row_pairs(count: int) -> ca.Function:
    """One up row with every down row: ``(up_p (3,), down (3, count)) -> (hi, lo, flat)``.

    ``count`` pairs, by selects rather than C's ``fmin`` (a library call); mapped over the
    up rows (:func:`_own_pairs`), so that the C source grows with the rows, not with their
    pairs.
    """
    up, down = ca.SX.sym("up", 3), ca.SX.sym("down", 3, count)
    coef = down[0, :].T * up[1] + up[0] * down[1, :].T
    rhs = down[0, :].T * up[2] + up[0] * down[2, :].T
    ratio = rhs / coef
    hi, lo, flat = ca.SX(ca.inf), ca.SX(-ca.inf), ca.SX(0.0)
    for k in range(count):
        c, r = coef[k], ratio[k]
        hi = ca.if_else(ca.logic_and(c > 0.0, r < hi), r, hi)
        lo = ca.if_else(ca.logic_and(c < 0.0, r > lo), r, lo)
        flat = ca.logic_or(flat, ca.logic_and(c == 0.0, rhs[k] < 0.0))
    return ca.Function("toppra_up_row_pairs", [up, down], [ca.vertcat(hi, lo, flat)])


def _reduce(count: int) -> ca.Function:
    """``(partial (3, count), singles (3,)) -> (hi, lo, flat) (3,)``: the up rows' bounds."""
    part, singles = ca.SX.sym("part", 3, count), ca.SX.sym("singles", 3)
    hi, lo, flat = singles[0], singles[1], singles[2]
    for k in range(count):
        hi = ca.if_else(part[0, k] < hi, part[0, k], hi)
        lo = ca.if_else(part[1, k] > lo, part[1, k], lo)
        flat = ca.logic_or(flat, part[2, k])
    return ca.Function("toppra_reduce", [part, singles], [ca.vertcat(hi, lo, flat)])


def _own_pairs(count: int) -> ca.Function:
    """Every up row with every down row: ``(up, down (3, count), singles (3,)) -> (3,)``.

    ``(hi, lo, flat)`` of the ``count^2`` pairs and the singles (about a quarter of every
    pair of a stage's rows).
    """
    up, down, singles = ca.MX.sym("up", 3, count), ca.MX.sym("down", 3, count), \
        ca.MX.sym("singles", 3)
    part = _up_row_pairs(count).map(count, [False, True], [False])(up, down)
    return ca.Function("toppra_own_pairs", [up, down, singles],
                       [_reduce(count)(part, singles)])


def _paired_stage(count: int) -> ca.Function:
    """``(K_{i+1}, own (3,), up, down (3, count), x_max_i, 2 delta_i) -> K_i``.

    The next set's two rows paired with the stage's weighted up and down rows and with each
    other, then with the stage's own bounds ``own`` and ``0 <= x <= x_max_i``.
    """
    k_next, own = ca.SX.sym("k_next", 2), ca.SX.sym("own", 3)
    up, down = ca.SX.sym("up", 3, count), ca.SX.sym("down", 3, count)
    x_max, two_d = ca.SX.sym("x_max"), ca.SX.sym("two_d")
    # x + 2 delta u <= K1 (up, weight 2 delta) with each down row; -x - 2 delta u <= -K0
    # (down) with each up row; the two together.
    coef = ca.vertcat(down[0, :].T + two_d * down[1, :].T,
                      two_d * up[1, :].T + up[0, :].T * -1.0, two_d * 1.0 + two_d * -1.0)
    rhs = ca.vertcat(down[0, :].T * k_next[1] + two_d * down[2, :].T,
                     two_d * up[2, :].T + up[0, :].T * -k_next[0],
                     two_d * k_next[1] + two_d * -k_next[0])
    hi, lo, flat = _bounds(coef, rhs)
    hi, lo = ca.fmin(ca.fmin(own[0], hi), x_max), ca.fmax(ca.fmax(own[1], lo), 0.0)
    k = ca.if_else(ca.fmax(own[2], flat) > 0.0, ca.vertcat(ca.inf, -ca.inf),
                   ca.vertcat(lo, hi))
    return ca.Function("toppra_paired_stage", [k_next, own, up, down, x_max, two_d], [k])


def _paired_sweeps(rows: int, stages: int, tiny: float) -> ca.Function:
    """:func:`_sweeps` with each stage's own rows paired up with down.

    :func:`_own_rows` and :func:`_own_pairs` for all stages in one map ahead of the
    sequential sweep (:func:`_paired_stage`), the same numbers as :func:`_sweeps` with
    about a quarter of the pairs; one more output ``exact`` (1, N): where it is 0 the
    result is not :func:`_sweeps`', and the caller uses that instead.
    """
    A, B, G = (ca.MX.sym(name, rows, stages) for name in ("A", "B", "G"))
    x_max, two_d, x0 = ca.MX.sym("x_max", 1, stages), ca.MX.sym("two_d", 1, stages), \
        ca.MX.sym("x0")
    count = rows // 2 + 1
    up, down, singles, exact = _own_rows(rows).map(stages)(A, B, G)
    own = _own_pairs(count).map(stages)(up, down, singles)
    rev = list(range(stages - 1, -1, -1))
    up_rev = ca.horzcat(*(up[:, count * i:count * (i + 1)] for i in rev))
    down_rev = ca.horzcat(*(down[:, count * i:count * (i + 1)] for i in rev))
    back = _paired_stage(count).mapaccum("toppra_paired_back", stages)
    k_rev = back(ca.DM.zeros(2, 1), own[:, rev], up_rev, down_rev, x_max[:, rev],
                 two_d[:, rev])
    K = ca.horzcat(k_rev[:, rev], ca.DM.zeros(2, 1))
    fwd = _forward_stage(rows, tiny).mapaccum("toppra_fwd", stages)
    x, ok = fwd(x0, A, B, G, x_max, two_d, K[:, 1:])
    return ca.Function(f"toppra_paired_{rows}x{stages}", [A, B, G, x_max, two_d, x0],
                       [K, x, ok, exact], ["A", "B", "G", "x_max", "two_d", "x0"],
                       ["K", "x", "ok", "exact"])


#: model -> {(rows, stages): (the library's function, both buffered)}: a plain call converts
#: every argument to CasADi's DM, 0.2 ms of a 0.4 ms call on the Panda.
_BUFFERED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def sweeps_function(model: object, rows: int, stages: int
                    ) -> tuple[BufferedFunction, BufferedFunction]:
    """Both sweeps for ``rows`` rows per stage and ``stages`` stages, compiled, per model.

    Parameters
    ----------
    model : object
        Owner of the library (a :class:`~tocontrol_ros.core.robot.model.RobotModel`, held
        weakly); the cache on disk is keyed by the source, which depends only on ``rows`` and
        ``stages``, so every robot with as many rows shares the file.
    rows : int
        Rows of a stage (gridpoint ``i``'s and ``i + 1``'s, a multiple of 4), without the
        four added.
    stages : int
        ``N``: the path's segments.

    Returns
    -------
    paired, every : BufferedFunction
        ``(A, B, G (rows, N), x_max (1, N), two_d (1, N), x0) -> (K (2, N + 1), x (1, N),
        ok (1, N)[, exact (1, N)])`` (see :func:`controllable_and_forward`): the own rows
        paired up with down (:func:`_paired_sweeps`), and every pair (:func:`_sweeps`).
    """
    from toppra.constants import TINY

    funs, _ = compile_owned(model, ("toppra_sweeps", rows, stages),
                            f"toppra_sweeps_{rows}x{stages}",
                            lambda: [_paired_sweeps(rows, stages, TINY),
                                     _sweeps(rows, stages, TINY)])
    table = _BUFFERED.setdefault(model, {})
    key = (rows, stages)
    if key not in table or table[key][0] is not funs[0]:
        table[key] = (funs[0], BufferedFunction(funs[0]), BufferedFunction(funs[1]))
    return table[key][1], table[key][2]


def _paired_mapped(model: object, rows: int, stages: int, count: int) -> BufferedFunction:
    """The paired sweeps (:func:`sweeps_function`'s first) mapped over ``count`` paths.

    The library's own function called once per path inside one call (CasADi's ``map``: the
    same compiled code, the same numbers), buffered; kept per model with the library.
    """
    sweeps_function(model, rows, stages)  # the library, loaded or built: its entry's first
    table = _BUFFERED[model]
    paired = table[(rows, stages)][0]
    key = (rows, stages, count)
    if key not in table or table[key][0] is not paired:
        table[key] = (paired, BufferedFunction(paired.map(count)))
    return table[key][1]


def controllable_and_forward(model: object, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                             x_max: np.ndarray, s: np.ndarray, x0: float
                             ) -> tuple[np.ndarray, np.ndarray, bool, bool]:
    """One TOPP-RA pass's sweeps on rows ``a u + b x + c <= 1`` per gridpoint.

    Parameters
    ----------
    model : object
        The robot model (owner of the compiled library).
    a, b, c : ndarray, shape (N + 1, m)
        The rows at the gridpoints (normalised: ``<= 1``), ``m`` even: column ``j`` and
        column ``j + m / 2`` partners (one joint's upper and lower bound, ``alpha`` of
        opposite signs but where friction lines differ), as
        :func:`~tocontrol_ros.core.direct.time_scaling.time_scaling` builds them.
    x_max : ndarray, shape (N + 1,)
        Upper bound of ``x = sd^2`` at each gridpoint (1/s^2).
    s : ndarray, shape (N + 1,)
        The gridpoints (path parameter, increasing).
    x0 : float
        The start's ``x`` (1/s^2).

    Returns
    -------
    K : ndarray, shape (N + 1, 2)
        The controllable sets ``[lo, hi]`` (1/s^2); a stage without one has ``lo > hi`` or
        NaN there, and so do the stages before it.
    x : ndarray, shape (N + 1,)
        The forward sweep's ``x`` from ``x0`` (meaningless where ``K`` is empty).
    feasible : bool
        Whether every forward step's ``u`` was feasible.
    paired : bool
        Whether the paired sweep served (False: a partner pair had one sign somewhere, and
        every pair was taken: the same numbers, more work).
    """
    two_d = 2.0 * np.diff(s)
    A = np.concatenate([a[:-1], a[1:] + two_d[:, None] * b[1:]], axis=1).T
    B = np.concatenate([b[:-1], b[1:]], axis=1).T
    G = np.concatenate([1.0 - c[:-1], 1.0 - c[1:]], axis=1).T
    paired, every = sweeps_function(model, A.shape[0], A.shape[1])
    args = (A, B, G, x_max[None, :-1], two_d[None, :], x0)
    K, x, ok, exact = paired(*args)
    used = bool(np.all(exact))
    if not used:
        K, x, ok = every(*args)
    return K.T, np.concatenate([[x0], x.ravel()]), bool(np.all(ok)), used


def controllable_and_forward_many(model: object, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                                  x_max: np.ndarray, s: np.ndarray, x0: np.ndarray) -> list:
    """:func:`controllable_and_forward` of several paths' rows on one grid, in one call.

    Parameters
    ----------
    model : object
        The robot model (owner of the compiled library).
    a, b, c : ndarray, shape (P, N + 1, m)
        Each path's rows, as :func:`controllable_and_forward` takes them.
    x_max : ndarray, shape (P, N + 1)
        Each path's upper bounds of ``x`` (1/s^2).
    s : ndarray, shape (N + 1,)
        The gridpoints.
    x0 : ndarray, shape (P,)
        Each path's start ``x`` (1/s^2).

    Returns
    -------
    list of tuple
        Per path, what :func:`controllable_and_forward` returns for its rows: the same
        numbers (the paired sweep mapped over the paths; a path where it does not serve is
        swept again alone, as that function does).
    """
    count, stages = a.shape[0], a.shape[1] - 1
    two_d = 2.0 * np.diff(s)
    A = np.concatenate([a[:, :-1], a[:, 1:] + two_d[None, :, None] * b[:, 1:]], axis=2)
    B = np.concatenate([b[:, :-1], b[:, 1:]], axis=2)
    G = np.concatenate([1.0 - c[:, :-1], 1.0 - c[:, 1:]], axis=2)
    rows = A.shape[2]
    # columns path after path, as CasADi's map concatenates its instances' inputs
    A, B, G = (v.transpose(2, 0, 1).reshape(rows, count * stages) for v in (A, B, G))
    fun = _paired_mapped(model, rows, stages, count)
    K, x, ok, exact = fun(A, B, G, x_max[:, :-1].reshape(1, -1),
                          np.tile(two_d, count)[None, :], np.asarray(x0, dtype=float)[None, :])
    exact, ok = (v.reshape(count, stages).all(axis=1) for v in (exact, ok))
    K = K.reshape(2, count, stages + 1)
    x = np.concatenate([np.asarray(x0, dtype=float)[:, None], x.reshape(count, stages)],
                       axis=1)
    return [(K[:, i].T, x[i], bool(ok[i]), True) if exact[i] else  # else every pair, alone
            controllable_and_forward(model, a[i], b[i], c[i], x_max[i], s, float(x0[i]))
            for i in range(count)]
