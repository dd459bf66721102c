"""Entry point of ``ros2 run tocontrol_ros recorder`` and ``python -m tocontrol_ros.recorder``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.recording.recorder`.
"""

import sys

import tocontrol_ros.single_blas  # noqa: F401  (first: one BLAS thread, before numpy loads)
from tocontrol_ros.recording.recorder import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
