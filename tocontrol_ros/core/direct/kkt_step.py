"""The parametric step's derivatives through bound NumPy buffers.

The parametric warm re-solve (:mod:`~tocontrol_ros.core.direct.sensitivity`) takes 2-12
Newton steps, each with the rows and their Jacobian, at times the Lagrangian's Hessian.
Called as plain CasADi functions (:attr:`FlatTranscription.kkt_functions`) every argument
and result is converted to and from ``DM`` and the sparse results copied out by
``nonzeros()``: 0.2-1.5 ms a call on the Panda's 24 spans, more than the compiled kernels
themselves. :class:`KKTDerivatives` wraps the same functions (the same graph, the same
numbers to the bit) with dense outputs (the rows, the Jacobian's and the Hessian's
nonzeros) called through bound NumPy buffers
(:class:`~tocontrol_ros.core.robot.compiled.BufferedFunction`).

Tried and not kept (docs/limits.md, "Warm re-solves by the parametric step"): the KKT
matrix assembled and solved in one compiled call by CasADi's code-generated sparse
``LDL^T`` (its ``"ldl"`` linear solver): 0.4 ms against the banded LU's 0.6-2 ms, but it
does not pivot, and these KKT matrices (condition numbers near 1e17, more negative
eigenvalues than rows where the Hessian is indefinite) gave steps wrong by 250 % where the
banded LU with partial pivoting has a backward error of 1e-23; its code-generated ``"qr"``
took 98 ms.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from tocontrol_ros.core.robot.compiled import BufferedFunction

__all__ = ["KKTDerivatives", "buffered_rows", "kkt_derivatives"]


class KKTDerivatives:
    """The rows, their Jacobian's and the Hessian's nonzeros, through NumPy buffers.

    Parameters
    ----------
    jac_fun, hess_fun : casadi.Function
        :attr:`FlatTranscription.kkt_functions`: ``(w, p) -> (g, J)`` and
        ``(w, p, lam_f, lam_g) -> H`` (upper triangle).

    Attributes
    ----------
    functions : tuple of casadi.Function
        ``(jac_fun, hess_fun)``, as given.
    jac_sparsity, hess_sparsity : casadi.Sparsity
        Of ``J`` (rows, K n + 1) and of ``H`` (K n + 1, K n + 1); the nonzeros returned are
        in their column-major order (as ``DM.nonzeros()``).
    """

    def __init__(self, jac_fun: ca.Function, hess_fun: ca.Function) -> None:
        self.functions = (jac_fun, hess_fun)
        self.jac_sparsity = jac_fun.sparsity_out(1)
        self.hess_sparsity = hess_fun.sparsity_out(0)
        w = ca.MX.sym("w", jac_fun.size1_in(0))
        p = ca.MX.sym("p", jac_fun.size1_in(1))
        lam = ca.MX.sym("lam", hess_fun.size1_in(3))
        g, jac = jac_fun(w, p)
        hess = hess_fun(w, p, 1.0, lam)
        self._jac = BufferedFunction(ca.Function("kkt_jac", [w, p],
                                                 [ca.densify(g), jac.nz[:]]))
        self._hess = BufferedFunction(ca.Function("kkt_hess", [w, p, lam], [hess.nz[:]]))

    def rows(self, w: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rows' values (rows,) and their Jacobian's nonzeros at ``w`` (K n + 1,)."""
        g, jv = self._jac(w, p)
        return g, jv

    def hessian(self, w: np.ndarray, p: np.ndarray, lam_g: np.ndarray) -> np.ndarray:
        """The nonzeros of the Lagrangian's Hessian (objective weight 1) at ``w``, ``lam_g``."""
        return self._hess(w, p, lam_g)[0]


def kkt_derivatives(flat) -> KKTDerivatives:
    """``flat``'s :class:`KKTDerivatives`, built at its first use and kept on it."""
    der = flat.kkt_cache.get("derivatives")
    if der is None:
        der = flat.kkt_cache["derivatives"] = KKTDerivatives(*flat.kkt_functions)
    return der


def buffered_rows(flat) -> BufferedFunction:
    """``flat``'s rows ``(w, p) -> [g (rows,)]`` through NumPy buffers, built once and kept.

    The NLP's row function (``flat.row_function``, the same evaluation to the bit) without
    converting its arguments and its result to and from ``DM``: 0.07 against 0.21 ms a call
    on the Panda's 24 spans. The residual of each time stretch tried on an answer
    (``checked.stretched``: six of them) and of every solve goes through it (issue 47).
    """
    fun = flat.kkt_cache.get("rows")
    if fun is None:
        g = flat.row_function
        w = ca.MX.sym("w", g.size1_in(0))
        p = ca.MX.sym("p", g.size1_in(1))
        fun = flat.kkt_cache["rows"] = BufferedFunction(
            ca.Function("rows", [w, p], [ca.densify(g(w, p))]))
    return fun
