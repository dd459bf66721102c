"""The paper's indirect method.

The maximum principle's control law and canonical system, multiple shooting with Newton and
the iterate of one start, the mesh, the continuation in ``k`` and in the smoothing
``delta``, the solution as a trajectory, its own certificate (with the adaptive integrator),
and :mod:`.method`, which puts it on the method contract (``"indirect"``, ``"auto"``). Its
tuning constants are in :mod:`.tuning`.
"""
