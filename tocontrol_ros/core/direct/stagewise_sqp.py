"""A real-time-iteration SQP on the stage-wise NLP, its QPs solved by HPIPM (Riccati).

CasADi's ``sqpmethod`` with ``qpsol="hpipm"`` stopped after its first QP on the Panda (no
return status, from a cold guess and from the converged solution of a 2 cm move), so the
SQP is written here, in a few lines: per iteration the Lagrangian's Hessian, the constraint
Jacobian and values (CasADi functions of the NLP), each stage's Hessian block clipped to
eigenvalues of at least :data:`MARGIN` (the NLP has directions without curvature), then
one QP in the step, solved by ``conic("hpipm")`` with the OCP structure (``N``, ``nx``,
``nu``, ``ng``), and a full step with the QP's multipliers as the new ones (real-time
iterations, Diehl et al. 2005: from a shifted or nearby solution, no line search).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from tocontrol_ros.core.direct.stagewise import StagewiseTranscription

__all__ = ["MARGIN", "StageSqp"]

#: Least eigenvalue of each stage's Hessian block in the QP (eigenvalues below it are clipped
#: to it). Measured on a Panda case (N = 20, a 2 cm move, from the converged solution): 1e-2
#: and 1e-3 act as a proximal term that holds the path back (T 2 % and 0.6 % off after one
#: iteration, 0.3 % and 0.1 % after 15); 1e-6: 1e-3 after one iteration, 3e-5 after two;
#: 1e-8: HPIPM at its iteration limit in every QP.
MARGIN = 1e-6
#: HPIPM's options: its residual tolerances, and an iteration limit. The first QP after a
#: move reaches the limit (300 iterations did not converge it either, 71-145 ms at N = 20);
#: its step, taken as it is, gave the same iterates with a limit of 30, 50 or 300.
HPIPM = {"mode": "robust", "iter_max": 30, "res_g_max": 1e-6, "res_b_max": 1e-6,
         "res_d_max": 1e-6, "res_m_max": 1e-8}
#: HPIPM's return statuses whose step is taken: success and its iteration limit.
USABLE = (0, 1)


class StageSqp:
    """Full-step SQP with HPIPM on one transcription (functions and QP built once).

    Parameters
    ----------
    transcription : StagewiseTranscription
    margin : float
        Least eigenvalue of the QP's Hessian blocks.
    """

    def __init__(self, transcription: StagewiseTranscription, margin: float = MARGIN,
                 hpipm: dict | None = None) -> None:
        tr = self.tr = transcription
        self.margin = margin
        x, p = tr.nlp["x"], tr.nlp["p"]
        lam = ca.SX.sym("lam", tr.n_g)
        hess = ca.hessian(tr.nlp["f"] + ca.dot(lam, tr.nlp["g"]), x)[0]
        jac = ca.jacobian(tr.nlp["g"], x)
        self._eval = ca.Function("sqp_eval", [x, p, lam],
                                 [hess, jac, tr.nlp["g"], ca.gradient(tr.nlp["f"], x)])
        self._hess_sp = hess.sparsity()
        # Stage blocks (x_k, u_k), the last x_N alone.
        sizes = [a + b for a, b in zip(tr.nx, tr.nu, strict=True)]
        self._starts = np.concatenate([[0], np.cumsum(sizes)])
        self._bs = max(sizes)
        blocks = ca.diagcat(*[ca.DM.ones(s, s) for s in sizes])
        self._qp_h = blocks.sparsity()
        rows, cols = (np.array(v) for v in self._qp_h.get_triplet())
        self._qp_rc = (rows, cols)
        hr, hc = (np.array(v) for v in self._hess_sp.get_triplet())
        blk = np.searchsorted(self._starts, hr, side="right") - 1
        self._hess_idx = (blk, hr - self._starts[blk], hc - self._starts[blk])
        self._qp_idx = (np.searchsorted(self._starts, rows, side="right") - 1,)
        self._qp_idx += (rows - self._starts[self._qp_idx[0]],
                         cols - self._starts[self._qp_idx[0]])
        self._jac_sp = jac.sparsity()
        self.qp = ca.conic("stage_qp", "hpipm", {"h": self._qp_h, "a": self._jac_sp},
                           {"N": tr.N, "nx": tr.nx, "nu": tr.nu, "ng": tr.ng,
                            "hpipm": dict(HPIPM if hpipm is None else hpipm),
                            "error_on_fail": False})

    def _convexified(self, hess: ca.DM) -> ca.DM:
        """The Hessian's stage blocks with eigenvalues clipped to at least the margin."""
        nb = len(self._starts) - 1
        B = np.zeros((nb, self._bs, self._bs))
        b, r, c = self._hess_idx
        B[b, r, c] = np.array(hess.nonzeros())
        B = 0.5 * (B + np.transpose(B, (0, 2, 1)))
        sizes = np.diff(self._starts)
        for i in np.flatnonzero(sizes < self._bs):  # the last block (x_N) is smaller
            B[i, sizes[i]:, :] = 0.0
            B[i, :, sizes[i]:] = 0.0
        ev, V = np.linalg.eigh(B)
        B = np.einsum("bij,bj,bkj->bik", V, np.maximum(ev, self.margin), V)
        b, r, c = self._qp_idx
        return ca.DM(self._qp_h, B[b, r, c])

    def iterate(self, w: np.ndarray, lam_g: np.ndarray, par: np.ndarray, lbx, ubx, lbg, ubg
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
        """One SQP iteration from ``(w, lam_g)``: the new point, ``lam_g``, ``lam_x``, figures.

        Figures: ``step`` (largest |dw|), ``qp_status``, ``qp_iterations``, ``eval_s``,
        ``qp_s`` (wall times, s).
        """
        t0 = time.perf_counter()
        hess, jac, g, grad = self._eval(w, par, lam_g)
        H = self._convexified(hess)
        t1 = time.perf_counter()
        g = np.array(g).ravel()
        sol = self.qp(h=H, g=grad, a=jac, lba=lbg - g, uba=ubg - g, lbx=lbx - w, ubx=ubx - w)
        t2 = time.perf_counter()
        st = self.qp.stats()
        dw = np.array(sol["x"]).ravel()
        usable = st.get("return_status") in USABLE and bool(np.all(np.isfinite(dw)))
        return (w + dw, np.array(sol["lam_a"]).ravel(), np.array(sol["lam_x"]).ravel(),
                {"step": float(np.max(np.abs(dw))), "qp_status": st.get("return_status"),
                 "qp_ok": usable, "qp_converged": bool(st.get("success", False)),
                 "qp_iterations": int(st.get("iter_count", -1)),
                 "eval_s": t1 - t0, "qp_s": t2 - t1})

    def solve(self, w0: np.ndarray, lam_g0: np.ndarray | None, par: np.ndarray, lbx, ubx,
              lbg, ubg, max_iter: int = 50, t_tol: float = 1e-9, residual_tol: float = 1e-8
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Iterate until ``T`` settles (relative change below ``t_tol``) on a feasible point.

        The path itself need not settle: the self-motion of a redundant arm and the
        velocity-limited arcs leave directions along which ``T`` does not change, and the
        steps along them stay at tenths of a radian (measured) while ``T`` has converged.

        Returns ``w``, ``lam_g``, ``lam_x`` and one figures dict per iteration (each with the
        ``residual`` after it).
        """
        w = np.clip(np.asarray(w0, dtype=float), lbx, ubx)
        lam = np.zeros(self.tr.n_g) if lam_g0 is None else np.asarray(lam_g0, dtype=float)
        lam_x = np.zeros_like(w)
        log = []
        for _ in range(max_iter):
            t_last = self.tr.unpack(w)[0]
            w, lam, lam_x, fig = self.iterate(w, lam, par, lbx, ubx, lbg, ubg)
            fig["residual"] = self.tr.residual(w, par, lbx, ubx, lbg, ubg)
            fig["dT"] = abs(self.tr.unpack(w)[0] - t_last) / t_last
            log.append(fig)
            if not fig["qp_ok"] or (fig["dT"] < t_tol and fig["residual"] < residual_tol):
                break
        return w, lam, lam_x, log
