"""Read at start-up by a planner process whose PYTHONPATH holds this folder: puts the
test's solve gate (test/solve_gate.py) on the planner when $TOCONTROL_TEST_SOLVE_GATE is
set."""

import os
import sys

if os.environ.get("TOCONTROL_TEST_SOLVE_GATE"):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from solve_gate import install_from_environment

    install_from_environment()
