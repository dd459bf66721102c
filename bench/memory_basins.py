"""A hit's basins one after the other against side by side (issue 50, session 39).

``recall`` re-solves up to ``memory_basins`` stored motions per hit (two by default, the
least ``T`` published). With ``workers`` above 1 they are one map of the planner's worker
pool (``PreparedModel.map``: this process and a worker process take them from one queue),
as the planner node runs them (its ``workers`` default 0 is one process per core). For
each inside request of ``bench/memory_cell/requests.yaml`` that is a hit with at least two
basins, ``recall`` is called with ``workers`` 1 and 2, alternated (the order swapped every
request), after one uncounted call of each: the wall time of each call, the paired ratio,
and whether both give the same answer (``T`` to the bit, the same entries and starts).

Command: ``scripts/dev run python -P bench/memory_basins.py --memory FILE [--count N]``
(FILE: a memory of the cell with serving states, e.g. the memory benchmark's; only read).
Figures from one run are in docs/memory.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import load_text, log, table  # noqa: E402

REQUESTS = Path(__file__).resolve().parent / "memory_cell" / "requests.yaml"


def cell_problems(count: int) -> tuple:
    """A planner of the Panda and the first ``count`` inside requests as problems.

    The Panda of example-robot-data with its URDF limits (``bench.limits.robots``), the
    cell's class (``k`` 4, ``reserve`` 0.1); the requests of :data:`REQUESTS`, from their
    stations' points. Returns ``(planner, problems)``.
    """
    from bench.limits import robots
    from tocontrol_ros.core import Planner
    from tocontrol_ros.core.types.problem import Problem, point

    model, limits = robots()["Panda"]
    requests = yaml.safe_load(REQUESTS.read_text())
    stations = {k: v["point"] for k, v in requests["stations"].items()}
    return Planner(model), [
        Problem(model, point(stations[r["start"]]), point(r["target"]), k=4.0, reserve=0.1,
                limits=limits) for r in requests["inside"][:count]]


def run(memory: Path, count: int) -> tuple[list[dict], str]:
    """One dict per hit with two basins or more; and the load at the start."""
    from tocontrol_ros.core import SolverOptions
    from tocontrol_ros.core.memory.recall import recall
    from tocontrol_ros.core.memory.store import MotionStore

    planner, problems = cell_problems(count)
    base = SolverOptions(time_limit=600.0)
    variants = {"one after the other": replace(base, workers=1),
                "side by side": replace(base, workers=2)}
    start = load_text()
    rows = []
    with MotionStore(memory) as store:
        for options in variants.values():  # uncounted: libraries, transcriptions
            recall(planner, problems[0], options, store)
        for case, problem in enumerate(problems, start=1):
            order = list(variants) if case % 2 else list(reversed(variants))
            row = {"case": case}
            for name in order:
                t0 = time.perf_counter()
                found = recall(planner, problem, variants[name], store)
                row[name] = {"total": time.perf_counter() - t0, "found": found}
            a, b = (row[n]["found"] for n in variants)
            if len(a.entries) < 2:
                continue
            row["same"] = (a.result is not None and b.result is not None
                           and a.result.T == b.result.T and a.entries == b.entries
                           and a.starts == b.starts)
            rows.append(row)
            log(f"memory basins {case}: " + ", ".join(
                f"{n} {row[n]['total'] * 1e3:.0f} ms" for n in variants)
                + f", same {row['same']}")
    return rows, start


def report(rows: list[dict], start: str) -> str:
    names = ("one after the other", "side by side")
    ratios = [r[names[1]]["total"] / r[names[0]]["total"] for r in rows]
    head = ["", "median (ms)", "p95 (ms)"]
    body = [[n, f"{np.median([r[n]['total'] for r in rows]) * 1e3:.0f}",
             f"{np.percentile([r[n]['total'] for r in rows], 95) * 1e3:.0f}"] for n in names]
    return (f"{len(rows)} hits with two basins or more; load average {start} at the start, "
            f"{load_text()} at the end (two cores). Side by side / one after the other, "
            f"paired: median {np.median(ratios):.2f} (range {min(ratios):.2f}-"
            f"{max(ratios):.2f}); the same answer on {sum(r['same'] for r in rows)}/"
            f"{len(rows)}.\n\n" + "\n".join(table(head, body)))


def cell_main(doc: str, run_fn, report_fn, argv=None) -> int:
    """A cell bench's command line: ``--memory FILE`` (read only), ``--count N`` requests;
    ``report_fn(*run_fn(memory, count))`` printed."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--memory", type=Path, required=True)
    parser.add_argument("--count", type=int, default=50)
    args = parser.parse_args(argv)
    if not args.memory.is_file():
        parser.error(f"--memory: no file {args.memory}")
    print(report_fn(*run_fn(args.memory, args.count)))
    return 0


def main(argv=None) -> int:
    return cell_main(__doc__, run, report, argv)


if __name__ == "__main__":
    sys.exit(main())
