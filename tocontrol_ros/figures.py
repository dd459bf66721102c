"""Entry point of ``ros2 run tocontrol_ros figures`` and ``python -m tocontrol_ros.figures``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.recording.figures`.
"""

import sys

from tocontrol_ros.recording.figures import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
