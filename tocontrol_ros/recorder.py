"""Entry point of ``ros2 run tocontrol_ros recorder`` and ``python -m tocontrol_ros.recorder``.

An entry point only (``setup.py``'s ``EXECUTABLES``); the code is
:mod:`tocontrol_ros.recording.recorder`.
"""

import os
import sys

# Before numpy and CasADi load their BLAS: one thread unless the user set it (the solves
# factor small banded and sparse matrices, where BLAS threads only cost; docs/speed.md).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from tocontrol_ros.recording.recorder import main  # noqa: E402

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
