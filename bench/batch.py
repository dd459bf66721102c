"""Batch planning throughput (motions per second) on the paper's arm (issue 19).

The motions are the ordered pairs of the five stations of ``config/cell_example.yaml`` (20;
fewer with ``--quick``), planned with the file's settings (k = 4, multistart 16 x 3,
verification on) or the given multistart. Four ways, side by side in this process:

- *single-process loop*: ``run_task`` on each motion in this process, one after the other
  (a freshly loaded model, so its compiled functions are loaded as a worker loads them);
- ``batch -j 1`` and ``batch -j 2``: the local process pool, end to end (workers spawned,
  model built once per worker, journal, library and summary written);
- ``batch --ray local -j 2``: a private 2-CPU Ray cluster on loopback, end to end (cluster
  start included) and in steady state (first to last result).

The T of every motion is compared with the loop's: the same solver on the same task must
give the same motion wherever it runs.

    python bench/batch.py [--quick] [--count N] [--starts S --candidates C]
"""

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parents[1]))

import yaml  # noqa: E402

from bench import common  # noqa: E402  (sets the thread variables before numpy)
from bench.common import Section, log, table  # noqa: E402
from tocontrol_ros.batch import cli as batch  # noqa: E402
from tocontrol_ros.batch.library import library_paths  # noqa: E402
from tocontrol_ros.batch.tasks import load_model, load_task_file  # noqa: E402
from tocontrol_ros.batch.worker import run_task  # noqa: E402

EXAMPLE = common.REPO / "config" / "cell_example.yaml"


def task_file(directory, count, starts=None, candidates=None):
    """The example's first `count` station pairs as explicit motions; returns the path."""
    doc = yaml.safe_load(EXAMPLE.read_text())
    names = list(doc["stations"])
    pairs = [(a, b) for a in names for b in names if a != b][:count]
    doc["motions"] = [{"start": a, "target": b} for a, b in pairs]
    if starts is not None:
        doc["solver"].update(starts=starts, candidates=candidates)
    path = Path(directory) / "cell.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _journal(path):
    lines = library_paths(path)["journal"].read_text().splitlines()[1:]
    return [json.loads(line) for line in lines]


def _batch_run(tasks_path, out, argv):
    t0 = time.perf_counter()
    code = batch.main([str(tasks_path), "-o", str(out), "--quiet", *argv])
    wall = time.perf_counter() - t0
    entries = _journal(out)
    ends = sorted(e["finished"] for e in entries)
    steady = (len(ends) - 1) / ((ends[-1] - ends[0]) * 1e-9) if len(ends) > 1 and \
        ends[-1] > ends[0] else float("nan")
    return {"code": code, "wall": wall, "steady": steady,
            "T": {e["index"]: e["T"] for e in entries},
            "ok": sum(e["status"] == "SUCCESS" for e in entries), "n": len(entries)}


def _loop(task_set):
    model_t0 = time.perf_counter()
    load_model(task_set.robot)  # what a worker's initializer pays
    t0 = time.perf_counter()
    results = [run_task(task_set.robot, t) for t in task_set.tasks]
    wall = time.perf_counter() - model_t0
    return {"code": 0, "wall": wall, "steady": float("nan"),
            "solve": time.perf_counter() - t0,
            "T": {r["index"]: r["T"] for r in results},
            "ok": sum(r["status"] == "SUCCESS" for r in results), "n": len(results)}


def run(count=20, starts=None, candidates=None):
    with tempfile.TemporaryDirectory(prefix="tocontrol-bench-batch-") as tmp:
        tmp = Path(tmp)
        path = task_file(tmp, count, starts, candidates)
        task_set, _ = load_task_file(path)
        n = len(task_set.tasks)
        runs = {}
        log(f"batch: single-process loop over {n} motions")
        runs["single-process loop"] = _loop(task_set)
        for label, argv in (("`batch -j 1`", ["-j", "1"]), ("`batch -j 2`", ["-j", "2"])):
            log(f"batch: {label}")
            runs[label] = _batch_run(path, tmp / f"j{argv[1]}.mcap", argv)
        if importlib.util.find_spec("ray") is not None:
            log("batch: `batch --ray local -j 2`")
            runs["`batch --ray local -j 2`"] = _batch_run(path, tmp / "ray.mcap",
                                                          ["--ray", "local", "-j", "2"])
        return _section(task_set, runs, n)


def _section(task_set, runs, n):
    solver = dict(task_set.tasks[0].solver)
    loop = runs["single-process loop"]
    rows = []
    for label, r in runs.items():
        rate = r["n"] / r["wall"] if r["wall"] > 0 else float("nan")
        same = sum(1 for i, T in r["T"].items() if T is not None and loop["T"].get(i) is not
                   None and abs(T - loop["T"][i]) <= 1e-9 * abs(T))
        rows.append([label, f"{r['ok']}/{r['n']}" + ("" if r["code"] == 0 else
                                                     f" (exit {r['code']})"),
                     f"{r['wall']:.1f}", f"{rate:.2f}", f"{rate * loop['wall'] / n:.2f}",
                     f"{r['steady']:.2f}" if r["steady"] == r["steady"] else "—",
                     f"{same}/{n}"])
    lines = [
        f"{n} motions: ordered pairs of the stations of `config/cell_example.yaml` (paper's "
        f"arm, k = {task_set.tasks[0].k:g}, starts = {solver.get('starts', 16)}, "
        f"candidates = {solver.get('candidates', 3)}, verification "
        f"{'on' if solver.get('verify', True) else 'off'}). Wall time end to end: process "
        "or cluster start, model builds, planning, journal, library and summary. *Steady*: "
        "motions per second between the first and the last result. *Same T*: motions whose "
        "T equals the loop's to 1e-9 (relative).",
        "",
    ]
    lines += table(["", "solved", "wall (s)", "motions/s", "x loop", "steady motions/s",
                    "same T as loop"], rows)
    if not any("ray" in k for k in runs):
        lines += ["", "Ray is not installed here (`pip install '.[ray]'`): no Ray row."]
    return Section("Batch planning throughput (issue 19)", lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="6 motions, 4 x 2 multistart")
    parser.add_argument("--count", type=int, default=None)
    parser.add_argument("--starts", type=int, default=None)
    parser.add_argument("--candidates", type=int, default=None)
    args = parser.parse_args(argv)
    count = args.count or (6 if args.quick else 20)
    starts = args.starts or (4 if args.quick else None)
    candidates = args.candidates or (2 if args.quick else 3 if starts else None)
    sec = run(count, starts, candidates)
    print("\n".join([f"## {sec.title}", ""] + sec.lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
