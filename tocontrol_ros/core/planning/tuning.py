"""The tuning constants of the orchestration, read together.

The numeric knobs of the warm start against the cold multistart and of the answer at the
caller's deadline (:mod:`~tocontrol_ros.core.planning.solver`), each with why it has its
value; what the maximum principle does after a shooting failed is in
:mod:`tocontrol_ros.core.indirect.tuning`; the seeds' and candidates' knobs are in
:mod:`tocontrol_ros.core.methods.tuning`, the warm start's radii in
:mod:`tocontrol_ros.core.types.tuning`. The modules that use them import them by name
(``from tocontrol_ros.core.planning.tuning import WARM_GAIN``), so a test that patches a
knob patches it on the module that reads it. This module imports nothing.
"""

__all__ = ["WARM_GAIN", "INCUMBENT_TRIES"]


# ----------------------------------------- the warm start (solver.py)
#: A warm solution replaces the cold multistart's only when its ``T`` is lower by more than
#: this (relative): within it both are the same basin, and the cold answer, which does not
#: depend on earlier requests, is kept.
WARM_GAIN = 1e-6


# ------------------------------------------ at the caller's deadline (solver.py)
#: At the caller's deadline at most this many motions found so far are checked (least ``T``
#: first) for a ``TIME_LIMIT`` result that carries one: the result comes at most this many
#: certificates after the deadline.
INCUMBENT_TRIES = 2
