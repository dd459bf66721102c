"""Demo: load a manipulator from a URDF and report its model and a dynamics check.

Run as ``tocontrol-demo`` (pip), ``ros2 run tocontrol_ros demo`` (either route) or
``python -m tocontrol_ros.demo``.
"""

import argparse
import os
import sys
from pathlib import Path

PACKAGE_NAME = "tocontrol_ros"
DEFAULT_URDF = "galicki_3r.urdf"


def _config_dirs():
    """Return the candidate ``config`` directories, most authoritative first.

    Returns
    -------
    list of pathlib.Path
        The share directory found through the ament index (colcon install, or a pip
        install with ``AMENT_PREFIX_PATH`` naming its prefix), then ``sys.prefix``'s
        share directory (a pip install without the ament environment), then the
        source tree's ``config/`` next to this package.
    """
    dirs = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError:
        pass
    else:
        try:
            dirs.append(Path(get_package_share_directory(PACKAGE_NAME)) / "config")
        except (PackageNotFoundError, OSError):
            # OSError: AMENT_PREFIX_PATH unset (a plain pip venv).
            pass
    dirs.append(Path(sys.prefix) / "share" / PACKAGE_NAME / "config")
    dirs.append(Path(__file__).resolve().parent.parent / "config")
    return dirs


def default_urdf_path():
    """Return the path of the bundled example arm's URDF.

    Returns
    -------
    pathlib.Path
        The first existing ``config/galicki_3r.urdf`` among `_config_dirs`.

    Raises
    ------
    FileNotFoundError
        If no candidate directory holds the file; the message lists where it looked.
    """
    candidates = [d / DEFAULT_URDF for d in _config_dirs()]
    for path in candidates:
        if path.is_file():
            return path
    looked = ", ".join(str(p) for p in candidates)
    raise FileNotFoundError(f"bundled URDF {DEFAULT_URDF!r} not found; looked in: {looked}")


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
    path = args.urdf if args.urdf is not None else default_urdf_path()
    if not os.path.isfile(path):
        raise SystemExit(f"demo: --urdf: no such file: {path}")

    # Imported after argument parsing so that --help stays fast and works without
    # the numerical stack loaded.
    from tocontrol_ros.core.model import load_robot

    model = load_robot(str(path))
    print(model.summary())
    print(model.check_dynamics())
    return 0


if __name__ == "__main__":
    sys.exit(main())
