"""The ``memory`` executable: a memory of optimal motions built from a cell file.

And the tools around it (list, inspect, prune, export, figure). See
:mod:`tocontrol_ros.memory.cli`;
the memory itself (the file, the lookup, the warm re-solve) is
:mod:`tocontrol_ros.core.memory`.
"""

from tocontrol_ros.memory.cli import main

__all__ = ["main"]
