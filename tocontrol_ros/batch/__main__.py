"""``python -m tocontrol_ros.batch``: the ``batch`` executable."""

import sys

from tocontrol_ros.batch.cli import main

sys.exit(main())
