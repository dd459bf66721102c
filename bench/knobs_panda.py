"""The Panda's cold plan under other values of the multistart's and the refinement's knobs.

Issue 47 (a default Panda plan through the node in 1 s): each candidate change is measured
here first, in this one process, paired with the defaults. The cases are those of
``bench/deployed_panda.py`` (the best-motion section's draw, seed of
:mod:`bench.optimum_panda`, each from the end-effector point of its start configuration to
its target, k = 4, the URDF limits), planned with the defaults and with each variant in
turn, alternating who goes first case by case, after one warm-up plan; ``workers=1``, so
the planner's shared pieces run here and are timed (:class:`bench.profile_panda.Recorder`).

Per variant: CPU time per plan (``time.process_time``: less sensitive to other work on a
shared machine than wall time, not immune to it), the estimated plan time on two cores
(:func:`bench.profile_panda.two_core_path`, what the node's default ``workers`` could reach
on these one-process timings), the IPOPT iterations, and ``T`` against the defaults' in the
same run (within 1e-3; worse or better by more).

Variants (``name=value``, joined by ``+``):

- ``guess_tol``, ``guess_intervals``, ``candidates``: :class:`SolverOptions` fields;
- ``T_SETTLED``, ``REFINE_WINDOW``, ``GUESS_WINDOW``: the constants of
  :mod:`tocontrol_ros.core.direct.limited` (read there at each plan).

``--uniform`` instead re-solves the uniform-mesh solves of the cases' default plans
(captured: start, target, guess, bounds) with other IPOPT start options (JSON objects),
on one new transcription per option set: iterations, CPU time, ``T`` against the default.

Run alone: ``scripts/dev run python -P bench/knobs_panda.py [CASES] [VARIANT ...]``, e.g.
``bench/knobs_panda.py 10 T_SETTLED=5e-4 REFINE_WINDOW=5e-3+T_SETTLED=5e-4``, or
``bench/knobs_panda.py 6 --uniform '{"ipopt.mu_strategy": "monotone", "ipopt.mu_init": 1e-3}'``;
``--reference`` after the count plans ``bench/reference_panda.py``'s cases instead (a variant
with the default's ``T`` on all 50 keeps its standing against the reference).
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.common import log, table  # noqa: E402
from bench.limits import draw_cases, robots  # noqa: E402
from bench.optimum_panda import SEED, K  # noqa: E402
from bench.profile_panda import Recorder, two_core_path  # noqa: E402
from tocontrol_ros.core import Problem, SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.direct import flat, limited  # noqa: E402
from tocontrol_ros.core.direct.tuning import SPANS  # noqa: E402
from tocontrol_ros.core.types.problem import point  # noqa: E402

#: The SolverOptions fields a variant may set.
OPTION_FIELDS = {"guess_tol": float, "guess_intervals": int, "candidates": int}
#: The constants of core/direct/limited.py a variant may set.
CONSTANTS = ("T_SETTLED", "REFINE_WINDOW", "GUESS_WINDOW")


def cases(count: int, reference: bool = False) -> list[Problem]:
    """``bench/deployed_panda.py``'s cases: point to point, k = 4, the URDF limits; with
    ``reference`` those of ``bench/reference_panda.py`` (odd ones from a joint state)."""
    model, limits = robots()["Panda"]
    if reference:
        from bench.peer_compiled import _problems

        return _problems(model, limits, count)
    return [Problem(model, point(model.point(q0)), point(target), k=K, limits=limits)
            for q0, _qd0, target in draw_cases(model, limits, count, seed=SEED)]


class Variant:
    """One variant's options and module patches, applied around a plan."""

    def __init__(self, spec: str) -> None:
        self.name = spec
        self.options: dict = {"time_limit": 600.0}
        self.patches: dict = {}
        if spec == "default":
            return
        for part in spec.split("+"):
            key, _, value = part.partition("=")
            if key in OPTION_FIELDS:
                self.options[key] = OPTION_FIELDS[key](value)
            elif key in CONSTANTS:
                self.patches[key] = float(value)
            else:
                raise SystemExit(f"unknown knob {key!r} in {spec!r}")

    def plan(self, problem: Problem):
        saved = {name: getattr(limited, name) for name in self.patches}
        try:
            for name, value in self.patches.items():
                setattr(limited, name, value)
            return plan(problem, SolverOptions(**self.options))
        finally:
            for name, value in saved.items():
                setattr(limited, name, value)


def run(count: int, specs: list[str], reference: bool = False) -> list[str]:
    variants = [Variant("default")] + [Variant(s) for s in specs]
    problems = cases(count, reference)
    plan(problems[0], SolverOptions(time_limit=600.0))  # warm-up: compile cache
    per: dict = {v.name: [] for v in variants}
    with Recorder() as rec:
        for i, problem in enumerate(problems):
            for v in (variants if i % 2 == 0 else variants[::-1]):
                s0, g0 = len(rec.solves), len(rec.groups)
                c0, t0 = time.process_time(), time.perf_counter()
                res = v.plan(problem)
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                solves = rec.solves[s0:]
                groups = [dict(g, first_solve=g["first_solve"] - s0) for g in rec.groups[g0:]]
                path = two_core_path(wall, groups, solves)
                per[v.name].append({
                    "T": res.T if res.success else np.nan, "cpu": cpu, "wall": wall,
                    "two": sum(b for _, b in path.values()) * cpu / wall,
                    "iterations": sum(s["iterations"] for s in solves)})
            log(f"knobs Panda {i + 1}/{count}: " + ", ".join(
                f"{name} T {rows[-1]['T']:.6f} cpu {rows[-1]['cpu']:.2f} s"
                for name, rows in per.items()))
    base = per["default"]
    rows = []
    for name, got in per.items():
        gap = [(g["T"] - b["T"]) / b["T"] for g, b in zip(got, base, strict=True)]
        rows.append([name, f"{statistics.median(g['cpu'] for g in got):.2f}",
                     f"{sum(g['cpu'] for g in got) / sum(b['cpu'] for b in base):.2f}",
                     f"{statistics.median(g['two'] for g in got):.2f}",
                     f"{max(g['two'] for g in got):.2f}",
                     f"{sum(g['iterations'] for g in got) / len(got):.0f}",
                     f"{sum(abs(x) <= 1e-3 for x in gap)}/{len(gap)}",
                     f"{sum(x > 1e-3 for x in gap)}", f"{sum(x < -1e-3 for x in gap)}",
                     f"{max(gap):.1e}"])
    which = "bench/reference_panda.py's, odd ones from a joint state" if reference else \
        "bench/deployed_panda.py's, point to point"
    flag = " --reference" if reference else ""
    return [f"{count} Panda cases ({which}, k = {K:g}), "
            "one process, paired with the defaults. CPU: process time per plan; two "
            "cores: the estimate of bench/profile_panda.py (CPU-scaled). Command: "
            f"`scripts/dev run python -P bench/knobs_panda.py {count}{flag} "
            f"{' '.join(specs)}`.",
            "", *table(["variant", "CPU median (s)", "CPU / default's", "two cores median (s)",
                        "two cores max (s)", "IPOPT iterations / plan",
                        "T within 1e-3 of the default's", "worse by more",
                        "better by more", "largest T gap"], rows)]


def run_uniform(count: int, option_sets: list[dict]) -> list[str]:
    """The cases' uniform-mesh solves again with other IPOPT start options."""
    captured = []
    original = flat.FlatTranscription.solve

    def capture(obj, *args, **kwargs):
        out = original(obj, *args, **kwargs)
        if obj.spans == SPANS and obj.warm is False and not kwargs.get("set_pad"):
            captured.append((obj.start_kind, obj.target_kind, obj.torque_scale, args,
                             kwargs.get("max_iter"), out.T, out.iterations))
        return out

    flat.FlatTranscription.solve = capture
    try:
        for problem in cases(count):
            plan(problem, SolverOptions(time_limit=600.0))
    finally:
        flat.FlatTranscription.solve = original
    model = robots()["Panda"][0]
    base_T = np.array([c[5] for c in captured])
    rows = []
    options_of = flat.ipopt_options  # flat.py's IPOPT options; its start modes' are added after
    for extra in [{}] + option_sets:
        flat.ipopt_options = lambda *args, extra=extra: {**options_of(*args), **extra}
        try:
            kinds = captured[0][:3]
            nlp = flat.FlatTranscription(model, SPANS, kinds[0], kinds[1], torque_scale=kinds[2])
        finally:
            flat.ipopt_options = options_of
        its, Ts, cpu = 0, [], 0.0
        for *_, args, max_iter, _T, _its in captured:
            c0 = time.process_time()
            out = nlp.solve(*args, max_iter=max_iter)
            cpu += time.process_time() - c0
            its += out.iterations
            Ts.append(out.T if out.success else np.nan)
        gap = np.array(Ts) / base_T - 1.0
        rows.append([json.dumps(extra) if extra else "default", f"{np.sum(np.isfinite(gap))}",
                     f"{its}", f"{cpu:.2f}", f"{np.sum(np.abs(gap) <= 1e-6)}",
                     f"{np.sum(gap > 1e-4)}", f"{np.sum(gap < -1e-4)}"])
        log(f"uniform re-solves {rows[-1]}")
    return [f"The {len(captured)} uniform-mesh solves of {count} default plans "
            "(bench/deployed_panda.py's cases) solved again from their guesses with other "
            "IPOPT options. Command: `scripts/dev run python -P bench/knobs_panda.py "
            f"{count} --uniform ...`.", "",
            *table(["IPOPT options", "converged", "iterations", "CPU (s)",
                    "same T (1e-6)", "T worse by > 1e-4", "better by > 1e-4"], rows)]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    count = int(argv[0]) if argv and argv[0].isdigit() else 10
    rest = argv[1:] if argv and argv[0].isdigit() else argv
    if rest and rest[0] == "--uniform":
        lines = run_uniform(count, [json.loads(s) for s in rest[1:]])
    elif rest and rest[0] == "--reference":  # the 50 cases of the independent reference
        lines = run(count, rest[1:], reference=True)
    else:
        lines = run(count, rest)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
