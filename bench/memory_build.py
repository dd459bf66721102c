"""A memory's build on the local worker pool against a local Ray cluster (issue 50).

The same first ``tasks`` of the memory benchmark's cell (``bench/memory_cell/panda_cell.yaml``:
the Panda with its limits, the build's wide search) built twice with the ``memory build``
verb, each into a new file, one after the other in this script (after one uncounted task
that fills the compile cache): with its two local worker
processes (``-j 2``) and on a Ray cluster started on this machine (``--ray local -j 2``).
Measured per backend: the command's wall time (Ray's start included), motions per minute
over the command and over the span of the build log's finish times (plus one median
solve: the steady rate, as ``bench/memory.py`` reports it), the median solve per motion;
and whether both files hold the same motions (``T`` of each request to the bit: the same
request gives the same plan on any backend).

Command: ``scripts/dev run python -P bench/memory_build.py [--tasks N]``, or ``scripts/dev
bench run_all.py --update --only memory_build``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench.common import Section, load_text, log, table  # noqa: E402

CELL = Path(__file__).resolve().parent / "memory_cell" / "panda_cell.yaml"
#: Tasks built per backend (the cell's first ones: the home station's).
TASKS = 24
BACKENDS = (("local pool, 2 processes", ["-j", "2"]),
            ("Ray, local cluster, 2 workers", ["--ray", "local", "-j", "2"]))


def _build(memory: Path, tasks: int, extra: list) -> float:
    """The build verb for the first ``tasks`` tasks into ``memory``; its wall time (s)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-P", "-m", "tocontrol_ros.memory", "build", str(CELL),
                    str(memory), "--limit", str(tasks), "--quiet", *extra], check=True)
    return time.perf_counter() - t0


def _figures(memory: Path) -> dict:
    from bench.memory import build_span
    from tocontrol_ros.core.memory.store import MotionStore

    with MotionStore(memory) as store:
        tasks = store.tasks()
    Ts = {key: t["T"] for key, t in tasks.items() if t["status"] == "SUCCESS"}
    span, solve = build_span(tasks)
    return {"ok": sum(t["status"] == "SUCCESS" for t in tasks.values()), "T": Ts,
            "span": span, "solve": solve}


def run(tasks: int = TASKS) -> Section:
    """Both builds; the section."""
    start = load_text()
    rows, figures = [], []
    with tempfile.TemporaryDirectory(prefix="tocontrol-memory-build-") as tmp:
        # Uncounted: one task first, so that neither backend pays the compile cache's
        # builds (run_all.py starts from an empty cache).
        warm = _build(Path(tmp) / "warm.sqlite", 1, ["-j", "1"])
        log(f"memory build: one task first (compile cache) in {warm:.1f} s")
        for i, (name, extra) in enumerate(BACKENDS):
            memory = Path(tmp) / f"build{i}.sqlite"
            wall = _build(memory, tasks, extra)
            f = _figures(memory)
            figures.append(f)
            log(f"memory build: {name}: {f['ok']}/{tasks} in {wall:.1f} s")
            rows.append([name, f"{f['ok']}/{tasks}", f"{wall:.1f}",
                         f"{60.0 * f['ok'] / wall:.1f}", f"{60.0 * f['ok'] / f['span']:.1f}",
                         f"{f['solve']:.2f}"])
    a, b = (f["T"] for f in figures)
    same = sum(a[k] == b.get(k) for k in a)
    body = [
        f"The first {tasks} tasks of `bench/memory_cell/panda_cell.yaml` (the home "
        f"station's; the build's wide search), built with `memory build` into a new file "
        f"per backend, one after the other, after one uncounted task that fills the "
        f"compile cache ({warm:.0f} s; load average {start} at the start, "
        f"{load_text()} at the end; two cores). Command: `scripts/dev run python -P "
        f"bench/memory_build.py --tasks {tasks}`.",
        "",
        *table(["backend", "motions", "command (s)", "motions per minute (command)",
                "motions per minute (steady: the log's span)", "solve median (s)"], rows),
        "",
        f"The same motions from both backends: `T` equal to the bit on {same} of {len(a)} "
        f"requests.",
    ]
    return Section("A memory's build on Ray against the local pool (issue 50)", body)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, default=TASKS)
    args = parser.parse_args(argv)
    run(args.tasks).print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
