"""The clearance certificate before and after session 37, paired in one process (issue 51).

Draws of the table stream of :mod:`bench.collision` (the Panda, its limits and SRDF, k = 4,
margin 1 cm, the bench's solver options), each planned twice by ``plan()``, alternated
(A first on even cases, B first on odd ones):

- **A**: the certificate's clearance item as before session 37: the bound between its
  times from the joint velocity limits, no interval halved (the function below, what
  ``checks/certificate.py`` had);
- **B**: as committed: the motion's own joint speed bound on each interval
  (``FlatTrajectory.joint_speed_bounds``), intervals under the margin halved.

Each plan's status, ``T``, processor time (``time.process_time``: the plan is in this
process) and its certificate's ``clearance_bound`` are printed. ``--pose`` measures instead
what the pose goal's search with a scene costs (:func:`~tocontrol_ros.core.geometry.reach.
clear_pose_configuration`): a pose whose IK solution from the start has its forearm in a
ball (found), and a pose inside a 10 cm ball (refused), each 3 times with a new collision
model object (no remembered verdict), processor time.

Run: ``scripts/dev run python -P bench/certificate_ab.py 35:0 4:0 3:0.01`` (``CASE:ROOM``:
the table stream's draw and its start room, ``--start-room`` of bench/collision.py);
``... bench/certificate_ab.py --pose``; ``--time-limit S`` (wall seconds a plan, default
the bench's), ``--only A|B``. docs/collision.md (session 37) has what these
measured.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see bench/common.py

import numpy as np  # noqa: E402

from bench.collision import TIME_LIMIT, K, draw_table, load_scene_dict  # noqa: E402
from bench.common import PANDA_LOCKED, panda_urdf  # noqa: E402
from tocontrol_ros.core.checks import certificate  # noqa: E402
from tocontrol_ros.core.geometry.collision import body_frames, collision_model  # noqa: E402
from tocontrol_ros.core.geometry.reach import clear_pose_configuration  # noqa: E402
from tocontrol_ros.core.geometry.scene import scene_from_dict  # noqa: E402
from tocontrol_ros.core.geometry.tuning import CERTIFY_STEPS  # noqa: E402
from tocontrol_ros.core.planning.solver import SolverOptions, plan  # noqa: E402
from tocontrol_ros.core.robot.ik import ik_pose  # noqa: E402
from tocontrol_ros.core.robot.kinematics import tip_pose  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import load_robot  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

COMMITTED = certificate.clearance_checks


def limits_clearance_checks(problem, trajectory, steps: int = CERTIFY_STEPS):
    """The clearance item before session 37: the velocity limits between the times."""
    col = problem.collision
    if col is None:
        return [], {}
    t = np.linspace(0.0, trajectory.T, steps + 1)
    sample = trajectory.evaluate(t)
    v = problem.limits.velocity
    v = np.where(np.isfinite(v), v, 2.0 * np.max(np.abs(sample.qd), axis=0))
    swept = col.swept(t, sample.q, v)
    item = certificate.check_item("clearance", col.margin - swept.lower_bound, 0.0, "m",
                                  "margin minus the least distance (velocity limits' bound)")
    return [item], {"min_clearance": swept.minimum, "closest_pair": "/".join(swept.pair),
                    "closest_time": swept.time, "clearance_bound": swept.lower_bound}


def _models():
    urdf = panda_urdf()
    srdf = urdf.parent.parent / "srdf" / "panda.srdf"
    model = load_robot(str(urdf), tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    return model, urdf, srdf, collision_model(model, urdf, srdf)


def paired(cases: list[tuple[int, float]], time_limit: float = TIME_LIMIT,
           which: tuple[str, ...] = ("A", "B")) -> None:
    model, _, _, base = _models()
    limits = JointLimits.from_model(model)
    table = base.with_scene(scene_from_dict(load_scene_dict("table"), "bench scene table"))
    options = SolverOptions(starts=4, candidates=1, time_limit=time_limit)
    draws = {}
    for n, (case, room) in enumerate(cases):
        if room not in draws:
            draws[room] = draw_table(model, limits, table, 60, start_room=room)
        q0, target, why = draws[room][case]
        if q0 is None:
            print(f"case {case} room {room}: no start ({why})")
            continue
        problem = Problem(model, joint_state(q0), point(target), k=K, limits=limits,
                          collision=table)
        for mode in (which if n % 2 == 0 else which[::-1]):
            certificate.clearance_checks = limits_clearance_checks if mode == "A" \
                else COMMITTED
            t0 = time.process_time()
            res = plan(problem, options)
            cpu = time.process_time() - t0
            fig = res.certificate.figures if res.certificate is not None else {}
            print(f"[{time.strftime('%H:%M:%S')}] case {case} room {room} {mode}: "
                  f"{res.status.name} T {res.T:.6f} cpu {cpu:.1f} s bound "
                  f"{fig.get('clearance_bound')} refined {fig.get('clearance_refined')}",
                  flush=True)
        certificate.clearance_checks = COMMITTED


def pose_search() -> None:
    model, urdf, srdf, base = _models()
    lo, hi = model.q_lower, model.q_upper
    q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
    rot, pos = tip_pose(model, q0 + np.array([1.2, 0.3, 0.0, 0.3, 0.0, -0.2, 0.0]))
    [first], _, _ = ik_pose(model, pos, rot, q0[None], lo, hi)
    frames = body_frames(model, first[None])[1][0]
    scenes = {"found": {"name": "ball", "type": "sphere", "radius": 0.05,
                        "position": (0.5 * (frames[3] + frames[5])).tolist()},
              "refused": {"name": "block", "type": "sphere", "radius": 0.1,
                          "position": pos.tolist()}}
    for _ in range(3):
        for name, ball in scenes.items():
            col = base.with_scene(scene_from_dict({"obstacles": [ball]}))
            t0 = time.process_time()
            out = clear_pose_configuration(col, pos, rot, lo, hi)
            print(f"{name}: found {out.found}, {out.seeds} seeds, {out.solutions} solutions, "
                  f"{out.tried} measured, clearance {out.clearance:.4f} m "
                  f"({'/'.join(out.pair)}): {time.process_time() - t0:.3f} s of CPU")


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cases", nargs="*", help="CASE:ROOM (the table stream's draw, its "
                        "start room in m)")
    parser.add_argument("--pose", action="store_true", help="the pose search's cost instead")
    parser.add_argument("--time-limit", type=float, default=TIME_LIMIT,
                        help=f"each plan's (wall s; default the bench's {TIME_LIMIT:g})")
    parser.add_argument("--only", choices=("A", "B"), help="one certificate only")
    args = parser.parse_args()
    if args.pose:
        pose_search()
    else:
        paired([(int(c.split(":")[0]), float(c.split(":")[1])) for c in args.cases],
               args.time_limit, (args.only,) if args.only else ("A", "B"))
