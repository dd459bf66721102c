"""Shared fixtures of the core tests: the paper's arm and its solved example, robots of
example-robot-data.

Models are session-scoped: loading them and building their CasADi functions is the slow
part, and every test only reads them. Test modules get the robots' load arguments from the
``robot_specs`` fixture rather than by importing this file (two conftest.py modules share the
name ``conftest``).
"""

from __future__ import annotations

import site
import sys
from pathlib import Path

import pytest
from skip_policy import missing

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.planning.solver import SolverOptions, plan
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.problem import Problem, point

#: Pinocchio's default gravity; the cross-checks give our models the same one.
PIN_GRAVITY = (0.0, 0.0, -9.81)
PANDA_LOCKED = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}


def _example_robot_data_dir() -> Path | None:
    """``share/example-robot-data/robots`` of the cmeel wheel, wherever site-packages is."""
    candidates = []
    try:
        import cmeel.consts

        candidates.append(Path(cmeel.consts.SITELIB) / cmeel.consts.CMEEL_PREFIX)
    except (ImportError, AttributeError):
        pass
    dirs = list(sys.path) + site.getsitepackages() + [site.getusersitepackages()]
    candidates += [Path(d) / "cmeel.prefix" for d in dirs if d]
    for prefix in candidates:
        robots = prefix / "share" / "example-robot-data" / "robots"
        if robots.is_dir():
            return robots
    return None


@pytest.fixture(scope="session")
def galicki():
    """The paper's planar 3R arm, from ``config/galicki_3r.urdf``."""
    return load_robot(default_urdf_path())


@pytest.fixture(scope="session")
def solved(galicki):
    """The paper's example at k = 4 (one start) with switch nodes, and without."""
    problem = Problem(galicki, point(PAPER_START), point(PAPER_TARGET), k=4)
    return {"problem": problem, "nodes": plan(problem, SolverOptions(starts=1, candidates=1)),
            "uniform": plan(problem, SolverOptions(starts=1, candidates=1,
                                                   switch_nodes=False))}


@pytest.fixture(scope="session")
def solved_grid(galicki, solved):
    """The final grid of the switch-node solve, its nodes, T and interval lengths."""
    from tocontrol_ros.core.planning.solver import Planner

    st = solved["nodes"].warm_state
    grid = st.grid(Planner(galicki).system, "point", "point")
    nodes, t_final, _, _ = grid.unpack(st.w)
    return grid, nodes, t_final, grid.lengths_of(st.w)


#: A spatial chain that exercises what the planar arm does not: a prismatic joint on an
#: oblique axis, a revolute axis that is not normalised in the file, rpy joint origins,
#: inertial frames rotated off the link axes with products of inertia, a massive link on a
#: fixed joint (lumped), and a revolute joint locked at a non-zero angle mid-chain.
RPR_URDF = """<?xml version="1.0"?>
<robot name="rpr">
  <link name="base"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="l1"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.2 -0.1 0.4"/>
    <axis xyz="0 0 1"/>
    <limit effort="40" lower="-3" upper="3" velocity="2"/>
    <dynamics damping="0.7"/>
  </joint>
  <link name="l1">
    <inertial>
      <origin xyz="0.2 0.05 -0.1" rpy="0.3 0.2 -0.5"/>
      <mass value="3.0"/>
      <inertia ixx="0.05" ixy="0.004" ixz="-0.003" iyy="0.06" iyz="0.002" izz="0.04"/>
    </inertial>
  </link>
  <joint name="j2" type="prismatic">
    <parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0.1 0.0" rpy="-0.3 0.5 0.1"/>
    <axis xyz="0.6 0 0.8"/>
    <limit effort="100" lower="-0.5" upper="0.5" velocity="1"/>
    <dynamics damping="2.5"/>
  </joint>
  <link name="l2">
    <inertial>
      <origin xyz="0.05 0.1 0.15" rpy="0.1 0.7 0.2"/>
      <mass value="2.0"/>
      <inertia ixx="0.03" ixy="-0.002" ixz="0.001" iyy="0.02" iyz="0.003" izz="0.025"/>
    </inertial>
  </link>
  <joint name="jlock" type="revolute">
    <parent link="l2"/><child link="l3"/>
    <origin xyz="0.0 0.3 0.1" rpy="0.0 0.0 0.6"/>
    <axis xyz="1 0 0"/>
    <limit effort="10" lower="-2" upper="2" velocity="1"/>
  </joint>
  <link name="l3">
    <inertial>
      <origin xyz="0.1 0.0 0.05" rpy="0 0 0"/>
      <mass value="0.8"/>
      <inertia ixx="0.004" ixy="0.0" ixz="0.0" iyy="0.005" iyz="0.0" izz="0.006"/>
    </inertial>
  </link>
  <joint name="j3" type="revolute">
    <parent link="l3"/><child link="l4"/>
    <origin xyz="0.25 0.0 -0.1" rpy="0.4 0.0 -0.2"/>
    <axis xyz="0 1 1"/>
    <limit effort="15" lower="-2.5" upper="2.5" velocity="3"/>
    <dynamics damping="0.2"/>
  </joint>
  <link name="l4">
    <inertial>
      <origin xyz="0.15 0.02 0.0" rpy="0.0 -0.4 0.3"/>
      <mass value="1.2"/>
      <inertia ixx="0.01" ixy="0.001" ixz="0.0" iyy="0.012" iyz="-0.001" izz="0.008"/>
    </inertial>
  </link>
  <joint name="tool_joint" type="fixed">
    <parent link="l4"/><child link="tool"/>
    <origin xyz="0.3 0.05 0.02" rpy="0.0 0.3 0.0"/>
  </joint>
  <link name="tool">
    <inertial>
      <origin xyz="0.02 0.0 0.01" rpy="0.2 0 0"/>
      <mass value="0.5"/>
      <inertia ixx="0.001" ixy="0.0" ixz="0.0" iyy="0.002" iyz="0.0" izz="0.0015"/>
    </inertial>
  </link>
</robot>
"""
RPR_LOCKED = {"jlock": 0.7}
#: Gravity off the base's axes, so that no component of it drops out by accident.
RPR_GRAVITY = (0.8, -1.5, -9.6)




@pytest.fixture(scope="session")
def robot_specs(request) -> dict:
    """Per robot: ``source`` (path or XML) and the ``load_robot`` keyword arguments.

    The keyword arguments always hold ``tip_link``, ``gravity`` and ``locked_joints``, so
    that a cross-check can build the same reduced model elsewhere (Pinocchio). Robots whose
    files are missing are left out.
    """
    specs = {"rpr": {"source": RPR_URDF, "kwargs": {
        "tip_link": "tool", "gravity": RPR_GRAVITY, "locked_joints": RPR_LOCKED}}}
    robots = _example_robot_data_dir()
    if robots is not None:
        files = {"panda": (robots / "panda_description/urdf/panda.urdf", "panda_hand",
                           PANDA_LOCKED),
                 "ur5": (robots / "ur_description/urdf/ur5_robot.urdf", "tool0", {}),
                 "xarm7": (robots / "xarm_description/urdf/xarm7.urdf", "link_eef", {})}
        for name, (path, tip, locked) in files.items():
            if path.is_file():
                specs[name] = {"source": path, "kwargs": {
                    "tip_link": tip, "gravity": PIN_GRAVITY, "locked_joints": locked}}
    return specs


def _load(specs: dict, name: str):
    if name not in specs:
        missing(f"the {name} URDF of example-robot-data (pip install '.[test]')")
    return load_robot(specs[name]["source"], **specs[name]["kwargs"])


@pytest.fixture(scope="session")
def panda(robot_specs):
    """Franka Panda arm to the hand, fingers locked closed, Pinocchio's gravity."""
    return _load(robot_specs, "panda")


@pytest.fixture(scope="session")
def panda_collision():
    """The Panda to the hand, fingers locked, the URDF's own gravity, with its collision model
    (Coal; the SRDF's disabled pairs): ``(model, urdf, srdf, collision)``.

    One for the session: test_geometry, test_self_rows, test_detour and test_clearance_start
    built the same model and spheres each (seconds apiece under load). Tests only read it
    (``with_scene`` and ``with_row_pairs`` return new collision models).
    """
    from skip_policy import panda_srdf, panda_urdf

    pytest.importorskip("coal")
    from tocontrol_ros.core.geometry.collision import collision_model

    urdf, srdf = panda_urdf(), panda_srdf()
    model = load_robot(urdf, tip_link="panda_hand", locked_joints=PANDA_LOCKED)
    return model, urdf, srdf, collision_model(model, urdf, srdf)


@pytest.fixture(scope="session")
def ur5(robot_specs):
    """Universal Robots UR5 to ``tool0``, Pinocchio's gravity."""
    return _load(robot_specs, "ur5")


@pytest.fixture(scope="session")
def xarm7(robot_specs):
    """UFactory xArm7 to ``link_eef`` (7 joints), Pinocchio's gravity."""
    return _load(robot_specs, "xarm7")


@pytest.fixture(scope="session")
def rpr(robot_specs):
    """The spatial revolute-prismatic-revolute chain above (3 joints, one locked)."""
    return _load(robot_specs, "rpr")
