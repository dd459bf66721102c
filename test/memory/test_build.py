"""The ``memory`` tool: a small cell of the paper's arm built, resumed, listed, inspected,
exported, drawn and pruned; bad cell files named.

The build runs on the batch machinery's local pool (one worker process), as a user's
``ros2 run tocontrol_ros memory build`` does; its motions are checked against the store.
"""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tocontrol_ros.batch.tasks import TaskFileError
from tocontrol_ros.core.memory.codec import decode_sample
from tocontrol_ros.core.memory.store import MotionStore
from tocontrol_ros.memory import cli
from tocontrol_ros.memory.cell import load_cell

REPO = Path(__file__).resolve().parents[2]
URDF = REPO / "config" / "galicki_3r.urdf"
#: A handful of motions: 2 starts x 2 targets, a small search (the format is under test).
CELL = {"robot": {"urdf": str(URDF)}, "k": 4, "reserve": 0.0,
        "solver": {"starts": 2, "candidates": 1, "time_limit": 60.0},
        "starts": {"stations": {"feeder": {"point": [1.0, 1.0]},
                                "home": {"q": [0.0, 1.5, 1.5]}}},
        "targets": {"points": [[2.2, 1.5], [2.0, 1.8]]}}


def write_cell(path: Path, **changes) -> Path:
    doc = {**CELL, **changes}
    path.write_text(yaml.safe_dump(doc))
    return path


def run(*argv) -> tuple[int, str]:
    err = io.StringIO()
    args = cli.build_parser().parse_args([str(a) for a in argv])
    return cli.run(args, err), err.getvalue()


def test_a_cell_builds_resumes_and_the_tools_read_it(tmp_path, capsys):
    cell = write_cell(tmp_path / "cell.yaml")
    memory = tmp_path / "cell.sqlite"
    code, err = run("build", cell, memory, "-j", "1", "--limit", "3")
    assert code == 0, err
    assert "4 tasks, 0 done already" in err and "1 tasks left" in err
    code, err = run("build", cell, memory, "-j", "1")
    assert code == 0, err
    assert "3 done already" in err and "1 to plan" in err
    assert "4 motions in" in err
    code, err = run("build", cell, memory, "-j", "1")
    assert code == 0 and "0 to plan" in err, err
    with MotionStore(memory) as store:
        rows = store.summary()
        tasks = store.tasks()
        entries = [store.get(r["id"]) for r in rows]
    assert len(rows) == 4 and all(t["status"] == "SUCCESS" for t in tasks.values())
    for e in entries:
        s = decode_sample(e.trajectory)
        assert s["t"][-1] == pytest.approx(e.T)
        assert e.certificate["passed"] is True and e.source == "build"
    starts = {e.request.start_kind for e in entries}
    assert starts == {"point", "state"}

    capsys.readouterr()
    assert run("list", memory)[0] == 0
    listed = capsys.readouterr().out
    assert "4 motions" in listed and listed.count("build") == 4
    assert run("inspect", memory)[0] == 0
    text = capsys.readouterr().out
    assert "4 motions" in text and "robot_hash" in text and "SUCCESS" in text
    assert run("inspect", memory, rows[0]["id"])[0] == 0
    assert "certificate: certified" in capsys.readouterr().out

    out = tmp_path / "motions.mcap"
    assert run("export", memory, out)[0] == 0
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        topics = sorted(ch.topic for ch in make_reader(f).get_summary().channels.values())
    assert topics == [f"/library/memory_{r['id']:05d}" for r in rows]

    png = tmp_path / "coverage.png"
    assert run("figure", memory, png)[0] == 0
    assert png.read_bytes()[:4] == b"\x89PNG"

    assert run("prune", memory, "--ids", rows[0]["id"])[0] == 0
    with MotionStore(memory) as store:
        assert store.count() == 3


@pytest.mark.parametrize("changes, match", [
    ({"robot": {"urdf": "nowhere.urdf"}}, "robot.urdf: no such file"),
    ({"robot": {"urdf": "example-robot-data:nosuchrobot"}}, "nosuchrobot"),
    ({"k": "four"}, "k: must be a finite number"),
    ({"targets": {"boxes": [{"lower": [1, 1], "upper": [0, 2], "spacing": 0.1}]}},
     "upper must be >= lower"),
    ({"targets": {"points": [[9.0, 0.0]]}}, "not reachable"),
    ({"starts": {"stations": {"a": {"q": [0.0, float("nan"), 0.0]}}}}, "finite number"),
    ({"solver": {"starts": 0}}, "solver"),
    ({"colour": "red"}, r"unknown key\(s\) \['colour'\]"),
])
def test_bad_cell_files_name_the_field(tmp_path, changes, match):
    cell = write_cell(tmp_path / "cell.yaml", **changes)
    with pytest.raises(TaskFileError, match=match):
        load_cell(cell)
    code, err = run("build", cell, tmp_path / "m.sqlite")
    assert code == 2 and "memory:" in err


def test_a_target_box_is_a_grid_that_holds_its_corners(tmp_path):
    cell = load_cell(write_cell(tmp_path / "cell.yaml", targets={"boxes": [
        {"lower": [1.5, 1.0], "upper": [2.0, 1.3], "spacing": 0.25}]}))
    targets = {t.target[1] for t in cell.tasks if t.start_name == "feeder"}
    assert len(targets) == 3 * 3
    assert (1.5, 1.0) in targets and (2.0, 1.3) in targets


def test_a_memory_of_another_robot_is_not_built_over(tmp_path):
    memory = tmp_path / "m.sqlite"
    code, err = run("build", write_cell(tmp_path / "a.yaml"), memory, "-j", "1", "--limit",
                    "1")
    assert code == 0, err
    code, err = run("build", write_cell(tmp_path / "b.yaml", k=8), memory, "-j", "1")
    assert code == 2 and "made for another options" in err


def test_the_executable_answers_help():
    out = subprocess.run([sys.executable, "-m", "tocontrol_ros.memory", "--help"],
                         capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0 and "build" in out.stdout and "prune" in out.stdout
