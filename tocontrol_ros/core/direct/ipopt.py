"""The IPOPT options both direct transcriptions share.

Each transcription hands IPOPT its own exact derivatives (objective gradient, constraint
Jacobian, Lagrangian Hessian) and adds the options of its own warm starts.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

__all__ = ["IpoptOutcome", "ipopt_options"]


@dataclass(frozen=True)
class IpoptOutcome:
    """What every IPOPT solve of a time-optimal transcription reports.

    The transcriptions' results add their solution (as keyword-only fields).

    Attributes
    ----------
    success : bool
    message : str
        IPOPT's return status (or why the solve was stopped).
    T : float
        Final time (s).
    iterations : int
    solve_time : float
        Wall time of the IPOPT call (s).
    """

    success: bool
    message: str
    T: float
    iterations: int
    solve_time: float


def ipopt_options(tol: float, max_iter: int, grad_f: ca.Function, jac_g: ca.Function,
                  hess_lag: ca.Function) -> dict:
    """Options for ``casadi.nlpsol(..., "ipopt", ...)`` with the NLP's own derivatives.

    Parameters
    ----------
    tol : float
        IPOPT's ``tol`` and ``acceptable_tol``.
    max_iter : int
        IPOPT's iteration limit.
    grad_f, jac_g, hess_lag : casadi.Function
        ``(x, p) -> (f, grad)``, ``(x, p) -> (g, jac)`` and
        ``(x, p, lam_f, lam_g) -> hess`` (upper triangle).

    Returns
    -------
    dict
        Silent IPOPT, adaptive barrier, MUMPS without its scaling and permutation (the
        NLPs are well scaled: joint units and a normalised torque), and no Lagrangian
        gradient, ``f``, ``g`` or bound multipliers computed by CasADi (the solution, ``f``,
        ``g`` and the multipliers come from IPOPT; a Lagrangian gradient would
        differentiate the compiled constraints).
    """
    return {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.tol": tol, "ipopt.max_iter": max_iter, "ipopt.acceptable_tol": tol,
            "ipopt.mu_strategy": "adaptive", "calc_lam_p": False,
            "ipopt.mumps_scaling": 0, "ipopt.mumps_permuting_scaling": 0,
            "grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag,
            "no_nlp_grad": True, "calc_lam_x": False, "calc_f": False, "calc_g": False}
