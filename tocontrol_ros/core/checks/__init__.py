"""Checks that hold for a motion whatever method made it.

The open-loop certificate (the nominal torques re-integrated by another integrator, the
torque set, the joint limits) and the verdict that turns a certificate into a status. A
method adds its own checks on top (the maximum principle's canonical system:
:mod:`tocontrol_ros.core.indirect.certificate`).
"""
