"""Issue 49: the README's Panda ("Your own arm") holding goal after goal, in process (no ROS).

Run from the repository root (inside the dev environment: ``scripts/dev run python -P``)::

    python bench/bench_hold.py                          # 20 goals, identical plant
    python bench/bench_hold.py --plant heavier          # bodies 10 % heavier, friction x2
    python bench/bench_hold.py --gains readme           # the README's former per-joint gains
    python bench/bench_hold.py --nominal                # the feedforward between samples
    python bench/bench_hold.py --reserve-cost 0,0.05,0.1,0.2

The scenario: the Panda of example-robot-data to ``panda_hand`` (fingers locked at 0), the
URDF's limits with ``limit_margin`` 0.05, trajectories sampled every ``--sample`` (2 ms), the
tracker at 1 kHz (plant 2 kHz) from the README's start configuration. Goals one after
another, each planned from the arm's state (``joint_state(q, qd)``): the issue's
(0.5, -0.2, 0.4), the start's own point, then points of seeded random configurations inside
the limits (a third with joint 2 near 0: joints 1 and 3 aligned), in front of the base and
above 0.15 m. After each motion the tracker holds for ``--hold`` seconds. Per goal: ``T``,
whether certified, the end-effector error at the motion's end, the distance to the goal at
the end of the hold, the largest joint motion over its last second, the share of control
instants with a saturated joint during the motion, the largest feedback share, the hold's
saturation. ``--nominal``: feedforward alone on the identical plant, the nominal's torque
between samples as the chord of the samples against the model's inverse dynamics of the
interpolated state, at 10 and 2 ms. ``--reserve-cost``: ``T`` for torque reserves on five
Panda goals and three cases of the paper's arm. Prints to stdout; nothing is written.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.append(str(REPO))  # bench.common; the installed tocontrol_ros comes first

import numpy as np  # noqa: E402

from bench.common import panda_urdf  # noqa: E402
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET  # noqa: E402
from tocontrol_ros.core.planning.solver import plan  # noqa: E402
from tocontrol_ros.core.robot.limits import JointLimits  # noqa: E402
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot  # noqa: E402
from tocontrol_ros.core.sim.tracking import (  # noqa: E402
    NominalTrajectory,
    PlantConfig,
    Tracker,
    TrackingGains,
)
from tocontrol_ros.core.types.options import SolverOptions  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

#: The README's start configuration (rad).
Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
#: The README's per-joint gains before issue 49 (30 rad/s on M's diagonal at Q0, zeta 0.7).
README_GAINS = TrackingGains(kp=(10.0, 20.0, 13.0, 10.0, 2.4, 4.0, 0.5),
                             kd=(0.47, 0.91, 0.6, 0.49, 0.11, 0.19, 0.023))
#: The issue's "payload +10 %, friction x2", read two ways: every body 10 % heavier, or 0.3 kg
#: at the hand (10 % of the Panda's rated 3 kg payload).
PLANTS = {"identical": PlantConfig(),
          "heavier": PlantConfig(mass_scale=1.1, inertia_scale=1.1, friction_scale=2.0),
          "payload": PlantConfig(payload_mass=0.3, friction_scale=2.0)}
#: Five goals of the reserve's cost (m, panda_link0).
COST_GOALS = ((0.5, -0.2, 0.4), (0.4, 0.2, 0.5), (0.3, 0.3, 0.6), (0.6, 0.0, 0.3),
              (0.2, -0.4, 0.7))


def panda():
    """The README's Panda, its limits with margin 0.05, and the solver options."""
    path = panda_urdf()
    if path is None:
        sys.exit("bench_hold: example-robot-data's Panda is not installed")
    model = load_robot(str(path), tip_link="panda_hand")
    return model, JointLimits.from_model(model).with_margin(0.05), SolverOptions(
        time_limit=120.0)


def goals(model, limits, count: int, seed: int = 49) -> list:
    """The issue's goal, the start's point, then seeded reachable points (m), shape (3,)."""
    rng = np.random.default_rng(seed)
    out = [np.array([0.5, -0.2, 0.4]), model.point(Q0)]
    lo, hi = limits.plan_lower, limits.plan_upper
    while len(out) < count:
        q = lo + (hi - lo) * rng.uniform(0.1, 0.9, model.n)
        if rng.uniform() < 0.3:
            q[1] = rng.uniform(-0.05, 0.05)
        p = model.point(q)
        if p[2] > 0.15 and 0.3 < np.hypot(p[0], p[1]) < 0.75 and p[0] > 0.1:
            out.append(p)
    return out[:count]


def nominal_of(result, dt: float) -> NominalTrajectory:
    """The tracker's nominal of a plan sampled every ``dt`` (s), as from the message."""
    s = result.trajectory.sample(dt)
    return NominalTrajectory(s.t, s.q, s.qd, s.qdd, s.tau)


def scenario(args) -> None:
    """Goals one after another, each held for ``args.hold`` s."""
    model, limits, options = panda()
    gains = (README_GAINS if args.gains == "readme"
             else TrackingGains(bandwidth=args.bandwidth))
    tracker = Tracker(model, PLANTS[args.plant], gains, q0=Q0)
    last_second = int(round(1.0 / tracker.h))
    rows = []
    label = "readme" if args.gains == "readme" else f"bandwidth {args.bandwidth:g} rad/s"
    print(f"plant {args.plant}, gains {label}, reserve {args.reserve:g}, sample "
          f"{1e3 * args.sample:g} ms, hold {args.hold:g} s")
    for i, goal in enumerate(goals(model, limits, args.goals)):
        try:
            result = plan(Problem(model, joint_state(tracker.q, tracker.qd), point(goal),
                                  reserve=args.reserve, limits=limits), options)
        except ValueError as exc:  # a start state the planner refuses (ProblemError)
            print(f"{i:2d} {np.round(goal, 3)} refused: {exc}", flush=True)
            tracker.advance(tracker.t + args.hold)
            continue
        certified = result.certificate is not None and result.certificate.passed
        if not result.success:
            print(f"{i:2d} {np.round(goal, 3)} not planned: {result.message}", flush=True)
            tracker.advance(tracker.t + args.hold)
            continue
        nominal = nominal_of(result, args.sample)
        tracker.start(nominal)
        summary = tracker.advance(tracker.t + nominal.duration + tracker.h).summaries[0]
        hold = tracker.advance(tracker.t + args.hold).log
        dist = float(np.linalg.norm(model.point(tracker.q) - goal))
        tail = np.vstack([hold.q[-last_second:], tracker.q[None, :]])
        drift = float(np.max(np.abs(tail - tracker.q)))
        hold_sat = float(hold.saturated.any(axis=1).mean())
        rows.append((result.T, certified, summary.final_point_error, dist, drift,
                     summary.saturated_fraction, summary.max_feedback, hold_sat))
        print(f"{i:2d} {np.round(goal, 3)} T {result.T:.4f} s certified {certified} | end "
              f"{1e3 * summary.final_point_error:.3f} mm, +{args.hold:g} s "
              f"{1e3 * dist:.4f} mm, last-second motion {drift:.1e} rad, saturated "
              f"{100 * summary.saturated_fraction:.1f} %, feedback "
              f"{summary.max_feedback:.3f}, hold saturated {100 * hold_sat:.0f} %",
              flush=True)
    if not rows:
        return
    a = np.array([[r[0], r[2], r[3], r[4], r[5], r[6], r[7]] for r in rows])
    print(f"{len(rows)} of {args.goals} executed, {sum(r[1] for r in rows)} certified; "
          f"sum T {a[:, 0].sum():.4f} s; end error max {1e3 * a[:, 1].max():.3f} mm; "
          f"+{args.hold:g} s max {1e3 * a[:, 2].max():.4f} mm; last-second motion max "
          f"{a[:, 3].max():.1e} rad; saturated mean {100 * a[:, 4].mean():.2f} % max "
          f"{100 * a[:, 4].max():.1f} %; feedback max {a[:, 5].max():.3f}; hold saturated "
          f"max {100 * a[:, 6].max():.0f} %")


def nominal_accuracy(args) -> None:
    """Feedforward alone: the chord of the torque samples against the model's torque."""
    model, limits, options = panda()
    inverse_dynamics = model.function("id")
    for goal in COST_GOALS[:2] + COST_GOALS[4:]:
        result = plan(Problem(model, joint_state(Q0), point(goal), limits=limits), options)
        exact = nominal_of(result, 5e-5)
        t = np.linspace(0.0, result.T, 4001)
        reference = exact.evaluate(t).effort
        print(f"goal {goal}: T {result.T:.4f} s")
        for dt in (0.01, 0.002):
            for label in ("chord", "model"):
                nominal = nominal_of(result, dt)
                if label == "model":
                    nominal = nominal.with_inverse_dynamics(inverse_dynamics)
                du = np.max(np.abs(nominal.evaluate(t).effort - reference) / model.tau_max)
                # A nominal that has its own inverse dynamics keeps it in the tracker.
                chord = (nominal if label == "model" else
                         nominal.with_inverse_dynamics(_no_model))
                tracker = Tracker(model, PlantConfig(), TrackingGains(), q0=nominal.q[0])
                tracker.start(chord)
                summary = tracker.advance(nominal.duration + tracker.h).summaries[0]
                print(f"  {1e3 * dt:g} ms, {label}: largest torque error {du:.3f} tau_max, "
                      f"feedforward alone ends {1e3 * summary.final_point_error:.3f} mm off")


def _no_model(q, qd, qdd):
    """An ``inverse_dynamics`` of zero torque: the residual, the effort, is then the chord."""
    return np.zeros_like(np.asarray(q, dtype=float))


def reserve_cost(args) -> None:
    """``T`` against the torque reserve: five Panda goals and three cases of the paper."""
    reserves = [float(r) for r in args.reserve_cost.split(",")]
    rows = []
    model, limits, options = panda()
    for goal in COST_GOALS:
        rows.append((f"Panda {goal}", [
            plan(Problem(model, joint_state(Q0), point(goal), reserve=r, limits=limits),
                 options).T for r in reserves]))
        print(rows[-1], flush=True)
    arm = load_robot(default_urdf_path())
    for a, b, k in ((PAPER_START, PAPER_TARGET, 1), (PAPER_START, PAPER_TARGET, 4),
                    ((1.5, 0.5), (0.5, 1.8), 4)):
        rows.append((f"paper {a} -> {b}, k = {k}", [
            plan(Problem(arm, point(a), point(b), k=k, reserve=r)).T for r in reserves]))
        print(rows[-1], flush=True)
    print("| case | " + " | ".join(f"T at {r:g} (s)" for r in reserves) + " |")
    print("|---" * (len(reserves) + 1) + "|")
    for name, ts in rows:
        print(f"| {name} | " + " | ".join(
            f"{t:.4f}" + ("" if j == 0 else f" ({100 * (t / ts[0] - 1):+.1f} %)")
            for j, t in enumerate(ts)) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plant", choices=sorted(PLANTS), default="identical")
    parser.add_argument("--gains", choices=("derived", "readme"), default="derived")
    parser.add_argument("--bandwidth", type=float, default=50.0, help="rad/s")
    parser.add_argument("--reserve", type=float, default=0.1)
    parser.add_argument("--hold", type=float, default=5.0, help="s after each motion")
    parser.add_argument("--goals", type=int, default=20)
    parser.add_argument("--sample", type=float, default=0.002, help="s")
    parser.add_argument("--nominal", action="store_true")
    parser.add_argument("--reserve-cost", default="")
    args = parser.parse_args()
    if args.nominal:
        nominal_accuracy(args)
    elif args.reserve_cost:
        reserve_cost(args)
    else:
        scenario(args)


if __name__ == "__main__":
    main()
