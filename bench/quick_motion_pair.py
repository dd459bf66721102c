"""A replan's quick motion of another commit's package against this one's, paired in one process.

For a change that must keep the plans to the bit and only cut work (issue 47's 10 ms bar):
the package of ``REV`` (default ``main``) is exported by ``git archive`` into a temporary
directory under another name (``tocontrol_ref``, its imports renamed, its ``config/`` next to
it) and imported beside the installed ``tocontrol_ros``; each builds the replans of
``bench/quick_motion.py`` (the moving-target chain of ``bench/replan.py --moving``) with its
own code, and the same replan is then solved by each in turn, alternately first, ``REPS``
times over, optionally after a pause (s) before each call (as the planner node's worker
meets a goal: asleep between goals). Printed: whether every replan's plan is the same to
the bit (``T``, the squared path speeds, a sampling's positions and torques, the
certificate's verdict), how far apart the certificates' open-loop ends are (0 for the same
integration), how the TOPP-RA passes made compare (the work,
not the plan: the time scales' ranking passes made together make one or two more), and the
medians (ms) of the parts
(``PlanResult.timings``) and of the calling thread's CPU time (``time.thread_time``: less
moved by other processes on a loaded machine than the wall clock), reference against this
package.

Usage: ``scripts/dev run python -P bench/quick_motion_pair.py [paper|panda] [REPS] [PAUSE]
[REV]``.
"""

from __future__ import annotations

import importlib
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))

from bench.quick_motion import replans  # noqa: E402

#: The reference package's import name.
REF = "tocontrol_ref"
KEYS = ("guess", "scaling", "verify", "total")


def export_reference(rev: str, where: Path) -> None:
    """``rev``'s ``tocontrol_ros`` as package ``REF`` under ``where`` (imports renamed)."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "tocontrol_ros",
                              "config"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(where)], input=archive, check=True)
    pkg = where / REF
    (where / "tocontrol_ros").rename(pkg)
    (where / "config").rename(pkg / "config")  # where the package looks for its URDF
    for path in pkg.rglob("*.py"):
        text = path.read_text()
        path.write_text(text.replace("tocontrol_ros", REF))


def cases(pkg: str, name: str) -> tuple:
    """``(quick_motion, [(problem, q_near), ...])`` of package ``pkg``: the chain of
    ``bench/quick_motion.py``'s ``replans``, each package with its own types."""
    chain = replans(name, pkg)
    if chain is None:
        raise RuntimeError(f"{name}: its URDF is not installed")
    return importlib.import_module(f"{pkg}.core.direct.first_motion").quick_motion, chain


def same(a, b) -> bool:
    """Whether two quick motions are the same plan to the bit (their passes aside: the
    work made, counted by :func:`main` apart; the certificate's open-loop end by
    :func:`end_gap`)."""
    if (a.success, a.T) != (b.success, b.T):
        return False
    if not a.success:
        return True
    sa, sb = a.trajectory.sample(0.01), b.trajectory.sample(0.01)
    return bool(np.array_equal(a.trajectory.x, b.trajectory.x)
                and np.array_equal(sa.q, sb.q) and np.array_equal(sa.u, sb.u)
                and a.certificate.passed == b.certificate.passed)


def end_gap(a, b) -> float:
    """The largest difference of two certificates' open-loop ends (0 where either has
    none): the same integration gives 0, another one its own error (rad, rad/s)."""
    if a.certificate is None or b.certificate is None:
        return 0.0
    return float(np.max(np.abs(a.certificate.open_loop_end - b.certificate.open_loop_end)))


def main(name: str = "paper", reps: int = 3, pause: float = 0.0, rev: str = "main") -> None:
    with tempfile.TemporaryDirectory() as tmp:
        export_reference(rev, Path(tmp))
        sys.path.insert(0, tmp)
        runs = {"ref": cases(REF, name), "new": cases("tocontrol_ros", name)}
        for quick, chain in runs.values():  # warm-up: builds, mappings
            for problem, q_near in chain[:5]:
                quick(problem, q_near)
        for pkg in (REF, "tocontrol_ros"):  # each package's own background builds
            importlib.import_module(f"{pkg}.core.robot.compiled").wait_for_builds()
        for quick, chain in runs.values():  # the optimised libraries loaded by each
            for problem, q_near in chain[:5]:
                quick(problem, q_near)
        parts = {k: {p: [] for p in KEYS} for k in runs}
        cpu = {k: [] for k in runs}
        identical, passes, gaps = 0, [], []
        count = len(runs["new"][1])
        for r in range(reps):
            for i in range(count):
                order = ("ref", "new") if (i + r) % 2 == 0 else ("new", "ref")
                res = {}
                for key in order:
                    quick, chain = runs[key]
                    if pause:
                        time.sleep(pause)
                    c0 = time.thread_time()
                    res[key] = quick(*chain[i])
                    cpu[key].append(time.thread_time() - c0)
                    for p in KEYS:
                        parts[key][p].append(res[key].timings[p])
                if r == 0:
                    identical += same(res["ref"], res["new"])
                    gaps.append(end_gap(res["ref"], res["new"]))
                    passes.append(res["new"].iterations - res["ref"].iterations)

    def med(values: list) -> float:
        return 1e3 * statistics.median(values)

    print(f"{name}: {rev} against this package, {reps} x {count} replans, pause {pause:g} s: "
          f"the same plan to the bit {identical}/{count}; TOPP-RA passes the same "
          f"{passes.count(0)}/{count}, new minus {rev}: median {statistics.median(passes):g}, "
          f"range [{min(passes)}, {max(passes)}]; the certificate's open-loop end the same to "
          f"the bit {gaps.count(0.0)}/{count}, largest difference {max(gaps):.2g}")
    for p in KEYS:
        print(f"  {p:8s} {rev} {med(parts['ref'][p]):7.2f}  new {med(parts['new'][p]):7.2f} ms"
              f"  ratio {med(parts['new'][p]) / med(parts['ref'][p]):.3f}")
    print(f"  {'CPU':8s} {rev} {med(cpu['ref']):7.2f}  new {med(cpu['new']):7.2f} ms"
          f"  ratio {med(cpu['new']) / med(cpu['ref']):.3f}")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0] if args else "paper", int(args[1]) if len(args) > 1 else 3,
         float(args[2]) if len(args) > 2 else 0.0, args[3] if len(args) > 3 else "main")
