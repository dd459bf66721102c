"""Time-optimal point-to-point motions for robot manipulators, served over ROS 2.

Pontryagin's maximum principle on a strictly convexified torque set
(``sum_i u_i**(2k) <= 1``): ``tocontrol_ros.core`` holds the mathematics (no ROS
import); the nodes convert messages and call it.
"""

__version__ = "0.1.0"
