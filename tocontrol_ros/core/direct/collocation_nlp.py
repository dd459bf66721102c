"""The symbolic NLP of the Hermite-Simpson transcription and its compiled functions.

Where the variables and constraints sit (:class:`Layout`), the per-point derivatives of
the dynamics and the per-interval chain rules, assembled into sparse constraint Jacobian
and Lagrangian Hessian (:class:`Scatter`), compiled once per model and mesh
(:func:`compiled_functions`). :class:`~tocontrol_ros.core.direct.collocation.DirectCollocation`
builds its IPOPT solver from these.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from tocontrol_ros.core.robot.compiled import LARGE_CFLAGS, compile_owned
from tocontrol_ros.core.robot.model import RobotModel, spd_solve

__all__ = ["Layout", "Scatter", "compiled_functions", "nlp_functions"]


class Layout:
    """Where the variables and constraints of the NLP sit (indices into ``w`` and ``g``).

    ``w = (vec X, vec U, vec UM, T)`` with ``X`` (2n, N + 1), ``U`` (n, N + 1), ``UM``
    (n, N) stored column by column; ``g = (vec defects, control set (unless box), start
    conditions, target conditions)``.
    """

    def __init__(self, n: int, m: int, intervals: int, start_kind: str, target_kind: str,
                 box: bool) -> None:
        self.n, self.m, self.N, self.box = n, m, intervals, box
        N = intervals
        self.nx = 2 * n * (N + 1)
        self.nu = n * (N + 1)
        self.num = n * N
        self.nw = self.nx + self.nu + self.num + 1
        self.iT = self.nw - 1
        self.kinds = (start_kind, target_kind)
        self.sizes = tuple(m if kind == "point" else 2 * n for kind in self.kinds)
        self.npar = sum(self.sizes) + 1
        self.r_ctrl = 2 * n * N
        self.n_ctrl = 0 if box else 2 * N + 1
        self.r_bound = (self.r_ctrl + self.n_ctrl,
                        self.r_ctrl + self.n_ctrl + self._rows(start_kind))
        self.ng = self.r_bound[1] + self._rows(target_kind)
        lbg = [np.zeros(self.r_ctrl), -np.inf * np.ones(self.n_ctrl),
               np.zeros(self.ng - self.r_ctrl - self.n_ctrl)]
        self.lbg = np.concatenate(lbg)
        self.ubg = np.zeros(self.ng)

    def _rows(self, kind: str) -> int:
        return self.m + self.n if kind == "point" else 2 * self.n

    def x(self, j: int) -> np.ndarray:
        """Indices of the state at node ``j``."""
        return 2 * self.n * j + np.arange(2 * self.n)

    def u(self, p: int) -> np.ndarray:
        """Indices of control column ``p`` of ``(U, UM)`` (nodes 0..N, then midpoints)."""
        return self.nx + self.n * p + np.arange(self.n)

    def z(self, j: int) -> np.ndarray:
        """Indices of ``(x_j, u_j)`` at node ``j``."""
        return np.concatenate([self.x(j), self.u(j)])

    def interval(self, j: int) -> np.ndarray:
        """Indices of the variables of interval ``j``: ``(x_j, x_j+1, u_j, u_j+1, um_j, T)``."""
        return np.concatenate([self.x(j), self.x(j + 1), self.u(j), self.u(j + 1),
                               self.u(self.N + 1 + j), [self.iT]])


class Scatter:
    """Sums blocks of values into one sparse matrix through a constant 0/1 matrix.

    Blocks are registered with :meth:`add` (the global row and column of each value, in the
    order of the values), then :meth:`apply` makes the sparsity (upper triangle only when
    ``triu``) and the matrix ``P`` with ``nonzeros = P @ values`` (entries that fall at the
    same place add up; values below the diagonal are dropped when ``triu``).
    """

    def __init__(self, nrow: int, ncol: int, triu: bool = False) -> None:
        self.shape = (nrow, ncol)
        self.triu = triu
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []

    def add(self, rows, cols) -> None:
        """Entries at ``rows`` x ``cols`` (broadcast; values column by column)."""
        rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
        self.rows.append(rows.ravel(order="F"))
        self.cols.append(cols.ravel(order="F"))

    def block(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """A dense block (values column by column) at ``rows`` x ``cols``."""
        self.add(np.asarray(rows)[:, None], np.asarray(cols)[None, :])

    def apply(self, values: ca.MX) -> ca.MX:
        """The sparse matrix of the added entries holding ``values``, in the order added."""
        nrow, ncol = self.shape
        rows = np.concatenate(self.rows)
        cols = np.concatenate(self.cols)
        assert values.numel() == rows.size, (values.numel(), rows.size)
        keep = np.flatnonzero(rows <= cols) if self.triu else np.arange(rows.size)
        key = cols[keep] * nrow + rows[keep]
        uniq, inv = np.unique(key, return_inverse=True)
        sp = ca.Sparsity.triplet(nrow, ncol, (uniq % nrow).tolist(), (uniq // nrow).tolist())
        gather = ca.DM(ca.Sparsity.triplet(uniq.size, rows.size, inv.tolist(), keep.tolist()),
                       1.0)
        return ca.sparsity_cast(ca.mtimes(gather, values), sp)


def _point_functions(model: RobotModel) -> list[ca.Function]:
    """The dynamics at one point ``z = (q, qd, u)`` and its derivatives (SX).

    ``a(z) = M(q)^-1 (scale u - b(q, qd))`` is the forward dynamics; its derivatives are
    taken through the inverse dynamics ``R(q, qd, a) = M(q) a + b(q, qd)`` (linear in ``a``),
    which is much smaller than differentiating the factorised mass matrix: with
    ``y = (q, qd)``, ``da/dz = M^-1 (-dR/dy, diag(scale))`` and, for ``mu = M^-1 v``,
    ``Hess_z(v^T a) = -(Hess_yy(mu^T R) (+) 0 + C^T A + A^T C)`` with
    ``C = (d(M mu)/dy, 0)`` and ``A = da/dz`` (``mu``, ``a`` held fixed inside ``R``).

    Returns
    -------
    list of casadi.Function
        ``direct_f``: (x, u, scale) -> ``f = (qd, a)``; ``direct_dyn``: (x, u, scale) ->
        (``a``, ``A = da/dz`` (n, 3n)); ``direct_dyn_hess``: (x, a, A, v) -> ``Hess_z(v^T a)``
        (3n, 3n), from the point's ``a`` and ``A``.
    """
    n = model.n
    x = ca.SX.sym("x", 2 * n)
    u = ca.SX.sym("u", n)
    scale = ca.SX.sym("scale", n)
    v = ca.SX.sym("v", n)
    acc = ca.SX.sym("a", n)
    jac = ca.SX.sym("A", n, 3 * n)
    mu = ca.SX.sym("mu", n)
    q, qd = x[:n], x[n:]
    qdd = model.forward_dynamics_sym(q, qd, scale * u)
    mass = model.mass_matrix_sym(q)
    rnea = model.rnea_sym(q, qd, acc)
    rhs = ca.horzcat(-ca.jacobian(rnea, x), ca.diag(scale))
    da = ca.Function("da", [x, acc, scale], [ca.horzcat(
        *[spd_solve(mass, rhs[:, i]) for i in range(3 * n)])])(x, qdd, scale)
    out = ca.cse(ca.vertcat(qdd, ca.vec(da)))
    lag = ca.dot(mu, rnea)
    curv = ca.Function("curv", [x, acc, mu], [
        ca.hessian(lag, x)[0], ca.jacobian(ca.jacobian(lag, acc).T, x)])
    hyy, c_y = curv(x, acc, spd_solve(mass, v))
    c_z = ca.horzcat(c_y, ca.SX.zeros(n, n))
    hess = -(ca.diagcat(hyy, ca.SX.zeros(n, n)) + ca.mtimes(c_z.T, jac)
             + ca.mtimes(jac.T, c_z))
    return [
        ca.Function("direct_f", [x, u, scale], [ca.vertcat(qd, qdd)]),
        ca.Function("direct_dyn", [x, u, scale],
                    [out[:n], ca.densify(ca.reshape(out[n:], n, 3 * n))]),
        ca.Function("direct_dyn_hess", [x, acc, jac, v], [ca.densify(ca.cse(hess))])]


def _unpack(lay: Layout, w: ca.MX) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX]:
    n, N = lay.n, lay.N
    return (ca.reshape(w[:lay.nx], 2 * n, N + 1),
            ca.reshape(w[lay.nx:lay.nx + lay.nu], n, N + 1),
            ca.reshape(w[lay.nx + lay.nu:lay.iT], n, N), w[lay.iT])


def _interval_functions(n: int) -> list[ca.Function]:
    """Derivative blocks of one interval's defect from its points' values (SX).

    Per point ``z = (q, qd, u)`` the dynamics ``f(z) = (qd, a(z))``; ``A = da/dz``,
    ``F = df/dz``. Interval ``j`` (``s = h/6``, ``sigma = h/8``, ``h = T/N``) has the midpoint
    ``xm = (x_j + x_j+1)/2 + sigma (f_j - f_j+1)``, ``zm = (xm, um_j)`` and the defect
    ``c_j = x_j+1 - x_j - s (f_j + 4 f(zm) + f_j+1)``.

    Jacobian of ``c_j``: ``-E - s (F_j + 4 Fm_x (E/2 + sigma F_j))`` in ``z_j``,
    ``E - s (F_j+1 + 4 Fm_x (E/2 - sigma F_j+1))`` in ``z_j+1``, ``-4 s Fm_u`` in ``um_j``
    and ``-(f_j + f_j+1 + 4 fm)/(6N) - 4 s Fm_x (f_j - f_j+1)/(8N)`` in ``T``.

    Hessian of ``lambda^T c_j``: the curvature of ``a`` enters only as ``Hess(w^T a)`` at a
    point, ``w`` being the adjoint of that point's ``a``: ``-4 s lambda_v`` at the midpoint
    (seen through ``D = d(zm)/d(z_j, z_j+1, um_j, T) = [[Pj, Pk, 0, t], [0, 0, I, 0]]``:
    ``D^T H D``), and ``-s lambda_v -+ 4 s sigma gx_v`` at the left/right node
    (``g = Fm^T lambda``, ``gx`` its state part, ``_v`` the velocity rows), summed over the
    two intervals of a node (:func:`_assembly_functions`). The rest is bilinear in ``T``:
    ``T``-``z_j``: ``-F_j^T lambda/(6N) - E^T gx/(3N) - T F_j^T gx/(6N^2)``, ``T``-``z_j+1``:
    ``-F_j+1^T lambda/(6N) - E^T gx/(3N) + T F_j+1^T gx/(6N^2)``, ``T``-``um_j``:
    ``-2 gc/(3N)``, ``T``-``T``: ``-gx^T (f_j - f_j+1)/(6N^2)``.

    Straight-line code (the mesh size ``N`` is an input), so it compiles with the model's
    per-point functions and a mesh only adds the gathering of the blocks.

    Returns
    -------
    list of casadi.Function
        ``direct_jac_int``: (Aj, Ak, Am, fj, fk, fm, T, N) -> Jacobian of ``c_j`` (2n, 7n + 1)
        in the variables ``(x_j, x_j+1, u_j, u_j+1, um_j, T)`` (their order in ``w``);
        ``direct_hess_int``: (Aj, Ak, fj, fk, Hm, g, lambda, T, N) -> upper triangle of the
        interval's Hessian block in the same variables, column by column.
    """
    sel = ca.DM(np.hstack([np.zeros((n, n)), np.eye(n), np.zeros((n, n))]))
    E = ca.DM(np.hstack([np.eye(2 * n), np.zeros((2 * n, n))]))
    Aj, Ak, Am = (ca.SX.sym(s, n, 3 * n) for s in ("Aj", "Ak", "Am"))
    fj, fk, fm = (ca.SX.sym(s, 2 * n) for s in ("fj", "fk", "fm"))
    T = ca.SX.sym("T")
    N = ca.SX.sym("N")
    lam = ca.SX.sym("lam", 2 * n)
    g = ca.SX.sym("g", 3 * n)
    Hm = ca.SX.sym("Hm", 3 * n, 3 * n)
    Fj, Fk, Fm = (ca.vertcat(sel, A) for A in (Aj, Ak, Am))
    s = T / N / 6
    sig = T / N / 8
    # (z_j, z_j+1, um_j, T) -> (x_j, x_j+1, u_j, u_j+1, um_j, T)
    order = np.concatenate([np.arange(2 * n), 3 * n + np.arange(2 * n), 2 * n + np.arange(n),
                            5 * n + np.arange(n), 6 * n + np.arange(n), [7 * n]]).tolist()
    d = 7 * n + 1
    Fmx, Fmu = Fm[:, :2 * n], Fm[:, 2 * n:]
    jac = ca.horzcat(
        -E - s * (Fj + 4 * ca.mtimes(Fmx, 0.5 * E + sig * Fj)),
        E - s * (Fk + 4 * ca.mtimes(Fmx, 0.5 * E - sig * Fk)),
        -4 * s * Fmu,
        -(fj + fk + 4 * fm) / (6 * N) - 4 * s * ca.mtimes(Fmx, fj - fk) / (8 * N))
    jac_int = ca.Function("direct_jac_int", [Aj, Ak, Am, fj, fk, fm, T, N],
                          [ca.densify(jac[:, order])])
    gx, gc = g[:2 * n], g[2 * n:]
    Pj = 0.5 * E + sig * Fj
    Pk = 0.5 * E - sig * Fk
    t = (fj - fk) / (8 * N)
    Hxx, Hxu, Huu = Hm[:2 * n, :2 * n], Hm[:2 * n, 2 * n:], Hm[2 * n:, 2 * n:]
    HPj, HPk, Ht = ca.mtimes(Hxx, Pj), ca.mtimes(Hxx, Pk), ca.mtimes(Hxx, t)
    Bjk = ca.mtimes(Pj.T, HPk)
    Bjc, Bkc = ca.mtimes(Pj.T, Hxu), ca.mtimes(Pk.T, Hxu)
    col_j = ca.mtimes(Pj.T, Ht) - ca.mtimes(Fj.T, lam) / (6 * N) \
        - ca.mtimes(E.T, gx) / (3 * N) - T * ca.mtimes(Fj.T, gx) / (6 * N ** 2)
    col_k = ca.mtimes(Pk.T, Ht) - ca.mtimes(Fk.T, lam) / (6 * N) \
        - ca.mtimes(E.T, gx) / (3 * N) + T * ca.mtimes(Fk.T, gx) / (6 * N ** 2)
    col_c = ca.mtimes(Hxu.T, t) - 2 * gc / (3 * N)
    col_t = ca.dot(t, Ht) - ca.dot(gx, fj - fk) / (6 * N ** 2)
    B = ca.blockcat([[ca.mtimes(Pj.T, HPj), Bjk, Bjc, col_j],
                     [Bjk.T, ca.mtimes(Pk.T, HPk), Bkc, col_k],
                     [Bjc.T, Bkc.T, Huu, col_c],
                     [col_j.T, col_k.T, col_c.T, col_t]])
    B = ca.densify(B[order, order])
    upper = ca.vertcat(*[B[r, c] for c in range(d) for r in range(c + 1)])
    hess_int = ca.Function("direct_hess_int", [Aj, Ak, fj, fk, Hm, g, lam, T, N],
                           [ca.cse(ca.densify(upper))])
    return [jac_int, hess_int]


def _assembly_functions(model: RobotModel, lay: Layout) -> list[ca.Function]:
    """The constraints, and the gathering of the derivative blocks into sparse matrices (MX).

    Adds the control set's and the boundary conditions' terms, and the nodes' weighted
    Hessians, whose weight is the adjoint of the node's acceleration summed over its two
    intervals (see :func:`_interval_functions`).

    Returns
    -------
    list of casadi.Function
        ``direct_asm_g``: (w, p, F, FM) -> g; ``direct_asm_jac``: (w, p, F, FM, J) -> (g,
        jac); ``direct_asm_adj``: (w, lam_g, AM) -> (midpoint weights, ``g = Fm^T lambda``
        per interval, node weights); ``direct_asm_hess``: (w, p, lam_g, B, H) -> upper
        triangle of the Lagrangian's Hessian. ``F``, ``H`` are the nodes' ``f`` and weighted
        Hessians side by side, ``FM``, ``AM`` the midpoints' ``f`` and ``da/dz``, ``J``, ``B``
        the intervals' blocks (:func:`_interval_functions`).
    """
    n, N = lay.n, lay.N
    fk, fk_jac, fk_hess = _kinematics_functions(model, lay)
    d = 7 * n + 1
    upper_r, upper_c = (np.array(v) for v in zip(*[(r, c) for c in range(d)
                                                   for r in range(c + 1)], strict=True))

    w = ca.MX.sym("w", lay.nw)
    par = ca.MX.sym("p", lay.npar)
    lam_g = ca.MX.sym("lam_g", lay.ng)
    F = ca.MX.sym("F", 2 * n, N + 1)
    FM = ca.MX.sym("FM", 2 * n, N)
    AM = ca.MX.sym("AM", n, 3 * n * N)
    J = ca.MX.sym("J", 2 * n, d * N)
    B = ca.MX.sym("B", upper_r.size, N)
    Hn = ca.MX.sym("H", 3 * n, 3 * n * (N + 1))
    X, U, UM, T = _unpack(lay, w)
    k = par[-1]
    h = T / N
    allu = ca.horzcat(U, UM)

    g, absu = _constraints(lay, par, X, allu, k, h, F, FM, fk)
    asm_g = ca.Function("direct_asm_g", [w, par, F, FM], [g])
    asm_jac = ca.Function("direct_asm_jac", [w, par, F, FM, J],
                          [g, _constraint_jacobian(lay, X, allu, absu, k, J, fk_jac)])
    wm, gm, wn = _adjoint_weights(lay, lam_g, AM, h)
    asm_adj = ca.Function("direct_asm_adj", [w, lam_g, AM], [wm, gm, wn])
    hess = _lagrangian_hessian(lay, X, absu, k, lam_g, B, Hn, (upper_r, upper_c), fk_hess)
    asm_hess = ca.Function("direct_asm_hess", [w, par, lam_g, B, Hn], [hess])
    return [asm_g, asm_jac, asm_adj, asm_hess]


def _kinematics_functions(model: RobotModel, lay: Layout
                          ) -> tuple[ca.Function, ca.Function, ca.Function]:
    """The point's forward kinematics and its derivatives (SX), for the point conditions.

    Returns
    -------
    P : casadi.Function
        ``q`` (n,), rad -> the point ``P(q)`` (m,), m.
    P_jac : casadi.Function
        ``q`` -> ``dP/dq`` (m, n), dense.
    P_hess : casadi.Function
        ``(q, nu)``, ``nu`` (m,) -> ``Hess_q(nu^T P)`` (n, n), dense.
    """
    n, m = lay.n, lay.m
    q_sym = ca.SX.sym("q", n)
    nu_sym = ca.SX.sym("nu", m)
    point = model.point_sym(q_sym)
    fk = ca.Function("P", [q_sym], [point])
    fk_jac = ca.Function("P_jac", [q_sym], [ca.densify(ca.jacobian(point, q_sym))])
    fk_hess = ca.Function("P_hess", [q_sym, nu_sym],
                          [ca.densify(ca.hessian(ca.dot(nu_sym, point), q_sym)[0])])
    return fk, fk_jac, fk_hess


def _boundaries(lay: Layout) -> tuple[tuple[str, int, int, int], tuple[str, int, int, int]]:
    """The start's and the target's ``(kind, node, offset, size)``.

    ``kind`` is "point" or "state", ``node`` the column of ``X`` the condition holds at (0
    or N), and ``p[offset:offset + size]`` its values in the NLP's parameters.
    """
    N = lay.N
    return ((lay.kinds[0], 0, 0, lay.sizes[0]), (lay.kinds[1], N, lay.sizes[0], lay.sizes[1]))


def _constraints(lay: Layout, par: ca.MX, X: ca.MX, allu: ca.MX, k: ca.MX, h: ca.MX,
                 F: ca.MX, FM: ca.MX, fk: ca.Function) -> tuple[ca.MX, ca.MX]:
    """The constraints ``g`` from the nodes' and the midpoints' dynamics (MX).

    Parameters
    ----------
    lay : Layout
    par : casadi.MX, shape (lay.npar, 1)
        The NLP's parameters (boundary values, then ``k``).
    X : casadi.MX, shape (2n, N + 1)
        The states at the nodes.
    allu : casadi.MX, shape (n, 2N + 1)
        The controls ``(U, UM)``, nodes then midpoints.
    k : casadi.MX
        The control set's exponent (``par[-1]``).
    h : casadi.MX
        The interval length ``T / N``, s.
    F : casadi.MX, shape (2n, N + 1)
        ``f`` at the nodes.
    FM : casadi.MX, shape (2n, N)
        ``f`` at the midpoints.
    fk : casadi.Function
        The point's forward kinematics (:func:`_kinematics_functions`).

    Returns
    -------
    g : casadi.MX, shape (lay.ng, 1)
        Defects, the control set (unless box), start and target conditions.
    absu : casadi.MX, shape (n, 2N + 1)
        ``|allu|``, which the derivatives share.
    """
    n = lay.n
    # Constraints: the same expression as the plain transcription.
    defects = X[:, 1:] - X[:, :-1] - h / 6 * (F[:, :-1] + 4 * FM + F[:, 1:])
    g = [ca.vec(defects)]
    # |u|^(2k): k need not be an integer.
    absu = ca.fabs(allu)
    if not lay.box:
        g.append(ca.sum1(absu ** (2 * k)).T - 1)
    for kind, col, offset, size in _boundaries(lay):
        xc = X[:, col]
        target = par[offset:offset + size]
        g += [fk(xc[:n]) - target, xc[n:]] if kind == "point" else [xc - target]
    g = ca.vertcat(*g)
    return g, absu


def _constraint_jacobian(lay: Layout, X: ca.MX, allu: ca.MX, absu: ca.MX, k: ca.MX,
                         J: ca.MX, fk_jac: ca.Function) -> ca.MX:
    """The sparse constraint Jacobian: the intervals' blocks scattered, and the rest (MX).

    Parameters
    ----------
    lay : Layout
    X : casadi.MX, shape (2n, N + 1)
        The states at the nodes.
    allu, absu : casadi.MX, shape (n, 2N + 1)
        The controls ``(U, UM)`` and their absolute values (:func:`_constraints`).
    k : casadi.MX
        The control set's exponent.
    J : casadi.MX, shape (2n, (7n + 1) N)
        The intervals' defect Jacobians side by side (``direct_jac_int``).
    fk_jac : casadi.Function
        ``dP/dq`` (:func:`_kinematics_functions`).

    Returns
    -------
    casadi.MX, shape (lay.ng, lay.nw)
        ``dg/dw``, sparse.
    """
    n, m, N = lay.n, lay.m, lay.N
    sc = Scatter(lay.ng, lay.nw)
    values = [ca.vec(J)]
    for j in range(N):
        sc.block(2 * n * j + np.arange(2 * n), lay.interval(j))
    if not lay.box:
        values.append(ca.vec(2 * k * ca.sign(allu) * absu ** (2 * k - 1)))
        for p in range(2 * N + 1):
            sc.add(lay.r_ctrl + p, lay.u(p))
    for (kind, col, _, _), row in zip(_boundaries(lay), lay.r_bound, strict=True):
        xi = lay.x(col)
        if kind == "point":
            values += [ca.vec(fk_jac(X[:n, col])), ca.DM.ones(n)]
            sc.block(row + np.arange(m), xi[:n])
            sc.add(row + m + np.arange(n), xi[n:])
        else:
            values.append(ca.DM.ones(2 * n))
            sc.add(row + np.arange(2 * n), xi)
    return sc.apply(ca.vertcat(*values))


def _adjoint_weights(lay: Layout, lam_g: ca.MX, AM: ca.MX, h: ca.MX
                     ) -> tuple[ca.MX, ca.MX, ca.MX]:
    """The adjoints of the accelerations at the midpoints and the nodes (the chain rule, MX).

    With ``s = h/6``, ``sigma = h/8`` and the defects' multipliers ``lambda`` (2n, N): the
    midpoint of interval ``j`` weighs its ``a`` with ``-4 s lambda_v``; node ``j`` with
    ``-s lambda_v - 4 s sigma gv`` from the interval it starts and ``-s lambda_v + 4 s sigma
    gv`` from the one it ends, ``g = Fm^T lambda`` (see :func:`_interval_functions`).

    Parameters
    ----------
    lay : Layout
    lam_g : casadi.MX, shape (lay.ng, 1)
        The constraints' multipliers (the defects' first).
    AM : casadi.MX, shape (n, 3n N)
        ``da/dz`` at the midpoints side by side.
    h : casadi.MX
        The interval length ``T / N``, s.

    Returns
    -------
    wm : casadi.MX, shape (n, N)
        The midpoints' weights.
    gm : casadi.MX, shape (3n, N)
        ``Fm^T lambda`` per interval.
    wn : casadi.MX, shape (n, N + 1)
        The nodes' weights, summed over their two intervals.
    """
    n, N = lay.n, lay.N
    lam = ca.reshape(lam_g[:2 * n * N], 2 * n, N)
    s = h / 6
    sigma = h / 8
    a_sym = ca.SX.sym("A", n, 3 * n)
    l_sym = ca.SX.sym("lam", 2 * n)
    adj = ca.Function("adj", [a_sym, l_sym], [  # Fm^T lambda with Fm = ((0, I, 0), A)
        ca.vertcat(ca.SX.zeros(n), l_sym[:n], ca.SX.zeros(n))
        + ca.mtimes(a_sym.T, l_sym[n:])])
    gm = adj.map(N)(AM, lam)
    lam_v = lam[n:, :]
    gv = gm[n:2 * n, :]
    zero = ca.MX.zeros(n, 1)
    wn = (ca.horzcat(-s * lam_v - 4 * s * sigma * gv, zero)
          + ca.horzcat(zero, -s * lam_v + 4 * s * sigma * gv))
    return -4 * s * lam_v, gm, wn


def _lagrangian_hessian(lay: Layout, X: ca.MX, absu: ca.MX, k: ca.MX, lam_g: ca.MX,
                        B: ca.MX, Hn: ca.MX, upper: tuple[np.ndarray, np.ndarray],
                        fk_hess: ca.Function) -> ca.MX:
    """The upper triangle of the Lagrangian's Hessian, its blocks scattered (MX).

    Parameters
    ----------
    lay : Layout
    X : casadi.MX, shape (2n, N + 1)
        The states at the nodes.
    absu : casadi.MX, shape (n, 2N + 1)
        ``|(U, UM)|`` (:func:`_constraints`).
    k : casadi.MX
        The control set's exponent.
    lam_g : casadi.MX, shape (lay.ng, 1)
        The constraints' multipliers.
    B : casadi.MX, shape ((7n + 1)(7n + 2)/2, N)
        The intervals' upper triangles (``direct_hess_int``), column by column.
    Hn : casadi.MX, shape (3n, 3n (N + 1))
        The nodes' weighted Hessians side by side.
    upper : tuple of ndarray
        Rows and columns of an interval block's upper triangle, in the order of ``B``.
    fk_hess : casadi.Function
        ``Hess_q(nu^T P)`` (:func:`_kinematics_functions`).

    Returns
    -------
    casadi.MX, shape (lay.nw, lay.nw)
        The Hessian's upper triangle, sparse.
    """
    n, m, N = lay.n, lay.m, lay.N
    upper_r, upper_c = upper
    sh = Scatter(lay.nw, lay.nw, triu=True)
    values = [ca.vec(B), ca.vec(Hn)]
    for j in range(N):
        v = lay.interval(j)
        sh.add(v[upper_r], v[upper_c])
    for j in range(N + 1):
        sh.block(lay.z(j), lay.z(j))
    if not lay.box:
        mu = lam_g[lay.r_ctrl:lay.r_ctrl + lay.n_ctrl].T
        values.append(ca.vec(2 * k * (2 * k - 1) * absu ** (2 * k - 2) * ca.repmat(mu, n, 1)))
        for p in range(2 * N + 1):
            sh.add(lay.u(p), lay.u(p))
    for (kind, col, _, _), row in zip(_boundaries(lay), lay.r_bound, strict=True):
        if kind == "point":
            qi = lay.x(col)[:n]
            values.append(ca.vec(fk_hess(X[:n, col], lam_g[row:row + m])))
            sh.block(qi, qi)
    return sh.apply(ca.vertcat(*values))


def nlp_functions(lay: Layout, point: list[ca.Function], asm: list[ca.Function],
                   scale: np.ndarray) -> dict:
    """The NLP's functions from the per-point, interval and assembly functions.

    Returns
    -------
    dict of casadi.Function
        ``g``: (w, p) -> g; ``grad_f``: (w, p) -> (f, grad); ``jac_g``: (w, p) -> (g, jac)
        and ``hess_l``: (w, p, lam_f, lam_g) -> upper triangle, the signatures ``nlpsol``
        expects for its ``grad_f``, ``jac_g`` and ``hess_lag`` options.
    """
    n, N = lay.n, lay.N
    f_pt, dyn, dyn_hess, jac_int, hess_int = point
    asm_g, asm_jac, asm_adj, asm_hess = asm
    w = ca.MX.sym("w", lay.nw)
    par = ca.MX.sym("p", lay.npar)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", lay.ng)
    X, U, UM, T = _unpack(lay, w)
    h = T / N
    S = ca.DM(scale)

    F = f_pt.map(N + 1)(X, U, S)
    XM = 0.5 * (X[:, :-1] + X[:, 1:]) + h / 8 * (F[:, :-1] - F[:, 1:])
    FM = f_pt.map(N)(XM, UM, S)
    g_fun = ca.Function("g", [w, par], [asm_g(w, par, F, FM)], ["x", "p"], ["g"])
    grad = ca.DM.zeros(lay.nw)  # dense: IPOPT's interface copies it as a dense vector
    grad[lay.iT] = 1.0
    grad_f = ca.Function("grad_f", [w, par], [T, grad], ["x", "p"], ["f", "grad"])

    an, An = dyn.map(N + 1)(X, U, S)
    F = ca.vertcat(X[n:, :], an)
    XM = 0.5 * (X[:, :-1] + X[:, 1:]) + h / 8 * (F[:, :-1] - F[:, 1:])
    am, AM = dyn.map(N)(XM, UM, S)
    FM = ca.vertcat(XM[n:, :], am)
    Aj, Ak = An[:, :3 * n * N], An[:, 3 * n:]
    J = jac_int.map(N)(Aj, Ak, AM, F[:, :-1], F[:, 1:], FM, T, N)
    g, jac = asm_jac(w, par, F, FM, J)
    jac_g = ca.Function("jac_g", [w, par], [g, jac], ["x", "p"], ["g", "jac"])

    wm, G, wn = asm_adj(w, lam_g, AM)
    HM = dyn_hess.map(N)(XM, am, AM, wm)
    Hn = dyn_hess.map(N + 1)(X, an, An, wn)
    lam = ca.reshape(lam_g[:2 * n * N], 2 * n, N)
    B = hess_int.map(N)(Aj, Ak, F[:, :-1], F[:, 1:], HM, G, lam, T, N)
    hess = asm_hess(w, par, lam_g, B, Hn)
    hess_l = ca.Function("hess_l", [w, par, lam_f, lam_g], [hess],
                         ["x", "p", "lam_f", "lam_g"], ["hess"])
    return {"g": g_fun, "grad_f": grad_f, "jac_g": jac_g, "hess_l": hess_l}


def _flags(n: int) -> tuple[str, ...] | None:
    """The optimised flags of the per-point and per-interval libraries of an n-joint arm."""
    # As one library their source was above LARGE_SOURCE from 7 joints on (the Panda 1.76 MB,
    # the xArm7 1.87 MB; the UR5 0.89 MB).
    return LARGE_CFLAGS if n >= 7 else None


def compiled_functions(model: RobotModel, lay: Layout) -> tuple[list, str, list, str]:
    """The per-point and the assembly functions, compiled once per model (and mesh)."""
    n, N = lay.n, lay.N
    # The dynamics' derivatives (the costly part to compile) depend on the model only. Two
    # libraries, built at the same time, optimised with the flags they had as one library
    # (the same code as before; -O2 takes gcc several times longer on these sources).
    point, how_point = compile_owned(model, "direct_point", f"direct_point{n}",
                                     lambda: _point_functions(model), _flags(model.n))
    inter, how_inter = compile_owned(model, "direct_interval", f"direct_interval{n}",
                                     lambda: _interval_functions(n), _flags(model.n))
    if how_inter != how_point:
        how_point = f"{how_point}, intervals {how_inter}"
    asm, how_asm = compile_owned(
        model, ("direct_asm", N, lay.kinds, lay.box),
        f"direct_asm{n}x{N}", lambda: _assembly_functions(model, lay))
    return point + inter, how_point, asm, how_asm
