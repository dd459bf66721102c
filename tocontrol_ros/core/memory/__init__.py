"""A memory of optimal motions: solved once offline, recalled by a warm re-solve.

The layer above the orchestration (:mod:`tocontrol_ros.core.planning`), below the core's
face: :mod:`~.codec` turns a result's warm state and motion into bytes and back (npz, never
pickle), :mod:`~.keys` names what a memory is valid for (the robot's and the options'
hashes), :mod:`~.store` is the SQLite file (:class:`~.store.MotionStore`), :mod:`~.recall`
finds the nearest stored motions of a request and re-solves them warm through the method
contract (:func:`~.recall.recall`). No ROS here: the planner node's policy
(:mod:`tocontrol_ros.nodes.planning_service`) and the ``memory`` tool
(:mod:`tocontrol_ros.memory`) use it. ``docs/memory.md`` tells the whole story.
"""
