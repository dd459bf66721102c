"""The tuning constants of the direct transcriptions, read together.

The numeric knobs of the ``k = 1`` collocation guess and of the bounded direct solve (where
joint limits bind: the B-spline transcription, its IPOPT starts, the set pad and the mesh
refinement), each with why it has its value. The modules that use them import them by name
(``from tocontrol_ros.core.direct.tuning import PAD, SPANS``), so a test that patches a knob
patches it on the module that reads it (``monkeypatch.setattr(limited, "LEVEL_WINDOWS",
...)``). This module imports nothing.
"""

__all__ = ["GUESS_LOAD", "TOUCH", "SPANS", "PAD", "SET_PAD", "RESIDUAL_TOL", "SAME_T",
           "GUESS_WINDOW", "REFINEMENTS", "REFINE_JUMP", "REFINE_WINDOW", "LEVEL_WINDOWS",
           "T_SETTLED", "SPAN_BUCKET", "SCENE_MAX_SPANS", "SET_MARGIN", "INSIDE_TIE",
           "PAD_ROUNDS", "STRETCHES",
           "NEAR_MAX_ITER", "WARM_MU", "TIGHT_MU", "WARM_PUSH", "RESUME_MU",
           "RESTART_MAX_PERTURBATION",
           "FINE_GUESS_INTERVALS", "FINE_GUESS_TOL", "GRIDPOINTS", "ADAPT_PASSES",
           "ADAPT_FLOOR", "MARGIN_ROUNDS", "CHECK_POINTS", "VELOCITY_PAD", "ACCELERATION_PAD",
           "TANGENT_FLOOR",
           "SPEED_CAP", "X_HUGE", "SCALING_SET_MARGIN", "CANDIDATES", "FOLLOW_STEPS",
           "FOLLOW_ITERATIONS", "TIME_SCALES", "OPEN_LOOP_RTOL", "OPEN_LOOP_ATOL",
           "QUICK_GRIDPOINTS", "QUICK_IK_ITERATIONS", "QUICK_TIME_SCALES",
           "QUICK_SPEED_SLACK"]


# ---------------------------------------------- the k = 1 guess (collocation.py)
#: :func:`~tocontrol_ros.core.direct.collocation.initial_path` times the path so that the
#: largest Euclidean norm of its normalised torques is this: inside the k = 1 control set
#: (the unit ball) with some room.
GUESS_LOAD = 0.8


# ------------------------------------------ whether the limits bind (limited.py)
#: A direct guess within this fraction of a position range (or of a velocity limit) of the
#: planning limits is taken to touch them.
TOUCH = 0.02


# ------------------------------------- the B-spline solves (limited.py, flat.py)
#: Uniform spans of the first B-spline solve.
SPANS = 32

#: The bounded solve keeps inside the planning limits by this fraction of each range (of
#: each velocity limit), so that its certificate's re-integration, a different integrator,
#: stays inside them.
PAD = 3e-4

#: The control set is sampled: the NLP keeps ``sum u^(2k)`` this far below 1 at the sample
#: times, so that the torques between them stay inside the set.
SET_PAD = 1e-3

#: Tolerance on the bounded NLP's constraint violation (its residual).
RESIDUAL_TOL = 1e-6

#: Two uniform-mesh solutions with ``T`` this close (relative) and the same control points
#: are one.
SAME_T = 1e-6


#: Candidates whose guess's ``T`` (at the requested ``k``, since issue 35; the figures below
#: are of guesses at ``k = 1``) is more than this fraction above the best
#: guess's are solved as B-spline paths only when all those within it fail (not in the
#: exhaustive mode, nor in the fallback of a failed shooting). The k = 1 guess ranks the
#: basins loosely: on the 50 Panda cases of BENCHMARKS.md ("against an independent
#: reference") the best motion's guess was 9.2 % above the best guess in one case and the
#: window of 0.05 (12 % less CPU time than none on the 20 first cases) missed it by 15 %;
#: with 0.15 and 16 IK seeds (RANDOM_IK_FACTOR) 47/50 within 1e-3 of the reference, against
#: 43/50, at 1.19 times the plan time in all (the median 2.30 -> 2.84 s). With the guesses
#: at the requested k (issue 35) and 24 starts, 0.05 gave 43/50 against 48/50 (cases 18,
#: 20, 34, 44 and 50, 0.2-46 % slower), at 7 % less plan time (median 3.46 s against 3.71 s).
GUESS_WINDOW = 0.15


# ------------------------------- the refinement (limited.py, flat_trajectory.py)
#: The spans are halved at the junctions at most this many times.
REFINEMENTS = 4

#: A span is halved when some joint's acceleration changes across it by more than this
#: fraction of that joint's largest acceleration (a junction of arcs: the cubic path ramps
#: its acceleration over one span, which costs time in proportion to the span).
REFINE_JUMP = 0.1

#: Candidates whose first (uniform-mesh) ``T`` is within this fraction of the best one are
#: refined: the refinement lowers ``T`` by up to about 1.6 % (the Panda).
REFINE_WINDOW = 0.02

#: After refinement level ``l`` (0-based), candidates more than ``LEVEL_WINDOWS[l]`` above
#: the best ``T`` so far stop there: the refinement lowers ``T`` by up to 1.6 % in all, of
#: which up to 0.2 % after the first level and 4e-5 after the second (the Panda's
#: candidates; a candidate 0.2 % behind after the first level was the best in the end).
LEVEL_WINDOWS = (5e-3, 1e-3, 5e-4)

#: Refinement stops when ``T`` changes by less than this (relative). The changes shrink
#: by 3-5x per level once the junctions are resolved (the Panda: 1.5e-4, 3e-5, 1.2e-5), so
#: the level after a change this small would move ``T`` by about 5e-5, a twentieth of the
#: benchmark's 1e-3 against the reference, at the cost of the finest and slowest solve
#: (120-170 spans: 0.6-6 s, up to half of a Panda plan). On 8 Panda problems (one start)
#: 2e-4 instead of 1e-4 left out 3 such levels and took 20 % less time in all, with T
#: higher by 6e-5 at most (3e-4: 9e-5).
T_SETTLED = 2e-4

#: Refined meshes have a multiple of this many spans (the longest halved to get there), so
#: that their transcriptions, built once per number of spans, serve other motions.
SPAN_BUCKET = 8

#: With clearance rows (a collision model), a refinement level whose mesh would have more
#: spans than this is not solved: the coarser mesh stands. An iteration with the rows costs
#: about 1 s at 216 spans on a loaded 2-core machine; case 1 pillar of bench/collision.py
#: (docs/collision.md, session 35) refined 32, 64, 120, 216 spans (T 0.6175, 0.5333,
#: 0.5208, 0.5122 s), then its level at 368 spans stopped at its 150-iteration limit after
#: 318 s, unconverged (the 216-span motion returned, certified): 670 s in all, past the
#: bench's 600 s time limit.
SCENE_MAX_SPANS = 256


# ---------------------------------- the torques between the samples (limited.py)
#: The torques between the sample times keep this far inside the control set; the set's
#: pad (:data:`SET_PAD` at first) is widened at most :data:`PAD_ROUNDS` times to get there.
SET_MARGIN = 1e-7
PAD_ROUNDS = 3

#: Refined candidates are held inside the set fastest first; the next one is not when its
#: ``T`` is within this fraction of the best so held (it could beat it by no more). Each
#: holding may take up to three IPOPT re-solves on the finest mesh: on a Panda plan from a
#: moving state, a second candidate 1e-5 behind the first cost 3.6 s of re-solves (150
#: iterations of one at 15 ms) to end 2e-5 behind it.
INSIDE_TIE = 2e-5

#: Relative slow-downs of a path tried before widening the pad
#: (:func:`~tocontrol_ros.core.direct.checked.stretched`).
STRETCHES = (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4)


# ---------------------------- IPOPT from a nearby solution (flat.py, limited.py)
#: IPOPT iterations a solve from a nearby solution may take (a refinement level, a pad
#: re-solve, a warm re-solve): they take 15-40, one that needs far more is crawling (a
#: regularised Hessian, seen at 0.7 s per iteration on a UR5's 119 spans), and the coarser
#: solution stands. A count, not a time: the same request takes the same path on an idle and
#: on a loaded machine.
NEAR_MAX_ITER = 150

#: IPOPT's first barrier parameter on a mesh whose solves start at a nearby solution
#: (``FlatTranscription(warm=True)``), decreased monotonically, and how far (absolute and
#: relative) the start is moved inside its bounds. With IPOPT's defaults (adaptive
#: barrier from 0.1, 1 % inside the bounds) the first steps of a refined Panda solve left
#: the solution (T 0.2756 -> 0.54 s) and then crawled (1.5 s per iteration at 132 spans);
#: measured on 8 Panda problems with its limits (one start): 70 s in all and 33 s at most
#: with the defaults, 14.6 s and 2.8 s from mu 1e-6 (1e-4: 48 s; 1e-5: 17 s); from 1e-7
#: the refined solves took 716 IPOPT iterations in all instead of 867 (1e-8: 781), the
#: same T on every problem.
WARM_MU = 1e-7
WARM_PUSH = 1e-6
#: A warm re-solve from a converged solution and its multipliers on the same mesh
#: (``FlatTranscription(warm="dual_tight")``, issue 47): IPOPT's barrier starts at this and
#: its warm start's pushes into the bounds (default 1e-3) are this too.
TIGHT_MU = 1e-9
#: A warm re-solve from a stored neighbour a few centimetres away (a memory's hit:
#: ``FlatTranscription(warm="dual_far")``, ``SolverOptions.warm_far``, issue 50): IPOPT's
#: barrier starts at this and its warm start's pushes into the bounds are this too. Between
#: the stored solution and the new optimum a median 55 of the 675 rows of the Panda's
#: 64-span NLP change activity; from :data:`WARM_MU` (pushes 1e-3) IPOPT took 18-150
#: iterations on the cell's 14 hits (median 89, 3 failed at 150), from 1e-5 (pushes 1e-5)
#: 30-99 (median 41, none failed); 1e-6: 13/14, median 40; 3e-6: 14/14, median 39 but more
#: in all; 1e-4: median 70; 1e-5 with the default pushes: 13/14, median 55; IPOPT's
#: adaptive barrier from 1e-3: 13/14, median 63 (docs/memory.md).
FAR_MU = 1e-5
#: A memory's hit (``warm_far``) tries the single parametric step before IPOPT only where
#: its move is at most this many sub-moves (``path_following.move_size``: 0.6 cm of a point
#: end, so that the measured 0.5 cm moves are in). On the Panda cell's 64-span serving
#: states (bench/memory_density.py, 8 stored motions, 24 moves each): the step arrived on
#: 15/24 moves of 0.5 cm (median 104 ms a hit against 170 ms from IPOPT's distant start),
#: on 4/24 of 1 cm and 2/24 of 2 cm, where the failed steps cost more than they saved (276
#: and 260 ms against 222 and 203).
FAR_STEP_MOVE = 0.3

#: IPOPT's first barrier parameter when a solution is solved again with a wider set pad
#: (``FlatTranscription(warm="resume")``; the start moved at most ``WARM_PUSH`` inside its
#: bounds). From IPOPT's default start (1 % inside the bounds: on a 96-span Panda mesh the
#: set's value at the start was 1e10) such re-solves crawled (0.5 s per iteration, MUMPS
#: reallocating, 20 s without converging) on a Panda plan from a moving state; from this
#: barrier they took 0.7 and 1.8 s there and 0.7 s on another Panda case (from 1e-3:
#: 2.6-3.3 s; the adaptive barrier with the small push failed on one of the three; from
#: :data:`WARM_MU` all three re-solves of a Panda case failed).
RESUME_MU = 1e-5

#: IPOPT's largest Hessian regularisation in a solve from its default start
#: (``FlatTranscription(warm=False)``, ``"restart"``) and in a resumed one; past it IPOPT
#: skips to its restoration phase. The uniform mesh's first solves from the guesses are
#: capped too since issue 35: with the guesses at k, one of the Panda's 24 candidates of a
#: point-to-point case (bench/deployed_panda.py's case 10) crawled to its 300-iteration
#: limit at 64 ms per iteration (19.2 s; 3 ms is usual), capped 1.3 s, the plan 24.4 s ->
#: 6.0 s, the same T; on the 50 reference cases T changed on 2 by 1e-4 (one better).
#: Such re-solves (a wider set pad after the resumed one failed) can crawl with the
#: regularisation at 1e8-1e12, each iteration factorising the KKT matrix over and over
#: (a Panda case from a moving state, 96 spans: 150 iterations in 100 s, 0.7 s each); capped
#: here, the same 150 iterations took 2.2 s (1e6: 5.8 s), and bench/limits.py's case 29,
#: whose resumed re-solves all fail, still converges from the default start. A bound on
#: work per iteration where a wall-time cap was before. The resumed re-solves
#: (``warm="resume"``) are capped alike: on the profile's Panda case 12 (a moving start,
#: 112 spans) the resumed one crawled at 270 ms per iteration to its 150-iteration limit
#: (40.5 s) before the restart converged in 29 (0.3 s); capped, it gives up by its
#: restoration phase in 0.97 s and the plan takes 6.2 s instead of 45.8 s, the same T (the
#: 20 Panda cases of BENCHMARKS.md all end with the same T to 6 digits).
RESTART_MAX_PERTURBATION = 1e4


# -------------------------- the finer guess after a failed shooting (limited.py)
#: The finer direct guess: a guess solved again on this many intervals, to this tolerance
#: (after a failed shooting, for the shooting's retry and for the fallback).
FINE_GUESS_INTERVALS = 24
FINE_GUESS_TOL = 1e-8


# ------------------------------ the first motion (first_motion.py, time_scaling.py)
#: TOPP-RA segments along the path. On the Panda and the limited 3R (bench/limits.py cases)
#: T fell by 1-3 % from 50 to 100 segments and by 0.1-1.2 % from 100 to 200; each pass, and
#: the certificate's open loop, costs in proportion.
GRIDPOINTS = 100

#: Passes that adapt each gridpoint's box to the torques of the pass before (a second one
#: gained under 0.1 % of T on the Panda and the limited 3R of bench/limits.py).
ADAPT_PASSES = 1

#: Share of the corner direction given to every joint when a box is adapted, so that a
#: joint the last pass hardly loaded keeps some room.
ADAPT_FLOOR = 0.1

#: The boxes are shrunk by this fraction at first: the torques between the gridpoints,
#: which TOPP-RA does not see, stay inside the set.
SCALING_SET_MARGIN = 1e-3

#: Times the path is timed again with wider margins when the torques between the
#: gridpoints still leave the set.
MARGIN_ROUNDS = 3

#: Times per segment (both ends included) at which the torques are checked.
CHECK_POINTS = 5

#: The velocity limits are kept by this fraction (the open-loop re-integration of the
#: certificate, a different integrator, must stay within them).
VELOCITY_PAD = 1e-4

#: The acceleration limits are kept by this fraction at the gridpoints: between two of them
#: TOPP-RA's path acceleration is constant while ``q'(s)`` and ``q''(s)`` vary, so the joint
#: accelerations there may pass the gridpoints' by a little (the certificate checks them).
ACCELERATION_PAD = 1e-2

#: Friction's tangent lines are taken at no less than this fraction of the largest squared
#: path speed of the pass before (a tangent near zero would pin the path speed there).
TANGENT_FLOOR = 1e-2

#: The friction chords hold up to this multiple of the last pass's largest squared path
#: speed, which bounds the path speed there.
SPEED_CAP = 4.0

#: Stands for "no bound" on a squared path speed (1/s^2): TOPP-RA's solvers take numbers.
X_HUGE = 1e8

#: Candidate end configurations timed at rest before one is chosen (the planner's seed pairs
#: and the target followed from the start, ranked by :func:`_estimates`). On 40 cases drawn
#: as bench/limits.py's (Panda, UR5, xArm7, limited 3R; 10 each, from rest) the chosen line
#: was the fastest of all 17 candidates in 38 and within 6 % in the others; the first seed
#: pair's alone was up to 4 times slower, and the followed target was the fastest in 30.
CANDIDATES = 3

#: Points of the straight task-space line along which the target's configuration is
#: followed from the start (:func:`_followed`), and Newton steps at each.
FOLLOW_STEPS, FOLLOW_ITERATIONS = 20, 3

#: A moving start's parabola is tried with these multiples of the straight path's
#: rest-to-rest time as ``tau``, in turn, until one can be timed. A longer ``tau`` starts
#: more slowly along the path (``qdd(0) = 2 (q_b - q_0 - v) / tau^2``, less force needed at
#: the start); on the moving cases of bench/limits.py (Panda, limited 3R) the first was
#: always the fastest, by 5-25 %.
TIME_SCALES = (1.0, 2.0, 4.0)

#: The certificate re-integrates the nominal torques open loop at these tolerances, tighter
#: than the optimum's (1e-10): a first motion is slower, and an arm that is unstable open
#: loop amplifies the integration error with time (a 1.8 s Panda motion: about e^(15 t),
#: 3 mm at the target from 1e-10, 0.03 mm from 1e-12, at the same cost).
OPEN_LOOP_RTOL, OPEN_LOOP_ATOL = 1e-12, 1e-13


# ------------------------------ the quick replan (first_motion.quick_motion)
#: TOPP-RA segments of a replan's quick motion (each pass and the certificate's open loop
#: cost in proportion; a replan's motion is short). On a Panda replan from a moving state:
#: 40 segments 20.9 ms, T 0.1049 s; 30: 17.6 ms, 0.1055 s; 20: 14.8 ms, 0.1065 s.
QUICK_GRIDPOINTS = 30

#: Newton steps from the running motion's end to the replan's target before the
#: task-space line is followed instead (a target a few centimetres away converges in 3-4).
QUICK_IK_ITERATIONS = 8

#: A quick motion's parabola from a moving start is tried with these multiples of the
#: straight path's rest-to-rest time as ``tau``; the one of least ``T`` is kept (the first
#: motion's ``TIME_SCALES`` take the first that can be timed).
QUICK_TIME_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0)

#: A quick motion from a moving start keeps each joint's speed below this much more than
#: the larger of its speed at the start and its peak on the straight path's rest-to-rest
#: timing (first_motion.quick_motion).
QUICK_SPEED_SLACK = 0.01

#: ``FlatTrajectory.joint_speed_bounds`` (the clearance certificate's joint speeds between
#: its times) is raised by this fraction plus this much (rad/s): the spline's coefficients
#: and samples carry rounding errors of about 1e-15 of their size, and a bound must not fall
#: short by them.
SPEED_BOUND_SLACK = 1e-9
