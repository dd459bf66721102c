"""Plan one named case and print its fingerprint as one JSON line (run in a new process).

Usage: ``python -P test/core/plan_probe.py CASE`` with CASE ``paper`` (the paper's arm from
its example start to its target, k = 4, the default multistart) or ``panda`` (the Panda of
example-robot-data with its URDF limits, from rest to a point: the bounded solve, default
options). The fingerprint holds every digit of ``T``, the start records and a hash of the
trajectory sampled at 101 times, and the clock's call sites in the core (see ``--sites``).
Used by ``test_determinism.py``: the same case planned in two processes, one of them beside
CPU-bound processes, must print the same fingerprint.
"""

from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.problem import Problem, joint_state, point

#: A Panda motion from rest whose velocity and position limits bind (as in test_flat.py).
PANDA_Q0 = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
PANDA_Q1 = np.array([1.2, -0.3, 0.4, -1.6, -0.5, 2.2, 0.2])


def problem_of(case: str, panda_urdf: str | None = None) -> Problem:
    """The named case's problem."""
    if case == "paper":
        model = load_robot(str(default_urdf_path()))
        return Problem(model, point(PAPER_START), point(PAPER_TARGET), k=4.0)
    if case == "panda":
        model = load_robot(panda_urdf, tip_link="panda_hand",
                           locked_joints={"panda_finger_joint1": 0.0,
                                          "panda_finger_joint2": 0.0})
        return Problem(model, joint_state(PANDA_Q0), point(model.point(PANDA_Q1)), k=4.0)
    raise ValueError(f"`case` must be 'paper' or 'panda', not {case!r}")


def fingerprint(result) -> dict:
    """Every number of a result that two equal solves share (not the timings)."""
    out = {"status": result.status.name, "T": repr(result.T), "method": result.method,
           "iterations": result.iterations, "intervals": result.intervals,
           "starts": [[s.index, repr(s.guess_T), repr(s.T), s.status] for s in result.starts],
           "warnings": list(result.warnings)}
    if result.trajectory is not None:
        ev = result.trajectory.evaluate(np.linspace(0.0, result.T, 101))
        digest = hashlib.sha256()
        for values in (ev.q, ev.qd, ev.u):
            digest.update(np.ascontiguousarray(values, dtype=float).tobytes())
        out["trajectory"] = digest.hexdigest()
    return out


def main(argv: list[str]) -> int:
    case = argv[1]
    problem = problem_of(case, argv[2] if len(argv) > 2 else None)
    print(json.dumps(fingerprint(plan(problem, SolverOptions()))), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
