"""QoS profiles shared by the nodes (one place, so that publishers and subscribers match).

See msg_docs/ for which topic uses which.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["ACTION_SERVICES", "LATCHED", "RELIABLE", "BEST_EFFORT", "profile", "status_profile"]

def profile(depth: int, reliable: bool = True, latched: bool = False) -> QoSProfile:
    """A keep-last profile ``depth`` deep: reliable or best effort; latched or volatile.

    Latched (transient local): late subscribers get the last ``depth`` messages.
    """
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                      else DurabilityPolicy.VOLATILE)


#: Plans and their views: late subscribers (a viewer, a tracker started after the plan)
#: get the last one.
LATCHED = profile(1, latched=True)
#: Streams and commands: reliable publishers match reliable and best-effort subscribers.
RELIABLE = profile(10)
#: Inputs from other people's publishers: best effort matches both kinds.
BEST_EFFORT = profile(10, reliable=False)
#: The ``FollowJointTrajectory`` action's goal, result and cancel services, on the planner's
#: client and the tracker's server. rclpy's default (``qos_profile_services_default``) keeps
#: the last 10 requests or responses: a burst of more (replans queued while an executor was
#: starved on a loaded machine, sent at once) overwrote the oldest before they were taken,
#: and those plans never got an outcome (session 35, docs/nodes.md).
ACTION_SERVICES = profile(1000)


def status_profile(depth: int, latched: bool) -> QoSProfile:
    """Reliable status events, ``depth`` deep, kept for late subscribers when ``latched``."""
    return profile(depth, latched=latched)
