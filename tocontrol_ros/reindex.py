"""Entry point of ``ros2 run tocontrol_ros reindex`` and ``python -m tocontrol_ros.reindex``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.recording.reindex`.
"""

import sys

from tocontrol_ros.recording.reindex import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
