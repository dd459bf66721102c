"""The orchestration: which method solves a request, warm or cold, and what is returned.

:func:`~.solver.plan` and :class:`~.solver.Planner` (a model's compiled functions, kept
across solves: :mod:`.prepared`), the worker processes of a solve (:mod:`.pool`), and the
replans of a running motion (:mod:`.replan`). It sees the methods only through
:mod:`tocontrol_ros.core.methods.contract`.
"""
