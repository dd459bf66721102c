"""config/foxglove_layout.json: a Foxglove layout installed with the package, for recordings.

"Loads" is checked structurally against Foxglove's layout format (what File > Import layout
reads: ``configById``, ``layout``, ``globalVariables``, ``userNodes``, ``playbackConfig``):
the tree of panels names only configured panels, each panel id is ``<PanelType>!<id>`` of a
built-in panel, and the panels read topics the recorder writes: the 3D panel draws the URDF
from ``/robot_description`` (placed by ``/tf``, ``/tf_static``), the plots read the joint
states.
"""

import json
import re

import pytest

from tocontrol_ros.recording import link_frames
from tocontrol_ros.recording.recorder import DEFAULT_TOPICS

#: The recorder's default topics as recorded without a namespace (they are relative).
RECORDED = {t if t.startswith("/") else f"/{t}" for t in DEFAULT_TOPICS}

LAYOUT = "foxglove_layout.json"
#: Built-in Foxglove panels the layout may use.
PANEL_TYPES = {"3D", "Plot", "RawMessages", "StateTransitions", "Table"}


@pytest.fixture(scope="module")
def layout(prefix, repo):
    installed = prefix / "share" / "tocontrol_ros" / "config" / LAYOUT
    assert installed.read_text() == (repo / "config" / LAYOUT).read_text()
    return json.loads(installed.read_text())


def _leaves(node):
    if isinstance(node, str):
        return [node]
    assert set(node) >= {"first", "second", "direction"}, node
    assert node["direction"] in ("row", "column")
    return _leaves(node["first"]) + _leaves(node["second"])


def test_layout_has_foxglove_layout_keys_and_a_consistent_tree(layout):
    assert set(layout) >= {"configById", "layout", "globalVariables", "userNodes",
                           "playbackConfig"}
    panels = _leaves(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    for panel in panels:
        assert re.fullmatch(r"[A-Za-z0-9]+![A-Za-z0-9]+", panel), panel
        assert panel.split("!")[0] in PANEL_TYPES, panel


def test_3d_panel_draws_the_recorded_robot(layout):
    (panel,) = [c for pid, c in layout["configById"].items() if pid.startswith("3D!")]
    urdf = [layer for layer in panel["layers"].values() if layer["layerId"] == "foxglove.Urdf"]
    assert len(urdf) == 1
    assert urdf[0]["sourceType"] == "topic"
    assert urdf[0]["topic"] == link_frames.DESCRIPTION_TOPIC
    assert set(panel["topics"]) <= RECORDED


def test_plots_read_recorded_topics(layout):
    plots = [c for pid, c in layout["configById"].items() if pid.startswith("Plot!")]
    topics = {p["value"].split(".")[0] for plot in plots for p in plot["paths"]}
    assert "/joint_states" in topics
    assert topics <= RECORDED
