"""Bench cases of ``bench/collision.py`` planned by an earlier ``plan_limited`` and this one.

Each case (``SCENE:DRAW``, the bench's draws, scenes and options) is planned with the bounded
solve of a git revision (A: ``core/direct/limited.py`` at ``--before``, loaded beside the
package) and of the working tree (B), alternated in one process; per plan the status, ``T``,
the exact clearance (Coal, 2001 times), the start returned, whether a detour was made, and
the process's CPU and wall seconds (docs/collision.md, session 38). Only ``plan_limited``
differs between A and B: the rest of the package (the certificate included) is the tree's.

Run: ``scripts/dev run python -P bench/collision_ab.py table:1 shelf:0 [--before REV]
[--only A|B]``.
"""

import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench import collision as bc  # noqa: E402
from bench.common import PANDA_LOCKED, panda_urdf  # noqa: E402
from bench.limits import draw_cases  # noqa: E402
from tocontrol_ros.core.errors import ProblemError  # noqa: E402
from tocontrol_ros.core.geometry.collision import CollisionModel, collision_model  # noqa: E402
from tocontrol_ros.core.geometry.scene import scene_from_dict  # noqa: E402
from tocontrol_ros.core.planning.solver import plan  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LIMITED = "tocontrol_ros/core/direct/limited.py"


def case_problem(model, limits: JointLimits, base: CollisionModel, scene: str, draw: int
                 ) -> Problem | None:
    """The bench's problem of ``draw`` in ``scene`` (None: the draw is left out there)."""
    def problem(q0, target, col) -> Problem:
        return Problem(model, joint_state(q0), point(target), k=bc.K, limits=limits,
                       collision=col)

    table = base.with_scene(scene_from_dict(bc.load_scene_dict("table"), "bench scene table"))
    if scene == "table":
        q0, target, _ = bc.draw_table(model, limits, table, draw + 1)[draw]
        return None if q0 is None else problem(q0, target, table)
    q0, _, target = draw_cases(model, limits, draw + 1, bc.SEED)[draw]
    free = plan(problem(q0, target, None), bc.OPTIONS)
    for at in bc.PLACE_AT:
        try:
            return problem(q0, target, base.with_scene(bc.place_scene(scene, free, model, at)[0]))
        except ProblemError:
            continue
    return None


def limited_at(rev: str):
    """``plan_limited`` of ``core/direct/limited.py`` at git revision ``rev``."""
    text = subprocess.run(["git", "show", f"{rev}:{LIMITED}"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "limited_before.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("tocontrol_ros.core.direct.limited_before",
                                                  path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.plan_limited


def main(cases: list[str], before: str, only: str) -> None:
    import tocontrol_ros.core.direct.method as direct_method
    import tocontrol_ros.core.indirect.method as indirect_method
    from tocontrol_ros.core.direct import limited

    impl = {"A": limited_at(before), "B": limited.plan_limited}
    urdf = panda_urdf()
    model = load_robot(str(urdf), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    limits = JointLimits.from_model(model)
    base = collision_model(model, urdf, urdf.parent.parent / "srdf" / "panda.srdf")
    for case in cases:
        scene, draw = case.split(":")
        problem = case_problem(model, limits, base, scene, int(draw))
        if problem is None:
            print(f"{case}: left out by the bench", flush=True)
            continue
        for which in only:
            direct_method.plan_limited = indirect_method.plan_limited = impl[which]
            t0, c0 = time.perf_counter(), time.process_time()
            res = plan(problem, bc.OPTIONS)
            cpu, wall = time.process_time() - c0, time.perf_counter() - t0
            clear = "—"
            if res.success:
                q = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001)).q
                exact = problem.collision.clearance(q)
                clear = f"{exact.minimum * 100:.2f} cm ({'/'.join(exact.pair)})"
            returned = [r.index for r in res.starts if r.status == "returned"]
            detour = any("detour seed (" in w for w in res.warnings)
            print(f"{case} {which}: {res.status.name} T {res.T:.6f} clear {clear} returned "
                  f"{returned} detour {detour} CPU {cpu:.1f} s wall {wall:.1f} s | "
                  f"{res.message[:160]}", flush=True)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cases", nargs="+", metavar="SCENE:DRAW")
    parser.add_argument("--before", default="ffb9775", help="git revision of A (default "
                        "ffb9775, main before session 38)")
    parser.add_argument("--only", choices=("A", "B"), help="only one of the two")
    args = parser.parse_args()
    main(args.cases, args.before, args.only or "AB")
