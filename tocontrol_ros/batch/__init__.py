"""Batch planning: many tasks from a YAML file, in worker processes or on Ray.

``tocontrol_ros.batch:main`` is the ``batch`` executable (:mod:`tocontrol_ros.batch.cli`).
"""

from tocontrol_ros.batch.cli import main

__all__ = ["main"]
