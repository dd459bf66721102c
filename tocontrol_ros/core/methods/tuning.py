"""The tuning constants of the seeds and of the choice of candidates, read together.

The numeric knobs of the multistart's seeds (:mod:`~tocontrol_ros.core.methods.seeding`) and
of which distinct direct solutions are continued (by the maximum principle's candidates in
:mod:`~tocontrol_ros.core.planning.solver` and by the bounded solve in
:mod:`~tocontrol_ros.core.direct.limited`), each with why it has its value; the methods' own
knobs are in :mod:`tocontrol_ros.core.indirect.tuning` and
:mod:`tocontrol_ros.core.direct.tuning`, the orchestration's in
:mod:`tocontrol_ros.core.planning.tuning`. The modules that use them import them by name, so
a test that patches a knob patches it on the module that reads it
(``monkeypatch.setattr(solver, "CANDIDATE_MARGIN", ...)``). This module imports nothing.
"""

__all__ = ["EXHAUSTIVE_IK_COUNT", "RANDOM_IK_FACTOR", "RANDOM_STARTS_EXTRA", "NEAR_TARGETS",
           "EXHAUSTIVE_STARTS", "SEED_SPACING", "MAX_BRANCH_JOINTS", "RECOMBINED_PARENTS",
           "RECOMBINED_STARTS", "RECOMBINED_NEAR", "EXHAUSTIVE_CANDIDATES", "SAME_BASIN",
           "CANDIDATE_MARGIN", "GRAVITY_FREE"]


# -------------------------------------------------------- the seeds (seeding.py)
#: Self-motion angles per end point in the exhaustive mode (the default's ``ik_count`` is
#: the ranked mode's); denser than any default, so the reference covers the manifold.
EXHAUSTIVE_IK_COUNT = 24

#: A problem with joint limits on an arm whose self-motion family is random seeds (not the
#: planar arms' angles, each with both elbows: :func:`~tocontrol_ros.core.robot.ik.
#: angle_family`) gets ``ik_count`` times this many seeds per end point: as many
#: configurations as a planar arm gets. The limits cut the self-motion manifold into
#: pieces, each a basin of its own. On the 50 Panda cases of BENCHMARKS.md ("against an
#: independent reference"), with GUESS_WINDOW 0.15, 16 seeds found the best basin in 47
#: (24 seeds: 47, missing three others, in 10 % more time); 8 seeds with the window of
#: 0.05 in 43 (in one case 16 seeds were needed, in another the wider window).
RANDOM_IK_FACTOR = 2

#: On such an arm (random seeds, joint limits) ``starts`` seed pairs are solved and half as
#: many more (``starts + starts // 2``: 24 for the default 16, one for one): the limits'
#: basins are more than the planar arms'. On the 50 Panda cases against the independent
#: reference (guesses at the requested k, ``core/planning/guesses.py``): 48/50 within 1e-3 with 24,
#: 47/50 with 16 and with 20, at about 1.13 times the plan time of 16 (docs/seeding.md, 4).
RANDOM_STARTS_EXTRA = 0.5

#: On such an arm (random seeds, joint limits) each start configuration also gets the
#: target configuration that Levenberg-Marquardt reaches from it (:func:`~tocontrol_ros.
#: core.robot.ik.ik_near`: little motion from that start). On the 50 Panda cases against the
#: reference that keeps the limits between its points: the same 46/50 within 1e-3, five
#: plans faster (case 11 by 1.6 %), none slower, median plan time 2.71 s (2.78 s).
NEAR_TARGETS = True

#: Seed pairs solved by the direct method in the exhaustive mode, spread evenly over the
#: branches (the best-ranked of each branch in turn), so that the reference does not lean on
#: the ranking's preference between branches.
EXHAUSTIVE_STARTS = 216

#: Ranked seeds closer than this to a better one at both ends (max-norm, rad) are tried only
#: after every farther one.
SEED_SPACING = 1.5

#: At most this many joints get branch variants at once (2^J or 3^J variants per pair).
MAX_BRANCH_JOINTS = 7

#: The ends of this many distinct direct solutions (fastest first) are recombined into
#: more seeds (:func:`~tocontrol_ros.core.methods.seeding.recombined_pairs`): on the paper's
#: arm the best motion's start often lies in one of the first four and its end in another.
RECOMBINED_PARENTS = 4

#: Recombined seeds solved by the direct method after the ranked ones (at most three
#: quarters as many as those; not in the exhaustive mode): the first by their parents'
#: direct ``T``. On the 100 pairs of issue 35's reference, 7 found the best basin of 97,
#: 8 of 97 and 12 of 98 (pair 63's best is reached from the 12th only), median plan time
#: 0.37, 0.41 and 0.42 s on an idle machine (docs/seeding.md).
RECOMBINED_STARTS = 12

#: A recombined seed whose start (modulo 2 pi) and displacement are within this of a
#: parent's (max-norm, rad or m) is that parent's basin again, and is not solved.
RECOMBINED_NEAR = 0.5


# ------- which candidates to continue (seeding.py, solver.py, direct/limited.py)
#: Distinct direct solutions continued in the exhaustive mode, best direct ``T`` first.
#: Measured on 15 random pairs with every one continued: the best final basin was the first
#: to third of them by direct ``T``.
EXHAUSTIVE_CANDIDATES = 12

#: Two direct solutions whose start and end configurations differ by less than this
#: (max-norm, rad or m) are taken to be in the same basin.
SAME_BASIN = 1e-3

#: A candidate is not continued when its direct ``T`` (k = 1) times
#: :func:`~tocontrol_ros.core.methods.seeding.time_ratio_bound` exceeds the best final ``T`` so far
#: by more than this (relative):
#: the bound is exact only without gravity and friction and the direct ``T`` is a coarse
#: mesh's, so it gets a margin.
CANDIDATE_MARGIN = 0.02

#: Gravity torques below this (relative to tau_max) count as none for the rule of
#: :func:`~tocontrol_ros.core.methods.seeding.time_ratio_bound` (the solver's skip of candidates
#: that cannot beat the best).
GRAVITY_FREE = 1e-9
