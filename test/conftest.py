"""Session-wide environment for the tests, set at import time (before rclpy loads).

ROS traffic stays on this machine and in a domain of its own, so parallel sessions
and CI runs do not see each other's nodes; BLAS stays single-threaded (small dense
solves are much slower with threads on two cores); plots render off screen.
"""

import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# FastDDS port arithmetic allows domain ids 0-101 (and 215-232); stay inside 42-91.
os.environ.setdefault("ROS_DOMAIN_ID", str(42 + os.getpid() % 50))
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("MPLBACKEND", "Agg")

# A skip for a missing dependency or data file fails under scripts/dev (test/skip_policy.py).
from skip_policy import (  # noqa: E402, F401  (hooks: pytest finds them by name here)
    pytest_make_collect_report,
    pytest_runtest_makereport,
    pytest_terminal_summary,
)
