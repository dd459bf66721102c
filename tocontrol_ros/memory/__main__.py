"""``python -m tocontrol_ros.memory``: the ``memory`` executable."""

import sys

from tocontrol_ros.memory.cli import main

sys.exit(main())
