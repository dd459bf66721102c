"""The robot.

URDF, rigid-body dynamics, kinematics, inverse kinematics, joint limits, and the cache
of compiled CasADi functions that the methods evaluate.
"""
