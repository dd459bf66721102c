"""All benchmarks in one process; writes BENCHMARKS.md (issue 7).

Run from the repository root::

    scripts/dev bench                      # the full run (about an hour on 2 cores)
    scripts/dev bench run_all.py --quick   # fewer runs and pairs, for development
    python bench/run_all.py [--quick] [--out FILE]
        [--only paper,peers,random,optimum,reference_paper,optimum_panda,reference_panda,
                profile_panda,scaling,
                panda_peer,
                peer_compiled,first_use,deployed_panda,
                verification,deployed,replan,replan_moving,quick_motion,batch,limits,
                first_motion,collision,memory,memory_build,cancel,pose_goals]
        [--memory-file FILE]

Parts (one module each): ``paper`` (k = 1 ... 16 and the box: cold, warm, multistart), ``peers``
(direct collocation, Hermite-Simpson and Radau, and TOPP-RA on the paper's example),
``random_pairs`` (seeded start/target pairs), ``optimum`` (the default multistart against the
exhaustive reference on 100 seeded pairs, about half an hour), ``reference_paper`` (the default
on the same pairs against an independent direct-collocation reference and its convergence,
about 40 minutes on 2 processes), ``optimum_panda`` (the same on the
Panda with its joint limits), ``reference_panda`` (the default on 50 Panda cases with
its limits against an independent reference, the compiled collocation peer from many seeds,
and its convergence, about 40 minutes on 2 processes), ``profile_panda`` (where a default
Panda plan's time goes, and the same plans with two worker processes), ``scaling`` (planar
arms of 2 to 8 links, the Panda),
``panda_peer`` (the Panda with its limits against Hermite-Simpson collocation),
``peer_compiled`` (the default Panda plan on the 20 best-motion cases against an independent
direct-collocation peer built once with parameters and compiled derivatives), ``first_use``
(the Panda's compile routes, each in a new process with an empty cache), ``verification`` (the
certificate's cost against the solve, the 3R and the Panda), ``deployed`` (planner and tracker as
processes: idle CPU and ~/plan round trip against the same request in-process),
``deployed_panda`` (the Panda through two planner nodes, one process against one per core),
``replan`` (a target moving at 10 Hz through planner and tracker processes: replan latency,
splices, the paper's arm and the Panda), ``replan_moving`` (the same with targets that keep
the arm moving, the Panda from the README's set-up, latency also as a client sees it),
``quick_motion`` (issue 47: a replan's quick motion in process on the moving-target replans,
its parts paired against the TOPP-RA and open loop before issue 47's cuts),
``stagewise`` (issue 47's stage-wise transcription: IPOPT, Fatrop and an SQP with HPIPM on
the same NLPs, 10 Panda cases), ``warm_resolve`` (one replan after a 2 cm move on 20 Panda
cases: the parametric step, IPOPT warm with multipliers, IPOPT with tight warm options,
the path refit, the quick motion, the barrier step alone, the active-set SQP tried and not
kept (bench/warm_active_set.py) and IPOPT from a failed step's iterate, side by side),
``batch`` (batch
planning throughput: loop, process pool, Ray), ``limits`` (random cases with joint limits
enforced), ``first_motion`` (the first motion's time and T against the full plan, the
Panda), ``collision`` (issue 51: the Panda in three scenes placed on each case's
obstacle-free optimum, planned with the clearance rows, checked exactly with Coal, against
OMPL + TOPP-RA; ``--collision-cases``, about a minute a case and scene; the cases in
``--collision-workers`` processes),
``memory`` (issue 50: a memory of optimal motions of a Panda cell, built with the
``memory`` tool (resumed in ``--memory-file``; about half an hour on two cores from scratch),
then 50 requests inside the cell and 20 outside through a planner node with it against one
without, and the compiled peer from the same stored motions), ``memory_build`` (the
memory's build on the local worker pool against a local Ray cluster, the cell's first 24
tasks each, a few minutes), ``cancel`` (a cancel during a
Panda plan through ``~/plan_motion``: cancel to result, issue 52), ``pose_goals`` (pose goals
on the Panda through the planning service against the joint goal they came from, issue 52).
Every timing is taken in
this one process, side by side; compiled functions go to a fresh temporary cache so that
first-run costs are measured, not inherited.
"""

import argparse
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

# `python -P bench/run_all.py` (as scripts/dev runs it) does not put bench/ on sys.path;
# the repository goes last so that an installed tocontrol_ros still wins.
sys.path.append(str(Path(__file__).resolve().parents[1]))

from bench import common  # noqa: E402  (sets the thread variables before numpy)

#: The parts, in the order they run (``--only`` picks some).
PARTS = ("paper", "peers", "random", "optimum", "reference_paper", "optimum_panda",
         "reference_panda",
         "profile_panda", "scaling", "panda_peer", "peer_compiled",
         "first_use",
         "verification", "deployed", "deployed_panda", "replan", "replan_moving",
         "quick_motion", "batch",
         "limits", "stagewise", "warm_resolve",
         "first_motion", "collision", "memory", "memory_build", "cancel", "pose_goals")


def _parse(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="3 runs per case, 8 random pairs, planar arms 2, 3, 5 and one "
                             "Panda run: checks the pipeline in a few minutes")
    parser.add_argument("--runs", type=int, default=None,
                        help="timed runs per case (default 10; 3 with --quick)")
    parser.add_argument("--pairs", type=int, default=None,
                        help="random start/target pairs (default 50; 8 with --quick)")
    parser.add_argument("--pair-starts", type=int, default=16,
                        help="multistart starts for the random pairs (16)")
    parser.add_argument("--pair-candidates", type=int, default=3,
                        help="multistart candidates for the random pairs (3)")
    parser.add_argument("--budget", type=float, default=None,
                        help="seconds per case before its runs are reduced (45; 15 quick)")
    parser.add_argument("--optimum-pairs", type=int, default=None,
                        help="pairs of the default-against-exhaustive section (default 100; "
                             "4 with --quick); the exhaustive reference takes 10-40 s each")
    parser.add_argument("--only", default=",".join(PARTS),
                        help="comma-separated parts (peers needs paper)")
    parser.add_argument("--memory-file", type=Path, default=None,
                        help="the memory part's file, built or resumed there (default: "
                             "panda_cell.sqlite in the temporary folder)")
    parser.add_argument("--memory-requests", default=None, metavar="INSIDE,OUTSIDE,PEER",
                        help="the memory part's request counts (default 50,20,10; 5,2,2 "
                             "with --quick)")
    parser.add_argument("--memory-no-build", action="store_true",
                        help="the memory part serves --memory-file as it is (a partial "
                             "build is reported as such)")
    parser.add_argument("--optimum-panda-cases", type=int, default=20,
                        help="cases of the best-motion section on the Panda (default 20)")
    parser.add_argument("--limit-cases", type=int, default=10,
                        help="random cases per robot of the joint-limits part (10)")
    parser.add_argument("--limit-robots", default="3R-limited,UR5:50,Panda:50,xArm7",
                        help="robots of the joint-limits part, comma-separated, of "
                             "3R-limited, UR5, Panda, xArm7, each with an optional :cases "
                             "(default --limit-cases)")
    parser.add_argument("--collision-cases", type=int, default=20,
                        help="drawn cases of the collision part (20; 2 with --quick)")
    parser.add_argument("--collision-workers", type=int, default=2,
                        help="worker processes planning the collision part's cases (2; 0: "
                             "in the main process)")
    parser.add_argument("--out", type=Path, default=common.REPO / "BENCHMARKS.md")
    parser.add_argument("--update", action="store_true",
                        help="replace only the sections of the parts run (and their target "
                             "rows) in the existing --out file, each marked with this run's "
                             "commit and date; the rest of the file stays as it was")
    parser.add_argument("--keep-cache", action="store_true",
                        help="use the usual compile cache instead of a fresh one")
    args = parser.parse_args(argv)
    args.runs = args.runs or (3 if args.quick else 10)
    args.pairs = args.pairs or (8 if args.quick else 50)
    args.budget = args.budget or (15.0 if args.quick else 45.0)
    args.optimum_pairs = args.optimum_pairs or (4 if args.quick else 100)
    args.only = [p.strip() for p in args.only.split(",") if p.strip()]
    bad = set(args.only) - set(PARTS)
    if bad:
        parser.error(f"--only: unknown parts {sorted(bad)}")
    if "peers" in args.only and "paper" not in args.only:
        parser.error("--only: peers needs paper (it reuses its solutions)")
    if args.runs < 1 or args.pairs < 1:
        parser.error("--runs and --pairs must be >= 1")
    return args


def main(argv=None):
    args = _parse(argv)
    cache = None
    if not args.keep_cache:
        cache = tempfile.mkdtemp(prefix="tocontrol-bench-cache-")
        os.environ["TOCONTROL_CACHE"] = cache
    try:
        return _run(args)
    finally:
        if cache:
            shutil.rmtree(cache, ignore_errors=True)


def _run(args):
    from bench import (
        batch,
        cancel,
        collision,
        deployed,
        deployed_panda,
        first_motion,
        first_use,
        limits,
        memory,
        memory_build,
        optimum,
        optimum_panda,
        panda_peer,
        paper,
        peer_compiled,
        peers,
        pose_goals,
        profile_panda,
        quick_motion,
        random_pairs,
        reference_panda,
        reference_paper,
        replan,
        scaling,
        stagewise,
        verification,
        warm_resolve,
    )

    t0 = time.perf_counter()
    info = common.machine_info()
    load_start = common.load_text()
    ticks_start = common.cpu_ticks()
    common.log(f"run_all: {info['CPU']}, {info['cores (usable)']} cores, load {load_start}, "
               f"{'quick' if args.quick else 'full'}")
    model = common.paper_model()
    sections = []

    def section(run):
        """``run()`` -> Section, timed, with the CPU steal while it ran; kept in order."""
        speed = common.speed_probe()
        ts, ticks = time.perf_counter(), common.cpu_ticks()
        sec = run()
        sec.speed = speed
        sec.seconds = time.perf_counter() - ts
        sec.steal = common.steal_text(ticks, common.cpu_ticks())
        sections.append(sec)

    paper_out = None
    if "paper" in args.only:
        def run_paper():
            nonlocal paper_out
            sec, paper_out = paper.run(model, args.runs, args.budget, first_run=True)
            return sec
        section(run_paper)
    if "peers" in args.only:
        section(lambda: peers.run(model, paper_out, args.runs, args.budget))
    if "random" in args.only:
        section(lambda: random_pairs.run(model, args.pairs, args.pair_starts,
                                         args.pair_candidates))
    if "optimum" in args.only:
        section(lambda: optimum.run(model, args.optimum_pairs))
    if "reference_paper" in args.only:
        section(lambda: reference_paper.run(args.optimum_pairs or 100,
                                             256 if args.quick else reference_paper.SEEDS))
    if "optimum_panda" in args.only:
        section(lambda: optimum_panda.run(2 if args.quick else args.optimum_panda_cases))
    if "reference_panda" in args.only:
        section(lambda: reference_panda.run(2 if args.quick else 50,
                                            16 if args.quick else reference_panda.SEEDS))
    if "scaling" in args.only:
        if args.quick:
            scaling.PLANAR_NS = (2, 3, 5)
        section(lambda: scaling.run(runs=3 if args.quick else 5,
                                    panda_runs=1 if args.quick else 2))
    if "profile_panda" in args.only:
        section(lambda: profile_panda.run(2 if args.quick else args.optimum_panda_cases))
        section(lambda: profile_panda.run_cores(2 if args.quick else args.optimum_panda_cases))
    if "panda_peer" in args.only:
        section(lambda: panda_peer.run(runs=1 if args.quick else 3))
    if "peer_compiled" in args.only:
        section(lambda: peer_compiled.run(2 if args.quick else args.optimum_panda_cases))
    if "first_use" in args.only:
        section(lambda: first_use.run(runs=1 if args.quick else 3))
    if "verification" in args.only:
        section(lambda: verification.run(model, args.runs, args.budget))
    if "deployed" in args.only:
        section(lambda: deployed.run(runs=5 if args.quick else 10,
                                     window=4.0 if args.quick else deployed.WINDOW))
    if "deployed_panda" in args.only:
        section(lambda: deployed_panda.run(2 if args.quick else args.optimum_panda_cases))
    if "replan" in args.only:
        section(lambda: replan.run())
    if "replan_moving" in args.only:
        section(lambda: replan.run(moving=True))
    if "quick_motion" in args.only:
        section(lambda: quick_motion.run())
    if "stagewise" in args.only:
        section(lambda: stagewise.run(3 if args.quick else 10))
    if "warm_resolve" in args.only:
        section(lambda: warm_resolve.run(3 if args.quick else warm_resolve.CASES))
    if "batch" in args.only:
        section(lambda: batch.run(count=6, starts=4, candidates=2) if args.quick
                else batch.run(count=20))
    if "limits" in args.only:
        section(lambda: limits.run(3 if args.quick else args.limit_cases,
                                   limits.parse_robots(args.limit_robots,
                                                       3 if args.quick else args.limit_cases)))
    if "first_motion" in args.only:
        section(lambda: first_motion.run(runs=3 if args.quick else args.runs,
                                         count=3 if args.quick else 9))
    if "collision" in args.only:
        section(lambda: collision.run(2 if args.quick else args.collision_cases,
                                      workers=args.collision_workers))
    if "memory" in args.only:
        counts = (5, 2, 2) if args.quick else (50, 20, memory.PEER_CASES)
        if args.memory_requests:
            counts = tuple(int(v) for v in args.memory_requests.split(","))
        section(lambda: memory.run(args.memory_file, *counts,
                                   build=not args.memory_no_build))
    if "memory_build" in args.only:
        section(lambda: memory_build.run(4 if args.quick else memory_build.TASKS))
    if "cancel" in args.only:
        section(lambda: cancel.run(4 if args.quick else 12))
    if "pose_goals" in args.only:
        section(lambda: pose_goals.run(2 if args.quick else 6))
    total = time.perf_counter() - t0
    load_end = common.load_text()
    info["CPU steal over the run (time the hypervisor took)"] = common.steal_text(
        ticks_start, common.cpu_ticks())
    if args.update:
        text = _update(args.out.read_text(), info, sections)
    else:
        text = _report(args, info, load_start, load_end, sections, total)
    args.out.write_text(text)
    common.log(f"wrote {args.out} ({total:.0f} s)")
    return 0


def _report(args, info, load_start, load_end, sections, total):
    mode = "quick (`--quick`)" if args.quick else "full"
    busy = max(float(load_start.split()[0]), float(load_end.split()[0])) > 1.0
    lines = [
        "# Benchmarks",
        "",
        "Generated by `scripts/dev bench` (`bench/run_all.py`; do not edit by hand), "
        f"{mode} mode. Every figure below comes from this one process, side by side; wall "
        "times; compiled functions in a fresh temporary cache (first-run costs are "
        "measured, not inherited).",
        "",
        "## Machine",
        "",
    ]
    rows = list(info.items()) + [("load average at start (1, 5, 15 min)", load_start),
                                 ("load average at the end", load_end),
                                 ("benchmark wall time", f"{total:.0f} s")]
    lines += common.table(["", ""], rows)
    if busy:
        lines += ["", "**The load average was above 1**: other processes shared the two "
                  "cores during this run, so the timings are pessimistic (inflated) and the "
                  "relative figures measured side by side are the ones to trust."]
    targets = [t for s in sections for t in s.targets]
    if targets:
        lines += ["", "## Targets", ""]
        lines += common.table(["target", "met?"], targets)
    for s in sections:
        lines += ["", f"## {s.title}", "",
                  f"({s.seconds:.0f} s of the run; CPU steal {s.steal}; machine speed "
                  f"before it: {s.speed}.)", ""] + s.lines
    return "\n".join(lines) + "\n"


def _stem(title: str) -> str:
    """A section title without its trailing count in parentheses."""
    return re.sub(r" \(\d+ [a-z]+\)$", "", title)


def _update(text: str, info: dict, sections) -> str:
    """``text`` (a report) with these sections and their target rows replaced or added."""
    head, *parts = text.rstrip("\n").split("\n## ")
    # Every block ends with a blank line (the file's last one lost it to the strip).
    blocks = {p.split("\n", 1)[0]: p if p.endswith("\n") else p + "\n" for p in parts}
    order = [p.split("\n", 1)[0] for p in parts]
    stamp = f"regenerated alone by `run_all.py --update` on {info['commit']}, {info['date']}"
    for s in sections:
        body = [s.title, "", f"({s.seconds:.0f} s, {stamp}; CPU steal {s.steal}; machine "
                             f"speed before it: {s.speed}.)", ""]
        body += s.lines + [""]
        # The same section run with another count ("... (6 cases)") is replaced, in place.
        same = [t for t in order if _stem(t) == _stem(s.title)]
        if same:
            order[order.index(same[0])] = s.title
            for t in same[1:]:
                order.remove(t)
            for t in same:
                blocks.pop(t, None)
        else:
            order.append(s.title)
        blocks[s.title] = "\n".join(body)
    new_targets = [t for s in sections for t in s.targets]
    if new_targets:
        old = blocks.get("Targets", "Targets\n\n| target | met? |\n|---|---|").split("\n")
        # A row is replaced by a new one with the same name, or the same first 20 characters
        # (a target whose wording changed, e.g. "issue 3: multistart (k = 4, 16x6) ...").
        keys = {str(t[0])[:20] for t in new_targets}
        rows = [r for r in old[4:] if r.startswith("| ")
                and r.split("|")[1].strip()[:20] not in keys]
        blocks["Targets"] = "\n".join(old[:4] + rows + common.table(["", ""], new_targets)[2:]
                                      + [""])
        if "Targets" not in order:
            order.insert(0, "Targets")
    # Every block ends with one newline (the last one read lost it), so that a section
    # added after it is set off by a blank line.
    return "\n## ".join([head] + [blocks[t].rstrip("\n") + "\n" for t in order]
                        ).rstrip("\n") + "\n"


if __name__ == "__main__":
    sys.exit(main())
