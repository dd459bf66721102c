"""QoS profiles shared by the nodes (one place, so that publishers and subscribers match).

See msg_docs/ for which topic uses which.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["LATCHED", "RELIABLE", "BEST_EFFORT", "status_profile"]

#: Plans and their views: late subscribers (a viewer, a tracker started after the plan)
#: get the last one.
LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Streams and commands: reliable publishers match reliable and best-effort subscribers.
RELIABLE = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
#: Inputs from other people's publishers: best effort matches both kinds.
BEST_EFFORT = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)


def status_profile(depth: int, latched: bool) -> QoSProfile:
    """Reliable status events, ``depth`` deep, kept for late subscribers when ``latched``."""
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                      else DurabilityPolicy.VOLATILE)
