"""The tuning constants of the paper's indirect method, read together.

The numeric knobs of the shooting, the continuation in ``k`` and in the smoothing ``delta``,
the mesh, and the certificate's adaptive integrator: tolerances, step counts and factors,
each with why it has its value. The modules that use them import them by name (``from
tocontrol_ros.core.indirect.tuning import WIDE_DELTA``), so a test that patches a knob
patches it on the module that reads it (``monkeypatch.setattr(continuation, "WIDE_DELTA",
...)``). This module imports nothing.
"""

__all__ = ["GRADING", "CHORD_CONTRACTION", "CHORD_MAX", "STALL_STEP", "STALL_COUNT",
           "CONTINUATION_TOL", "PLACEMENT_TOL", "CONTINUATION_STEPS", "STALL_REFINE_TOL",
           "EASY_K_NEWTON", "WIDE_DELTA", "DELTA_FACTOR", "MIN_DELTA_RATIO", "EASY_NEWTON",
           "TANGENT_DIFFERENCE", "SMOOTHING_BISECT_RATIO", "MERGE_MARGIN", "CASCADE_RATIO",
           "PLACING_TOL", "SPLIT_PASSES", "BUDGETS", "MIN_STEP", "SAME_K1", "AT_K_MARGIN"]


# ------------------------- multiple shooting and Newton (shooting.py, newton.py)
#: Grading exponent of the RK4 steps next to a switch
#: (:func:`~tocontrol_ros.core.indirect.shooting.step_fractions`).
GRADING = 4.0

#: Newton keeps its factorised Jacobian while each step shrinks max |G| at least this much
#: (Broyden's updates keep the chord steps good for longer, so a loose bound pays).
CHORD_CONTRACTION = 0.8

#: ...and for at most this many chord steps per Jacobian (with Broyden's updates of the
#: factors, :class:`~tocontrol_ros.core.indirect.newton._Broyden`).
CHORD_MAX = 10

#: Newton gives up after STALL_COUNT damped steps in a row shorter than STALL_STEP.
STALL_STEP = 0.05
STALL_COUNT = 4


# --------------------------------------- the continuation in k (continuation.py)
#: Newton tolerance of the solves along the continuation in k (from the direct guess up to
#: the requested k at the intermediate smoothing): each only starts the next, and the last
#: is solved again to ``options.tol`` (on the switch mesh, or by the mesh refinement).
CONTINUATION_TOL = 1e-6

#: ...and of the last one when switch nodes follow: that solve only locates the switches of
#: the control law, and the switch mesh solves the problem again from its interpolation
#: (whose residual dwarfs this).
PLACEMENT_TOL = 1e-5

#: RK4 steps per interval of the k = 1 solve and the continuation in k when switch nodes
#: follow (at most ``options.steps``): those solutions only lead to the switch mesh, which
#: is solved with ``options.steps`` and refined, so fewer steps do the same job for less work.
CONTINUATION_STEPS = 6

#: Mesh tolerance of the refinement tried when the continuation in k stalls (a coarse mesh
#: may not resolve the steeper law); it only places the nodes.
STALL_REFINE_TOL = 1e-4

#: A continuation step in k that converged in at most this many Newton iterations doubles
#: the next step (after a failure the step stays short until the solution moves easily
#: again, instead of jumping back to the next doubling of k and failing there again).
EASY_K_NEWTON = 6


# -------------- when it stalls: from k = 1 at a wide smoothing (continuation.py)
#: Smoothing of the second path of the continuation in k
#: (:func:`~tocontrol_ros.core.indirect.continuation._continue_smoothed`): wide enough that
#: the law's transition at a switch spans several RK4 steps of the coarse mesh.
WIDE_DELTA = 0.3

#: ...then delta comes down at the requested k, first by this factor per step,
DELTA_FACTOR = 2.0

#: ...a failed step is bisected (geometrically) until it is less than this ratio,
MIN_DELTA_RATIO = 1.1

#: ...and a step's ratio grows by half (in log delta) after a step that took at most this
#: many Newton iterations (the solution barely moved: a longer step will do), and shrinks
#: by a third after one that took more than twice as many (close to the radius where
#: Newton fails; a failure costs far more than a short step).
EASY_NEWTON = 4

#: Relative change of delta of the central differences of
#: :func:`~tocontrol_ros.core.indirect.continuation._predicted`.
TANGENT_DIFFERENCE = 1e-6


# ---------------------------- the smoothing at the requested k (continuation.py)
#: A failed step of the smoothing schedule is retried through the geometric mean of the two
#: deltas while they are more than this factor apart (a decade is split twice at most).
SMOOTHING_BISECT_RATIO = 3.0


# ------------------------------------ the mesh: refinement and merging (mesh.py)
#: Two neighbouring intervals are merged when the estimate for the merged one is below
#: the tolerance divided by this (so that the next check does not split them again).
MERGE_MARGIN = 8.0

#: Cascade of a split graded interval: each uniform part ends this many times farther from
#: the switch than it starts (a uniform interval as long as its distance to the switch has
#: a far smaller error than the graded one next to it).
CASCADE_RATIO = 4.0

#: Newton tolerance on the intermediate levels of
#: :func:`~tocontrol_ros.core.indirect.mesh.refine`, which only place the nodes.
PLACING_TOL = 1e-7

#: Splitting passes on one solution before Newton runs on the new mesh.
SPLIT_PASSES = 8


# ------------------------------------ the certificate's integrator (adaptive.py)
#: Trial steps per segment in one call; a segment that has not reached its end after them
#: is integrated again with the next budget (the whole chain: the open-loop state is
#: carried through).
BUDGETS = (256, 4096)

#: Smallest step the integrator takes, relative to its segment: it gives up below.
MIN_STEP = 1e-12


# ----------------------------------------- after the shooting failed (method.py)
#: The finer direct guess (:func:`~tocontrol_ros.core.direct.limited.finer_guess`) tried when the
#: shooting failed from every coarse one is not shot from when the first candidate's
#: continuation in k stalled from a k = 1 solution whose ``T`` it matches to this
#: (relative): the same k = 1 solution, the same stall (the Panda without limits repeated
#: its continuation's 19 Newton solves to the digit, 2.3 s).
SAME_K1 = 1e-3

#: A candidate whose shooting failed from its guess is solved by the direct method at the
#: requested k (then shot from there) when its direct ``T`` (k = 1) is within this
#: (relative) of the first candidate that succeeded, or none succeeded yet: within a few
#: percent the k = 1 order of two basins often reverses at k = 4 on the paper's arm
#: (0.6 % and 1.5 % apart at k = 1 in two of the reference's pairs).
AT_K_MARGIN = 0.02
