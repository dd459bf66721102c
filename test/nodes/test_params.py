"""The nodes' shared parameter helper: specs, descriptors and the robot parameters."""

import pytest
from rcl_interfaces.msg import ParameterType

from tocontrol_ros.core.robot.model import default_urdf_path
from tocontrol_ros.nodes import params
from tocontrol_ros.nodes.params import (
    ParameterSpec,
    RobotDescriptionError,
    descriptor,
    load_model,
    parse_locked_joints,
)
from tocontrol_ros.nodes.planner_config import PARAMETERS as PLANNER
from tocontrol_ros.nodes.tracker_config import PARAMETERS as TRACKER
from tocontrol_ros.recording.recorder import PARAMETERS as RECORDER


def test_every_node_takes_the_robot_under_the_same_names():
    for table in (PLANNER, TRACKER):
        names = [spec.name for spec in table]
        assert "robot_description" in names and "robot_description_file" in names
        assert "robot" not in names and "urdf_path" not in names
    assert all(isinstance(spec, ParameterSpec) for spec in (*PLANNER, *TRACKER, *RECORDER))


@pytest.mark.parametrize("default, expected", [
    (True, ParameterType.PARAMETER_BOOL), (3, ParameterType.PARAMETER_INTEGER),
    (0.5, ParameterType.PARAMETER_DOUBLE), ("x", ParameterType.PARAMETER_STRING),
    ([1.0], ParameterType.PARAMETER_DOUBLE_ARRAY), (["/a"], ParameterType.PARAMETER_STRING_ARRAY),
    (None, ParameterType.PARAMETER_DOUBLE_ARRAY),
])
def test_descriptor_type_follows_the_default(default, expected):
    d = descriptor(ParameterSpec("p", default, "doc", read_only=True))
    assert d.type == expected and d.read_only and "restart" in d.description


def test_empty_robot_is_the_bundled_arm():
    model, bundled = load_model("", "")
    assert bundled and model.name == "galicki_3r"


def test_robot_description_xml_and_file_agree():
    text = default_urdf_path().read_text()
    a, bundled_a = load_model(text, "")
    b, bundled_b = load_model("", str(default_urdf_path()))
    assert not bundled_a and not bundled_b and a.joint_names == b.joint_names


@pytest.mark.parametrize("description, file, match", [
    ("x" * 100_000, "", r"`robot_description` must be URDF XML \(starting with '<'\), got "
     r"'x{40}\.\.\.' \(100000 characters\); for a file use `robot_description_file`"),
    ("<robot/>", "arm.urdf", "not both"),
    ("", "/nonexistent/" + "y" * 5000, r"`robot_description_file` '/nonexistent/y{27}\.\.\.' "
     r"cannot be read: File name too long"),
])
def test_bad_robot_parameters_give_one_line(description, file, match):
    # Issue 14: a long non-XML `robot` gave an uncaught OSError echoing the whole string.
    with pytest.raises(RobotDescriptionError, match=match) as info:
        load_model(description, file)
    assert "\n" not in str(info.value) and len(str(info.value)) < 300
    assert isinstance(info.value, ValueError)


def test_parameters_help_lists_each_name():
    text = params.parameters_help(TRACKER)
    assert all(f"  {spec.name}: " in text for spec in TRACKER)


@pytest.mark.parametrize("name, table", [("tracker", TRACKER), ("recorder", RECORDER)])
def test_yaml_matches_the_table(name, table):
    import pathlib

    import yaml

    repo = pathlib.Path(__file__).resolve().parents[2]
    values = yaml.safe_load((repo / "config" / f"{name}.yaml").read_text())
    assert values["/**"]["ros__parameters"] == {
        spec.name: spec.default for spec in table if spec.default is not None}


@pytest.mark.parametrize("text, expected", [
    ("", {}),
    ("panda_finger_joint1=0.04", {"panda_finger_joint1": 0.04}),
    ("a=1, b=-0.5  c=2e-3", {"a": 1.0, "b": -0.5, "c": 0.002}),
])
def test_locked_joints_parse(text, expected):
    assert parse_locked_joints(text) == expected


@pytest.mark.parametrize("text, match", [
    ("a", "must be name=position"), ("a=", "must be name=position"),
    ("=1", "must be name=position"), ("a=nan", "must be name=position"),
    ("a=1 a=2", "names joint 'a' twice"),
])
def test_bad_locked_joints_are_named(text, match):
    with pytest.raises(RobotDescriptionError, match=match):
        parse_locked_joints(text)


def test_the_tables_parameter_types_are_the_messages():
    # parameter_specs repeats rcl_interfaces' values so that the tables load without ROS.
    from tocontrol_ros.nodes.parameter_specs import ParamType

    names = [n for n in vars(ParamType) if n.startswith("PARAMETER_")]
    assert len(names) == 6
    assert all(getattr(ParamType, n) == getattr(ParameterType, n) for n in names)


def test_each_solver_parameter_takes_its_options_default():
    """One hierarchy of knobs (issue 48): a planner parameter that is a solver option has the
    option's default, but for the one listed exception (workers: a node solves on every
    core), and solver_options passes each of them through."""
    from tocontrol_ros.core.types.options import SolverOptions
    from tocontrol_ros.nodes.planner_config import (
        NODE_DEFAULTS,
        PARAMETERS,
        SOLVER_PARAMETERS,
        config_from_values,
        solver_options,
    )

    core = SolverOptions()
    specs = {spec.name: spec for spec in PARAMETERS}
    assert set(SOLVER_PARAMETERS) <= set(specs)
    assert set(NODE_DEFAULTS) <= set(SOLVER_PARAMETERS)
    for name in SOLVER_PARAMETERS:
        expected = NODE_DEFAULTS.get(name, getattr(core, name))
        assert specs[name].default == expected, name
    options = solver_options(config_from_values({spec.name: spec.default for spec in PARAMETERS}))
    for name in SOLVER_PARAMETERS:
        assert getattr(options, name) == specs[name].default, name
