"""Demo: load a manipulator, check its dynamics, plan a time-optimal motion and verify it.

With no arguments it runs the paper's example: the planar 3R arm from (1.0, 1.0) to
(2.2, 1.5) with k = 4. With ``--urdf`` it loads another arm and, if ``--start`` and
``--target`` are given (task-space points, m), plans between them.

Run as ``tocontrol-demo`` (pip), ``ros2 run tocontrol_ros demo`` (either route) or
``python -m tocontrol_ros.demo``.
"""

import argparse
import os
import sys
from pathlib import Path

DEFAULT_URDF = "galicki_3r.urdf"


def default_urdf_path():
    """Path of the bundled example arm (see :func:`tocontrol_ros.core.model.default_urdf_path`)."""
    from tocontrol_ros.core.model import default_urdf_path as core_default

    return core_default()


def build_parser():
    """Return the demo's command-line parser."""
    parser = argparse.ArgumentParser(
        prog="demo",
        description="Load a manipulator from a URDF; print its summary and a check of "
        "its dynamics.",
    )
    parser.add_argument(
        "--urdf",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"URDF file of the arm (default: the bundled config/{DEFAULT_URDF})",
    )
    parser.add_argument("--start", type=float, nargs="+", default=None, metavar="X",
                        help="start end-effector point (default: the paper's 1.0 1.0)")
    parser.add_argument("--target", type=float, nargs="+", default=None, metavar="X",
                        help="target end-effector point (default: the paper's 2.2 1.5)")
    parser.add_argument("--k", type=float, default=4.0,
                        help="convexification exponent k >= 1 (default 4)")
    parser.add_argument("--starts", type=int, default=16,
                        help="multistart seed pairs (default 16)")
    return parser


def main(argv=None):
    """Run the demo.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments without the program name; ``sys.argv[1:]`` if None.

    Returns
    -------
    int
        Process exit status (0 on success).
    """
    args = build_parser().parse_args(argv)
    # Imported after argument parsing so that --help stays fast and works without
    # the numerical stack loaded.
    from tocontrol_ros.core.model import load_robot

    path = args.urdf if args.urdf is not None else default_urdf_path()
    if not os.path.isfile(path):
        raise SystemExit(f"demo: --urdf: no such file: {path}")

    model = load_robot(str(path))
    print(model.summary())
    print(model.check_dynamics())
    if args.urdf is not None and (args.start is None or args.target is None):
        return 0
    from tocontrol_ros.core.errors import ProblemError
    from tocontrol_ros.core.problem import Problem, point
    from tocontrol_ros.core.solver import SolverOptions, plan

    start = args.start if args.start is not None else [1.0, 1.0]
    target = args.target if args.target is not None else [2.2, 1.5]
    try:
        problem = Problem(model, point(start), point(target), k=args.k)
    except ProblemError as exc:
        raise SystemExit(f"demo: {exc}") from exc
    print(f"\nplanning {start} -> {target} with k = {args.k:g}, {args.starts} starts "
          f"(the first run compiles the solver, about 15 s; later runs use the cache)")
    result = plan(problem, SolverOptions(starts=args.starts, candidates=3))
    print(f"  {result.status.name}: {result.message}")
    if not result.success:
        return 1
    ver = result.verification
    print(f"  T = {result.T:.6f} s   max |u_i| = {result.max_abs_u:.4f}   "
          f"BVP residual = {result.residual:.1e}   Newton iterations = {result.iterations}")
    print(f"  solve time {result.timings['total']:.2f} s (guess {result.timings['guess']:.2f}, "
          f"shooting {result.timings['shooting']:.2f}, refinement "
          f"{result.timings['refine']:.2f}, verification {result.timings['verify']:.2f})")
    print(f"  re-integration of the nominal torques: end point off by "
          f"{ver['point_error']:.1e} m, end speed {ver['velocity_error']:.1e} rad/s; "
          f"max |H| = {ver['max_abs_H']:.1e}")
    for rec in result.starts:
        if rec.status in ("returned", "continued"):
            print(f"  start {rec.index:2d}: T = {rec.T:.6f} s ({rec.status})")
    for warning in result.warnings:
        print(f"  warning: {warning}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
