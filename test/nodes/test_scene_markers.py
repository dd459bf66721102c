"""~/scene's MarkerArray applied to a scene (issue 51): pure conversions, no spinning."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.geometry.scene import Scene, scene_from_dict
from tocontrol_ros.nodes.scene_markers import scene_from_markers, scene_marker_list

FRAME = "panda_link0"


def marker(mid=0, kind=Marker.CUBE, action=Marker.ADD, scale=(0.2, 0.3, 0.4),
           position=(0.5, 0.0, 0.2), frame=FRAME, ns="cell", quat=(0.0, 0.0, 0.0, 1.0)):
    return Marker(header=Header(frame_id=frame), ns=ns, id=mid, type=kind, action=action,
                  pose=Pose(position=Point(x=position[0], y=position[1], z=position[2]),
                            orientation=Quaternion(x=quat[0], y=quat[1], z=quat[2],
                                                   w=quat[3])),
                  scale=Vector3(x=scale[0], y=scale[1], z=scale[2]))


def apply(*markers, current=None):
    return scene_from_markers(MarkerArray(markers=list(markers)), current or Scene(), FRAME)


def test_add_modify_delete_deleteall():
    scene = apply(marker(0), marker(1, Marker.SPHERE, scale=(0.1, 0.1, 0.1)),
                  marker(2, Marker.CYLINDER, scale=(0.1, 0.1, 0.8)))
    assert scene.names() == ("cell/0", "cell/1", "cell/2")
    kinds = {o.name: (o.kind, o.size) for o in scene.obstacles}
    assert kinds["cell/0"] == ("box", (0.2, 0.3, 0.4))
    assert kinds["cell/1"] == ("sphere", (0.05,))
    assert kinds["cell/2"] == ("cylinder", (0.05, 0.8))
    moved = apply(marker(0, position=(0.1, 0.2, 0.3), action=Marker.MODIFY), current=scene)
    assert np.allclose(moved.obstacles[0].translation, [0.1, 0.2, 0.3])
    fewer = apply(marker(1, action=Marker.DELETE), current=moved)
    assert fewer.names() == ("cell/0", "cell/2")
    # DELETEALL, then the markers after it in the same message.
    fresh = apply(marker(action=Marker.DELETEALL), marker(7), current=fewer)
    assert fresh.names() == ("cell/7",)


def test_allowed_pairs_of_deleted_obstacles_go_with_them():
    current = scene_from_dict({"obstacles": [
        {"name": "cell/0", "type": "sphere", "radius": 0.1}],
        "allowed": [["panda_link0", "cell/0"], ["panda_link1", "panda_link3"]]})
    scene = apply(marker(0, action=Marker.DELETE), current=current)
    assert scene.allowed == frozenset({frozenset(("panda_link1", "panda_link3"))})


BAD = [
    (marker(kind=Marker.ARROW), "is not CUBE (1), SPHERE (2) or CYLINDER (3)"),
    (marker(frame="world"), "is in frame 'world'"),
    (marker(scale=(0.1, math.nan, 0.1)), "must be finite"),
    (marker(scale=(0.1, 0.0, 0.1)), "scale must be > 0"),
    (marker(kind=Marker.SPHERE, scale=(0.1, 0.2, 0.1)), "needs equal scales"),
    (marker(kind=Marker.CYLINDER, scale=(0.1, 0.2, 0.5)), "scale.x == scale.y"),
    (marker(quat=(0.0, 0.0, 0.0, 0.0)), "zero orientation quaternion"),
    (marker(action=Marker.DELETE, mid=9), "DELETE of 'cell/9', which is not in the scene"),
    (marker(action=7), "action 7 is not ADD"),
]


@pytest.mark.parametrize("bad, fragment", BAD, ids=[b[1][:20] for b in BAD])
def test_a_bad_marker_refuses_the_whole_message(bad, fragment):
    current = apply(marker(0))
    with pytest.raises(ProblemError) as err:
        apply(marker(1), bad, current=current)
    assert fragment in str(err.value)
    assert current.names() == ("cell/0",)  # the scene in use is unchanged (frozen)


def test_scene_drawn_back_as_markers():
    scene = apply(marker(0, quat=(0.0, 0.0, math.sin(0.3), math.cos(0.3))),
                  marker(1, Marker.CYLINDER, scale=(0.1, 0.1, 0.8)))
    drawn = scene_marker_list(scene, Header(frame_id=FRAME))
    assert [m.type for m in drawn] == [Marker.CUBE, Marker.CYLINDER]
    again = apply(*[marker(m.id, m.type, scale=(m.scale.x, m.scale.y, m.scale.z),
                           position=(m.pose.position.x, m.pose.position.y, m.pose.position.z),
                           quat=(m.pose.orientation.x, m.pose.orientation.y,
                                 m.pose.orientation.z, m.pose.orientation.w))
                    for m in drawn])
    for a, b in zip(scene.obstacles, again.obstacles, strict=True):
        assert a.kind == b.kind and np.allclose(a.size, b.size)
        assert np.allclose(a.rotation, b.rotation) and np.allclose(a.translation, b.translation)
