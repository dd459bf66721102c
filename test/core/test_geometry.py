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
from tocontrol_ros.core.geometry.collision import (  # noqa: E402
    body_frames,
    collision_model,
    disabled_pairs,
)
from tocontrol_ros.core.geometry.reach import (  # noqa: E402
    CLEAR_POSE_ROUNDS,
    clear_configuration,
    clear_pose_configuration,
    note_clear,
)
from tocontrol_ros.core.geometry.scene import load_scene, scene_from_dict  # noqa: E402
from tocontrol_ros.core.geometry.shapes import LinkShape  # noqa: E402
from tocontrol_ros.core.robot.ik import ik_pose, pose_errors  # noqa: E402
from tocontrol_ros.core.robot.kinematics import tip_pose  # noqa: E402
from tocontrol_ros.core.types.problem import (  # noqa: E402
    Problem,
    joint_state,
    note_reachable,
    point,
)

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


def _turned(angle: float, axis: np.ndarray) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.mark.parametrize(("kind", "size"), [("box", (0.1, 0.04, 0.3)),
                                            ("cylinder", (0.05, 0.2)),
                                            ("sphere", (0.07,))])
def test_reach_bounds_every_surface_point_and_is_attained(kind, size):
    # The lever of the certificate's between-samples bound: no surface point farther out
    # (else the bound would not hold), and a dense sampling comes within its spacing of it.
    shape = LinkShape("l", 0, kind, size, _turned(0.7, np.array([1.0, 2.0, -0.5])),
                      np.array([0.12, -0.03, 0.05]))
    norms = np.linalg.norm(shape.points(0.002), axis=1)
    assert norms.max() <= shape.reach() + 1e-12
    assert norms.max() >= shape.reach() - 0.002


def test_reach_of_the_panda_meshes_is_their_farthest_vertex(panda):
    _, _, _, col = panda
    for shape in (s for s in col.shapes if s.kind == "mesh"):
        v = np.asarray(shape.geometry().vertices()) @ shape.rotation.T + shape.translation
        assert shape.reach() == pytest.approx(np.linalg.norm(v, axis=1).max(), abs=1e-12)
        centre, radius = shape.bounding_sphere()
        assert shape.reach() <= np.linalg.norm(centre) + radius + 1e-12


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


#: A table at z = 0 under the Panda (bench/scenes/table.yaml), the base standing on it.
TABLE = {"obstacles": [{"name": "table", "type": "box", "size": [1.6, 1.6, 0.04],
                        "position": [0.3, 0.0, -0.02]}],
         "allowed": [["panda_link0", "table"], ["panda_link1", "table"]]}


def test_target_point_in_collision_refused_naming_pair_and_why(panda):
    model, _, _, col = panda
    # Inside a 10 cm ball: every configuration reaching the point has the hand in it.
    inside = scene_from_dict({"obstacles": [
        {"name": "block", "type": "sphere", "radius": 0.1, "position": [0.3, 0.4, 0.5]}]})
    with pytest.raises(ProblemError, match=r"`target` point \[0\.3, 0\.4, 0\.5\] has no "
                                           r"configuration clear of the scene by the margin "
                                           r".* the clearest is in collision, \w+ and block "
                                           r"closest"):
        Problem(model, joint_state(Q0), point([0.3, 0.4, 0.5]),
                collision=col.with_scene(inside))
    # Reachable only through the table or the base (draw 17 of bench.limits.draw_cases,
    # seed 51: case 17 table of bench/collision.py before session 36, LIMITS_INFEASIBLE;
    # 6.9 cm above the table, 15.7 cm from the base's axis): no IK solution is clear.
    low = [-0.08442261, -0.13228413, 0.06938094]
    with pytest.raises(ProblemError, match=r"`target` point .* no configuration clear .*"
                                           r"closest; the point is inside an obstacle, or "
                                           r"the arm reaches it only through one"):
        Problem(model, joint_state(Q0), point(low), collision=col.with_scene(
            scene_from_dict(TABLE)))
    # The same as a start point is refused the same way; a point with room is accepted.
    with pytest.raises(ProblemError, match=r"`start` point .* no configuration clear"):
        Problem(model, point(low), point([0.3, 0.4, 0.5]),
                collision=col.with_scene(scene_from_dict(TABLE)))
    Problem(model, joint_state(Q0), point([0.3, 0.4, 0.5]),
            collision=col.with_scene(scene_from_dict(TABLE)))


def test_clear_configuration_reaches_the_point_inside_the_limits_and_clear(panda):
    model, _, _, col = panda
    table = col.with_scene(scene_from_dict(TABLE))
    lo, hi = model.q_lower, model.q_upper
    p = np.array([0.45, -0.2, 0.15])  # low over the table: some configurations hit it
    found = clear_configuration(table, p, lo, hi)
    assert found.found and found.tried >= 1
    assert np.linalg.norm(model.point(found.q) - p) < 1e-6
    assert np.all(found.q >= lo) and np.all(found.q <= hi)
    # Checked again pair by pair with Coal directly: every checked pair keeps the margin.
    assert min(float(d[0]) for d in table.clearance(found.q).pair_distances.values()) \
        >= table.margin
    assert found.clearance == pytest.approx(table.clearance(found.q).minimum)
    # The same question gives the same answer (a fixed amount of seeded work), asked of
    # another collision model object (not the remembered verdict).
    again = clear_configuration(col.with_scene(scene_from_dict(TABLE)), p, lo, hi)
    assert np.array_equal(again.q, found.q)


def test_a_replans_noted_configuration_spares_the_clear_search(panda):
    # A replan's goal: the configuration reached by steps from the running motion's end is
    # checked clear once and used, no IK search; one in collision is not remembered.
    model, _, _, col = panda
    table = col.with_scene(scene_from_dict(TABLE))
    lo, hi = model.q_lower, model.q_upper
    found = clear_configuration(table, np.array([0.45, -0.2, 0.15]), lo, hi)
    near = model.point(found.q) + np.array([0.0, 0.004, 0.002])  # the target moved 4.5 mm
    assert note_reachable(model, near, found.q, table)
    noted = clear_configuration(table, near, lo, hi)
    assert noted.found and noted.seeds == 0 and noted.tried == 1
    assert np.linalg.norm(model.point(noted.q) - near) < 1e-6
    assert noted.clearance == pytest.approx(table.clearance(noted.q).minimum)
    assert noted.clearance >= table.margin
    # Outside the limits a problem is given, the noted configuration is not used.
    tight = np.where(np.arange(model.n) == 0, noted.q[0] + 0.01, lo)
    assert clear_configuration(table, near, tight, hi).seeds > 0
    # A configuration in collision: nothing remembered, the search answers.
    low = np.array([0.5, 0.0, -0.02])  # 2 cm under the table top (z = 0)
    q_low = clear_configuration(col, low, lo, hi).q  # reaches it without the table
    assert not note_clear(table, low, q_low)
    assert clear_configuration(table, low, lo, hi).seeds > 0


def test_a_pose_whose_first_solution_touches_an_obstacle_has_a_clear_one_found(panda):
    """A ball on the forearm of the pose's IK solution from the start; another is clear.

    The solution found puts the tip on the pose (its residuals), is inside the limits and
    keeps the margin by Coal pair by pair; the same answer from another collision model
    object. A pose inside a 10 cm ball has none: the clearest tried and its pair.
    """
    model, _, _, col = panda
    lo, hi = model.q_lower, model.q_upper
    rot, pos = tip_pose(model, Q0 + np.array([1.2, 0.3, 0.0, 0.3, 0.0, -0.2, 0.0]))
    [first], _, _ = ik_pose(model, pos, rot, Q0[None], lo, hi)  # what the start's seed finds
    frames = body_frames(model, first[None])[1][0]
    forearm = 0.5 * (frames[3] + frames[5])  # between the elbow and the wrist
    ball = {"obstacles": [{"name": "ball", "type": "sphere", "radius": 0.05,
                           "position": forearm.tolist()}]}
    scene = col.with_scene(scene_from_dict(ball))
    assert scene.clearance(first).minimum < 0.0  # the forearm in the ball
    found = clear_pose_configuration(scene, pos, rot, lo, hi)
    assert found.found and found.seeds <= sum(c for c, _ in CLEAR_POSE_ROUNDS)
    pos_err, ang_err = pose_errors(model, found.q, pos, rot)
    assert pos_err[0] < 1e-6 and ang_err[0] < 1e-6
    assert np.all(found.q >= lo) and np.all(found.q <= hi)
    assert min(float(d[0]) for d in scene.clearance(found.q).pair_distances.values()) \
        >= scene.margin
    again = clear_pose_configuration(col.with_scene(scene_from_dict(ball)), pos, rot, lo, hi)
    assert np.array_equal(again.q, found.q)
    inside = col.with_scene(scene_from_dict({"obstacles": [
        {"name": "block", "type": "sphere", "radius": 0.1, "position": pos.tolist()}]}))
    none = clear_pose_configuration(inside, pos, rot, lo, hi)
    assert not none.found and none.tried > 0
    assert none.seeds == sum(c for c, _ in CLEAR_POSE_ROUNDS)
    assert none.pair[1] == "block" and none.clearance < 0.0


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
