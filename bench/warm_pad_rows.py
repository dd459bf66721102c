"""The parametric re-solve's route mix on bench/warm_resolve.py's 20 moves, by work counts.

Issue 47's one-replan bar needs most of the 20 moves answered by one parametric solve of a
few Newton steps (docs/limits.md, "Where the 10 ms stands"). This script builds the same 20
serving solutions and 2 cm moves as ``bench/warm_resolve.py`` (the same draw; with
``--cache FILE`` pickled there on the first run and read back on the next, so that variants
are counted again in a minute), then answers each move with ``Planner.plan(moved, replan
options, warm_start=serving)`` under each of :data:`VARIANTS` (settings of
``core.direct.set_pads``), in one process, and counts per case: the route (one parametric
solve, a pad round, the sub-moves, or IPOPT with its solves and iterations), the parametric
solves and their Newton steps, ``T`` against IPOPT's warm re-solve (``warm_parametric=False``
with the default settings) and against IPOPT on the NLP at the row pads from the serving
solution, and whether the plan is certified. The first two variants are then timed, two
calls each, alternated (orientation only: the work counts decide; two shared cores).

Command: ``scripts/dev run python -P bench/warm_pad_rows.py [--cache FILE] [cases]``.
"""

from __future__ import annotations

import pickle
import re
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))


def build(count: int = 20) -> tuple:
    """The planner, options and ``(moved, serving)`` per case (None where not served):
    ``bench/warm_step_work.py``'s serving cases with their plans."""
    from bench.warm_step_work import serving_cases
    from tocontrol_ros.core.planning.replan import replan_options
    from tocontrol_ros.core.types.options import SolverOptions

    planner, cases = serving_cases(count, results=True, label="warm_pad_rows")
    return planner, replan_options(SolverOptions(), 0.0, 24), cases


#: Variants counted: a name and the settings of ``core.direct.set_pads`` (and, prefixed
#: ``sensitivity.``, of ``core.direct.sensitivity``) that differ from the defaults; the
#: first: main's route before the pads per sample, the second: the defaults.
VARIANTS = (
    ("before", {"ROW_PADS": False, "sensitivity.DUAL_RESET": False}),
    ("now", {}),
    ("pads alone, no reset", {"sensitivity.DUAL_RESET": False}),
    ("global rounds", {"LOCAL_ROUNDS": False}),
    ("fallback at one pad", {"FALLBACK_PADS": False}),
    ("factor 1.5", {"ROW_PAD_FACTOR": 1.5}),
    ("factor 3", {"ROW_PAD_FACTOR": 3.0}),
    ("near 0.05", {"ROW_PAD_NEAR": 0.05}),
    ("near 0.2", {"ROW_PAD_NEAR": 0.2}),
)


@contextmanager
def settings(values: dict):
    """``core.direct.set_pads``'s module settings set to ``values`` inside."""
    from tocontrol_ros.core.direct import sensitivity, set_pads

    def where(key):
        return (sensitivity, key.split(".")[1]) if key.startswith("sensitivity.") \
            else (set_pads, key)

    saved = {key: getattr(*where(key)) for key in values}
    for key, value in values.items():
        setattr(*where(key), value)
    try:
        yield
    finally:
        for key, value in saved.items():
            setattr(*where(key), value)


def ipopt_counter() -> list:
    """A list that collects the iterations of every IPOPT solve of a B-spline NLP."""
    from tocontrol_ros.core.direct.flat import FlatTranscription

    seen = []
    solve = FlatTranscription.solve

    def counted(self, *args, **kwargs):
        out = solve(self, *args, **kwargs)
        seen.append(out.iterations)
        return out

    FlatTranscription.solve = counted
    return seen


def same_nlp(planner, moved, serving):
    """IPOPT (``warm="dual"``) from the serving solution on the NLP at the row pads."""
    from tocontrol_ros.core.direct.limited import state_bounds
    from tocontrol_ros.core.direct.set_pads import row_pads
    from tocontrol_ros.core.direct.tuning import PAD

    ws = serving.warm_state
    flat = planner.flat(moved, ws.breaks, warm="dual")
    pads = row_pads(serving.trajectory, flat.samples)
    return flat.solve(moved.start.value, moved.target.value, moved.k, ws.T, ws.P,
                      *state_bounds(moved, PAD), set_pad=pads, lam_g0=ws.lam_g,
                      lam_x0=ws.lam_x)


def describe(result) -> tuple[str, int, int]:
    """Route, parametric solves and Newton steps of a warm re-solve, from its warnings."""
    text = " ".join(result.warnings)
    steps = sum(int(x) for x in re.findall(r"after (\d+) Newton steps", text))
    solves = len(re.findall(r"parametric step(?: in \d+ sub-moves)?: ", text))
    if "(route: parametric)" in text:
        rounds = text.count("; pad ")
        sub = "sub-moves: converged" in text
        route = "sub-moves" if sub else "pad round" if rounds else "one solve"
    else:
        route = "ipopt"
    return route, solves, steps


def main(argv: list[str]) -> None:
    cache = None
    if argv[:1] == ["--cache"]:
        cache, argv = Path(argv[1]), argv[2:]
    count = int(argv[0]) if argv else 20
    if cache is not None and cache.exists():
        from tocontrol_ros.core.planning.replan import replan_options
        from tocontrol_ros.core.planning.solver import Planner
        from tocontrol_ros.core.types.options import SolverOptions

        with cache.open("rb") as f:
            cases = pickle.load(f)[:count]
        planner = Planner(next(c for c in cases if c is not None)[0].model)
        ropts = replan_options(SolverOptions(), 0.0, 24)
    else:
        planner, ropts, cases = build(count)
        if cache is not None:
            with cache.open("wb") as f:
                pickle.dump(cases, f)
    counter = ipopt_counter()
    ipopt_opts = replace(ropts, warm_parametric=False)
    tally = {name: {} for name, _ in VARIANTS}
    times = {name: [] for name, _ in VARIANTS[:2]}
    for i, case in enumerate(cases):
        if case is None:
            print(f"case {i + 1}: not served")
            continue
        moved, serving = case
        ref = planner.plan(moved, ipopt_opts, warm_start=serving)
        same = same_nlp(planner, moved, serving)
        print(f"case {i + 1}: ipopt T {ref.T:.7f} (its route: {describe(ref)[0]}); IPOPT on "
              f"the row pads' NLP: T {same.T:.7f} ({same.iterations} it, "
              f"{'converged' if same.success else 'FAILED'})", flush=True)
        for name, values in VARIANTS:
            counter.clear()
            with settings(values):
                t0 = time.perf_counter()
                res = planner.plan(moved, ropts, warm_start=serving)
                elapsed = time.perf_counter() - t0
            route, solves, steps = describe(res)
            if route == "ipopt":
                route = f"ipopt ({len(counter)} solves, {sum(counter)} it)"
                solves = len(counter)
                steps = sum(counter)
            cert = bool(res.success and res.certificate is not None and res.certificate.passed)
            gap = res.T / ref.T - 1.0 if res.success and ref.success else float("nan")
            kind = route.split(" (")[0]
            tally[name][kind] = tally[name].get(kind, 0) + 1
            gap_rows = res.T / same.T - 1.0 if res.success and same.success else float("nan")
            print(f"    {name}: {route} ({solves} solves, {steps} steps) T {res.T:.7f} "
                  f"gap {gap:+.1e} (row pads' NLP {gap_rows:+.1e}) "
                  f"{'cert' if cert else 'NOT certified'} "
                  f"{1e3 * elapsed:.0f} ms", flush=True)
        for _ in range(2):  # the first two variants timed, alternated (orientation only)
            for name, values in VARIANTS[:2]:
                with settings(values):
                    res = planner.plan(moved, ropts, warm_start=serving)
                times[name].append(res.timings["shooting"])
        print("    solve ms (two calls each, alternated): " + "; ".join(
            f"{name} {1e3 * times[name][-2]:.1f}, {1e3 * times[name][-1]:.1f}"
            for name, _ in VARIANTS[:2]), flush=True)
    for name, _ in VARIANTS:
        extra = f"; solve median {1e3 * np.median(times[name]):.1f} ms (paired, alternated)" \
            if name in times else ""
        print(f"{name}: {tally[name]}{extra}")


if __name__ == "__main__":
    main(sys.argv[1:])
