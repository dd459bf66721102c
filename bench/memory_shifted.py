"""A hit's first motion: the stored motion moved onto the request against IPOPT's iterate.

With a ``first`` receiver (the planner's ``publish: first_then_optimum``) a memory hit
publishes a certified motion before its optimum. Before session 40 that was the warm
re-solve's first certified IPOPT iterate; now the nearest stored motion moved onto the
request's ends and timed (``core/direct/shifted.py``) is offered first, before IPOPT
starts. For each inside request of ``bench/memory_cell/requests.yaml`` that is a hit,
``recall`` (``memory_first_success``, as the benchmark's first-motion node) is called with
the shifted motion and without it (``shifted.SHIFTED_FIRST`` False: IPOPT's iterate as
before), alternated (the order swapped every request), after one uncounted call each:
the time from the call to the first motion, its ``T`` against the hit's answer, the
answer's time, and whether both calls give the same answer (``T`` to the bit: the re-solve
is the same).

Command: ``scripts/dev run python -P bench/memory_shifted.py --memory FILE [--count N]``
(FILE: a memory of the cell with serving states, e.g. the memory benchmark's; only read).
Figures from one run are in docs/memory.md.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import load_text, log, table  # noqa: E402

VARIANTS = ("shifted", "IPOPT's iterate")


def run(memory: Path, count: int) -> tuple[list[dict], str]:
    """One dict per hit; and the load at the start."""
    from bench.memory_basins import cell_problems
    from tocontrol_ros.core import SolverOptions
    from tocontrol_ros.core.direct import shifted
    from tocontrol_ros.core.memory.recall import recall
    from tocontrol_ros.core.memory.store import MotionStore

    planner, problems = cell_problems(count)
    options = replace(SolverOptions(time_limit=600.0), workers=1)

    def call(problem, store, variant: str):
        shifted.SHIFTED_FIRST = variant == VARIANTS[0]
        firsts: list = []
        t0 = time.perf_counter()
        try:
            found = recall(planner, problem, options, store, first_success=True,
                           first=firsts.append)
        finally:
            shifted.SHIFTED_FIRST = True
        return {"total": time.perf_counter() - t0, "found": found, "firsts": firsts}

    start = load_text()
    rows = []
    with MotionStore(memory) as store:
        for variant in VARIANTS:  # uncounted: libraries, transcriptions
            call(problems[0], store, variant)
        for case, problem in enumerate(problems, start=1):
            order = VARIANTS if case % 2 else tuple(reversed(VARIANTS))
            row = {"case": case}
            for name in order:
                row[name] = call(problem, store, name)
            a, b = (row[n]["found"] for n in VARIANTS)
            if not a.hit or a.result is None or b.result is None:
                log(f"memory shifted {case}: not a hit with an answer")
                continue
            row["same"] = a.result.T == b.result.T and a.starts == b.starts
            rows.append(row)
            log(f"memory shifted {case}: " + ", ".join(
                f"{n} first {_first_ms(row[n]):.0f} ms ({_gap(row[n]):+.2%}), answer "
                f"{row[n]['total'] * 1e3:.0f} ms" for n in VARIANTS) + f", same {row['same']}")
    return rows, start


def _first_ms(r: dict) -> float:
    """Milliseconds from the call to its first motion (nan: none)."""
    return r["found"].first_time * 1e3 if r["found"].first is not None else float("nan")


def _gap(r: dict) -> float:
    """The first motion's ``T`` above the answer's (relative; nan: none)."""
    first, answer = r["found"].first, r["found"].result
    return first.T / answer.T - 1.0 if first is not None else float("nan")


def report(rows: list[dict], start: str) -> str:
    def stats(name: str) -> list[str]:
        got = [r for r in rows if r[name]["found"].first is not None]
        ms = [_first_ms(r[name]) for r in got]
        gaps = [_gap(r[name]) for r in got]
        return [name, f"{len(got)}/{len(rows)}",
                f"{np.median(ms):.0f}" if ms else "-",
                f"{np.percentile(ms, 95):.0f}" if ms else "-",
                f"{np.median(gaps):+.2%}" if gaps else "-",
                f"{max(gaps):+.2%}" if gaps else "-",
                f"{np.median([r[name]['total'] for r in rows]) * 1e3:.0f}"]

    moved = sum(r[VARIANTS[0]]["found"].first is not None
                and r[VARIANTS[0]]["found"].first.iterations == 0 for r in rows)
    head = ["first motion", "hits with one", "to it: median (ms)", "p95 (ms)",
            "T above the answer: median", "worst", "answer: median (ms)"]
    ratio = [_first_ms(r[VARIANTS[0]]) / _first_ms(r[VARIANTS[1]]) for r in rows
             if r[VARIANTS[0]]["found"].first is not None
             and r[VARIANTS[1]]["found"].first is not None]
    return (f"{len(rows)} hits (`memory_first_success`, in process, one worker); load "
            f"average {start} at the start, {load_text()} at the end (two cores). Time to "
            f"the first motion, shifted / IPOPT's iterate, paired: median "
            f"{np.median(ratio):.2f} over {len(ratio)} hits with both; the same answer on "
            f"{sum(r['same'] for r in rows)}/{len(rows)}; with the shifted motion on, the "
            f"first motion was the moved stored one on {moved}/{len(rows)} (IPOPT's iterate "
            f"on the others).\n\n"
            + "\n".join(table(head, [stats(n) for n in VARIANTS])))


def main(argv=None) -> int:
    from bench.memory_basins import cell_main

    return cell_main(__doc__, run, report, argv)


if __name__ == "__main__":
    sys.exit(main())
