"""What a plan is, whichever method makes it (above the robot, below everything else).

The problem (start, target, ``k``, limits), the solver's options, the result and its
status, a sampled motion and the :class:`~.trajectory.Motion` protocol every solution
answers, the certificate's data, the torque set's parameters; and the warm start's radii.
"""
