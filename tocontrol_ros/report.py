"""Entry point of ``ros2 run tocontrol_ros report`` and ``python -m tocontrol_ros.report``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.recording.report`.
"""

import sys

from tocontrol_ros.recording.report import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
