"""The contract every method implements, and what the methods share.

The contract (:mod:`.contract`: prepare, solve, warm start, certify; a registry by name),
the solve's context (deadline, cancel, motions found so far), the seeds on the self-motion
manifolds that every method starts from, and their knobs. The methods themselves are the
peers :mod:`tocontrol_ros.core.direct` and :mod:`tocontrol_ros.core.indirect`.
"""
