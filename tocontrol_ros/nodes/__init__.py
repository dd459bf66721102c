"""The ROS 2 nodes.

The planner and the tracker, their parameters, the message conversions, the QoS profiles
and the shared main loop.
"""
