"""Demo: load a manipulator from a URDF and report its model and a dynamics check.

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
    return 0


if __name__ == "__main__":
    sys.exit(main())
