"""Multiple shooting with exact sensitivities (solved by :mod:`.newton`).

Unknowns ``w = (z_0, ..., z_N, T, nu_0, nu_T)``: the canonical state ``z = (x, psi)`` at the
``N + 1`` nodes of a uniform grid in normalised time, the final time, and the multipliers of
the transversality conditions. Equations: continuity ``z_{j+1} - Phi_j(z_j, T) = 0`` (each
interval integrated with a fixed number of RK4 steps, its Jacobians by CasADi's forward
mode) and the boundary and transversality conditions (21) in multiplier form:

- start point ``p0``: ``P(q(0)) = p0``, ``qd(0) = 0``, ``psi_q(0) = J(q(0))^T nu_0``;
- start joint state ``(q0, qd0)``: ``x(0) = (q0, qd0)``;
- target point, target joint state: likewise at ``T``;
- ``H(T) = 0``.

``psi_q = J^T nu`` says that ``psi_q`` is orthogonal to the tangent space ``null(J)`` of the
self-motion manifold, which is the paper's (18)-(20) without choosing ``m`` independent
columns, so it holds for any ``n >= m`` wherever ``J`` has full rank (for ``n = m`` it is
void, as it should be). The system is square: ``4n(N+1) + 1 + 2m`` unknowns and equations.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from tocontrol_ros.core.indirect.pmp import BufferedFunction, CanonicalSystem
from tocontrol_ros.core.indirect.tuning import GRADING
from tocontrol_ros.core.robot.compiled import c_name, compile_function

__all__ = ["ShootingGrid", "integrate", "step_fractions"]


def step_fractions(kinds: np.ndarray, steps: int, grading: float = GRADING) -> np.ndarray:
    """RK4 step lengths of each interval as fractions of the interval.

    Parameters
    ----------
    kinds : ndarray of int, shape (N,)
        0: uniform steps; 1: steps graded towards the interval's end (a switch of the
        control law there); -1: graded towards its start.
    steps : int
    grading : float
        Step ``s`` of a graded interval ends at ``(s / steps) ** grading`` of the interval,
        counted from the switch.

    Returns
    -------
    ndarray, shape (N, steps)
        Rows sum to 1.
    """
    kinds = np.asarray(kinds, dtype=int)
    uniform = np.full(steps, 1.0 / steps)
    towards_start = np.diff((np.arange(steps + 1) / steps) ** grading)
    table = {0: uniform, -1: towards_start, 1: towards_start[::-1]}
    return np.array([table[int(c)] for c in kinds]).reshape(len(kinds), steps)


def integrate(system: CanonicalSystem, starts: np.ndarray, lengths: np.ndarray, steps: int,
              t_final: float, par: np.ndarray, sensitivities: bool = True,
              fractions: np.ndarray | None = None):
    """Integrate ``dz/dtau = T F(z)`` over intervals, each with ``steps`` RK4 steps.

    Parameters
    ----------
    system : CanonicalSystem
    starts : ndarray, shape (N, 4n)
        State at the start of each interval.
    lengths : ndarray, shape (N,)
        Interval lengths in normalised time.
    steps : int
    t_final : float
        ``T`` (s).
    par : ndarray, shape (3,)
        ``(k, delta, torque_scale)``.
    sensitivities : bool
    fractions : ndarray, shape (N, steps), optional
        Step lengths as fractions of each interval (:func:`step_fractions`); default
        uniform.

    Returns
    -------
    z1 : ndarray, shape (N, 4n)
        End states.
    a : ndarray, shape (N, 4n, 4n)
        ``dz1/dz0`` per interval (None without sensitivities).
    b : ndarray, shape (N, 4n)
        ``dz1/dT`` per interval (None without sensitivities). The end state depends on
        ``T`` and the interval's length only through their product, so ``dz1/dlength`` is
        ``b * T / length``.
    """
    lengths = np.asarray(lengths, dtype=float)
    if fractions is None:
        fractions = np.full((len(lengths), steps), 1.0 / steps)
    if not system.stagewise:  # one compiled call for all intervals and steps
        c = lengths[:, None] * fractions
        with np.errstate(over="ignore", invalid="ignore"):
            return system.interval_batch(np.asarray(starts, dtype=float), t_final * c, c, par,
                                         sensitivities)
    z = np.ascontiguousarray(starts.T)
    a_tot = b_tot = None
    with np.errstate(over="ignore", invalid="ignore"):  # non-finite results are checked
        for i in range(steps):
            dtau = lengths * fractions[:, i]
            z, a_s, b_s = system.step_batch(z, (t_final * dtau)[None, :], par, sensitivities)
            if not sensitivities:
                continue
            db = b_s * dtau[:, None]  # dz1/dT = dz1/dh * dh/dT
            if i == 0:
                a_tot, b_tot = a_s, db
            else:
                a_tot = a_s @ a_tot
                b_tot = np.einsum("nij,nj->ni", a_s, b_tot) + db
    return z.T, a_tot, b_tot


class ShootingGrid:
    """Compiled equations of one problem structure on one grid.

    Parameters
    ----------
    system : CanonicalSystem
    lengths : ndarray, shape (N,)
        Lengths of the shooting intervals in normalised time (sum 1).
    steps : int
        RK4 steps per interval.
    start_kind, target_kind : {"point", "state"}
    kinds : ndarray of int, shape (N,), optional
        Step grading per interval (see :func:`step_fractions`); default all uniform.
    breaks : sequence of (int, int), optional
        Switch nodes ``(node, i)``: node ``node`` (0 < node < N, increasing) sits where the
        switching function ``S_i`` changes sign. Each adds its normalised time as an unknown
        and ``S_i(z_node) = 0`` as an equation, so the mesh moves with the switches; the
        intervals between two break nodes keep their relative lengths.
    """

    def __init__(self, system: CanonicalSystem, lengths: np.ndarray, steps: int,
                 start_kind: str, target_kind: str, kinds: np.ndarray | None = None,
                 breaks=()) -> None:
        self.system = system
        self.lengths = np.asarray(lengths, dtype=float)
        self.N = len(self.lengths)
        self.steps = steps
        self.start_kind = start_kind
        self.target_kind = target_kind
        self.kinds = (np.zeros(self.N, dtype=int) if kinds is None
                      else np.asarray(kinds, dtype=int).copy())
        self.fractions = step_fractions(self.kinds, steps)
        self.breaks = tuple((int(j), int(i)) for j, i in breaks)
        nodes_b = [j for j, _ in self.breaks]
        if any(not 0 < j < self.N for j in nodes_b) or np.any(np.diff(nodes_b) <= 0):
            raise ValueError(f"break nodes must increase within (0, {self.N}): {nodes_b}")
        self.B = len(self.breaks)
        self._break_nodes = np.array(nodes_b, dtype=int)
        self._break_comp = np.array([i for _, i in self.breaks], dtype=int)
        bounds = np.concatenate([[0], nodes_b, [self.N]]).astype(int)
        self._segment = np.searchsorted(bounds, np.arange(self.N), side="right") - 1
        seg_len = np.add.reduceat(self.lengths, bounds[:-1])
        self._rel = self.lengths / seg_len[self._segment]
        model = system.model
        n, m = model.n, model.m
        self.n, self.m = n, m
        self.nz = 4 * n
        self.n_nu0 = m if start_kind == "point" else 0
        self.n_nuT = m if target_kind == "point" else 0
        self._col_T = self.nz * (self.N + 1)
        self._col_b = self._col_T + 1 + self.n_nu0 + self.n_nuT
        self.size = self._col_b + self.B
        self.tau = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.bc = self._boundary_function()
        self._switch = self._switch_function() if self.B else None
        self._pattern()

    # ------------------------------------------------------------ mesh
    def lengths_of(self, w: np.ndarray) -> np.ndarray:
        """Interval lengths (N,) at unknowns ``w`` (they move with the break times)."""
        if not self.B:
            return self.lengths
        bounds = np.concatenate([[0.0], w[self._col_b:], [1.0]])
        return self._rel * np.diff(bounds)[self._segment]

    def tau_of(self, w: np.ndarray) -> np.ndarray:
        """Node times (N + 1,) in normalised time at unknowns ``w``."""
        return np.concatenate([[0.0], np.cumsum(self.lengths_of(w))])

    def flow(self, nodes: np.ndarray, t_final: float, par: np.ndarray, sensitivities=True,
             lengths: np.ndarray | None = None):
        """Integrate every interval from its start node (see :func:`integrate`)."""
        lengths = self.lengths if lengths is None else lengths
        return integrate(self.system, nodes[:-1], lengths, self.steps, t_final, par,
                         sensitivities, self.fractions)

    # ------------------------------------------------------------ boundary
    def _boundary_function(self) -> ca.Function:
        key = ("bc", self.start_kind, self.target_kind)
        cache = self.system.function_cache
        if key in cache:
            return cache[key]
        model, n, m = self.system.model, self.n, self.m
        z0 = ca.SX.sym("z0", self.nz)
        zT = ca.SX.sym("zT", self.nz)
        nu0 = ca.SX.sym("nu0", self.n_nu0)
        nuT = ca.SX.sym("nuT", self.n_nuT)
        ns = m if self.start_kind == "point" else 2 * n
        nt = m if self.target_kind == "point" else 2 * n
        values = ca.SX.sym("values", ns + nt)
        res = []
        for kind, z, nu, val in ((self.start_kind, z0, nu0, values[:ns]),
                                 (self.target_kind, zT, nuT, values[ns:])):
            q = z[:n]
            if kind == "point":
                jac = ca.jacobian(model.point_sym(q), q)
                res += [model.point_sym(q) - val, z[n:2 * n],
                        z[2 * n:3 * n] - ca.mtimes(jac.T, nu)]
            else:
                res.append(z[:2 * n] - val)
        ham = ca.Function("H", [self.system.z, self.system.par], [self.system.ham])
        res.append(ham(zT, self.system.par))
        r = ca.vertcat(*res)
        args = [z0, zT, nu0, nuT]
        fun = ca.Function(f"tocontrol_bc_{self.start_kind}_{self.target_kind}_"
                          f"{c_name(model.name)}_{n}",
                          [z0, zT, nu0, nuT, values, self.system.par],
                          [r] + [ca.densify(ca.jacobian(r, a)) for a in args])
        cache[key] = BufferedFunction(compile_function(fun)[0])  # with every residual
        return cache[key]

    def _switch_compiled(self) -> ca.Function:
        """``(z, par) -> (S, dS/dz)`` at one node, compiled (shared by the grids)."""
        cache = self.system.function_cache
        if "switch" not in cache:
            sy = self.system
            fun = ca.Function(f"tocontrol_switch_{c_name(sy.model.name)}_{sy.n}",
                              [sy.z, sy.par], [sy.s, ca.densify(ca.jacobian(sy.s, sy.z))])
            cache["switch"] = compile_function(fun)[0]
        return cache["switch"]

    def _switch_function(self) -> BufferedFunction:
        """``(z (4n, B), par (3, B)) -> (S (n, B), dS/dz (n, 4n B))`` at the break nodes."""
        switch = self._switch_compiled()
        return self.system.sized(("switch_buffer", self.B), lambda: BufferedFunction(
            switch.map(self.B, "serial")))

    def compile(self) -> None:
        """Build the compiled functions of this grid's equations now (not on first use)."""
        self._boundary_function()
        self._switch_compiled()

    # ------------------------------------------------------- sparse pattern
    def _pattern(self) -> None:
        """Row/column indices of the Jacobian's non-zeros, in the order values are filled.

        The values are filled in this order on every evaluation; the permutation to
        compressed-column order is computed once per structure (interval count, break
        nodes, boundary kinds) and kept with the system's other per-size objects.
        """
        key = ("pattern", self.N, tuple(self._break_nodes), self.start_kind, self.target_kind)
        (self._order, self._indices, self._indptr, self._break_j,
         self._break_sign) = self.system.sized(key, self._make_pattern)
        self._eye = np.ones(self.nz)

    def _make_pattern(self) -> tuple:
        nz, N = self.nz, self.N
        rows, cols = [], []
        it = np.arange(nz)
        rr, cc = np.meshgrid(it, it, indexing="ij")
        col_T = self._col_T
        for j in range(N):
            r0 = j * nz
            rows.append((r0 + rr).ravel())   # -A_j at block column j
            cols.append((j * nz + cc).ravel())
            rows.append(r0 + it)             # +I at block column j + 1
            cols.append((j + 1) * nz + it)
            rows.append(r0 + it)             # -b_j at column T
            cols.append(np.full(nz, col_T))
        # Break times: interval j of segment s ends at break s and starts at break s - 1.
        break_cols = []
        for j in range(N):
            s = self._segment[j]
            for b in (s, s - 1):
                if 0 <= b < self.B:
                    rows.append(j * nz + it)
                    cols.append(np.full(nz, self._col_b + b))
                    break_cols.append((j, 1.0 if b == s else -1.0))
        nbc = nz + 1 + self.n_nu0 + self.n_nuT
        r_bc = nz * N + np.arange(nbc)
        blocks = [np.arange(nz), N * nz + np.arange(nz),
                  col_T + 1 + np.arange(self.n_nu0),
                  col_T + 1 + self.n_nu0 + np.arange(self.n_nuT)]
        for b in blocks:
            rr2, cc2 = np.meshgrid(r_bc, b, indexing="ij")
            rows.append(rr2.ravel())
            cols.append(cc2.ravel())
        for r, (node, _) in enumerate(self.breaks):  # S_i(z_node) = 0
            rows.append(np.full(nz, nz * N + nbc + r))
            cols.append(node * nz + it)
        rows = np.concatenate(rows)
        cols = np.concatenate(cols)
        order = np.lexsort((rows, cols))
        if np.any((np.diff(cols[order]) == 0) & (np.diff(rows[order]) == 0)):
            raise AssertionError("duplicate entries in the Jacobian pattern")
        indptr = np.searchsorted(cols[order], np.arange(self.size + 1)).astype(np.int32)
        break_j = np.array([j for j, _ in break_cols], dtype=int)
        break_sign = np.array([sign for _, sign in break_cols])
        return order, rows[order].astype(np.int32), indptr, break_j, break_sign

    # ------------------------------------------------------------ pack/unpack
    def unpack(self, w: np.ndarray):
        """Split unknowns into nodes (N + 1, 4n), T, nu0 (m or 0), nuT (m or 0).

        The break times, if any, are ``w[grid.size - grid.B:]`` (see :meth:`lengths_of`).
        """
        nz, N = self.nz, self.N
        nodes = w[:nz * (N + 1)].reshape(N + 1, nz)
        t_final = w[self._col_T]
        nu0 = w[self._col_T + 1: self._col_T + 1 + self.n_nu0]
        nuT = w[self._col_T + 1 + self.n_nu0: self._col_b]
        return nodes, float(t_final), nu0, nuT

    def pack(self, nodes: np.ndarray, t_final: float, nu0=None, nuT=None) -> np.ndarray:
        """Inverse of :meth:`unpack`.

        Missing multipliers start at 0; the break times are those of the lengths given at
        construction.
        """
        nu0 = np.zeros(self.n_nu0) if nu0 is None else np.asarray(nu0, dtype=float)
        nuT = np.zeros(self.n_nuT) if nuT is None else np.asarray(nuT, dtype=float)
        t_breaks = self.tau[self._break_nodes]
        return np.concatenate([np.asarray(nodes, dtype=float).ravel(), [t_final], nu0, nuT,
                               t_breaks])

    # ------------------------------------------------------------ equations
    def residual(self, w: np.ndarray, values: np.ndarray, par: np.ndarray,
                 jacobian: bool = True):
        """Equations ``G(w)`` (size,) and, optionally, their sparse Jacobian (CSC)."""
        nodes, t_final, nu0, nuT = self.unpack(w)
        lengths = self.lengths_of(w)
        z1, a, b = self.flow(nodes, t_final, par, sensitivities=jacobian, lengths=lengths)
        cont = (nodes[1:] - z1).ravel()
        bc_out = self.bc(nodes[0], nodes[-1], nu0, nuT, values, par)
        parts = [cont, bc_out[0]]
        if self.B:
            s_val, s_jac = self._switch(nodes[self._break_nodes].T,
                                        np.broadcast_to(par[:, None], (3, self.B)))
            s_val = s_val.reshape(self.n, self.B)  # 1-D when there is one break
            parts.append(s_val[self._break_comp, np.arange(self.B)])
        g = np.concatenate(parts)
        if not jacobian:
            return g, None
        vals = [np.concatenate([-a.reshape(self.N, -1), np.broadcast_to(self._eye,
                                                                         (self.N, self.nz)),
                                -b], axis=1).ravel()]
        if self.B:
            dlen = b * (t_final / lengths)[:, None]  # dz1/dlength
            vals.append((-dlen[self._break_j]
                         * (self._break_sign * self._rel[self._break_j])[:, None]).ravel())
        for blk in bc_out[1:]:
            vals.append(blk.ravel())
        if self.B:  # row i of dS/dz at each break node
            vals.append(s_jac.reshape(self.n, self.B, self.nz)[self._break_comp,
                                                                np.arange(self.B)].ravel())
        data = np.concatenate(vals)[self._order]
        jac = sp.csc_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))
        return g, jac

    def admissible_step(self, w: np.ndarray, step: np.ndarray) -> float:
        """Largest fraction of ``step`` (at most 1) that keeps ``T`` positive.

        ``T`` and every interval length stay above a fifth of their current values.
        """
        lam = 1.0
        col_T = self._col_T
        if step[col_T] < 0 and w[col_T] + step[col_T] <= 0.2 * w[col_T]:
            lam = 0.8 * w[col_T] / -step[col_T]
        if self.B:
            now = self.lengths_of(w)
            while lam > 1e-6 and np.any(self.lengths_of(w + lam * step) <= 0.2 * now):
                lam *= 0.5
        return lam
