"""The paper's indirect method.

The maximum principle's control law and canonical system, multiple shooting with Newton,
the mesh, the adaptive integrator of the certificate, and the continuation in ``k`` and
in the smoothing ``delta``; their tuning constants in :mod:`.tuning`.
"""
