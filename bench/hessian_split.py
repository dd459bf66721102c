"""What a bounded solve's Hessian evaluation is made of: the per-sample library, or the rest.

The bounded B-spline transcription (:mod:`tocontrol_ros.core.direct.flat`) gives IPOPT the
Lagrangian's Hessian as one CasADi function of ``(w, p, lam_f, lam_g)`` evaluated by
CasADi's virtual machine: the per-sample library (``flat_set_hess``, compiled once per
model) mapped over the ``S = 3 L + 1`` samples, its blocks scattered into the sparse matrix,
plus the velocity rows' and the boundary rows' terms. A compiled function per span count
could only save what is not the library's own work. This measures, paired, on the Panda
(k = 4, point to point, a straight joint path at T = 0.6 s, random multipliers in [0, 1]):

- ``hess_l``: the NLP's Hessian as IPOPT calls it (``FlatTranscription.kkt_functions``);
- the library alone: ``flat_set_hess`` mapped over the same samples' inputs (each sample's
  control points and basis values taken from the mesh), nothing scattered;

and the same for the constraint Jacobian (``jac_g`` against ``flat_set_grad`` mapped). The
samples' inputs are checked first: the library's set values equal the NLP's rows.
Each figure is the median over 30 rounds of 3 calls of each, the calls alternated.

Run alone: ``scripts/dev run python -P bench/hessian_split.py [SPANS ...]`` (default 32 64
96 160).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import table  # noqa: E402
from bench.limits import robots  # noqa: E402
from tocontrol_ros.core.direct.bspline import basis  # noqa: E402
from tocontrol_ros.core.direct.flat import FlatTranscription, compile_flat  # noqa: E402
from tocontrol_ros.core.robot import compiled  # noqa: E402

#: Rounds and calls per round of each function (medians over the rounds).
ROUNDS, CALLS = 30, 3


def _local_inputs(flat: FlatTranscription, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's control points (n, 4 S) and basis values (3, 4 S), side by side."""
    span, b = basis(flat.breaks, flat.degree, flat.samples)
    cols = (span[:, None] + np.arange(flat.degree + 1)[None, :]).ravel()
    return P[cols].T, np.concatenate(list(b), axis=1)


def _timed(calls: dict) -> dict:
    times = {name: [] for name in calls}
    for _ in range(ROUNDS):
        for name, call in calls.items():
            t0 = time.perf_counter()
            for _ in range(CALLS):
                call()
            times[name].append((time.perf_counter() - t0) / CALLS)
    return {name: 1e3 * np.array(v) for name, v in times.items()}


def _measure(model, funs: list, spans: int, q0: np.ndarray, q1: np.ndarray,
             lam_rng: np.random.Generator) -> list[str]:
    """One table row: the Hessian and the Jacobian against the library's part, on ``spans``."""
    set_grad, set_hess = funs[1], funs[2]
    k, T = 4.0, 0.6
    flat = FlatTranscription(model, spans, "point", "point")
    jac_fun, hess_fun = flat.kkt_functions
    S = len(flat.samples)
    P = q0 + (q1 - q0) * np.linspace(0.0, 1.0, flat.K)[:, None]
    w = np.concatenate([P.ravel(), [T]])
    p = flat.parameters(model.point(q0), model.point(q1), k)
    lam = lam_rng.uniform(0.0, 1.0, flat.rows)
    Ploc, b = _local_inputs(flat, P)
    grad_map, hess_map = set_grad.map(S), set_hess.map(S)
    mine = np.array(grad_map(Ploc, T, b, k, flat.scale)[0]).ravel()
    theirs = np.array(jac_fun(w, p)[0]).ravel()[:S]
    if not np.allclose(mine, theirs, rtol=1e-12, atol=1e-14):
        raise SystemExit(f"{spans} spans: the samples' inputs do not give the NLP's rows")
    t = _timed({"hess": lambda: hess_fun(w, p, 1.0, lam),
                "lib_hess": lambda: hess_map(Ploc, T, b, k, flat.scale, lam[:S]),
                "jac": lambda: jac_fun(w, p),
                "lib_jac": lambda: grad_map(Ploc, T, b, k, flat.scale)})
    return [str(spans), str(S), f"{np.median(t['hess']):.2f}",
            f"{np.median(t['lib_hess']):.2f}", f"{np.median(t['lib_hess'] / t['hess']):.2f}",
            f"{np.median(t['jac']):.2f}", f"{np.median(t['lib_jac']):.2f}",
            f"{np.median(t['lib_jac'] / t['jac']):.2f}"]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    spans_list = [int(a) for a in argv] or [32, 64, 96, 160]
    model, _ = robots()["Panda"]
    compile_flat(model)
    compiled.wait_for_builds()
    funs, how = compile_flat(model)
    rng = np.random.default_rng(0)
    q0, q1 = rng.uniform(-0.8, 0.8, model.n), rng.uniform(-0.8, 0.8, model.n)
    rows = []
    for spans in spans_list:
        rows.append(_measure(model, funs, spans, q0, q1, rng))
        print(f"{spans} spans done", file=sys.stderr, flush=True)
    print(f"Panda, flat library {how}; load {os.getloadavg()[0]:.1f}")
    print("\n".join(table(["spans", "samples", "hess_l (ms)", "library alone (ms)",
                           "library's share (paired)", "jac_g (ms)", "library alone (ms)",
                           "library's share (paired)"], rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
