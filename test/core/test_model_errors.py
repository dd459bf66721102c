"""Bad robot descriptions and arguments: a ModelError that names the offending element.

Every case starts from the same valid two-joint chain (``base -> j1 -> l1 -> j2 -> l2 ->
tool``) and breaks one thing, so that a case that does not raise means the check is
missing, not that some other part of the URDF was wrong.
"""

from __future__ import annotations

import pytest

from tocontrol_ros.core.errors import ModelError, TocontrolError
from tocontrol_ros.core.robot.model import load_robot

INERTIAL = """<inertial><origin xyz="0.5 0 0"/><mass value="1"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>"""
LIMIT = '<limit effort="10" velocity="2" lower="-3" upper="3"/>'


def _joint(name, parent, child, kind="revolute", limit=LIMIT, axis="0 0 1", extra=""):
    axis_tag = f'<axis xyz="{axis}"/>' if axis is not None else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="1 0 0"/>{axis_tag}{limit}{extra}</joint>')


def _link(name, inertial=INERTIAL):
    return f'<link name="{name}">{inertial}</link>'


def chain(j1=None, j2=None, l2=None, extra=""):
    """The valid chain, with joint ``j1``/``j2``, link ``l2`` or extra elements replaced."""
    return "\n".join([
        '<?xml version="1.0"?>',
        '<robot name="bad">',
        '<link name="base"/>',
        j1 or _joint("j1", "base", "l1"),
        _link("l1"),
        j2 or _joint("j2", "l1", "l2"),
        l2 or _link("l2"),
        _joint("tool_joint", "l2", "tool", kind="fixed", limit="", axis=None),
        '<link name="tool"/>',
        extra,
        "</robot>",
    ])


BRANCH = _joint("jb", "l1", "lb") + _link("lb")
CASES = [
    # urdf, kwargs, match
    ('<robot name="x"><link name="a"></robot>', {}, r"malformed URDF"),
    ("/nonexistent/dir/robot.urdf", {}, r"not found: /nonexistent/dir/robot\.urdf"),
    (chain(), {"base_link": "nowhere"}, r"base link 'nowhere' is not a link"),
    (chain(), {"tip_link": "nowhere"}, r"tip link 'nowhere' is not a link"),
    (chain(), {"base_link": "l2", "tip_link": "l1"},
     r"tip link 'l1' is not below base link 'l2'"),
    (chain(), {"base_link": "tool"}, r"no moving joint between 'tool' and 'tool'"),
    (chain(extra=BRANCH), {"tip_link": "tool"}, r"branching chain: moving joint 'jb'"),
    (chain(extra=BRANCH), {}, r"several leaf links .*'lb'.*'tool'"),
    (chain(extra=_joint("jc", "l1", "l2")), {}, r"closed chain: link 'l2' .* 'jc'"),
    (chain(extra=_joint("jd", "base", "ghost")), {}, r"joint 'jd': child link 'ghost'"),
    (chain(j2=_joint("j2", "l1", "l2", kind="floating", limit="")), {},
     r"joint 'j2': unsupported type 'floating'"),
    (chain(j2=_joint("j2", "l1", "l2", kind="planar", limit="")), {},
     r"joint 'j2': unsupported type 'planar'"),
    (chain(extra=_joint("jf", "l1", "lf", kind="floating") + _link("lf")), {},
     r"several leaf links"),
    (chain(extra=_joint("jf", "l1", "lf", kind="floating") + _link("lf")),
     {"tip_link": "tool"}, r"joint 'jf': unsupported type 'floating'"),
    (chain(l2='<link name="l2"/>'), {}, r"link 'l2' \(moved by joint 'j2'\) has no <inertial>"),
    (chain(l2=_link("l2", INERTIAL.replace('value="1"', 'value="-1"'))), {},
     r"link 'l2': <mass> must be >= 0"),
    (chain(l2=_link("l2", INERTIAL.replace('iyy="0.1"', 'iyy="-0.5"'))), {},
     r"link 'l2': <inertia> is not positive semi-definite"),
    # A point mass on the axis of j2: no inertia about it.
    (chain(l2=_link("l2", '<inertial><mass value="1"/></inertial>')), {},
     r"joint 'j2': the bodies it moves have no inertia"),
    (chain(j2=_joint("j2", "l1", "l2", limit="")), {}, r"joint 'j2': <limit effort> is missing"),
    (chain(j2=_joint("j2", "l1", "l2", limit='<limit velocity="1" lower="-1" upper="1"/>')),
     {}, r"(?s)joint\[@name='j2'\]/limit.*effort"),
    (chain(j2=_joint("j2", "l1", "l2", limit=LIMIT.replace('effort="10"', 'effort="0"'))), {},
     r"joint 'j2': <limit effort> must be positive"),
    (chain(j2=_joint("j2", "l1", "l2", limit=LIMIT.replace('effort="10"', 'effort="inf"'))),
     {}, r"joint 'j2': <limit effort> must be positive and finite"),
    (chain(j2=_joint("j2", "l1", "l2", limit=LIMIT.replace('velocity="2"', 'velocity="0"'))),
     {}, r"joint 'j2': <limit velocity> must be positive"),
    (chain(j2=_joint("j2", "l1", "l2", limit=LIMIT.replace('lower="-3"', 'lower="3"'))), {},
     r"joint 'j2': position limits must satisfy lower < upper"),
    (chain(j2=_joint("j2", "l1", "l2", limit=LIMIT.replace('lower="-3"', 'lower="4"'))), {},
     r"joint 'j2': position limits must satisfy lower < upper"),
    (chain(j2=_joint("j2", "l1", "l2", axis="0 0 0")), {}, r"joint 'j2': <axis xyz> must be"),
    (chain(j2=_joint("j2", "l1", "l2", extra='<dynamics damping="-1"/>')), {},
     r"joint 'j2': <dynamics damping> must be >= 0"),
    (chain(), {"task_axes": "xq"}, r"`task_axes` .* 'xq'"),
    (chain(), {"task_axes": "xx"}, r"`task_axes` .* 'xx'"),
    (chain(), {"task_axes": ""}, r"`task_axes`"),
    (chain(), {"task_axes": (0, 3)}, r"`task_axes` .* \(0, 3\)"),
    (chain(), {"gravity": (0.0, -9.81)}, r"`gravity` must be 3 finite numbers"),
    (chain(), {"gravity": (0.0, 0.0, float("nan"))}, r"`gravity` must be 3 finite numbers"),
    (chain(), {"locked_joints": {"nope": 0.0}}, r"`locked_joints` names joint 'nope'"),
    (chain(), {"locked_joints": {"j1": 0.0, "j2": 0.0}}, r"no moving joint"),
    (42, {}, r"`source` must be a URDF path or XML string, got int"),
]


CASE_IDS = [
    "malformed-xml", "missing-file", "unknown-base", "unknown-tip", "tip-above-base",
    "no-moving-joint", "branching", "branching-no-tip", "closed-chain", "undefined-link",
    "floating-on-path", "planar-on-path", "floating-branch-no-tip", "floating-branch",
    "no-inertial", "negative-mass", "inertia-not-psd", "no-inertia-about-axis", "no-limit",
    "limit-without-effort", "zero-effort", "infinite-effort", "zero-velocity",
    "lower-equals-upper", "lower-above-upper", "zero-axis", "negative-damping",
    "task-axes-xq", "task-axes-xx", "task-axes-empty", "task-axes-index-3", "gravity-shape",
    "gravity-nan", "locked-unknown", "all-locked", "source-type",
]


@pytest.mark.parametrize("urdf, kwargs, match", CASES, ids=CASE_IDS)
def test_bad_input_raises_model_error(urdf, kwargs, match):
    with pytest.raises(ModelError, match=match):
        load_robot(urdf, **kwargs)


def test_base_chain_is_valid():
    """The chain the cases break loads, so each case fails for its own reason."""
    model = load_robot(chain())
    assert model.joint_names == ("j1", "j2")
    assert model.tip_link == "tool"
    assert model.task_axes == (0, 1)


def test_locking_the_branch_resolves_it():
    model = load_robot(chain(extra=BRANCH), tip_link="tool", locked_joints={"jb": 0.4})
    assert model.joint_names == ("j1", "j2")
    # The locked branch link rides on body 1: its mass is lumped into it.
    assert model.bodies[0].links == ("l1", "lb")
    assert model.bodies[0].mass == pytest.approx(2.0)


def test_model_error_is_a_value_error():
    assert issubclass(ModelError, ValueError)
    assert issubclass(ModelError, TocontrolError)
    with pytest.raises(ValueError, match="base link"):
        load_robot(chain(), base_link="nowhere")


def test_unknown_function_name(galicki):
    with pytest.raises(KeyError, match="'nope'"):
        galicki.function("nope")


@pytest.mark.parametrize("method, args", [
    ("mass_matrix", ([0.0, 0.0],)),
    ("bias", ([0.0] * 3, [0.0] * 4)),
    ("forward_dynamics", ([0.0] * 3, [0.0] * 3, [[0.0] * 3])),
    ("point", (0.0,)),
])
def test_numeric_methods_check_shapes(galicki, method, args):
    with pytest.raises(ValueError, match=r"must have shape \(3,\)"):
        getattr(galicki, method)(*args)
