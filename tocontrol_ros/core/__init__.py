"""Numerical core of tocontrol_ros: model, maximum principle, solver, trajectory.

Pure Python and numerics (numpy, scipy, CasADi); never imports rclpy or message types.
"""
