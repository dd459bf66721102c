"""The collision geometry (issue 51): shapes from the URDF, spheres, scenes, exact clearance.

The Panda of example-robot-data with its collision meshes; Coal for the exact distances.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from tocontrol_ros.core.errors import ModelError, ProblemError

coal = pytest.importorskip("coal")

from tocontrol_ros.core.checks.certificate import certify_open_loop  # noqa: E402
from tocontrol_ros.core.direct.first_motion import first_motion  # noqa: E402
from tocontrol_ros.core.geometry.collision import collision_model, disabled_pairs  # noqa: E402
from tocontrol_ros.core.geometry.scene import load_scene, scene_from_dict  # noqa: E402
from tocontrol_ros.core.robot.kinematics import tip_pose  # noqa: E402
from tocontrol_ros.core.types.problem import Problem, joint_state, point  # noqa: E402

Q0 = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])


@pytest.fixture(scope="module")
def panda(panda_collision):
    return panda_collision  # (model, urdf, srdf, collision), one for the session


def test_spheres_cover_every_mesh_vertex(panda):
    model, _, _, col = panda
    # Every link's mesh vertices (a primitive's surface points), in its body's frame, lie in
    # one of the link's spheres.
    assert any(s.kind == "mesh" for s in col.shapes)
    for spheres in col.spheres:
        for shape in (s for s in col.shapes if s.link == spheres.link):
            if shape.kind == "mesh":
                v = np.asarray(shape.geometry().vertices()) @ shape.rotation.T \
                    + shape.translation
            else:
                v = shape.points(0.005)
            inside = np.linalg.norm(v[:, None, :] - spheres.centers[None], axis=2) \
                <= spheres.radii[None] + 1e-9
            assert np.all(inside.any(axis=1)), spheres.link
    # Several spheres a link (not one bounding sphere), and the worst gap reported.
    assert max(len(s.radii) for s in col.spheres) > 1
    assert 0.0 < col.worst_gap() < 0.08


def test_self_pairs_skip_adjacent_and_srdf_disabled(panda):
    model, urdf, srdf, col = panda
    pairs = {frozenset(p) for p in col.self_pairs}
    disabled = disabled_pairs(srdf)
    assert frozenset(("panda_link1", "panda_link2")) not in pairs  # adjacent
    assert not pairs & disabled
    full = collision_model(model, urdf)  # without the SRDF: more pairs
    assert {frozenset(p) for p in full.self_pairs} > pairs


def test_package_uri_resolved_and_missing_mesh_named(panda, tmp_path):
    model, urdf, _, col = panda
    assert all(s.mesh.is_file() for s in col.shapes if s.kind == "mesh")
    text = urdf.read_text().replace("collision/link3.stl", "collision/nothing_here.stl")
    with pytest.raises(ModelError, match=r"mesh file .*nothing_here\.stl.* not found"):
        collision_model(model, text)


def test_start_in_collision_refused_naming_pair_and_distance(panda):
    model, _, _, col = panda
    _, tip = tip_pose(model, Q0)
    scene = scene_from_dict({"obstacles": [
        {"name": "block", "type": "sphere", "radius": 0.05, "position": tip.tolist()}]})
    with pytest.raises(ProblemError, match=r"`start` joint state is in collision: "
                                           r"\w+ and block are -[0-9.]+ m apart"):
        Problem(model, joint_state(Q0), point([0.3, 0.4, 0.5]),
                collision=col.with_scene(scene))


def test_certificate_refuses_a_motion_through_a_box(panda):
    model, _, _, col = panda
    free = Problem(model, joint_state(Q0), point([0.3, 0.4, 0.5]))
    motion = first_motion(free).trajectory
    mid = motion.evaluate(np.array([motion.T / 2])).q[0]
    _, tip = tip_pose(model, mid)
    for where, passes in ((tip, False), (np.array([2.0, 2.0, 2.0]), True)):
        scene = scene_from_dict({"obstacles": [
            {"name": "box", "type": "box", "size": [0.1, 0.1, 0.1],
             "position": where.tolist()}]})
        problem = Problem(model, joint_state(Q0), point([0.3, 0.4, 0.5]),
                          collision=col.with_scene(scene))
        cert = certify_open_loop(problem, motion)
        assert cert.item("clearance").passed is passes
        if not passes:
            assert cert.figures["min_clearance"] < 0
            assert cert.figures["closest_pair"].endswith("/box")
            assert not cert.passed


def test_exact_distance_of_a_known_placement(panda):
    model, _, _, col = panda
    # The hand's exact geometry against a sphere placed 5 cm beyond its farthest vertex along
    # z of the tip frame: Coal's distance is positive and below 5 cm + the hand's size.
    rot, tip = tip_pose(model, Q0)
    scene = scene_from_dict({"obstacles": [
        {"name": "ball", "type": "sphere", "radius": 0.02,
         "position": (tip + rot @ np.array([0.0, 0.0, 0.2])).tolist()}]})
    found = col.with_scene(scene).clearance(Q0)
    ball = found.pair_distances[("panda_hand", "ball")]
    assert 0.0 < ball[0] < 0.2


BAD_SCENES = [
    ({"obstacles": [{"name": "a", "type": "cone", "radius": 1}]}, "`type` must be one of"),
    ({"obstacles": [{"name": "a", "type": "box", "size": [1, 1]}]}, "`size` must be 3"),
    ({"obstacles": [{"name": "a", "type": "box", "size": [1, 1, -1]}]}, "sizes must be > 0"),
    ({"obstacles": [{"name": "a", "type": "sphere", "radius": float("nan")}]}, "finite"),
    ({"obstacles": [{"type": "sphere", "radius": 1}]}, "needs a `name`"),
    ({"obstacles": [{"name": "a", "type": "sphere", "radius": 1, "colour": 2}]},
     "unknown fields"),
    ({"obstacles": [{"name": "a", "type": "sphere", "radius": 1},
                    {"name": "a", "type": "sphere", "radius": 1}]}, "unique"),
    ({"obstacles": [{"name": "a", "type": "sphere", "radius": 1,
                     "orientation": [0, 0, 0, 0]}]}, "zero quaternion"),
    ({"obstacles": {}}, "must be a list"),
    ({"walls": []}, "unknown keys"),
    ({"allowed": [["a"]]}, "pair of names"),
    ([1, 2], "a scene is a mapping"),
]


@pytest.mark.parametrize("data, match", BAD_SCENES)
def test_bad_scene_refused_with_the_reason(data, match):
    with pytest.raises(ProblemError, match=re.escape(match)):
        scene_from_dict(data, "test scene")


def test_scene_files(tmp_path, panda):
    with pytest.raises(ProblemError, match="scene file not found"):
        load_scene(tmp_path / "none.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("obstacles: [\n")
    with pytest.raises(ProblemError, match=r"bad\.yaml could not be read"):
        load_scene(bad)
    good = tmp_path / "cell.yaml"
    good.write_text("frame: panda_link0\nobstacles:\n  - name: table\n    type: box\n"
                    "    size: [1.0, 1.0, 0.04]\n    position: [0.3, 0.0, -0.03]\n"
                    "allowed:\n  - [panda_link0, table]\n")
    scene = load_scene(good, frame="panda_link0")
    assert scene.names() == ("table",) and scene.allows("table", "panda_link0")
    with pytest.raises(ProblemError, match="base frame 'world'"):
        load_scene(good, frame="world")
    model, _, _, col = panda
    with pytest.raises(ProblemError, match="neither a link with geometry nor an obstacle"):
        col.with_scene(scene_from_dict({"allowed": [["panda_link0", "nowhere"]]}))


# Two Panda plans with 4 starts (over a minute under load). The default run keeps a Panda plan
# around a ball, certified and clear by Coal at 2001 times:
# test_clearance_start.py::test_a_start_2cm_from_an_obstacle_plans_and_is_clear[where1-False].
@pytest.mark.slow
def test_a_scene_makes_the_plan_avoid_it(panda):
    """A ball on the obstacle-free optimum's path: the plan with the scene goes around it.

    Checked independently of the solver and of its certificate: Coal's exact distances at
    2001 times of the published motion, every checked pair at least the margin apart.
    """
    from tocontrol_ros.core import SolverOptions, plan

    model, _, _, col = panda
    options = SolverOptions(starts=4, candidates=1, time_limit=600)
    target = point([0.3, 0.4, 0.5])
    free = plan(Problem(model, joint_state(Q0), target), options)
    assert free.success
    _, tip = tip_pose(model, free.trajectory.evaluate(np.array([free.T / 2])).q[0])
    scene = scene_from_dict({"obstacles": [
        {"name": "ball", "type": "sphere", "radius": 0.05, "position": tip.tolist()}]})
    problem = Problem(model, joint_state(Q0), target, collision=col.with_scene(scene))
    # The obstacle-free optimum goes through the ball.
    assert not certify_open_loop(problem, free.trajectory).item("clearance").passed
    res = plan(problem, options)
    assert res.success, res.message
    assert res.certificate.item("clearance").passed
    assert res.verification["min_clearance"] >= col.margin
    sample = res.trajectory.evaluate(np.linspace(0.0, res.T, 2001))
    exact = problem.collision.clearance(sample.q)
    assert exact.minimum >= col.margin, (exact.minimum, exact.pair)
    assert res.T > free.T  # going around costs time
