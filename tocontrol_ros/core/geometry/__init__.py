"""The arm's and the cell's geometry: collision shapes, their spheres, the scene, distances.

A layer above :mod:`tocontrol_ros.core.robot` (it reads the URDF's ``<collision>`` elements
and places them on the chain's bodies) and below :mod:`tocontrol_ros.core.types` (a
:class:`~tocontrol_ros.core.types.problem.Problem` carries a
:class:`~tocontrol_ros.core.geometry.collision.CollisionModel`). See ``docs/collision.md``.
"""
