"""Build script for tocontrol_ros (ament_python; installable with colcon and with pip).

Two install routes share this file:

- colcon (``colcon build``): ``setup.cfg`` sends console scripts to
  ``<prefix>/lib/tocontrol_ros``; dependencies come from rosdep (``package.xml``),
  ``install_requires`` is not acted upon.
- pip (``pip install .``, what ``scripts/dev`` does): console scripts go to
  ``<venv>/bin`` as ``tocontrol-<name>``; ``install_requires`` and the extras pull the
  dependencies, ``constraints.txt`` pins them.

Either way, ``ros2 run tocontrol_ros <name>`` runs ``<prefix>/lib/tocontrol_ros/<name>``,
a small shell wrapper from ``scripts/ros2run/`` installed as a data file.
"""

import glob
import os

from setuptools import find_packages, setup

PACKAGE_NAME = "tocontrol_ros"

# Executables for ``ros2 run tocontrol_ros <name>`` (and ``tocontrol-<name>`` on PATH):
# name -> module whose ``main()`` runs it. Adding one: one line here, plus a copy of
# ``scripts/ros2run/demo`` under the new name with its module edited
# (test/packaging/test_executables.py checks that the two agree).
EXECUTABLES = {
    "batch": "tocontrol_ros.batch",
    "memory": "tocontrol_ros.memory",
    "demo": "tocontrol_ros.demo",
    "figures": "tocontrol_ros.figures",
    "planner": "tocontrol_ros.planner",
    "recorder": "tocontrol_ros.recorder",
    "reindex": "tocontrol_ros.reindex",
    "replay": "tocontrol_ros.replay",
    "report": "tocontrol_ros.report",
    "tracker": "tocontrol_ros.tracker",
}

WRAPPER_DIR = os.path.join("scripts", "ros2run")


def _files(pattern):
    """Return the regular files matching `pattern`, sorted (dotfiles excluded by glob)."""
    return sorted(path for path in glob.glob(pattern) if os.path.isfile(path))


def _wrappers():
    """Return the ros2-run wrapper paths, one per entry of `EXECUTABLES`."""
    paths = [os.path.join(WRAPPER_DIR, name) for name in EXECUTABLES]
    missing = [path for path in paths if not os.path.isfile(path)]
    if missing:
        raise SystemExit(
            f"setup.py: EXECUTABLES lists {sorted(EXECUTABLES)}, but these wrappers are "
            f"missing: {missing}; copy {WRAPPER_DIR}/demo and edit its module."
        )
    return paths


setup(
    name=PACKAGE_NAME,
    version="0.1.0",
    description="Time-optimal manipulator motions (Pontryagin, convexified torque set) "
    "for ROS 2 Jazzy.",
    license="BSD-3-Clause",
    python_requires=">=3.11",
    packages=find_packages(include=[PACKAGE_NAME, PACKAGE_NAME + ".*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE_NAME]),
        ("share/" + PACKAGE_NAME, ["package.xml"]),
        ("share/" + PACKAGE_NAME + "/config", _files("config/*")),
        ("share/" + PACKAGE_NAME + "/launch", _files("launch/*")),
        ("lib/" + PACKAGE_NAME, _wrappers()),
    ],
    zip_safe=False,
    # Loose lower bounds only; constraints.txt pins the tested set.
    install_requires=[
        "numpy>=1.26",
        "scipy>=1.11",
        "casadi>=3.6",
        "urdfdom-py>=1.2",
        "PyYAML>=6.0",
        "matplotlib>=3.6",
        "mcap>=1.1",
        # The first motion (tocontrol_ros/core/direct/first_motion.py): TOPP-RA.
        "toppra>=0.6",
        # Exact distances of the collision geometry (tocontrol_ros/core/geometry/).
        "coal>=3",
        "ros-jazzy-rclpy>=7.1",
        "ros-jazzy-common-interfaces>=5.3",
        "ros-jazzy-rmw-fastrtps-cpp>=8.4",
    ],
    extras_require={
        "test": [
            "pytest>=8",
            "ruff>=0.6",
            "pin>=3",
            "example-robot-data>=4",
            "mcap-ros2-support>=0.5",
            "rosbags>=0.10",
            "ray>=2.9",
            # The bounded solve's detour seed (tocontrol_ros/core/direct/detour.py).
            "ompl>=2",
        ],
        # Seeds that avoid obstacles: OMPL's sampling planner (core/direct/detour.py imports
        # it inside its function; without it a plan with a scene has no detour seed).
        "collision": [
            "ompl>=2",
        ],
        "bench": [
            "ray>=2.9",
            # bench/collision.py's peer: OMPL's sampling planner (imported there only).
            "ompl>=2",
        ],
        # `batch --ray`: only tocontrol_ros/batch/ray_backend.py imports it, inside RayBackend.
        "ray": [
            "ray>=2.9",
        ],
    },
    entry_points={
        "console_scripts": [
            f"tocontrol-{name} = {module}:main" for name, module in EXECUTABLES.items()
        ],
    },
)
