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

__all__ = ["WARM_GAIN", "INCUMBENT_TRIES", "TAIL_MIN_REMAINING", "TAIL_MERGE", "HIGH_QUANTILE",
           "TARGET_STEPS", "REPLAN_JOINT_RADIUS", "REPLAN_SPANS", "FLAT_CACHE"]


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


# ------------------------------------- replans of a running motion (replan.py)
#: A tail shorter than this fraction of the motion is no warm start (the motion has nearly
#: ended: the arm is about to stop at the old target and a plan from rest is as good).
TAIL_MIN_REMAINING = 0.02

#: A cut this close (normalised time) to the next node drops that node: no interval is
#: left that is much shorter than its neighbours (badly scaled Newton steps).
TAIL_MERGE = 0.25

#: The lead covers this quantile of the recent latencies (times the margin).
HIGH_QUANTILE = 0.8

#: Target continuation of a warm replan whose direct warm solve fails: the fractions of the
#: way from the old target to the new one solved in turn (each warm from the previous).
TARGET_STEPS = ((1.0,), (0.5, 1.0), (0.25, 0.5, 0.75, 1.0))

#: ``SolverOptions.warm_joint_radius`` of the node's replans (rad, rad/s). Along a stream
#: of goals 1.9 cm apart on the paper's arm at k = 4 (bench/replan.py's circle, each replan
#: from rest at the last goal, warm from the last solution), 36 of 49 warm solves applied
#: and converged at 0.2, 25 of 49 at the default 0.05 (the others were solved cold, 2-5
#: times dearer); the warm solves that fail change the number of switches of the control.
REPLAN_JOINT_RADIUS = 0.2

#: ``SolverOptions.replan_spans`` of the node's replans of an arm whose limits bind (bounded
#: B-spline solves). The Panda with its URDF limits, the rest chain of the moving-target
#: circle (goals 1.3 cm apart), each problem replanned warm from the default plan of the one
#: before (its refined mesh; bench/replan.py, BENCHMARKS.md "Replanning"): at 24 spans
#: T 7.6e-4 (median) and at most 9.8e-4 above the default plan's, 111 ms median, 11/12
#: certified; on the refined mesh itself 325 ms median, 25 s at worst, 8/12 (16 spans:
#: 2.0e-3, 73 ms; 32: 4.5e-4, 131 ms). The node's next replan continues on the coarse mesh
#: from its multipliers (a stream's replans: 60-130 ms each). A cold replan is left on its
#: uniform mesh, unrefined.
REPLAN_SPANS = 24

#: Bounded B-spline transcriptions a planner keeps, the least recently used dropped (one
#: per number of spans, start mode and kinds; 4-17 MB each for the Panda at 64-192 spans
#: before their first solve).
FLAT_CACHE = 32
