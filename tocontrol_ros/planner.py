"""Entry point of ``ros2 run tocontrol_ros planner`` and ``python -m tocontrol_ros.planner``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.nodes.planner`.
"""

import sys

import tocontrol_ros.single_blas  # noqa: F401  (first: one BLAS thread, before numpy loads)
from tocontrol_ros.nodes.planner import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
