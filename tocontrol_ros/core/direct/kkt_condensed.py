"""The parametric step's KKT system with the barrier's inequality rows eliminated.

The parametric step (:mod:`~tocontrol_ros.core.direct.sensitivity`) solves, at each Newton
step, the primal-dual barrier system

    [[H + S_x, J^T], [J, -D]] [dw; dy] = [r_w; r_y]

with ``D`` a row's ``1 / sigma`` (its barrier's curvature ``sigma = z / slack``) where the
row is an inequality left to the barrier, and a small regularisation where it is an
equality or a row held at its bound. The inequality rows ``I`` give ``dy_I = sigma_I (J_I dw
- r_I)``; substituted, the system left is

    [[H + S_x + J_I^T Sigma_I J_I, J_E^T], [J_E, -D_E]] [dw; dy_E]
        = [r_w + J_I^T Sigma_I r_I; r_E]

over the variables and the equality and held rows ``E`` only: on the Panda's 24 spans 213
unknowns with a band of 41 instead of 468 with 65 (:class:`CondensedKKT`; the full
system is :class:`~tocontrol_ros.core.direct.sensitivity.BandedKKT`). The product ``J_I^T
Sigma_I J_I`` is summed span by span: every row (a sample's set row, a velocity row) touches
the control points of one span and ``T``, so the rows of a span make a dense block of
``(degree + 1) n + 1`` columns, and their products are one batched matrix product.

The elimination multiplies by ``sigma``, which reaches ``1e9`` and more on nearly active
rows, where the full system's partial pivoting keeps such rows' small ``D`` apart. Every
solve is therefore checked against the full system: its normwise backward error (the
residual's largest entry over the largest entries of the products that make it, at most
:data:`BACKWARD_TOL`); a solve that fails the check is refined once and, failing again,
left to the full system's LU (the caller counts those). On the 20 moves of
bench/warm_resolve.py the condensed solves' backward errors were about 1e-15 (median;
the full LU's about the same, up to 7e-10), 6 of about 300 solves went to the full LU,
and every move took the same steps to the same ``T`` (to 1e-15) as with the full LU
(docs/limits.md). The band's ordering depends on which rows are held: one layout per set
of held rows, kept.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

__all__ = ["BACKWARD_TOL", "CondensedKKT"]

#: A condensed solve is accepted when the full system's normwise backward error is at most
#: this: the full LU's own worst on the 20 moves was 7e-10 (median 5e-15); the condensed
#: first pass had 3e-11 (median), 4e-7 at worst, and 32 of 186 solves needed the refinement.
BACKWARD_TOL = 1e-9


class CondensedKKT:
    """The barrier system condensed onto the variables and the equality rows.

    Parameters
    ----------
    jac_rc, hess_rc : tuple of ndarray
        Row and column indices of the rows' Jacobian's nonzeros (rows, K n + 1) and of the
        Lagrangian Hessian's upper triangle (K n + 1, K n + 1), in the order of their
        nonzeros (column-major, as CasADi gives them).
    nw, ng : int
        Variables (K n control-point entries, then ``T``) and rows.
    n : int
        Joints: a control point's variables are ``n`` consecutive entries.
    """

    def __init__(self, jac_rc: tuple, hess_rc: tuple, nw: int, ng: int, n: int) -> None:
        jr, jc = (np.asarray(a, dtype=int) for a in jac_rc)
        hr, hc = (np.asarray(a, dtype=int) for a in hess_rc)
        self.jr, self.jc, self.hr, self.hc = jr, jc, hr, hc
        self.nw, self.ng, self.n, self.iT = nw, ng, n, nw - 1
        iT = nw - 1
        self.off = hr != hc
        # Each row's span: its first control point; its block's columns are the control
        # points from there (as many as the widest row needs) and T, last.
        path = jc != iT
        cp = jc // n
        first = np.full(ng, np.iinfo(int).max)
        np.minimum.at(first, jr[path], cp[path])
        last = np.full(ng, -1)
        np.maximum.at(last, jr[path], cp[path])
        touched = last >= 0
        first = np.where(touched, first, 0)
        width = int(np.max(last[touched] - first[touched])) + 1 if np.any(touched) else 1
        W = width * n + 1
        groups = int(np.max(first)) + 1
        # Rows per group, each row's slot within it.
        counts = np.bincount(first, minlength=groups)
        mr = int(np.max(counts))
        order = np.argsort(first, kind="stable")
        slot_row = np.empty(ng, dtype=int)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot_row[order] = np.arange(ng) - np.repeat(starts, counts)
        col_slot = np.where(path, (cp - first[jr]) * n + jc % n, W - 1)
        self.a_shape = (groups, mr, W)
        self.a_at = (first[jr] * mr + slot_row[jr]) * W + col_slot
        # The row behind each (group, slot); padding slots point at an extra zero.
        row_of = np.full(groups * mr, ng)
        row_of[first * mr + slot_row] = np.arange(ng)
        self.row_of = row_of
        # The variable behind each block column (-1 past the last control point).
        base = np.arange(groups)[:, None] * n + np.arange(width * n)[None, :]
        var = np.concatenate([np.where(base < iT, base, -1),
                              np.full((groups, 1), iT)], axis=1)  # (groups, W)
        g_rows = np.broadcast_to(var[:, :, None], (groups, W, W)).ravel()
        g_cols = np.broadcast_to(var[:, None, :], (groups, W, W)).ravel()
        # Every entry of the condensed matrix by its (row, column) in the full numbering
        # (variables 0..nw-1, rows nw..nw+ng-1): H, its mirror, the diagonal, J, J^T, and the
        # blocks J_I^T Sigma J_I; an entry whose row or column is not kept drops out.
        N = nw + ng
        self.rows = np.concatenate([hr, hc[self.off], np.arange(N), nw + jr, jc, g_rows])
        self.cols = np.concatenate([hc, hr[self.off], np.arange(N), jc, nw + jr, g_cols])
        self.g_valid = (g_rows >= 0) & (g_cols >= 0)
        # The full system's ordering along the path (as BandedKKT's): a row after the
        # control points it touches, T the border.
        key_w = np.arange(nw, dtype=float) // n
        tot, cnt = np.zeros(ng), np.zeros(ng)
        np.add.at(tot, jr[path], key_w[jc[path]])
        np.add.at(cnt, jr[path], 1.0)
        key_g = np.where(cnt > 0, tot / np.maximum(cnt, 1.0), 0.0)
        core = np.concatenate([np.arange(iT), nw + np.arange(ng)])
        keys = np.concatenate([key_w[:iT], key_g + 0.5])
        self.order = core[np.argsort(keys, kind="stable")]
        self._layouts: dict[bytes, dict] = {}

    def _layout(self, kept: np.ndarray) -> dict:
        """The band's ordering and each entry's place in it for these kept rows (cached)."""
        key = np.packbits(kept).tobytes()
        lay = self._layouts.get(key)
        if lay is not None:
            return lay
        nw, iT = self.nw, self.iT
        N = nw + self.ng
        keep = np.zeros(N, dtype=bool)
        keep[:iT] = True
        keep[nw:] = kept
        sel = self.order[keep[self.order]]
        pos = np.full(N, -1)
        pos[sel] = np.arange(len(sel))
        rows = np.where(self.rows >= 0, self.rows, 0)
        cols = np.where(self.cols >= 0, self.cols, 0)
        valid = np.ones(len(rows), dtype=bool)
        valid[len(valid) - len(self.g_valid):] = self.g_valid
        pr, pc = np.where(valid, pos[rows], -1), np.where(valid, pos[cols], -1)
        inner = (pr >= 0) & (pc >= 0)
        kl = int(np.max(pr[inner] - pc[inner]))
        ku = int(np.max(pc[inner] - pr[inner]))
        rows_ab = 2 * kl + ku + 1
        col_T = valid & (cols == iT) & (self.cols >= 0) & (pr >= 0)
        diag_T = valid & (rows == iT) & (cols == iT) & (self.rows >= 0)
        lay = {"pos": pos, "M": len(sel), "kl": kl, "ku": ku, "shape": (rows_ab, len(sel)),
               "inner": inner, "lin": (kl + ku + pr[inner] - pc[inner]) + pc[inner] * rows_ab,
               "col_T": col_T, "col_T_at": pr[col_T], "diag_T": diag_T,
               "core": pos >= 0}
        if len(self._layouts) > 64:  # a solve's sets of held rows: a few
            self._layouts.clear()
        self._layouts[key] = lay
        return lay

    def _blocks(self, jac: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """``J_I^T Sigma J_I`` span by span: (groups, W, W), flattened."""
        a = np.zeros(self.a_shape)
        a.reshape(-1)[self.a_at] = jac
        s = np.append(sigma, 0.0)[self.row_of].reshape(self.a_shape[:2])
        return np.matmul(np.swapaxes(a * s[:, :, None], 1, 2), a).reshape(-1)

    def factor(self, hess: np.ndarray, diag_w: np.ndarray, jac: np.ndarray,
               sigma: np.ndarray, kept: np.ndarray, d_kept: float):
        """Factorise the condensed matrix; None if singular.

        Parameters
        ----------
        hess : ndarray, shape (nnz(H),)
            The Lagrangian Hessian's upper-triangle nonzeros.
        diag_w : ndarray, shape (nw,)
            Added to the Hessian's diagonal (the bounds' barrier curvature and the primal
            regularisation).
        jac : ndarray, shape (nnz(J),)
            The rows' Jacobian's nonzeros.
        sigma : ndarray, shape (ng,)
            The barrier curvature of each inequality row (0 on the kept rows).
        kept : ndarray of bool, shape (ng,)
            The equality and held rows, kept as rows of the system.
        d_kept : float
            Their regularisation (the matrix holds ``-d_kept`` on their diagonal).
        """
        lay = self._layout(kept)
        diag_rows = np.where(kept, -d_kept, 0.0)
        data = np.concatenate([hess, hess[self.off], diag_w, diag_rows, jac, jac,
                               self._blocks(jac, sigma)])
        ab = np.bincount(lay["lin"], weights=data[lay["inner"]],
                         minlength=lay["shape"][0] * lay["M"]).reshape(lay["shape"], order="F")
        b = np.bincount(lay["col_T_at"], weights=data[lay["col_T"]], minlength=lay["M"])
        d = float(np.sum(data[lay["diag_T"]]))
        lub, piv, info = lapack.dgbtrf(ab, lay["kl"], lay["ku"], overwrite_ab=True)
        if info != 0:
            return None
        u, info = lapack.dgbtrs(lub, lay["kl"], lay["ku"], b, piv)
        schur = d - float(b @ u)
        if info != 0 or not np.isfinite(schur) or schur == 0.0:
            return None
        return lay, lub, piv, b, u, schur, sigma, kept

    def _solve_core(self, fact, jac: np.ndarray, rhs_w: np.ndarray, rhs_y: np.ndarray
                    ) -> np.ndarray:
        """``(dw, dy)`` from the condensed factorisation, unchecked."""
        lay, lub, piv, b, u, schur, sigma, kept = fact
        nw = self.nw
        jv_s = jac * (sigma * np.where(kept, 0.0, rhs_y))[self.jr]
        rhs = np.concatenate([rhs_w + np.bincount(self.jc, weights=jv_s, minlength=nw),
                              np.where(kept, rhs_y, 0.0)])
        pos, core = lay["pos"], lay["core"]
        r1 = np.empty(lay["M"])
        r1[pos[core]] = rhs[core]
        v, _ = lapack.dgbtrs(lub, lay["kl"], lay["ku"], r1, piv)
        xT = (rhs[self.iT] - float(b @ v)) / schur
        x1 = v - u * xT
        dw = np.zeros(nw)
        dy = np.zeros(self.ng)
        dw[:self.iT] = x1[pos[:self.iT]]
        dw[self.iT] = xT
        rows_at = pos[nw:]
        dy[kept] = x1[rows_at[kept]]
        jdw = np.bincount(self.jr, weights=jac * dw[self.jc], minlength=self.ng)
        dy = np.where(kept, dy, sigma * (jdw - rhs_y))
        return np.concatenate([dw, dy])

    def backward_error(self, hess: np.ndarray, diag: np.ndarray, jac: np.ndarray,
                       x: np.ndarray, rhs: np.ndarray) -> tuple[float, np.ndarray]:
        """The full system's normwise backward error of ``x``, and its residual (N,).

        ``||K x - rhs|| / (||H x_w|| + ||J^T x_y|| + ||J x_w|| + ||diag x|| + ||rhs||)``
        in the maximum norm (each product's largest entry standing in for ``||K|| ||x||``).
        ``diag`` (N,) is the full system's diagonal (``S_x`` and the regularisation on the
        variables, ``-D`` on the rows), as :meth:`BandedKKT.factor` takes it.
        """
        nw = self.nw
        hr, hc, off, jr, jc = self.hr, self.hc, self.off, self.jr, self.jc
        w, y = x[:nw], x[nw:]
        hw = np.bincount(hr, weights=hess * w[hc], minlength=nw) \
            + np.bincount(hc[off], weights=hess[off] * w[hr[off]], minlength=nw)
        jy = np.bincount(jc, weights=jac * y[jr], minlength=nw)
        jw = np.bincount(jr, weights=jac * w[jc], minlength=self.ng)
        dx = diag * x
        r = np.concatenate([hw + jy, jw]) + dx - rhs
        scale = sum(float(np.max(np.abs(v))) for v in (hw, jy, jw, dx, rhs))
        return (float(np.max(np.abs(r))) / scale if scale > 0.0 else 0.0), r

    def solve(self, fact, hess: np.ndarray, diag: np.ndarray, jac: np.ndarray,
              rhs: np.ndarray) -> tuple[np.ndarray | None, float]:
        """The full system's solution (N,) by the condensed factorisation, checked.

        Returns the solution and its backward error (:meth:`backward_error`, against the
        full system); None and the error when it stays above :data:`BACKWARD_TOL` after
        one step of iterative refinement.
        """
        nw = self.nw
        x = self._solve_core(fact, jac, rhs[:nw], rhs[nw:])
        err = np.inf
        for attempt in range(2):
            if not np.all(np.isfinite(x)):
                return None, np.inf
            err, r = self.backward_error(hess, diag, jac, x, rhs)
            if err <= BACKWARD_TOL:
                return x, err
            if attempt == 0:
                x = x - self._solve_core(fact, jac, r[:nw], r[nw:])
        return None, err
