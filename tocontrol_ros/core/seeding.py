"""Seed pairs of the multistart: start and target configurations, most promising first.

The configurations come from the inverse kinematics
(:func:`~tocontrol_ros.core.ik.ik_family`, spread over each end point's self-motion
manifold); this module pairs and ranks them.
"""

from __future__ import annotations

import numpy as np

from .ik import ik_family
from .options import SolverOptions
from .problem import Problem

__all__ = ["seed_pairs"]


def seed_pairs(problem: Problem, options: SolverOptions) -> list[tuple[np.ndarray, np.ndarray]]:
    """Seed pairs (q_start, q_target), most promising first.

    Each start configuration of the family is paired with each target configuration, the
    target unwrapped to the nearest equivalent angles (the short way) and, for continuous
    distal joints, also one full turn the other way; pairs are ranked by a bang-bang time
    estimate with diagonal inertia. The first ``options.starts`` are returned.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
        ``starts`` (how many pairs) and ``ik_count`` (configurations per end point).

    Returns
    -------
    list of (ndarray, ndarray), each shape (n,)
        ``(q_start, q_target)`` (rad, m); empty when an end point has no IK solution.
    """
    model = problem.model
    n = model.n
    if problem.start.kind == "state":
        starts = [problem.start.value[:n]]
    else:
        starts = ik_family(model, problem.start.value, options.ik_count)
    if problem.target.kind == "state":
        targets = [problem.target.value[:n]]
    else:
        targets = ik_family(model, problem.target.value, options.ik_count)
    if not starts or not targets:
        return []
    cont = ~np.isfinite(model.q_lower) & np.array([b.kind == "revolute" for b in model.bodies])
    acc = model.tau_max * problem.torque_scale
    qa = np.array(starts)                                   # (S, n)
    mass = np.array(model.function("M").map(len(qa))(qa.T))  # (n, S n), blocks per start
    inertia = np.array([np.diag(mass[:, i * n:(i + 1) * n]) for i in range(len(qa))])
    d = np.array(targets)[None, :, :] - qa[:, None, :]      # (S, G, n)
    if problem.target.kind == "point":
        d = np.where(cont, np.angle(np.exp(1j * d)), d)
    variants = [d]
    if problem.target.kind == "point" and cont[-1]:
        last = d[..., -1]
        turn = np.zeros_like(d)
        turn[..., -1] = np.where(last != 0, -2 * np.pi * np.sign(last), 2 * np.pi)
        variants.append(d + turn)
    # (S, G, V, n), in the order start, target, variant; ranked by a stable sort.
    dv = np.stack(variants, axis=2)
    est = np.max(2 * np.sqrt(np.abs(dv) * inertia[:, None, None, :] / acc), axis=-1)
    order = np.argsort(est.ravel(), kind="stable")[:options.starts]
    s_idx, _, _ = np.unravel_index(order, est.shape)
    flat = dv.reshape(-1, n)
    return [(qa[i], qa[i] + flat[j]) for i, j in zip(s_idx, order, strict=True)]
